"""MAVLink on the wire between the processes (DESIGN.md §4), in one place.

Plant → autopilot, once a tick: ``ODOMETRY`` (all float32): ``time_usec`` = simulated time, position in
``MAV_FRAME_LOCAL_NED``, quaternion [w, x, y, z] FRD → NED, velocity in NED (``child_frame_id`` =
``MAV_FRAME_LOCAL_NED``), body rates p, q, r (FRD).

Autopilot → plant, once a tick: ``HIL_ACTUATOR_CONTROLS`` with ``time_usec`` echoing the state it answers
and ``controls[0..3]`` = F_j / F_max for motors 1..4 (eq (8) numbering): in [0, 1], or [−1, 1] for
reversible (ideal) actuators.

Ground station ↔ autopilot: PX4 conventions (custom modes below, COMMAND_LONG/ACK, setpoints).

pymavlink only, so the ground side imports it without the compiler. The processes frame the two per-tick messages,
and any other message they send, with the compiled codec of :mod:`quadsitl.codec` (the same bytes as the message
builders here: a test compares them).
"""

from __future__ import annotations

import math
import struct
from enum import IntEnum

from pymavlink.dialects.v20 import common as mavlink

from quadsitl.frames import euler_rates_to_body_rates, euler_to_quaternion, geodetic_to_ned, ned_to_geodetic
from quadsitl.state import VehicleState

PLANT_SYSTEM_ID = 1
PLANT_COMPONENT_ID = mavlink.MAV_COMP_ID_USER1  # the simulator, as PX4's SIH/Gazebo bridges use a separate component
AUTOPILOT_COMPONENT_ID = mavlink.MAV_COMP_ID_AUTOPILOT1
GCS_SYSTEM_ID = 255
GCS_COMPONENT_ID = mavlink.MAV_COMP_ID_MISSIONPLANNER

UNKNOWN_COVARIANCE = [math.nan] + [0.0] * 20  # a covariance matrix's upper triangle: NaN first = unknown


STATUSTEXT_LEN = 50
_ASCII = str.maketrans(
    {
        "λ": "l",
        "ε": "eps",
        "²": "^2",
        "−": "-",
        "≥": ">=",
        "≤": "<=",
        "·": "*",
        "…": "...",
        "φ": "roll",
        "θ": "pitch",
        "ψ": "yaw",
        "°": " deg",
    }
)


def statustext(severity: int, text: str, chunk_id: int) -> list[mavlink.MAVLink_statustext_message]:
    """``text`` as STATUSTEXT, in ASCII (Greek letters and math signs spelt out, anything else
    replaced by "?"): one message when it fits in 50 bytes, else MAVLink 2 chunks sharing ``chunk_id``
    (1..65535) with ``chunk_seq`` 0, 1, …; the first chunk shorter than 50 bytes (an empty one if
    need be) ends the text, as the MAVLink spec has it."""
    data = text.translate(_ASCII).encode("ascii", errors="replace")
    if len(data) <= STATUSTEXT_LEN:
        return [mavlink.MAVLink_statustext_message(severity, data, 0, 0)]
    chunks = [data[i : i + STATUSTEXT_LEN] for i in range(0, len(data), STATUSTEXT_LEN)]
    if len(chunks[-1]) == STATUSTEXT_LEN:
        chunks.append(b"")
    return [mavlink.MAVLink_statustext_message(severity, ch, chunk_id, i) for i, ch in enumerate(chunks)]


class Mode(IntEnum):
    """The autopilot's flight modes (the numbers in telemetry's status) and their PX4 custom-mode encoding
    (main << 16 | sub << 24, DESIGN.md §9)."""

    HOLD = 0  # PX4 AUTO.LOITER (4/3): hold position, altitude and heading
    OFFBOARD = 1  # PX4 OFFBOARD (6): external position, velocity, acceleration or attitude setpoints
    LAND = 2  # PX4 AUTO.LAND (4/6): stop, descend where the vehicle is, disarm on touchdown
    TAKEOFF = 3  # PX4 AUTO.TAKEOFF (4/2): climb to the takeoff altitude, then hold
    RTL = 4  # PX4 AUTO.RTL (4/5): climb to RTL_RETURN_ALT, fly home, land, disarm
    MISSION = 5  # PX4 AUTO.MISSION (4/4): fly the uploaded mission (autopilot.missions)
    POSCTL = 6  # PX4 POSCTL (3): sticks to velocity, centred sticks hold position (autopilot.manual)
    ALTCTL = 7  # PX4 ALTCTL (2): sticks to attitude, throttle to climb rate, centred throttle holds altitude
    STABILIZED = 8  # PX4 STABILIZED (7): sticks to attitude and yaw rate, throttle to thrust
    ORBIT = 9  # PX4 ORBIT (3/1, POSCTL's sub mode): circle a point (MAV_CMD_DO_ORBIT)
    FOLLOW = 10  # PX4 AUTO.FOLLOW_TARGET (4/8): follow a target (FOLLOW_TARGET) at the FLW_TGT_* offset

    @property
    def px4_custom_mode(self) -> int:
        main, sub = _PX4_MODES[self]
        return (main << 16) | (sub << 24)

    @classmethod
    def from_px4(cls, custom_mode: int) -> Mode | None:
        main, sub = (custom_mode >> 16) & 0xFF, (custom_mode >> 24) & 0xFF
        for mode, (m, s) in _PX4_MODES.items():
            if main == m and (sub == s or m in _ANY_SUB):
                return mode
        return None


_PX4_MODES = {
    Mode.HOLD: (4, 3), Mode.OFFBOARD: (6, 0), Mode.LAND: (4, 6), Mode.TAKEOFF: (4, 2), Mode.RTL: (4, 5),
    Mode.MISSION: (4, 4), Mode.POSCTL: (3, 0), Mode.ALTCTL: (2, 0), Mode.STABILIZED: (7, 0),
    Mode.ORBIT: (3, 1), Mode.FOLLOW: (4, 8),
}  # fmt: skip
_ANY_SUB = (6, 2, 7)  # main modes whose sub mode PX4 does not read (POSCTL's sub 1 is its orbit)


# A parameter's value on the wire, as PX4 carries it (MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE): a REAL32 as
# itself, an integer's bytes in param_value's (MAVSDK and QGroundControl read a PX4 vehicle's integers so).
_INT_PARAM_FORMATS = {mavlink.MAV_PARAM_TYPE_UINT8: "<B", mavlink.MAV_PARAM_TYPE_INT8: "<b",
                      mavlink.MAV_PARAM_TYPE_UINT16: "<H", mavlink.MAV_PARAM_TYPE_INT16: "<h",
                      mavlink.MAV_PARAM_TYPE_UINT32: "<I", mavlink.MAV_PARAM_TYPE_INT32: "<i"}  # fmt: skip


def param_to_wire(value: float, integer: bool) -> tuple[float, int]:
    """(param_value, param_type) of a parameter's ``value``: an ``integer`` one as INT32, bytewise."""
    if not integer:
        return float(value), mavlink.MAV_PARAM_TYPE_REAL32
    return struct.unpack("<f", struct.pack("<i", int(value)))[0], mavlink.MAV_PARAM_TYPE_INT32


def param_from_wire(param_value: float, param_type: int) -> float:
    """A PARAM_SET's or PARAM_VALUE's value: an integer type's from the bytes of ``param_value`` (bytewise), any
    other type's as it is (a REAL32 value set on an integer parameter is taken as a number, whole or refused)."""
    fmt = _INT_PARAM_FORMATS.get(param_type)
    if fmt is None:
        return float(param_value)
    raw = struct.pack("<f", param_value)
    return float(struct.unpack(fmt, raw[: struct.calcsize(fmt)])[0])


def link(system: int, component: int) -> mavlink.MAVLink:
    """A MAVLink 2 encoder/decoder (no file: ``msg.pack(link)`` gives bytes, ``link.parse_buffer`` reads)."""
    mav = mavlink.MAVLink(None, srcSystem=system, srcComponent=component)
    mav.robust_parsing = True
    return mav


def state_message(time_usec: int, s: VehicleState) -> mavlink.MAVLink_odometry_message:
    """The plant's state as ODOMETRY (Euler-angle rates converted to body rates with eq (1))."""
    q = euler_to_quaternion(s.roll, s.pitch, s.yaw)
    p, qr, r = euler_rates_to_body_rates(s.roll, s.pitch, s.roll_dot, s.pitch_dot, s.yaw_dot)
    return mavlink.MAVLink_odometry_message(
        time_usec, mavlink.MAV_FRAME_LOCAL_NED, mavlink.MAV_FRAME_LOCAL_NED,
        s.x, s.y, s.z, q, s.vx, s.vy, s.vz, p, qr, r, UNKNOWN_COVARIANCE, UNKNOWN_COVARIANCE, 0,
        mavlink.MAV_ESTIMATOR_TYPE_NAIVE, 100,
    )  # fmt: skip


def actuator_message(
    time_usec: int, forces: tuple[float, float, float, float], max_thrust: float, armed: bool
) -> mavlink.MAVLink_hil_actuator_controls_message:
    """Motor forces [N] → HIL_ACTUATOR_CONTROLS with controls[j] = F_j / F_max."""
    controls = [f / max_thrust for f in forces] + [0.0] * 12
    mode = mavlink.MAV_MODE_FLAG_SAFETY_ARMED if armed else 0
    return mavlink.MAVLink_hil_actuator_controls_message(time_usec, controls, mode, 0)


def forces_from_message(m: mavlink.MAVLink_hil_actuator_controls_message, max_thrust: float) -> tuple[float, ...]:
    """HIL_ACTUATOR_CONTROLS → commanded motor forces [N]."""
    c = m.controls
    return (c[0] * max_thrust, c[1] * max_thrust, c[2] * max_thrust, c[3] * max_thrust)


UINT16_UNKNOWN = 65535  # MAVLink's "unknown" for uint16 fields (GPS eph, epv, vel, cog)


def hil_gps_message(
    time_usec: int,
    position: tuple[float, float, float],
    velocity: tuple[float, float, float],
    home: tuple[float, float, float],
    eph: float,
    epv: float,
    satellites: int,
) -> mavlink.MAVLink_hil_gps_message:
    """A GPS fix as PX4's simulators send it (``HIL_GPS``): ``position`` [m, NED from the local origin ``home`` =
    (lat [deg], lon [deg], alt [m AMSL])] as latitude and longitude [1e-7 deg] (PX4's projection,
    :func:`quadsitl.frames.ned_to_geodetic`) and altitude AMSL [mm]; ``velocity`` [m/s, NED] as vn, ve, vd and
    ground speed [cm/s], course over ground [cdeg, 0 = north; unknown below 1 cm/s]; fix type 3 (3D);
    ``eph``/``epv`` [m] in cm, as PX4's simulator bridge reads them."""
    lat, lon = ned_to_geodetic(position[0], position[1], home[0], home[1])
    vn, ve, vd = (max(-32768, min(32767, round(v * 100))) for v in velocity)
    speed = min(round(math.hypot(velocity[0], velocity[1]) * 100), UINT16_UNKNOWN - 1)
    cog = round(math.degrees(math.atan2(velocity[1], velocity[0])) % 360.0 * 100) % 36000 if speed else UINT16_UNKNOWN
    eph_cm, epv_cm = (min(round(e * 100), UINT16_UNKNOWN - 1) for e in (eph, epv))
    alt_mm = round((home[2] - position[2]) * 1000)
    return mavlink.MAVLink_hil_gps_message(
        time_usec, mavlink.GPS_FIX_TYPE_3D_FIX, round(lat * 1e7), round(lon * 1e7), alt_mm, eph_cm, epv_cm, speed,
        vn, ve, vd, cog, satellites,
    )  # fmt: skip


def gps_from_message(
    m: mavlink.MAVLink_hil_gps_message, home: tuple[float, float, float]
) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
    """The inverse of :func:`hil_gps_message`: (position [m, NED from ``home``], velocity [m/s, NED])."""
    north, east = geodetic_to_ned(m.lat * 1e-7, m.lon * 1e-7, home[0], home[1])
    return (north, east, home[2] - m.alt * 1e-3), (m.vn * 0.01, m.ve * 0.01, m.vd * 0.01)


# ---- any other message, for the ground-station links ---------------------------------------------------

_PARSER = link(0, 0)


def message_of(frame: bytes) -> mavlink.MAVLink_message:
    """The pymavlink message of one unsigned MAVLink 2 frame (a frame built by compiled code, to be sent through
    pymavlink: a signed link, a message asked for)."""
    msg = _PARSER.decode(bytearray(frame))
    _PARSER.seq = 0
    return msg


# ---- MAVLink 2 message signing on the ground-station links -------------------------------------------

SIGNING_ENV = "QUADSITL_SIGNING_KEY"
_SIGNING_EPOCH = 1420070400  # 2015-01-01T00:00:00Z: MAVLink signing timestamps count 10 µs from here


def load_signing_key(option: str, text: str) -> bytes:
    """A 32-byte signing key from 64 hex digits, or from a file holding them (or the 32 raw bytes).
    Errors name the option and what is allowed, never the value: a key must not reach a log."""
    from pathlib import Path

    from quadsitl.cli_util import UsageError

    candidate = text.strip()
    if len(candidate) == 64:
        try:
            return bytes.fromhex(candidate)
        except ValueError:
            pass
    path = Path(text)
    if path.is_file():
        data = path.read_bytes()
        if len(data) == 32:
            return data
        try:
            key = bytes.fromhex(data.decode("ascii").strip())
        except (UnicodeDecodeError, ValueError):
            key = b""
        if len(key) == 32:
            return key
        raise UsageError(f"{option}: the file holds neither 64 hex digits nor 32 raw bytes")
    raise UsageError(f"{option}: expected 64 hex digits (a 32-byte key) or the path of a file holding them")


def resolve_signing_key(text: str | None, option: str = "--signing-key") -> bytes | None:
    """The key an option gives, else ``$QUADSITL_SIGNING_KEY``, else None (no signing)."""
    import os

    text = text or os.environ.get(SIGNING_ENV)
    return load_signing_key(option, text) if text else None


def enable_signing(mav: mavlink.MAVLink, key: bytes, link_id: int = 0) -> None:
    """Sign everything ``mav`` packs and accept only correctly signed, fresh frames when it parses
    (pymavlink refuses unsigned frames, bad signatures and replayed timestamps, and counts them in
    ``mav.signing.badsig_count`` and ``reject_count``)."""
    import time

    mav.signing.secret_key = key
    mav.signing.sign_outgoing = True
    mav.signing.link_id = link_id
    mav.signing.timestamp = int((time.time() - _SIGNING_EPOCH) * 100_000)
    mav.signing.allow_unsigned_callback = None


def signing_refusals(mav: mavlink.MAVLink) -> int:
    """Frames refused for their signature: unsigned, wrongly signed or replayed."""
    s = mav.signing
    return s.badsig_count + s.reject_count if s.secret_key is not None else 0
