"""Fixed-step integrators of the rigid-body model (:func:`sitl.dynamics.derivatives`), inputs, wind and
external force held over the step (zero-order hold): ``euler`` (the paper's forward Euler, eq (9)) and ``rk4``.
Compiled (:mod:`quadsitl.jit`); states are 12-tuples."""

from __future__ import annotations

import numpy as np

from quadsitl.jit import jit
from sitl.dynamics import Disturbance, State, derivatives

EULER, RK4 = 0, 1
INTEGRATORS = {"euler": EULER, "rk4": RK4}
"""Integrator names (presets, ``--integrator``) → the code :func:`integrate` takes."""


@jit(inline=True)
def add_scaled(s: State, h: float, d: State) -> State:
    """s + h·d, element by element."""
    return (s[0] + h * d[0], s[1] + h * d[1], s[2] + h * d[2], s[3] + h * d[3], s[4] + h * d[4], s[5] + h * d[5],
            s[6] + h * d[6], s[7] + h * d[7], s[8] + h * d[8], s[9] + h * d[9], s[10] + h * d[10],
            s[11] + h * d[11])  # fmt: skip


@jit(inline=True)
def euler(s: State, u: tuple[float, float, float, float], omega_r: float, v: np.ndarray, d: Disturbance,
          h: float) -> State:  # fmt: skip
    """Forward Euler, paper eq (9): s⁺ = s + h·f(s)."""
    return add_scaled(s, h, derivatives(s, u, omega_r, v, d))


@jit(inline=True)
def rk4(s: State, u: tuple[float, float, float, float], omega_r: float, v: np.ndarray, d: Disturbance,
        h: float) -> State:  # fmt: skip
    """Classic fourth-order Runge–Kutta."""
    k1 = derivatives(s, u, omega_r, v, d)
    k2 = derivatives(add_scaled(s, 0.5 * h, k1), u, omega_r, v, d)
    k3 = derivatives(add_scaled(s, 0.5 * h, k2), u, omega_r, v, d)
    k4 = derivatives(add_scaled(s, h, k3), u, omega_r, v, d)
    h6 = h / 6.0
    return (s[0] + h6 * (k1[0] + 2.0 * k2[0] + 2.0 * k3[0] + k4[0]),
            s[1] + h6 * (k1[1] + 2.0 * k2[1] + 2.0 * k3[1] + k4[1]),
            s[2] + h6 * (k1[2] + 2.0 * k2[2] + 2.0 * k3[2] + k4[2]),
            s[3] + h6 * (k1[3] + 2.0 * k2[3] + 2.0 * k3[3] + k4[3]),
            s[4] + h6 * (k1[4] + 2.0 * k2[4] + 2.0 * k3[4] + k4[4]),
            s[5] + h6 * (k1[5] + 2.0 * k2[5] + 2.0 * k3[5] + k4[5]),
            s[6] + h6 * (k1[6] + 2.0 * k2[6] + 2.0 * k3[6] + k4[6]),
            s[7] + h6 * (k1[7] + 2.0 * k2[7] + 2.0 * k3[7] + k4[7]),
            s[8] + h6 * (k1[8] + 2.0 * k2[8] + 2.0 * k3[8] + k4[8]),
            s[9] + h6 * (k1[9] + 2.0 * k2[9] + 2.0 * k3[9] + k4[9]),
            s[10] + h6 * (k1[10] + 2.0 * k2[10] + 2.0 * k3[10] + k4[10]),
            s[11] + h6 * (k1[11] + 2.0 * k2[11] + 2.0 * k3[11] + k4[11]))  # fmt: skip


@jit(inline=True)
def integrate(method: int, s: State, u: tuple[float, float, float, float], omega_r: float, v: np.ndarray,
              d: Disturbance, h: float) -> State:  # fmt: skip
    """One step of ``method`` (EULER or RK4), the inputs, Ωr and the disturbance ``d`` held over it."""
    if method == RK4:
        return rk4(s, u, omega_r, v, d, h)
    return euler(s, u, omega_r, v, d, h)
