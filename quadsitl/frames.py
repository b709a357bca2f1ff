"""Frame and unit conversions, in one place (DESIGN.md §2).

Conventions: local NED, body FRD, ZYX Euler angles (roll φ, pitch θ, yaw ψ), radians, SI units.
Quaternions are [w, x, y, z] and rotate FRD vectors into NED, as MAVLink's ``q`` fields do.
"""

from __future__ import annotations

import math

TWO_PI = 2.0 * math.pi


def wrap_pi(angle: float) -> float:
    """Wrap an angle [rad] into [−π, π)."""
    return (angle + math.pi) % TWO_PI - math.pi


def euler_rates_to_body_rates(
    roll: float, pitch: float, roll_dot: float, pitch_dot: float, yaw_dot: float
) -> tuple[float, float, float]:
    """Paper eq (1): Euler-angle rates (φ̇, θ̇, ψ̇) → body rates (p, q, r), FRD, rad/s."""
    sr, cr = math.sin(roll), math.cos(roll)
    sp, cp = math.sin(pitch), math.cos(pitch)
    p = roll_dot - sp * yaw_dot
    q = cr * pitch_dot + sr * cp * yaw_dot
    r = -sr * pitch_dot + cr * cp * yaw_dot
    return p, q, r


def body_rates_to_euler_rates(roll: float, pitch: float, p: float, q: float, r: float) -> tuple[float, float, float]:
    """Inverse of paper eq (1): body rates (p, q, r) → Euler-angle rates (φ̇, θ̇, ψ̇).

    Singular at pitch = ±π/2 (gimbal lock), which the paper's angle ranges exclude.
    """
    sr, cr = math.sin(roll), math.cos(roll)
    cp = math.cos(pitch)
    tp = math.tan(pitch)
    roll_dot = p + sr * tp * q + cr * tp * r
    pitch_dot = cr * q - sr * r
    yaw_dot = (sr * q + cr * r) / cp
    return roll_dot, pitch_dot, yaw_dot


def euler_to_quaternion(roll: float, pitch: float, yaw: float) -> tuple[float, float, float, float]:
    """ZYX Euler angles → unit quaternion [w, x, y, z] (FRD → NED)."""
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    return (
        cr * cp * cy + sr * sp * sy,
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
    )


def quaternion_to_euler(w: float, x: float, y: float, z: float) -> tuple[float, float, float]:
    """Unit quaternion [w, x, y, z] (FRD → NED) → ZYX Euler angles (roll, pitch, yaw) [rad]."""
    roll = math.atan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
    sinp = 2.0 * (w * y - z * x)
    pitch = math.asin(max(-1.0, min(1.0, sinp)))
    yaw = math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    return roll, pitch, yaw
