"""The horizontal position and velocity loop around the paper's attitude loops (docs/position.md, eqs (46)–(58)).

The paper controls altitude and attitude; the horizontal motion follows from eqs (2)–(3),

    ẍ = −(cφ·sθ·cψ + sφ·sψ)·u1/m − K1·ẋ/m        ÿ = −(cφ·sθ·sψ − sφ·cψ)·u1/m − K2·ẏ/m      (NED).

The loop here is designed in the paper's discrete backstepping style with states x9 = x, x10 = ẋ, x11 = y,
x12 = ẏ (local NED [m], [m/s]) and poles λ9..λ12: the same errors (18)–(19), virtual controls (26) and (32)
as the altitude channel (:func:`autopilot.backstepping.virtual_velocity`), and an acceleration a = (a_x, a_y)
of the thrust chosen so that the Euler model gives e10⁺ = λ10·e10 (eq (52)):

    a_x = (x10d⁺ + λ10·e10 − (1 − T·K1/m)·x10)/T                                                    (52)

That acceleration, with the upward acceleration a_v the altitude channel asks of the thrust, is a thrust
direction; eqs (2)–(3) inverted for the measured yaw ψ give the roll and pitch references (eq (55)):

    a_f = cψ·a_x + sψ·a_y,  a_r = −sψ·a_x + cψ·a_y,  θ_d = atan2(−a_f, a_v),  φ_d = atan2(a_r·cθ_d, a_v)

The horizontal virtual velocity is bounded by MPC_XY_VEL_MAX and the tilt of the thrust by MPC_TILTMAX_AIR
(54); the integrator (an anti-windup one: it holds while the tilt limit acts, and
|κ·ζ| ≤ INT_LIM) removes the offset a constant horizontal force leaves (eqs (57)–(59)).

:func:`horizontal` is compiled (:mod:`quadsitl.jit`), pure, and shared by both inner controllers.
"""

from __future__ import annotations

import math

import numpy as np

from autopilot.backstepping import bounded_integral, integral_gain, virtual_velocity
from autopilot.control_params import (
    ACCELERATION,
    INT_LIM,
    KI_XY,
    PERIOD,
    POLES_XY,
    POSITION,
    TAN_TILT_AIR,
    VELOCITY,
    XY_VEL_MAX,
)
from quadsitl.jit import jit
from quadsitl.param_arrays import K1, K2, MASS


@jit
def channel_mode(position: float, velocity: float) -> int:
    """What a channel's reference controls: POSITION when a position is given, VELOCITY when only a velocity,
    ACCELERATION otherwise (NaN marks a field that is not given)."""
    if not math.isnan(position):
        return POSITION
    if not math.isnan(velocity):
        return VELOCITY
    return ACCELERATION


@jit
def controls_horizontal(sp: tuple[float, float, float, float, float, float]) -> bool:
    """Whether a reference (x, y, vx, vy, ax, ay; NaN: not given) controls the horizontal motion at all."""
    for value in sp:  # noqa: SIM110 (a loop numba compiles)
        if not math.isnan(value):
            return True
    return False


@jit
def or_zero(value: float) -> float:
    return 0.0 if math.isnan(value) else value


@jit
def scale_to(ax: float, ay: float, limit: float) -> tuple[float, float, bool]:
    """(ax, ay) scaled down to a norm of at most ``limit`` (≥ 0), and whether it was."""
    n = math.sqrt(ax * ax + ay * ay)
    if n <= limit:
        return ax, ay, False
    s = limit / n
    return ax * s, ay * s, True


@jit
def attitude_for(ax: float, ay: float, a_v: float, yaw: float) -> tuple[float, float]:
    """(roll, pitch) [rad] that point the thrust along the acceleration (a_x, a_y) north/east and a_v up
    [m/s²] at heading ``yaw`` [rad]: eqs (2)–(3) inverted (55). With a_v ≤ 0 the thrust cannot tilt usefully:
    level."""
    if a_v <= 0.0:
        return 0.0, 0.0
    cy, sy = math.cos(yaw), math.sin(yaw)
    a_f = cy * ax + sy * ay  # forward, in the heading frame
    a_r = -sy * ax + cy * ay  # right
    pitch = math.atan2(-a_f, a_v)
    roll = math.atan2(a_r * math.cos(pitch), a_v)
    return roll, pitch


@jit
def horizontal_acceleration(
    s: tuple[float, ...], sp: tuple[float, float, float, float, float, float], zeta_x: float, zeta_y: float,
    a_v: float, v: np.ndarray, c: np.ndarray,
) -> tuple[float, float, tuple[float, float, float, float], float, float]:  # fmt: skip
    """The horizontal loop's output for the state ``s`` (the 12 VehicleState fields), the reference ``sp`` (x, y
    [m], vx, vy [m/s], ax, ay [m/s²], NED; NaN: not given), the integrator states and the upward acceleration
    ``a_v`` [m/s²] of the thrust: the thrust's horizontal acceleration (a_x, a_y) [m/s², NED] within the tilt
    limit, (e9, e10, e11, e12), and the next integrator states ζx⁺, ζy⁺."""
    T = c[PERIOD]
    l9, l10, l11, l12 = c[POLES_XY], c[POLES_XY + 1], c[POLES_XY + 2], c[POLES_XY + 3]
    m = v[MASS]
    x9, x10, x11, x12 = s[0], s[3], s[1], s[4]
    mode_x, mode_y = channel_mode(sp[0], sp[2]), channel_mode(sp[1], sp[3])
    e9 = x9 - sp[0] if mode_x == POSITION else 0.0  # (46)
    e11 = x11 - sp[1] if mode_y == POSITION else 0.0
    kappa_x, kappa_y = integral_gain(c[KI_XY], l9, T), integral_gain(c[KI_XY], l11, T)
    vx_d, vx_next, zx = virtual_velocity(e9, x10, or_zero(sp[2]), or_zero(sp[4]), zeta_x, kappa_x, l9, T, mode_x)
    vy_d, vy_next, zy = virtual_velocity(e11, x12, or_zero(sp[3]), or_zero(sp[5]), zeta_y, kappa_y, l11, T, mode_y)
    # (54): the virtual velocity within MPC_XY_VEL_MAX (not where the reference sets only an acceleration).
    if mode_x != ACCELERATION or mode_y != ACCELERATION:
        vx_d, vy_d, _ = scale_to(vx_d, vy_d, c[XY_VEL_MAX])
        vx_next, vy_next, _ = scale_to(vx_next, vy_next, c[XY_VEL_MAX])
    e10, e12 = x10 - vx_d, x12 - vy_d  # (47)
    # (52): the thrust's horizontal acceleration that makes e10⁺ = λ10·e10 and e12⁺ = λ12·e12.
    ax = (vx_next + l10 * e10 - (1.0 - T * v[K1] / m) * x10) / T
    ay = (vy_next + l12 * e12 - (1.0 - T * v[K2] / m) * x12) / T
    # (54): the tilt of the thrust within MPC_TILTMAX_AIR; while it limits, the integrators hold (anti-windup).
    ax, ay, limited = scale_to(ax, ay, max(a_v, 0.0) * c[TAN_TILT_AIR])
    if limited:
        zx, zy = zeta_x, zeta_y
    zx, zy = bounded_integral(zx, kappa_x, c[INT_LIM]), bounded_integral(zy, kappa_y, c[INT_LIM])
    return ax, ay, (e9, e10, e11, e12), zx, zy


@jit
def horizontal(
    s: tuple[float, ...], sp: tuple[float, float, float, float, float, float], zeta_x: float, zeta_y: float,
    a_v: float, v: np.ndarray, c: np.ndarray,
) -> tuple[float, float, tuple[float, float, float, float], float, float]:  # fmt: skip
    """One step of the horizontal loop (:func:`horizontal_acceleration`), turned into attitude (55): (roll_ref,
    pitch_ref [rad], (e9, e10, e11, e12), ζx⁺, ζy⁺)."""
    ax, ay, errors, zx, zy = horizontal_acceleration(s, sp, zeta_x, zeta_y, a_v, v, c)
    roll, pitch = attitude_for(ax, ay, a_v, s[8])
    return roll, pitch, errors, zx, zy
