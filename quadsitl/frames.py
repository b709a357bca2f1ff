"""Frame and unit conversions, in one place (DESIGN.md §2).

Conventions: local NED, body FRD, ZYX Euler angles (roll φ, pitch θ, yaw ψ), radians, SI units.
Quaternions are [w, x, y, z] and rotate FRD vectors into NED, as MAVLink's ``q`` fields do.

The per-tick conversions are compiled (:mod:`quadsitl.jit`); call them with floats.
"""

from __future__ import annotations

import math

from quadsitl.jit import jit

TWO_PI = 2.0 * math.pi


@jit(inline=True)
def wrap_pi(angle: float) -> float:
    """Wrap an angle [rad] into [−π, π)."""
    return (angle + math.pi) % TWO_PI - math.pi


@jit(inline=True)
def altitude(s: tuple) -> float:
    """Height above the ground plane [m] of a state in VehicleState order: h = −z_NED (the paper's x1)."""
    return -s[2]


@jit(inline=True)
def climb_rate(s: tuple) -> float:
    """Vertical speed upwards [m/s] of a state in VehicleState order: ḣ = −vz_NED (the paper's x2)."""
    return -s[5]


@jit
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


@jit
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


@jit
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


@jit
def quaternion_to_euler(w: float, x: float, y: float, z: float) -> tuple[float, float, float]:
    """Unit quaternion [w, x, y, z] (FRD → NED) → ZYX Euler angles (roll, pitch, yaw) [rad]."""
    roll = math.atan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
    sinp = 2.0 * (w * y - z * x)
    pitch = math.asin(max(-1.0, min(1.0, sinp)))
    yaw = math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    return roll, pitch, yaw


# ---- local NED ↔ geodetic -------------------------------------------------------------------------

EARTH_RADIUS = 6371000.0  # [m], PX4's CONSTANTS_RADIUS_OF_EARTH


def ned_to_geodetic(north: float, east: float, lat0: float, lon0: float) -> tuple[float, float]:
    """Local north/east offsets [m] from a home at (lat0, lon0) [deg] → (lat, lon) [deg].

    The azimuthal equidistant projection on a sphere, as PX4's ``MapProjection::reproject``.
    """
    lat0_r, lon0_r = math.radians(lat0), math.radians(lon0)
    x, y = north / EARTH_RADIUS, east / EARTH_RADIUS
    c = math.hypot(x, y)
    if c == 0.0:
        return lat0, lon0
    sin_c, cos_c = math.sin(c), math.cos(c)
    sin_lat0, cos_lat0 = math.sin(lat0_r), math.cos(lat0_r)
    lat = math.asin(cos_c * sin_lat0 + x * sin_c * cos_lat0 / c)
    lon = lon0_r + math.atan2(y * sin_c, c * cos_lat0 * cos_c - x * sin_lat0 * sin_c)
    return math.degrees(lat), math.degrees(lon)


def geodetic_to_ned(lat: float, lon: float, lat0: float, lon0: float) -> tuple[float, float]:
    """Inverse of :func:`ned_to_geodetic`: (lat, lon) [deg] → north/east offsets [m] from (lat0, lon0)."""
    lat_r, lat0_r = math.radians(lat), math.radians(lat0)
    dlon = math.radians(lon - lon0)
    cos_c = math.sin(lat0_r) * math.sin(lat_r) + math.cos(lat0_r) * math.cos(lat_r) * math.cos(dlon)
    c = math.acos(max(-1.0, min(1.0, cos_c)))
    k = 1.0 if c == 0.0 else c / math.sin(c)
    north = k * (math.cos(lat0_r) * math.sin(lat_r) - math.sin(lat0_r) * math.cos(lat_r) * math.cos(dlon))
    east = k * math.cos(lat_r) * math.sin(dlon)
    return north * EARTH_RADIUS, east * EARTH_RADIUS
