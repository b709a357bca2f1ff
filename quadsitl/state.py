"""State and reference types shared by the plant, the controllers and the loggers.

Frames and units (DESIGN.md §2): local frame NED, body frame FRD, ZYX Euler angles, SI units,
radians. The model's angular state is the *Euler-angle rates* (φ̇, θ̇, ψ̇) as in paper eqs (5)–(7);
body rates (p, q, r) exist only on the wire and in logs (see :mod:`quadsitl.frames`).
"""

from __future__ import annotations

from typing import NamedTuple


class VehicleState(NamedTuple):
    """Rigid-body state of the quadrotor.

    x, y, z: position in NED [m] (z down; altitude h = −z).
    vx, vy, vz: velocity in NED [m/s].
    roll, pitch, yaw: ZYX Euler angles φ, θ, ψ [rad].
    roll_dot, pitch_dot, yaw_dot: Euler-angle rates φ̇, θ̇, ψ̇ [rad/s] (not body rates).
    """

    x: float = 0.0
    y: float = 0.0
    z: float = 0.0
    vx: float = 0.0
    vy: float = 0.0
    vz: float = 0.0
    roll: float = 0.0
    pitch: float = 0.0
    yaw: float = 0.0
    roll_dot: float = 0.0
    pitch_dot: float = 0.0
    yaw_dot: float = 0.0

    @property
    def altitude(self) -> float:
        """Height above the ground plane [m], the paper's x1 (= −z_NED)."""
        return -self.z

    @property
    def climb_rate(self) -> float:
        """Vertical speed upwards [m/s], the paper's x2 (= −vz_NED)."""
        return -self.vz


class Reference(NamedTuple):
    """Set-points of the four controlled outputs: altitude [m, up] and roll, pitch, yaw [rad]."""

    altitude: float = 0.0
    roll: float = 0.0
    pitch: float = 0.0
    yaw: float = 0.0


class Inputs(NamedTuple):
    """The paper's virtual inputs: u1 collective thrust [N] along −z_body; u2, u3 roll and pitch
    inputs [N] (torque = l·u); u4 yaw torque [N·m]. See paper eq (8)."""

    u1: float = 0.0
    u2: float = 0.0
    u3: float = 0.0
    u4: float = 0.0
