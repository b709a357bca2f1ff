"""Motor models: commanded motor forces [N] → forces acting on the airframe [N].

``ideal`` (the paper's assumption): reversible, clamped to [−F_max, F_max], no lag.
``realistic``: clamped to [0, F_max] with an optional first-order lag (separate time constants for
spinning up and down, as PX4's Gazebo motor model has).

Compiled (:mod:`quadsitl.jit`); ``a`` is the preset's :func:`quadsitl.param_arrays.actuator_array`.
"""

from __future__ import annotations

import math

import numpy as np

from quadsitl.jit import jit
from quadsitl.mixer import Forces, clamp4
from quadsitl.param_arrays import F_MAX, F_MIN, TAU_DOWN, TAU_UP


@jit(inline=True)
def motor_lag(f0: float, target: float, h: float, tau_up: float, tau_down: float) -> tuple[float, float]:
    """One motor over h seconds towards ``target``: (force at the end, mean force over the interval).

    The exact solution of τ·Ḟ = F_cmd − F: F(t) = c + (F0 − c)·e^(−t/τ), whose mean over [0, h] is
    c + (F0 − c)·(τ/h)·(1 − e^(−h/τ)); τ = 0 is no lag.
    """
    tau = tau_up if target > f0 else tau_down
    if tau == 0.0:
        return target, target
    decay = math.exp(-h / tau)
    return target + (f0 - target) * decay, target + (f0 - target) * (tau / h) * (1.0 - decay)


@jit(inline=True)
def advance(motors: Forces, commanded: Forces, h: float, a: np.ndarray) -> tuple[Forces, Forces]:
    """Advance the four motors by h seconds under ``commanded`` (clamped to the motors' range): (the motor
    forces at the end, their means over the interval, which act on the airframe)."""
    c1, c2, c3, c4 = clamp4(commanded, a[F_MIN], a[F_MAX])
    up, down = a[TAU_UP], a[TAU_DOWN]
    if up == 0.0 and down == 0.0:
        return (c1, c2, c3, c4), (c1, c2, c3, c4)
    n1, m1 = motor_lag(motors[0], c1, h, up, down)
    n2, m2 = motor_lag(motors[1], c2, h, up, down)
    n3, m3 = motor_lag(motors[2], c3, h, up, down)
    n4, m4 = motor_lag(motors[3], c4, h, up, down)
    return (n1, n2, n3, n4), (m1, m2, m3, m4)
