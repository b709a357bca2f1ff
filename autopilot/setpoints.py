"""Offboard position targets and position commands as PX4 reads them: pure, no I/O.

``SET_POSITION_TARGET_LOCAL_NED`` and ``SET_POSITION_TARGET_GLOBAL_INT`` become the commander's three groups
(:meth:`autopilot.commander.Commander.on_position_setpoint`): horizontal (x, y, vx, vy, ax, ay, local NED),
vertical (altitude up, climb rate, its rate) and heading (yaw, yaw rate), NaN for a field the ``type_mask``
ignores, None for a group whose fields are all ignored. Frames:

- 1 LOCAL_NED: as sent (z down: altitude = −z).
- 8 BODY_NED: velocity and acceleration in the heading frame, rotated by the vehicle's yaw into NED; a
  position is refused (PX4 flies no body-frame positions).
- 5 GLOBAL_INT (altitude AMSL), 6 GLOBAL_RELATIVE_ALT_INT (above home), 11 GLOBAL_TERRAIN_ALT_INT (above the
  ground, which is flat at the local origin's altitude): latitude and longitude by PX4's map projection
  from the local origin (:func:`quadsitl.frames.geodetic_to_ned`).

Refused (:class:`SetpointError`), with a reason that names the field, the value and what is allowed (the
caller counts it and keeps the last valid setpoint): another frame; a field used but not finite; acceleration
with FORCE_SET (512, as PX4); an altitude outside [0, SP_ALT_MAX]; a position farther than GF_MAX_HOR_DIST
from home (when > 0); a horizontal speed above MPC_XY_VEL_MAX; a climb or descent rate above
MPC_Z_VEL_MAX_UP/_DN.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from quadsitl.compiled_frames import geodetic_to_ned
from quadsitl.config import PositionParams

LOCAL_NED, GLOBAL, GLOBAL_INT, GLOBAL_RELATIVE_ALT_INT, BODY_NED, GLOBAL_TERRAIN_ALT_INT = 1, 0, 5, 6, 8, 11
GLOBAL_RELATIVE_ALT, MISSION = 3, 2
LOCAL_FRAMES = (LOCAL_NED, BODY_NED)
GLOBAL_FRAMES = (GLOBAL_INT, GLOBAL_RELATIVE_ALT_INT, GLOBAL_TERRAIN_ALT_INT)
# type_mask bits (POSITION_TARGET_TYPEMASK)
IGNORE_X, IGNORE_Y, IGNORE_Z, IGNORE_VX, IGNORE_VY, IGNORE_VZ = 1, 2, 4, 8, 16, 32
IGNORE_AX, IGNORE_AY, IGNORE_AZ, FORCE_SET, IGNORE_YAW, IGNORE_YAW_RATE = 64, 128, 256, 512, 1024, 2048
INT32_MAX = 2**31 - 1  # COMMAND_INT's "no latitude/longitude"

Horizontal = tuple[float, float, float, float, float, float]
Vertical = tuple[float, float, float]
Heading = tuple[float, float]


@dataclass(frozen=True)
class Frame:
    """Where setpoints are measured from: the local origin (latitude, longitude [deg], altitude AMSL [m]), home
    (x, y NED [m], altitude above the origin [m]), the vehicle's yaw [rad] now, and the limits (SP_ALT_MAX,
    GF_MAX_HOR_DIST (0: none), MPC_XY_VEL_MAX, MPC_Z_VEL_MAX_UP, MPC_Z_VEL_MAX_DN, the lowest normalised thrust)."""

    origin: tuple[float, float, float]
    home: tuple[float, float, float] = (0.0, 0.0, 0.0)
    yaw: float = 0.0
    altitude_max: float = 1000.0
    max_distance: float = 0.0
    xy_vel_max: float = PositionParams.xy_vel_max  # [m/s] the preset keys' defaults (quadsitl.config)
    z_vel_up: float = PositionParams.z_vel_max_up  # [m/s]
    z_vel_dn: float = PositionParams.z_vel_max_dn  # [m/s]
    thrust_low: float = 0.0  # the lowest normalised collective thrust: −1 on reversible motors


class SetpointError(ValueError):
    """A setpoint or command we do not fly; the message says why: "<what> refused: <field or check> …"."""

    @property
    def kind(self) -> str:
        """The field or check that refused (the first word after "refused: "), to say each kind once a while."""
        return str(self).split("refused: ", 1)[-1].split(" ", 1)[0]


def _field(name: str, value: float, ignored: bool, bit: int) -> float:
    if ignored:
        return math.nan
    if not math.isfinite(value):
        raise SetpointError(
            f"Position setpoint refused: {name} = {value:g}: expected a finite number "
            f"(or ignore it: type_mask bit {bit})"
        )
    return float(value)


def local_altitude(frame: int, alt: float, origin_alt: float, home_alt: float) -> float:
    """An altitude [m] in MAVLink ``frame`` → altitude above the local ground (the origin's altitude): AMSL
    frames minus the origin's altitude, relative ones (and a mission item's frame 2) plus home's, terrain
    frames as they are (the ground is flat)."""
    if frame in (GLOBAL, GLOBAL_INT):
        return alt - origin_alt
    if frame in (GLOBAL_RELATIVE_ALT, GLOBAL_RELATIVE_ALT_INT, MISSION):
        return alt + home_alt
    return alt


def altitude_of(frame: int, alt: float, f: Frame) -> float:
    """A global frame's altitude [m] → altitude above the local ground (:func:`local_altitude`)."""
    return local_altitude(frame, alt, f.origin[2], f.home[2])


def check_position(x: float, y: float, altitude: float, f: Frame, what: str = "Position setpoint") -> None:
    """Refuse a position beyond SP_ALT_MAX or GF_MAX_HOR_DIST (NaN: a coordinate not given)."""
    if not math.isnan(altitude) and not 0.0 <= altitude <= f.altitude_max:
        raise SetpointError(
            f"{what} refused: altitude {altitude:g} m; allowed: 0..{f.altitude_max:g} m (z = -altitude, NED), "
            "parameter SP_ALT_MAX"
        )
    if f.max_distance > 0.0 and not (math.isnan(x) and math.isnan(y)):
        hx = f.home[0] if math.isnan(x) else x
        hy = f.home[1] if math.isnan(y) else y
        d = math.hypot(hx - f.home[0], hy - f.home[1])
        if d > f.max_distance:
            raise SetpointError(
                f"{what} refused: distance from home {d:.1f} m; allowed: up to {f.max_distance:g} m (GF_MAX_HOR_DIST)"
            )


def position_target(
    frame: int,
    mask: int,
    pos: tuple[float, float, float],
    vel: tuple[float, float, float],
    acc: tuple[float, float, float],
    yaw: float,
    yaw_rate: float,
    f: Frame,
) -> tuple[Horizontal | None, Vertical | None, Heading | None]:
    """A SET_POSITION_TARGET_* → (horizontal, vertical, heading) groups, or :class:`SetpointError`. For the global
    frames ``pos`` is (latitude, longitude [deg], altitude [m] as the frame says); otherwise x, y, z [m]."""
    if frame not in LOCAL_FRAMES + GLOBAL_FRAMES:
        raise SetpointError(
            f"Position setpoint refused: frame {frame}: supported are LOCAL_NED (1), BODY_NED (8), and for "
            "GLOBAL_INT setpoints 5, 6 and 11"
        )
    ign = [bool(mask & (1 << i)) for i in range(12)]
    names = ("x", "y", "z", "vx", "vy", "vz", "afx", "afy", "afz")
    values = (*pos, *vel, *acc)
    if frame in GLOBAL_FRAMES:
        names = ("lat_int", "lon_int", "alt", *names[3:])
    v = [_field(names[i], values[i], ign[i], 1 << i) for i in range(9)]
    yaw_sp = _field("yaw", yaw, ign[10], IGNORE_YAW)
    rate_sp = _field("yaw_rate", yaw_rate, ign[11], IGNORE_YAW_RATE)
    accel_used = not (ign[6] and ign[7] and ign[8])
    if mask & FORCE_SET and accel_used:
        raise SetpointError(
            "Position setpoint refused: force setpoints (type_mask bit 512) are not supported, as in PX4; "
            "send accelerations"
        )
    if frame == BODY_NED:
        if not (ign[0] and ign[1] and ign[2]):
            raise SetpointError(
                "Position setpoint refused: frame BODY_NED (8): positions are not supported "
                "(ignore x, y, z: type_mask 7)"
            )
        c, s = math.cos(f.yaw), math.sin(f.yaw)
        for i in (3, 6):  # velocity and acceleration: heading frame → NED (NaN stays NaN)
            fwd, right = v[i], v[i + 1]
            if not (math.isnan(fwd) and math.isnan(right)):
                fwd, right = (0.0 if math.isnan(fwd) else fwd), (0.0 if math.isnan(right) else right)
                v[i], v[i + 1] = c * fwd - s * right, s * fwd + c * right
    altitude = math.nan
    if frame in GLOBAL_FRAMES:
        lat, lon = v[0] * 1e-7, v[1] * 1e-7
        if not math.isnan(lat) and not (-90.0 <= lat <= 90.0):
            raise SetpointError(
                f"Position setpoint refused: lat_int = {values[0]:g}: expected a latitude in [-90, 90] degrees × 1e7"
            )
        if not math.isnan(lon) and not (-180.0 <= lon <= 180.0):
            raise SetpointError(
                f"Position setpoint refused: lon_int = {values[1]:g}: expected a longitude in [-180, 180] degrees × 1e7"
            )
        if math.isnan(lat) != math.isnan(lon):
            raise SetpointError(
                "Position setpoint refused: lat_int and lon_int: give both or ignore both (type_mask bits 1 and 2)"
            )
        if not math.isnan(lat):
            v[0], v[1] = geodetic_to_ned(lat, lon, f.origin[0], f.origin[1])
        if not math.isnan(v[2]):
            altitude = altitude_of(frame, v[2], f)
    elif not math.isnan(v[2]):
        altitude = -v[2]
    check_position(v[0], v[1], altitude, f)
    if not (math.isnan(v[3]) and math.isnan(v[4])):
        speed = math.hypot(0.0 if math.isnan(v[3]) else v[3], 0.0 if math.isnan(v[4]) else v[4])
        if speed > f.xy_vel_max:
            raise SetpointError(
                f"Velocity setpoint refused: horizontal speed {speed:.3g} m/s; allowed: up to {f.xy_vel_max:g} "
                "m/s, parameter MPC_XY_VEL_MAX"
            )
    climb = -v[5]
    if not math.isnan(climb) and not -f.z_vel_dn <= climb <= f.z_vel_up:
        raise SetpointError(
            f"Velocity setpoint refused: vz = {v[5]:g} m/s; allowed: {-f.z_vel_up:g}..{f.z_vel_dn:g} m/s (up is "
            "negative), parameters MPC_Z_VEL_MAX_UP/_DN"
        )
    horizontal = (
        None if all(map(math.isnan, (v[0], v[1], v[3], v[4], v[6], v[7]))) else (v[0], v[1], v[3], v[4], v[6], v[7])
    )
    vertical = None if all(map(math.isnan, (altitude, climb, v[8]))) else (altitude, climb, -v[8])
    heading = None if math.isnan(yaw_sp) and math.isnan(rate_sp) else (yaw_sp, rate_sp)
    return horizontal, vertical, heading


def reposition(lat: float, lon: float, alt: float, frame: int, f: Frame,
               what: str = "Reposition") -> tuple[float, float, float]:  # fmt: skip
    """MAV_CMD_DO_REPOSITION's target (latitude, longitude [deg], altitude in ``frame``; NaN: keep) → local
    (x, y NED, altitude) with NaN kept, or :class:`SetpointError` (its text starts with ``what``: DO_ORBIT's centre
    is read so too)."""
    if frame not in (GLOBAL, GLOBAL_INT, GLOBAL_RELATIVE_ALT, GLOBAL_RELATIVE_ALT_INT, GLOBAL_TERRAIN_ALT_INT):
        raise SetpointError(
            f"{what} refused: frame {frame}; supported are GLOBAL (0), GLOBAL_INT (5), relative altitude "
            "(3, 6) and terrain altitude (11)"
        )
    for name, value, lo, hi in (("latitude", lat, -90.0, 90.0), ("longitude", lon, -180.0, 180.0)):
        if not math.isnan(value) and not lo <= value <= hi:
            raise SetpointError(f"{what} refused: {name} {value:g} deg; allowed: [{lo:g}, {hi:g}]")
    if math.isinf(alt):
        raise SetpointError(f"{what} refused: altitude {alt:g}; expected a finite number or NaN (keep)")
    if math.isnan(lat) != math.isnan(lon):
        raise SetpointError(f"{what} refused: give latitude and longitude both, or neither (NaN)")
    x = y = math.nan
    if not math.isnan(lat):
        x, y = geodetic_to_ned(lat, lon, f.origin[0], f.origin[1])
    altitude = math.nan if math.isnan(alt) else altitude_of(frame, alt, f)
    check_position(x, y, altitude, f, what)
    return x, y, altitude
