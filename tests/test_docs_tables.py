"""Each preset key is declared once (quadsitl.keys, the fields of quadsitl.config): its check, its refusal, its
MAVLink parameter and the documentation's tables come from there."""

from __future__ import annotations

import dataclasses
import importlib.util
from pathlib import Path

import pytest

from quadsitl.config import SCHEMA, ConfigError, PositionParams, check_value

ROOT = Path(__file__).resolve().parent.parent
spec = importlib.util.spec_from_file_location("docs_tables", ROOT / "scripts" / "docs_tables.py")
docs_tables = importlib.util.module_from_spec(spec)
spec.loader.exec_module(docs_tables)


@pytest.mark.parametrize("page", docs_tables.pages(), ids=lambda p: p.name)
def test_the_documentations_tables_are_what_the_keys_say(page):
    text = page.read_text(encoding="utf-8")
    assert docs_tables.generated(text) == text, f"run python scripts/docs_tables.py ({page.name} is stale)"


def test_the_generated_tables_are_there():
    text = (ROOT / "docs" / "presets.md").read_text(encoding="utf-8")
    assert all(f"<!-- generated: {s} -->" in text for s in ("position", "sensors", "wind"))
    assert "| `xy_vel_max` | 12 | a number in (0, 100] m/s | horizontal speed limit (`MPC_XY_VEL_MAX`) |" in text


def test_one_declaration_makes_the_default_the_check_the_refusal_and_the_parameter():
    from autopilot.params import INDEX, SPECS

    key = SCHEMA["position"]["xy_vel_max"]
    field = next(f for f in dataclasses.fields(PositionParams) if f.name == "xy_vel_max")
    assert field.metadata["key"] is key and PositionParams().xy_vel_max == key.default == 12.0
    with pytest.raises(ConfigError, match=r"^position\.xy_vel_max = 0: expected a number in \(0, 100\] m/s$"):
        check_value("position.xy_vel_max", 0, key)
    param = SPECS[INDEX["MPC_XY_VEL_MAX"]]
    assert (param.lo, param.hi, param.lo_open, param.unit, param.doc) == (0, 100, True, "m/s", key.doc)
    tilt = SPECS[INDEX["MPC_TILTMAX_AIR"]]  # a parameter in its own unit, as PX4's
    assert (tilt.hi, tilt.unit) == (89, "deg")
