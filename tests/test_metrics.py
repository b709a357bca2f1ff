"""Step metrics against a first-order response with known answers."""

import math

import numpy as np
import pytest

from groundstation.metrics import step_metrics


def test_first_order_step():
    tau = 0.2
    t = np.arange(0, 3, 1e-4)
    y = 2.0 * (1 - np.exp(-t / tau))
    m = step_metrics(t, y, np.full_like(t, 2.0), np.ones_like(t) * -3.0)
    assert m["rise_time"] == pytest.approx(tau * math.log(9), abs=2e-4)
    assert m["settling_time"] == pytest.approx(tau * math.log(50), abs=2e-4)
    assert m["overshoot_pct"] == 0.0
    assert m["peak_abs_u"] == 3.0
    assert m["steady_state_error"] == pytest.approx(2.0 * math.exp(-t[-1] / tau))


def test_overshoot_and_never_settling():
    t = np.linspace(0, 1, 1001)
    y = 1 - np.exp(-5 * t) * np.cos(20 * t)
    m = step_metrics(t, y, np.ones_like(t), np.zeros_like(t))
    assert m["overshoot_pct"] == pytest.approx(100 * (y.max() - 1), rel=1e-9) and m["overshoot_pct"] > 10
    m = step_metrics(t, 0.5 * t, np.ones_like(t), np.zeros_like(t))
    assert m["settling_time"] is None and m["rise_time"] is None


def test_position_metrics_count_only_the_samples_whose_position_is_controlled():
    from groundstation.metrics import format_position_table, position_metrics

    n = 1000
    t = np.arange(n) * 0.01
    x_ref, y_ref = np.cos(t), np.sin(t)
    x, y = x_ref + 0.3, y_ref - 0.4  # 0.5 m off everywhere...
    x[500:510] += 0.6 * np.linspace(0, 1, 10)  # ...up to |(0.9, −0.4)| = 0.985 m at sample 509
    altitude_ref = np.full(n, 5.0)
    altitude = altitude_ref - 0.2 * np.sin(2 * np.pi * np.arange(n) / 100)  # RMS 0.2/√2 over whole periods
    x_ref[:100], y_ref[:100] = np.nan, np.nan  # not controlled (an attitude setpoint): left out...
    x[:100], altitude[:100] = 1e3, -1e3  # ...however far off
    m = position_metrics(x, y, x_ref, y_ref, altitude, altitude_ref)
    assert m["samples"] == 900
    assert m["horizontal_max"] == pytest.approx(math.hypot(0.9, 0.4))
    e = np.full(900, 0.5)
    e[400:410] = np.hypot(0.3 + 0.6 * np.linspace(0, 1, 10), 0.4)
    assert m["horizontal_rms"] == pytest.approx(math.sqrt(np.mean(e**2)))
    assert m["altitude_rms"] == pytest.approx(0.2 / math.sqrt(2))
    table = format_position_table({"backstepping": m, "pd": position_metrics(x, y, x_ref * np.nan, y_ref,
                                                                             altitude, altitude_ref)})  # fmt: skip
    lines = table.splitlines()
    assert "horizontal RMS [m]" in lines[0] and "horizontal max [m]" in lines[0] and "altitude RMS [m]" in lines[0]
    assert lines[2].split() == ["backstepping", "900", f"{m['horizontal_rms']:.3f}", "0.985", "0.141"]
    assert lines[3].split() == ["pd", "0", "—", "—", "—"]  # no controlled sample: no numbers
