"""Discrete-time backstepping control of altitude and attitude: paper eqs (18)–(33), corrected.

State indices as in the paper (Section 3): x1 = h (altitude, up), x2 = ḣ, x3 = φ, x4 = φ̇, x5 = θ,
x6 = θ̇, x7 = ψ, x8 = ψ̇. For each channel (i = 1, 3, 5, 7) with poles λ_i, λ_{i+1}:

    e_i      = x_i − x_id                                   (18)
    x_(i+1)d = (−x_i + x_id⁺ + λ_i·e_i)/T                   (26)   paper: −k_i·e_i, i.e. λ_i = −k_i
    e_(i+1)  = x_(i+1) − x_(i+1)d                           (19)
    e_i⁺     = x_i + T·x_(i+1) − x_id⁺                      (20)
    x_(i+1)d⁺ = (−x_i⁺ + x_id⁺² + λ_i·e_i⁺)/T               (32)

and the input makes x_(i+1)⁺ = x_(i+1)d⁺ + λ_(i+1)·e_(i+1), so that on the Euler model

    e_i⁺ = λ_i·e_i + T·e_(i+1)       (27)        e_(i+1)⁺ = λ_(i+1)·e_(i+1)       (33)

References are constant between ticks (x_id⁺ = x_id⁺² = x_id, the paper's assumption), so with the
errors alone: x_(i+1)d = (λ_i − 1)/T·e_i and x_(i+1)d⁺ = (λ_i − 1)/T·e_i⁺. The yaw error is wrapped
to [−π, π) so that ψ = ±π is one heading.

Errata applied (DESIGN.md §3): (14) x5⁺ = x5 + T·x6; (17) and (25)/(31) use (1 − T·K6/Iz)·x8;
(28) −(1 − T·K3/m)·x2 + T·g; Ωr = Ω1 − Ω2 + Ω3 − Ω4; gains as poles λ_i = 1 − T·k_i.

:func:`backstepping` is the law, compiled (:mod:`quadsitl.jit`); :class:`BacksteppingController` keeps
its memory (the previous command, for Ωr) between calls.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np

from autopilot.control_params import (
    BACKSTEPPING,
    COS_MAX_TILT,
    INT_LIM,
    KI_ALT,
    MAX_TILT,
    MEM_ERRORS,
    MEM_OMEGA_R,
    MEM_SIZE,
    MEM_U,
    PERIOD,
    POLES,
    POSITION,
    THRUST_MAX,
    THRUST_MIN,
    VELOCITY,
    control_array,
)
from autopilot.gains import stability_interval
from autopilot.limits import clamp, tilt_factor
from quadsitl.compiled_frames import altitude, climb_rate, wrap_pi
from quadsitl.config import PositionParams, VehicleParams
from quadsitl.jit import jit, specialized
from quadsitl.mixer import inputs_to_forces, residual_rotor_speed
from quadsitl.param_arrays import ARM, D_OVER_B, IXX, IYY, IZZ, JR, K3, K4, K5, K6, MASS, B, G, vehicle_array
from quadsitl.state import Inputs, Reference, VehicleState

Errors = tuple[float, float, float, float, float, float, float, float]


@jit(inline=True)
def virtual_velocity(
    e_a: float, x_b: float, v_ff: float, a_ff: float, zeta: float, kappa: float, lam: float, T: float, mode: int
) -> tuple[float, float, float]:  # fmt: skip
    """One channel's virtual control x_(i+1)d, its next value x_(i+1)d⁺ and the next integrator state ζ⁺, for
    the position error ``e_a`` (18), the rate ``x_b``, feed-forward velocity ``v_ff`` and acceleration ``a_ff`` of
    the reference, the integrator state ``zeta`` [m·s] with gain ``kappa`` [1/s²] (0: the paper's law), and the
    channel's pole λ_i. With v_ff = a_ff = κ = 0 these are exactly the paper's (26) and (32)."""
    if mode == POSITION:
        zeta_next = zeta + T * e_a  # (48)
        x_bd = v_ff + (lam - 1.0) / T * e_a - kappa * zeta  # (26), (47)
        x_bd_next = v_ff + T * a_ff + (lam - 1.0) / T * (e_a + T * (x_b - v_ff)) - kappa * zeta_next  # (20), (32), (49)
    elif mode == VELOCITY:  # (50): the position is free, the rate follows the reference
        zeta_next, x_bd, x_bd_next = zeta, v_ff, v_ff + T * a_ff
    else:  # (50): acceleration only
        zeta_next, x_bd, x_bd_next = zeta, x_b, x_b + T * a_ff
    return x_bd, x_bd_next, zeta_next


@jit(inline=True)
def integral_gain(k_i: float, lam: float, T: float) -> float:
    """κ = k_I·k [1/s²] for the integral rate k_I [1/s] of a loop whose position pole is λ = 1 − T·k (51)."""
    return k_i * (1.0 - lam) / T


@jit(inline=True)
def bounded_integral(zeta: float, kappa: float, limit: float) -> float:
    """ζ with |κ·ζ| ≤ ``limit`` [m/s] (anti-windup); unchanged while κ = 0."""
    if kappa > 0.0:
        return clamp(zeta, -limit / kappa, limit / kappa)
    return zeta


@jit(inline=True)
def altitude_law(
    x1: float, x2: float, h_ref: float, climb_ff: float, climb_acc: float, zeta: float, mode: int, lo: float,
    hi: float, v: np.ndarray, c: np.ndarray,
) -> tuple[float, float, float, float]:  # fmt: skip
    """The altitude channel: (B, e1, e2, ζ⁺) with u1 = m/(T·cφcθ)·B (28), so B/T is the upward acceleration the
    thrust must give [m/s²]. ``lo``, ``hi`` bound the virtual climb rate [m/s] (±inf: the paper's law)."""
    T, l1, l2 = c[PERIOD], c[POLES], c[POLES + 1]
    m = v[MASS]
    e1 = x1 - h_ref if mode == POSITION else 0.0  # (18)
    kappa = integral_gain(c[KI_ALT], l1, T)
    x2d, x2d_next, zeta_next = virtual_velocity(e1, x2, climb_ff, climb_acc, zeta, kappa, l1, T, mode)
    zeta_next = bounded_integral(zeta_next, kappa, c[INT_LIM])
    e2 = x2 - clamp(x2d, lo, hi)  # (19)
    # (28), errata 4: −(1 − T·K3/m)·x2 + T·g; the paper's −k2·e2 is +λ2·e2.
    b = -(1.0 - T * v[K3] / m) * x2 + T * v[G] + clamp(x2d_next, lo, hi) + l2 * e2
    return b, e1, e2, zeta_next


@jit(inline=True)
def attitude_law(
    x: tuple[float, ...], roll_ref: float, pitch_ref: float, yaw_ref: float, yaw_rate_ff: float, yaw_mode: int,
    last: tuple[float, float, float, float], v: np.ndarray, c: np.ndarray,
) -> tuple[float, float, float, tuple[float, float, float, float, float, float], float]:  # fmt: skip
    """The roll, pitch and yaw channels: (u2, u3, u4, e3..e8, the Ωr assumed). ``last`` is the previous command
    (u1..u4), whose Ωr the step assumes: the current command's is not known before it is computed."""
    T = c[PERIOD]
    l3, l4, l5, l6 = c[POLES + 2], c[POLES + 3], c[POLES + 4], c[POLES + 5]
    l7, l8 = c[POLES + 6], c[POLES + 7]
    max_tilt = c[MAX_TILT]
    ix, iy, iz, arm, jr = v[IXX], v[IYY], v[IZZ], v[ARM], v[JR]
    k4, k5, k6 = v[K4], v[K5], v[K6]
    x3, x4, x5, x6, x7, x8 = x[6], x[9], x[7], x[10], x[8], x[11]
    # Ωr from the previous command (eq (8) inverse, Ω = sign(F)·sqrt(|F|/b)).
    omega_r = residual_rotor_speed(inputs_to_forces(last, v[D_OVER_B]), v[B])

    # (18): the roll and pitch references bounded (erratum 8), the yaw error wrapped.
    e3 = x3 - clamp(roll_ref, -max_tilt, max_tilt)
    e5 = x5 - clamp(pitch_ref, -max_tilt, max_tilt)
    e7 = wrap_pi(x7 - yaw_ref) if yaw_mode == POSITION else 0.0
    # (26) virtual controls, (19) rate errors, (20) predicted errors and (32) next virtual controls.
    x4d, x4d_next, _ = virtual_velocity(e3, x4, 0.0, 0.0, 0.0, 0.0, l3, T, POSITION)
    x6d, x6d_next, _ = virtual_velocity(e5, x6, 0.0, 0.0, 0.0, 0.0, l5, T, POSITION)
    x8d, x8d_next, _ = virtual_velocity(e7, x8, yaw_rate_ff, 0.0, 0.0, 0.0, l7, T, yaw_mode)
    e4, e6, e8 = x4 - x4d, x6 - x6d, x8 - x8d
    # (29)
    u2 = (
        ix
        / (T * arm)
        * (
            -(1.0 - T * k4 * arm / ix) * x4
            - T * x6 * x8 * (iy - iz) / ix
            - T * jr / ix * x6 * omega_r
            + x4d_next
            + l4 * e4
        )
    )
    # (30)
    u3 = (
        iy
        / (T * arm)
        * (
            -(1.0 - T * k5 * arm / iy) * x6
            - T * x4 * x8 * (iz - ix) / iy
            - T * jr / iy * x4 * omega_r
            + x6d_next
            + l6 * e6
        )
    )
    # (31), errata 3: (1 − T·K6/Iz), not (1 − T·K6/m).
    u4 = iz / T * (-(1.0 - T * k6 / iz) * x8 - T * x4 * x6 * (ix - iy) / iz + x8d_next + l8 * e8)
    return u2, u3, u4, (e3, e4, e5, e6, e7, e8), omega_r


@jit(inline=True)
def thrust(b: float, roll: float, pitch: float, v: np.ndarray, c: np.ndarray) -> float:
    """u1 = m/(T·cφcθ)·B (28), cφcθ bounded below (erratum 8), clamped to the thrust bounds [N]."""
    cc = tilt_factor(roll, pitch, c[COS_MAX_TILT])
    return clamp(v[MASS] / (c[PERIOD] * cc) * b, c[THRUST_MIN], c[THRUST_MAX])


@jit(inline=True)
def backstepping(
    x: tuple[float, ...], ref: tuple[float, float, float, float], last: tuple[float, float, float, float],
    v: np.ndarray, c: np.ndarray,
) -> tuple[Inputs, Errors, float]:  # fmt: skip
    """One step of the paper's law for the state ``x`` (the 12 VehicleState fields) and the reference (altitude,
    roll, pitch, yaw), constant between ticks: (u1..u4, the errors e1..e8, the Ωr assumed). ``last`` is the
    previous command (u1..u4), whose Ωr the step assumes."""
    inf = math.inf
    b, e1, e2, _ = altitude_law(altitude(x), climb_rate(x), ref[0], 0.0, 0.0, 0.0, POSITION, -inf, inf, v, c)
    u1 = thrust(b, x[6], x[7], v, c)
    u2, u3, u4, (e3, e4, e5, e6, e7, e8), omega_r = attitude_law(x, ref[1], ref[2], ref[3], 0.0, POSITION, last,
                                                                  v, c)  # fmt: skip
    return Inputs(u1, u2, u3, u4), (e1, e2, e3, e4, e5, e6, e7, e8), omega_r


@jit
def step_arrays(x: np.ndarray, ref: np.ndarray, mem: np.ndarray, v: np.ndarray, c: np.ndarray) -> None:
    """:func:`backstepping` on arrays, in place: ``x`` (12) the state, ``ref`` (4) the reference, ``mem``
    (MEM_SIZE) the previous command on entry, then the new one with the errors and Ωr."""
    s = (x[0], x[1], x[2], x[3], x[4], x[5], x[6], x[7], x[8], x[9], x[10], x[11])
    last = (mem[MEM_U], mem[MEM_U + 1], mem[MEM_U + 2], mem[MEM_U + 3])
    u, errors, omega_r = backstepping(s, (ref[0], ref[1], ref[2], ref[3]), last, v, c)
    for i in range(4):
        mem[MEM_U + i] = u[i]
    for i in range(8):
        mem[MEM_ERRORS + i] = errors[i]
    mem[MEM_OMEGA_R] = omega_r


class BacksteppingController:
    """The paper's controller with the errata applied.

    ``poles`` are λ1..λ8 (use :func:`autopilot.gains.poles_from_rates` for rates k in 1/s). They are
    checked against conditions (41)–(44) on construction (:class:`autopilot.gains.GainError`).

    ``step`` returns (u1..u4): u1 [N], u2 and u3 [N] (torque/l), u4 [N·m]. After a step, ``errors``
    holds (e1..e8) and ``omega_r`` the Ωr [rad/s] the step assumed: the one the previous command makes
    (the current command is not known before it is computed).
    """

    kind = BACKSTEPPING
    plug = None  # a built-in: nothing plugged (autopilot.plugin)

    def __init__(
        self,
        vehicle: VehicleParams,
        period: float,
        poles: Sequence[float],
        max_tilt: float = math.radians(80.0),
        thrust_min: float = -math.inf,
        thrust_max: float = math.inf,
        kp: Sequence[float] = (0.0,) * 4,
        kd: Sequence[float] = (0.0,) * 4,
        position: PositionParams | None = None,
    ) -> None:
        self.vehicle = vehicle
        self.period = period
        self.poles = tuple(float(p) for p in poles)
        self.epsilon_interval = stability_interval(self.poles, period)
        self.v = vehicle_array(vehicle)
        self.c = control_array(self.poles, period, kp, kd, max_tilt, thrust_min, thrust_max, position)
        self.x, self.ref, self.mem = np.zeros(12), np.zeros(4), np.zeros(MEM_SIZE)
        self._step: Callable | None = None  # specialized at the first step (a process never: its tick is compiled)
        self.reset()

    @property
    def max_tilt(self) -> float:
        """The bound on the roll and pitch references [rad]."""
        return float(self.c[MAX_TILT])

    def reset(self) -> None:
        self.last = Inputs()
        self.omega_r = 0.0
        self.errors = (0.0,) * 8

    def step(self, state: VehicleState, reference: Reference) -> Inputs:
        self.x[:], self.ref[:], self.mem[MEM_U : MEM_U + 4] = state, reference, self.last
        if self._step is None:
            self._step = specialized(step_arrays, self.x, self.ref, self.mem, self.v, self.c)
        self._step(self.x, self.ref, self.mem, self.v, self.c)
        self.last = Inputs._make(self.mem[MEM_U : MEM_U + 4].tolist())
        self.errors = tuple(self.mem[MEM_ERRORS : MEM_ERRORS + 8].tolist())
        self.omega_r = float(self.mem[MEM_OMEGA_R])
        return self.last
