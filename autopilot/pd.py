"""The PD baseline the paper compares against (it gives no gains; DESIGN.md §3, erratum 9).

A conventional PD per channel with derivative on the measurement (no derivative kick), gravity
feed-forward and tilt compensation on thrust, and inputs scaled by the model's inertias so that each
linearised channel closes as ë + kd·ė + kp·e = 0:

    u1 = m·(g + kp_h·(h_r − h) − kd_h·ḣ) / (cφ·cθ)
    u2 = (Ix/l)·(kp_φ·(φ_r − φ) − kd_φ·φ̇)
    u3 = (Iy/l)·(kp_θ·(θ_r − θ) − kd_θ·θ̇)
    u4 = Iz·(kp_ψ·wrap(ψ_r − ψ) − kd_ψ·ψ̇)

Fair tuning: the shipped presets set kp = k_i·k_(i+1) and kd = k_i + k_(i+1), which puts the PD's
linearised poles at −k_i and −k_(i+1), where the backstepping puts its (continuous-time equivalent)
poles. What differs is structure, not bandwidth: the PD does not cancel drag, gyroscopic and
cross-coupling terms, and it does not anticipate the discrete step.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from autopilot.limits import clamp, limit_reference, tilt_factor
from quadsitl.config import VehicleParams
from quadsitl.frames import wrap_pi
from quadsitl.state import Inputs, Reference, VehicleState


class PDController:
    """PD baseline. ``kp`` [1/s²] and ``kd`` [1/s] per channel (altitude, roll, pitch, yaw)."""

    def __init__(
        self,
        vehicle: VehicleParams,
        kp: Sequence[float],
        kd: Sequence[float],
        max_tilt: float = math.radians(80.0),
        thrust_min: float = -math.inf,
        thrust_max: float = math.inf,
    ) -> None:
        self.vehicle = vehicle
        self.kp = tuple(kp)
        self.kd = tuple(kd)
        self.max_tilt = max_tilt
        self.cos_max_tilt = math.cos(max_tilt)
        self.thrust_min, self.thrust_max = thrust_min, thrust_max

    def reset(self) -> None:
        pass

    def step(self, state: VehicleState, reference: Reference) -> Inputs:
        v = self.vehicle
        kp, kd = self.kp, self.kd
        ref = limit_reference(reference, self.max_tilt)
        c = tilt_factor(state.roll, state.pitch, self.cos_max_tilt)
        u1 = v.mass * (v.gravity + kp[0] * (ref.altitude - state.altitude) - kd[0] * state.climb_rate) / c
        u2 = v.ixx / v.arm_length * (kp[1] * (ref.roll - state.roll) - kd[1] * state.roll_dot)
        u3 = v.iyy / v.arm_length * (kp[2] * (ref.pitch - state.pitch) - kd[2] * state.pitch_dot)
        u4 = v.izz * (kp[3] * wrap_pi(ref.yaw - state.yaw) - kd[3] * state.yaw_dot)
        return Inputs(clamp(u1, self.thrust_min, self.thrust_max), u2, u3, u4)
