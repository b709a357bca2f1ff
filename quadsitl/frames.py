"""Frame and unit conversions, in one place (DESIGN.md §2).

Conventions: local NED, body FRD, ZYX Euler angles (roll φ, pitch θ, yaw ψ), radians, SI units.
Quaternions are [w, x, y, z] and rotate FRD vectors into NED, as MAVLink's ``q`` fields do.

Plain Python, importable without the compiler: the ground side's processes (the ground station, the dashboard, the
command line) call these as they are and start without loading numba (half a second each). Compiled code calls the
same functions compiled, from :mod:`quadsitl.compiled_frames`. So that one compiled version of each function is
possible, none of them calls another function of this module (numba looks a function's callees up in its own
module, where they are plain Python). Call them with floats.
"""

from __future__ import annotations

import math

TWO_PI = 2.0 * math.pi

# PX4 SITL's default home (Irchel Park, Zürich): where the local NED frame's origin is on the globe.
HOME_LAT = 47.397742  # [deg]
HOME_LON = 8.545594  # [deg]
HOME_ALT = 488.0  # [m] AMSL
PX4_HOME = (HOME_LAT, HOME_LON, HOME_ALT)
"""PX4 SITL's default home (Zürich): latitude, longitude [deg], altitude AMSL [m]. The autopilot's default origin
(``--home``) and a fleet's first vehicle's home."""


def wrap_pi(angle: float) -> float:
    """Wrap an angle [rad] into [−π, π): the angle itself when it is there already (exactly: the remainder's
    (angle + π) − π would round a small yaw error to a multiple of π's ulp, 4.4e-16 rad, and costs a floating-point
    remainder every tick)."""
    if -math.pi <= angle < math.pi:
        return angle
    return (angle + math.pi) % TWO_PI - math.pi


def altitude(s: tuple) -> float:
    """Height above the ground plane [m] of a state in VehicleState order: h = −z_NED (the paper's x1)."""
    return -s[2]


def climb_rate(s: tuple) -> float:
    """Vertical speed upwards [m/s] of a state in VehicleState order: ḣ = −vz_NED (the paper's x2)."""
    return -s[5]


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


# ---- local NED ↔ geodetic -------------------------------------------------------------------------

EARTH_RADIUS = 6371000.0  # [m], PX4's CONSTANTS_RADIUS_OF_EARTH


def ned_to_geodetic(north: float, east: float, lat0: float, lon0: float) -> tuple[float, float]:
    """Local north/east offsets [m] from a home at (lat0, lon0) [deg] → (lat, lon) [deg].

    The azimuthal equidistant projection on a sphere, as PX4's ``MapProjection::reproject``. The plant's GPS
    (:mod:`quadsitl.hil`, compiled) and the ground stations use this one function.
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


# ---- rotating vectors and composing rotations (the sensors and the estimator) ---------------------------


def body_to_ned(q: tuple, x: float, y: float, z: float) -> tuple[float, float, float]:
    """A vector in FRD body axes → NED, by the unit quaternion q = [w, x, y, z] (FRD → NED): v_n = R(q)·v_b."""
    w, a, b, c = q[0], q[1], q[2], q[3]
    return (
        (1.0 - 2.0 * (b * b + c * c)) * x + 2.0 * (a * b - w * c) * y + 2.0 * (a * c + w * b) * z,
        2.0 * (a * b + w * c) * x + (1.0 - 2.0 * (a * a + c * c)) * y + 2.0 * (b * c - w * a) * z,
        2.0 * (a * c - w * b) * x + 2.0 * (b * c + w * a) * y + (1.0 - 2.0 * (a * a + b * b)) * z,
    )


def ned_to_body(q: tuple, n: float, e: float, d: float) -> tuple[float, float, float]:
    """A vector in NED → FRD body axes, by the unit quaternion q (FRD → NED): v_b = R(q)ᵀ·v_n."""
    w, a, b, c = q[0], q[1], q[2], q[3]
    return (
        (1.0 - 2.0 * (b * b + c * c)) * n + 2.0 * (a * b + w * c) * e + 2.0 * (a * c - w * b) * d,
        2.0 * (a * b - w * c) * n + (1.0 - 2.0 * (a * a + c * c)) * e + 2.0 * (b * c + w * a) * d,
        2.0 * (a * c + w * b) * n + 2.0 * (b * c - w * a) * e + (1.0 - 2.0 * (a * a + b * b)) * d,
    )


def quaternion_multiply(p: tuple, q: tuple) -> tuple[float, float, float, float]:
    """The Hamilton product p ⊗ q of quaternions [w, x, y, z] (rotate by q, then by p)."""
    return (
        p[0] * q[0] - p[1] * q[1] - p[2] * q[2] - p[3] * q[3],
        p[0] * q[1] + p[1] * q[0] + p[2] * q[3] - p[3] * q[2],
        p[0] * q[2] - p[1] * q[3] + p[2] * q[0] + p[3] * q[1],
        p[0] * q[3] + p[1] * q[2] - p[2] * q[1] + p[3] * q[0],
    )


def rotation_vector_to_quaternion(x: float, y: float, z: float) -> tuple[float, float, float, float]:
    """The unit quaternion of a rotation by the angle |θ| [rad] about θ/|θ| (θ = (x, y, z)): Exp(θ)."""
    angle = math.sqrt(x * x + y * y + z * z)
    if angle < 1e-12:
        return (1.0, 0.5 * x, 0.5 * y, 0.5 * z)
    s = math.sin(0.5 * angle) / angle
    return (math.cos(0.5 * angle), s * x, s * y, s * z)


def normalize_quaternion(q: tuple) -> tuple[float, float, float, float]:
    """q / |q|, with the sign of w made non-negative (the same rotation)."""
    n = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    if q[0] < 0.0:
        n = -n
    return (q[0] / n, q[1] / n, q[2] / n, q[3] / n)
