"""An option several commands take is checked by one function (quadsitl.cli_util), wherever it is given: the same
range and the same words from `fly`, `up`, `replay`, the plant and the autopilot."""

from __future__ import annotations

import math

import pytest

from quadsitl.cli_util import UsageError, check_duration, check_speed, check_system_id


@pytest.mark.parametrize(
    ("check", "value", "message"),
    [
        (check_speed, -1.0, "--speed -1.0: expected a number in [0, 1000] (0 = as fast as possible)"),
        (check_speed, 1001.0, "--speed 1001.0: expected a number in [0, 1000] (0 = as fast as possible)"),
        (check_speed, math.nan, "--speed nan: expected a number in [0, 1000]"),
        (check_system_id, 0, "--system-id 0: expected an integer in 1..255"),
        (check_system_id, 256, "--system-id 256: expected an integer in 1..255"),
        (check_duration, -1.0, "--duration -1.0: expected a number in (0, 3600]"),
        (check_duration, 3601.0, "--duration 3601.0: expected a number in (0, 3600]"),
    ],
)
def test_a_value_out_of_range_is_refused_naming_the_option(check, value, message):
    with pytest.raises(UsageError) as e:
        check(value)
    assert str(e.value).startswith(message)


@pytest.mark.parametrize(
    ("check", "value"),
    [(check_speed, 0.0), (check_speed, 1000.0), (check_system_id, 1), (check_system_id, 255), (check_duration, None)],
)
def test_a_value_in_range_passes(check, value):
    check(value)


def test_no_command_checks_these_options_on_its_own():
    """grep: the ranges live in quadsitl.cli_util alone."""
    from pathlib import Path

    root = Path(__file__).resolve().parent.parent
    for path in [*root.glob("groundstation/**/*.py"), *root.glob("sitl/*.py"), *root.glob("autopilot/*.py")]:
        text = path.read_text(encoding="utf-8")
        assert 'check_range("--speed"' not in text and "expected a number in [0, 1000] (0 =" not in text, path
        assert 'check_range("--duration"' not in text and "system_id <= 255" not in text, path
