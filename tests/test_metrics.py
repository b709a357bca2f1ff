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
