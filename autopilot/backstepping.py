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
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from autopilot.gains import stability_interval
from autopilot.limits import clamp, limit_reference, tilt_factor
from quadsitl.config import VehicleParams
from quadsitl.frames import wrap_pi
from quadsitl.mixer import inputs_to_forces, residual_rotor_speed
from quadsitl.state import Inputs, Reference, VehicleState


class BacksteppingController:
    """The paper's controller with the errata applied.

    ``poles`` are λ1..λ8 (use :func:`autopilot.gains.poles_from_rates` for rates k in 1/s). They are
    checked against conditions (41)–(44) on construction (:class:`autopilot.gains.GainError`).

    ``step`` returns (u1..u4): u1 [N], u2 and u3 [N] (torque/l), u4 [N·m]. After a step, ``errors``
    holds (e1..e8) and ``omega_r`` the Ωr [rad/s] the step assumed: the one the previous command makes
    (the current command is not known before it is computed).
    """

    def __init__(
        self,
        vehicle: VehicleParams,
        period: float,
        poles: Sequence[float],
        max_tilt: float = math.radians(80.0),
        thrust_min: float = -math.inf,
        thrust_max: float = math.inf,
    ) -> None:
        self.vehicle = vehicle
        self.period = period
        self.poles = tuple(float(p) for p in poles)
        self.epsilon_interval = stability_interval(self.poles, period)
        self.max_tilt = max_tilt
        self.cos_max_tilt = math.cos(max_tilt)
        self.thrust_min, self.thrust_max = thrust_min, thrust_max
        self.reset()

    def reset(self) -> None:
        self.last = Inputs()
        self.omega_r = 0.0
        self.errors = (0.0,) * 8

    def step(self, state: VehicleState, reference: Reference) -> Inputs:
        v, T = self.vehicle, self.period
        l1, l2, l3, l4, l5, l6, l7, l8 = self.poles
        ref = limit_reference(reference, self.max_tilt)
        m, ix, iy, iz, arm, jr, g = v.mass, v.ixx, v.iyy, v.izz, v.arm_length, v.rotor_inertia, v.gravity
        k3, k4, k5, k6 = v.drag[2], v.drag[3], v.drag[4], v.drag[5]
        x1, x2 = state.altitude, state.climb_rate
        x3, x4, x5, x6, x7, x8 = (
            state.roll,
            state.roll_dot,
            state.pitch,
            state.pitch_dot,
            state.yaw,
            state.yaw_dot,
        )
        # Ωr from the previous command (eq (8) inverse, Ω = sign(F)·sqrt(|F|/b)).
        omega_r = residual_rotor_speed(inputs_to_forces(self.last, v.d_over_b), v.thrust_factor)

        # (18): position errors; the yaw error is wrapped.
        e1, e3, e5, e7 = x1 - ref.altitude, x3 - ref.roll, x5 - ref.pitch, wrap_pi(x7 - ref.yaw)
        # (26) virtual controls and (19) rate errors.
        e2 = x2 - (l1 - 1.0) / T * e1
        e4 = x4 - (l3 - 1.0) / T * e3
        e6 = x6 - (l5 - 1.0) / T * e5
        e8 = x8 - (l7 - 1.0) / T * e7
        # (20) predicted position errors and (32) next virtual controls x_(i+1)d⁺.
        x2d_next = (l1 - 1.0) / T * (e1 + T * x2)
        x4d_next = (l3 - 1.0) / T * (e3 + T * x4)
        x6d_next = (l5 - 1.0) / T * (e5 + T * x6)
        x8d_next = (l7 - 1.0) / T * (e7 + T * x8)

        # (28), errata 4: −(1 − T·K3/m)·x2 + T·g; the paper's −k2·e2 is +λ2·e2.
        c = tilt_factor(x3, x5, self.cos_max_tilt)
        u1 = m / (T * c) * (-(1.0 - T * k3 / m) * x2 + T * g + x2d_next + l2 * e2)
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

        out = Inputs(clamp(u1, self.thrust_min, self.thrust_max), u2, u3, u4)
        self.errors = (e1, e2, e3, e4, e5, e6, e7, e8)
        self.omega_r = omega_r
        self.last = out
        return out
