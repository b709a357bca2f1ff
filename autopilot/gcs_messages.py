"""The MAVLink messages the autopilot sends to ground stations, built from its state: pure, no I/O.

Conventions are PX4's (DESIGN.md §8), so QGroundControl, MAVProxy and MAVSDK read them as they read
PX4: local NED position and velocity, FRD body rates, quaternions [w, x, y, z] FRD → NED,
``GLOBAL_POSITION_INT`` from a home position by PX4's map projection (:mod:`quadsitl.frames`), motor
outputs as PWM 1000–2000 µs.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass

from autopilot.commander import Commander
from quadsitl import __version__
from quadsitl.frames import euler_to_quaternion, ned_to_geodetic
from quadsitl.state import Reference, VehicleState
from quadsitl.wire import Mode, mavlink

STATUSTEXT_LEN = 50


@dataclass(frozen=True)
class Home:
    """The home position: WGS84 latitude and longitude [deg], altitude AMSL [m]. The local NED
    origin is here. Default: PX4 SITL's default home (Zürich)."""

    lat: float = 47.397742
    lon: float = 8.545594
    alt: float = 488.0


@dataclass(frozen=True)
class Snapshot:
    """What one tick's telemetry is built from."""

    time_ms: int  # simulated time since start [ms]
    state: VehicleState
    body_rates: tuple[float, float, float]  # p, q, r [rad/s], FRD
    reference: Reference
    u1: float  # total thrust [N]
    controls: tuple[float, float, float, float]  # F_j / F_max
    reversible: bool
    max_total_thrust: float  # 4·F_max [N]
    load: float = 0.0  # fraction of the control period the tick used
    # SYS_STATUS errors_comm, errors_count1..4: bad ground-link frames, unknown messages, refused inputs,
    # plant-link errors, messages for another system/component
    errors: tuple[int, int, int, int, int] = (0, 0, 0, 0, 0)


def heartbeat(c: Commander) -> mavlink.MAVLink_heartbeat_message:
    base = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
    if c.armed:
        base |= mavlink.MAV_MODE_FLAG_SAFETY_ARMED
    if c.mode == Mode.OFFBOARD:
        base |= mavlink.MAV_MODE_FLAG_GUIDED_ENABLED | mavlink.MAV_MODE_FLAG_STABILIZE_ENABLED
    else:
        base |= mavlink.MAV_MODE_FLAG_AUTO_ENABLED | mavlink.MAV_MODE_FLAG_STABILIZE_ENABLED
    if c.failsafe:
        status = mavlink.MAV_STATE_CRITICAL
    elif c.armed:
        status = mavlink.MAV_STATE_ACTIVE
    else:
        status = mavlink.MAV_STATE_STANDBY
    return mavlink.MAVLink_heartbeat_message(
        mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_PX4, base, c.mode.px4_custom_mode, status, 3
    )


def landed_state(c: Commander, state: VehicleState) -> int:
    """MAV_LANDED_STATE: on the ground when disarmed or resting below 5 cm, landing in LAND."""
    if not c.armed:
        return mavlink.MAV_LANDED_STATE_ON_GROUND
    if c.mode == Mode.LAND:
        return mavlink.MAV_LANDED_STATE_LANDING
    if state.altitude < 0.05 and abs(state.climb_rate) < 0.1:
        return mavlink.MAV_LANDED_STATE_ON_GROUND
    return mavlink.MAV_LANDED_STATE_IN_AIR


def pwm(control: float, reversible: bool) -> int:
    """A normalised motor command → PWM [µs]: [0, 1] → 1000..2000, or [−1, 1] → 1000..2000
    (1500 = zero) for reversible motors."""
    c = (control + 1.0) / 2.0 if reversible else control
    return round(1000.0 + 1000.0 * min(max(c, 0.0), 1.0))


def _clamp_int(value: float, lo: int, hi: int) -> int:
    return int(min(max(round(value), lo), hi)) if math.isfinite(value) else 0


def build(msg_id: int, s: Snapshot, c: Commander, home: Home):
    """The telemetry message ``msg_id`` for this tick (one of :mod:`autopilot.streams`' ids)."""
    st, ms, (p, q, r) = s.state, s.time_ms & 0xFFFFFFFF, s.body_rates
    if msg_id == mavlink.MAVLINK_MSG_ID_ATTITUDE:
        return mavlink.MAVLink_attitude_message(ms, st.roll, st.pitch, st.yaw, p, q, r)
    if msg_id == mavlink.MAVLINK_MSG_ID_ATTITUDE_QUATERNION:
        return mavlink.MAVLink_attitude_quaternion_message(
            ms, *euler_to_quaternion(st.roll, st.pitch, st.yaw), p, q, r, [0.0] * 4
        )
    if msg_id == mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED:
        return mavlink.MAVLink_local_position_ned_message(ms, st.x, st.y, st.z, st.vx, st.vy, st.vz)
    if msg_id == mavlink.MAVLINK_MSG_ID_ATTITUDE_TARGET:
        ref = s.reference
        qd = euler_to_quaternion(ref.roll, ref.pitch, ref.yaw)
        thrust = min(max(s.u1 / s.max_total_thrust, 0.0), 1.0)
        # type_mask 7: the body-rate fields are not used.
        return mavlink.MAVLink_attitude_target_message(ms, 7, qd, 0.0, 0.0, 0.0, thrust)
    if msg_id == mavlink.MAVLINK_MSG_ID_POSITION_TARGET_LOCAL_NED:
        # Only z is a target (the altitude reference); x, y, velocities, accelerations, yaw rate ignored.
        mask = 1 | 2 | 8 | 16 | 32 | 64 | 128 | 256 | 2048  # yaw (1024) is a target too
        return mavlink.MAVLink_position_target_local_ned_message(
            ms, mavlink.MAV_FRAME_LOCAL_NED, mask, 0.0, 0.0, -s.reference.altitude, 0, 0, 0, 0, 0, 0,
            s.reference.yaw, 0.0,
        )  # fmt: skip
    if msg_id == mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT:
        lat, lon = ned_to_geodetic(st.x, st.y, home.lat, home.lon)
        hdg = round(math.degrees(st.yaw) % 360.0 * 100) % 36000
        return mavlink.MAVLink_global_position_int_message(
            ms,
            _clamp_int(lat * 1e7, -900_000_000, 900_000_000),
            _clamp_int(lon * 1e7, -1_800_000_000, 1_800_000_000),
            _clamp_int((home.alt - st.z) * 1000, -(2**31), 2**31 - 1),
            _clamp_int(-st.z * 1000, -(2**31), 2**31 - 1),
            _clamp_int(st.vx * 100, -32768, 32767),
            _clamp_int(st.vy * 100, -32768, 32767),
            _clamp_int(st.vz * 100, -32768, 32767),
            hdg,
        )
    if msg_id == mavlink.MAVLINK_MSG_ID_HOME_POSITION:
        return home_position(home, s.time_ms * 1000)
    if msg_id == mavlink.MAVLINK_MSG_ID_SYS_STATUS:
        return sys_status(s.load, s.errors)
    if msg_id == mavlink.MAVLINK_MSG_ID_EXTENDED_SYS_STATE:
        return mavlink.MAVLink_extended_sys_state_message(mavlink.MAV_VTOL_STATE_UNDEFINED, landed_state(c, st))
    if msg_id == mavlink.MAVLINK_MSG_ID_SERVO_OUTPUT_RAW:
        out = [pwm(x, s.reversible) if c.armed else 0 for x in s.controls]
        return mavlink.MAVLink_servo_output_raw_message((s.time_ms * 1000) & 0xFFFFFFFF, 0, *out, *[0] * 12)
    if msg_id == mavlink.MAVLINK_MSG_ID_ACTUATOR_OUTPUT_STATUS:
        return mavlink.MAVLink_actuator_output_status_message(s.time_ms * 1000, 0b1111, [*s.controls, *[0.0] * 28])
    raise ValueError(f"message id {msg_id} is not a telemetry stream")


SENSORS = (
    mavlink.MAV_SYS_STATUS_SENSOR_3D_GYRO
    | mavlink.MAV_SYS_STATUS_SENSOR_3D_ACCEL
    | mavlink.MAV_SYS_STATUS_SENSOR_ANGULAR_RATE_CONTROL
    | mavlink.MAV_SYS_STATUS_SENSOR_ATTITUDE_STABILIZATION
    | mavlink.MAV_SYS_STATUS_SENSOR_YAW_POSITION
    | mavlink.MAV_SYS_STATUS_SENSOR_Z_ALTITUDE_CONTROL
    | mavlink.MAV_SYS_STATUS_SENSOR_MOTOR_OUTPUTS
)


# Health bits say 1 = healthy; a geofence we do not have is not in breach (MAVProxy says "fence breach" otherwise).
HEALTH = SENSORS | mavlink.MAV_SYS_STATUS_GEOFENCE


def sys_status(load: float = 0.0, errors: tuple[int, ...] = (0, 0, 0, 0, 0)) -> mavlink.MAVLink_sys_status_message:
    """``load`` is the fraction of the control period the tick used; no battery is simulated. ``errors``:
    errors_comm (bad frames on the ground link), errors_count1 (unknown messages), errors_count2 (refused
    setpoints and parameter values), errors_count3 (plant-link errors), errors_count4 (messages for
    another system or component); each saturates at 65535."""
    comm, c1, c2, c3, c4 = (min(e, 65535) for e in errors)
    return mavlink.MAVLink_sys_status_message(
        SENSORS, SENSORS, HEALTH, _clamp_int(load * 1000, 0, 1000), 65535, -1, -1, 0, comm, c1, c2, c3, c4, 0, 0, 0,
    )  # fmt: skip


def home_position(home: Home, time_usec: int = 0) -> mavlink.MAVLink_home_position_message:
    return mavlink.MAVLink_home_position_message(
        _clamp_int(home.lat * 1e7, -900_000_000, 900_000_000),
        _clamp_int(home.lon * 1e7, -1_800_000_000, 1_800_000_000),
        _clamp_int(home.alt * 1000, -(2**31), 2**31 - 1),
        0.0, 0.0, 0.0, [1.0, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0, time_usec,
    )  # fmt: skip


CAPABILITIES = (
    mavlink.MAV_PROTOCOL_CAPABILITY_MAVLINK2
    | mavlink.MAV_PROTOCOL_CAPABILITY_SET_ATTITUDE_TARGET
    | mavlink.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_LOCAL_NED
    | mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_C_CAST
)


def version_number(version: str = __version__) -> int:
    """ "major.minor.patch" → MAVLink's flight_sw_version (major << 24 | minor << 16 | patch << 8 | type)."""
    parts = [int(x) for x in version.split(".")[:3] if x.isdigit()] + [0, 0, 0]
    return (parts[0] << 24) | (parts[1] << 16) | (parts[2] << 8) | mavlink.FIRMWARE_VERSION_TYPE_DEV


def autopilot_version(system_id: int) -> mavlink.MAVLink_autopilot_version_message:
    v = version_number()
    return mavlink.MAVLink_autopilot_version_message(
        CAPABILITIES, v, v, 0, 0, [0] * 8, [0] * 8, [0] * 8, 0, 0, 0x5155414453000000 | system_id, [0] * 18
    )


FTP_NAK = 129  # MAVLink FTP opcode
FTP_ERR_UNKNOWN_COMMAND = 7
_FTP_HEADER = struct.Struct("<HBBBBBBI")  # seq, session, opcode, size, req_opcode, burst_complete, padding, offset


def ftp_refusal(request: bytes | list[int]) -> bytes:
    """The FILE_TRANSFER_PROTOCOL payload that answers any MAVLink FTP request with NAK "unknown
    command": we have no file system. Ground stations that try FTP first (MAVProxy's parameter
    download, QGroundControl's component metadata) then fall back at once instead of timing out."""
    seq, session, opcode, *_ = _FTP_HEADER.unpack_from(bytes(request[: _FTP_HEADER.size]))
    head = _FTP_HEADER.pack((seq + 1) & 0xFFFF, session, FTP_NAK, 1, opcode, 0, 0, 0)
    return (head + bytes([FTP_ERR_UNKNOWN_COMMAND])).ljust(251, b"\0")


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
