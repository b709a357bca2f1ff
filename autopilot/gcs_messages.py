"""The MAVLink messages the autopilot sends to ground stations, built from its state: pure, no I/O.

Conventions are PX4's (DESIGN.md §8), so QGroundControl, MAVProxy and MAVSDK read them as they read
PX4: local NED position and velocity, FRD body rates, quaternions [w, x, y, z] FRD → NED,
``GLOBAL_POSITION_INT`` and ``GPS_RAW_INT`` from the geodetic origin of the local frame by PX4's map
projection (:mod:`quadsitl.frames`), motor outputs as PWM 1000–2000 µs.

Two positions matter, as in PX4: the **origin** (:class:`Origin`, ``--home``), where the local NED frame's
(0, 0, 0) is on the globe; and **home**, a point of that local frame (PX4: where the vehicle armed), which
``HOME_POSITION`` reports both ways (local x, y, z and latitude, longitude, altitude) and
``GLOBAL_POSITION_INT.relative_alt`` is measured from.

``SYS_STATUS`` says which sensors exist and are healthy the way MAVSDK's ``telemetry.health()`` reads it
(:func:`sys_status`): with a vehicle state from the plant, everything a PX4 vehicle needs to fly is healthy
and the pre-arm check passes; without one, the sensors and the pre-arm check are unhealthy.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass

import numpy as np

from autopilot import stream_frames
from autopilot.commander import (
    BAT_I,
    BAT_J,
    BAT_MAH,
    BAT_REMAINING,
    BAT_V,
    BAT_WARNING,
    GF_BREACH,
    MANUAL_MODES,
    ORBIT_ALT,
    ORBIT_R,
    ORBIT_V,
    ORBIT_X,
    ORBIT_Y,
    TOUCHDOWN_ALT,
    TOUCHDOWN_CLIMB,
    Commander,
)
from autopilot.estimator import VALID
from quadsitl import __version__, earth, hil
from quadsitl.codec import FRAME_MAX
from quadsitl.compiled_frames import euler_to_quaternion
from quadsitl.frames import PX4_HOME, ned_to_body
from quadsitl.state import Reference, VehicleState
from quadsitl.wire import STATUSTEXT_LEN as STATUSTEXT_LEN  # STATUSTEXT: one place for all, quadsitl.wire
from quadsitl.wire import Mode, mavlink, message_of
from quadsitl.wire import statustext as statustext


@dataclass(frozen=True)
class Origin:
    """The geodetic origin of the local NED frame (where local x = y = z = 0 is): WGS84 latitude and
    longitude [deg], altitude AMSL [m]. ``--home`` sets it; the default is PX4 SITL's default home
    (Zürich), where PX4 SITL's vehicle starts."""

    lat: float = PX4_HOME[0]
    lon: float = PX4_HOME[1]
    alt: float = PX4_HOME[2]


Home = Origin  # the former name, which autopilot.process still imports


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
    # Home in the local frame: x, y, z [m] NED from the origin, and heading [rad]. HOME_POSITION reports it,
    # GLOBAL_POSITION_INT.relative_alt is the altitude above it.
    home: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)
    has_state: bool = True  # a vehicle state arrives from the plant: sensors healthy, pre-arm check passed
    # The position reference flown (local NED x, y [m], vx, vy [m/s], altitude [m], climb rate [m/s]); NaN where
    # not controlled (the horizontal position under attitude setpoints, the altitude under a climb rate alone).
    target: tuple[float, float, float, float, float, float] = (math.nan,) * 4 + (0.0, math.nan)
    # ESTIMATOR_STATUS: flags, test ratios (velocity, horizontal and vertical position, magnetometer), horizontal and
    # vertical accuracy [m] (autopilot.estimator.Estimator.status); None: the true state is flown (all valid, exact)
    estimator: tuple[int, float, float, float, float, float, float] | None = None
    # HIGHRES_IMU in sensor mode: the newest measurements the estimator took (accel [m/s²], gyro [rad/s], mag
    # [gauss], FRD; barometric altitude [m AMSL]); None: the true state is flown (highres_imu builds what it can)
    imu: tuple[float, ...] | None = None


def heartbeat(c: Commander) -> mavlink.MAVLink_heartbeat_message:
    base = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
    if c.armed:
        base |= mavlink.MAV_MODE_FLAG_SAFETY_ARMED
    if c.mode == Mode.OFFBOARD:
        base |= mavlink.MAV_MODE_FLAG_GUIDED_ENABLED | mavlink.MAV_MODE_FLAG_STABILIZE_ENABLED
    elif c.mode in MANUAL_MODES:  # PX4: manual input, the attitude controlled
        base |= mavlink.MAV_MODE_FLAG_MANUAL_INPUT_ENABLED | mavlink.MAV_MODE_FLAG_STABILIZE_ENABLED
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


GROUND_ALTITUDE, GROUND_CLIMB_RATE = (
    TOUCHDOWN_ALT,
    TOUCHDOWN_CLIMB,
)  # [m], [m/s]: an armed vehicle resting on the ground


def landed_state(c: Commander, state: VehicleState) -> int:
    """MAV_LANDED_STATE, as ``EXTENDED_SYS_STATE`` and MAVSDK's ``landed_state``/``in_air`` read it:

    - ON_GROUND (1): disarmed, or armed and at rest on the ground (altitude below ``GROUND_ALTITUDE``,
      vertical speed below ``GROUND_CLIMB_RATE``), also in LAND once it has touched down;
    - TAKEOFF (3): armed in TAKEOFF (from arming, even before the wheels leave the ground);
    - LANDING (4): armed in LAND or in RTL's final descent, until touchdown;
    - IN_AIR (2): armed otherwise."""
    if not c.armed:
        return mavlink.MAV_LANDED_STATE_ON_GROUND
    if c.mode == Mode.TAKEOFF:
        return mavlink.MAV_LANDED_STATE_TAKEOFF
    if state.altitude < GROUND_ALTITUDE and abs(state.climb_rate) < GROUND_CLIMB_RATE:
        return mavlink.MAV_LANDED_STATE_ON_GROUND
    if c.landing:
        return mavlink.MAV_LANDED_STATE_LANDING
    return mavlink.MAV_LANDED_STATE_IN_AIR


def in_air(c: Commander, state: VehicleState) -> bool:
    """Anything but on the ground (taking off, flying, landing): a disarm now needs force."""
    return landed_state(c, state) != mavlink.MAV_LANDED_STATE_ON_GROUND


def _lat_lon_e7(origin: Origin, north: float, east: float) -> tuple[int, int]:
    """Local north/east [m] from ``origin`` → (lat, lon) [1e-7 deg] (:func:`autopilot.stream_frames.lat_lon_e7`)."""
    return stream_frames.lat_lon_e7(float(origin.lat), float(origin.lon), float(north), float(east))


def _frame_values(s: Snapshot, origin: Origin, armed: bool) -> tuple:
    """:func:`autopilot.stream_frames.encode`'s arguments after the time, from a snapshot: floats (and the PWM ints),
    so that the encoder has one signature (compiled before the first tick: :func:`warm_up`)."""
    thrust = min(max(s.u1 / s.max_total_thrust, 0.0), 1.0)
    controls = tuple(map(float, s.controls))
    servo = stream_frames.pwms(controls, bool(armed), bool(s.reversible))
    return (tuple(map(float, s.state)), tuple(map(float, s.body_rates)), tuple(map(float, s.reference)),
            float(thrust), (float(origin.lat), float(origin.lon), float(origin.alt)), float(s.home[2]),
            tuple(map(float, s.target)), controls, servo)  # fmt: skip


def compiled_frame(msg_id: int, s: Snapshot, origin: Origin, armed: bool) -> bytes:
    """The frame of one of :data:`autopilot.stream_frames.COMPILED`'s messages for this snapshot: the bytes the
    autopilot's tick builds for it (:func:`autopilot.stream_frames.encode`), with sequence 0 and system and component
    1: :func:`build` hands it to pymavlink, which packs it again with the link's own."""
    buf = np.zeros(FRAME_MAX, dtype=np.uint8)
    n = stream_frames.encode(buf, stream_frames.SLOT_OF[msg_id], 0, 1, 1, int(s.time_ms),
                             *_frame_values(s, origin, armed))  # fmt: skip
    return buf[:n].tobytes()


def build(msg_id: int, s: Snapshot, c: Commander, origin: Origin):
    """The telemetry message ``msg_id`` for this tick (one of :mod:`autopilot.streams`' ids); None when it has nothing
    to say now (ORBIT_EXECUTION_STATUS while not orbiting)."""
    if msg_id in stream_frames.SLOT_OF:  # built by compiled code, as the tick builds them
        return message_of(compiled_frame(msg_id, s, origin, c.armed))
    if msg_id == mavlink.MAVLINK_MSG_ID_HOME_POSITION:
        return home_position(origin, *s.home, time_usec=s.time_ms * 1000)
    if msg_id == mavlink.MAVLINK_MSG_ID_SYS_STATUS:
        return sys_status(s.load, s.errors, s.has_state, fence_breached=bool(c.cm[GF_BREACH]), cm=c.cm)
    if msg_id == mavlink.MAVLINK_MSG_ID_BATTERY_STATUS:
        return battery_status(c.cm)
    if msg_id == mavlink.MAVLINK_MSG_ID_HIGHRES_IMU:
        return highres_imu(s, origin)
    if msg_id == mavlink.MAVLINK_MSG_ID_ORBIT_EXECUTION_STATUS:
        return orbit_execution_status(c, origin, s.time_ms * 1000)
    if msg_id == mavlink.MAVLINK_MSG_ID_ESTIMATOR_STATUS:
        flags, vel, pos_h, pos_v, mag, acc_h, acc_v = s.estimator or (TRUE_STATE_FLAGS, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
        return mavlink.MAVLink_estimator_status_message(s.time_ms * 1000, flags, vel, pos_h, pos_v, mag, 0.0, 0.0,
                                                        acc_h, acc_v)  # fmt: skip
    if msg_id == mavlink.MAVLINK_MSG_ID_EXTENDED_SYS_STATE:
        return mavlink.MAVLink_extended_sys_state_message(mavlink.MAV_VTOL_STATE_UNDEFINED, landed_state(c, s.state))
    raise ValueError(f"message id {msg_id} is not a telemetry stream")


# The true state flown (--state truth): attitude, velocity and position all valid, exactly (a valid estimate's flags).
TRUE_STATE_FLAGS = VALID


SENSORS = (  # the simulated vehicle's sensors: the plant's state stands for all of them
    mavlink.MAV_SYS_STATUS_SENSOR_3D_GYRO
    | mavlink.MAV_SYS_STATUS_SENSOR_3D_ACCEL
    | mavlink.MAV_SYS_STATUS_SENSOR_3D_MAG
    | mavlink.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE
    | mavlink.MAV_SYS_STATUS_SENSOR_GPS
)
CONTROL = (  # what the autopilot controls
    mavlink.MAV_SYS_STATUS_SENSOR_ANGULAR_RATE_CONTROL
    | mavlink.MAV_SYS_STATUS_SENSOR_ATTITUDE_STABILIZATION
    | mavlink.MAV_SYS_STATUS_SENSOR_YAW_POSITION
    | mavlink.MAV_SYS_STATUS_SENSOR_Z_ALTITUDE_CONTROL
    | mavlink.MAV_SYS_STATUS_SENSOR_XY_POSITION_CONTROL
    | mavlink.MAV_SYS_STATUS_SENSOR_MOTOR_OUTPUTS
)
PRESENT = SENSORS | CONTROL | mavlink.MAV_SYS_STATUS_PREARM_CHECK  # also "enabled"
# Health bits say 1 = healthy; the geofence's is clear while it is breached (MAVProxy says "fence breach"); a geofence
# we do not have is not in breach.
HEALTH_ALWAYS = CONTROL | mavlink.MAV_SYS_STATUS_GEOFENCE
HEALTH_WITH_STATE = SENSORS | mavlink.MAV_SYS_STATUS_PREARM_CHECK


FLOAT32_MAX = 3.4028234663852886e38
IMU_ALL = 0b1101111111111  # HIGHRES_IMU.fields_updated: accel, gyro, mag, abs pressure, pressure alt, temperature
IMU_NO_ACCEL = IMU_ALL & ~0b111


def highres_imu(s: Snapshot, origin: Origin) -> mavlink.MAVLink_highres_imu_message:
    """``HIGHRES_IMU`` (MAVSDK's ``telemetry.imu()``), FRD. In sensor mode the measurements the estimator took last
    (:attr:`Snapshot.imu`), all fields updated. On the true state: the gyro is the body rates, the magnetometer the
    Earth's field (quadsitl.earth's) turned into the body, the barometer the altitude AMSL through the standard
    atmosphere; the true state carries no acceleration, so the accelerometer's fields are 0 and ``fields_updated``
    leaves them out."""
    if s.imu is not None:
        accel, gyro, mag, alt = s.imu[0:3], s.imu[3:6], s.imu[6:9], s.imu[9]
        fields = IMU_ALL
    else:
        st = s.state
        field = earth.magnetic_field_ned(earth.MAG_STRENGTH, math.radians(earth.MAG_DECLINATION_DEG),
                                         math.radians(earth.MAG_INCLINATION_DEG))  # fmt: skip
        q = euler_to_quaternion(st.roll, st.pitch, st.yaw)
        accel, gyro, mag = (0.0, 0.0, 0.0), s.body_rates, ned_to_body(q, *field)
        alt, fields = origin.alt + st.altitude, IMU_NO_ACCEL
    values = (*accel, *gyro, *mag, earth.isa_pressure(alt) / 100.0, 0.0, alt, earth.isa_temperature(alt) - 273.15)
    return mavlink.MAVLink_highres_imu_message(s.time_ms * 1000, *map(float32, values), fields, 0)


def float32(value: float) -> float:
    """``value`` as a float32 field holds it: beyond its range (a diverged state), infinite; NaN stays NaN."""
    return value if not abs(value) > FLOAT32_MAX else math.copysign(math.inf, value)


# BATTERY_STATUS.charge_state for the commander's warning level (none, low, critical, emergency)
CHARGE_STATES = (mavlink.MAV_BATTERY_CHARGE_STATE_OK, mavlink.MAV_BATTERY_CHARGE_STATE_LOW,
                 mavlink.MAV_BATTERY_CHARGE_STATE_CRITICAL, mavlink.MAV_BATTERY_CHARGE_STATE_EMERGENCY)  # fmt: skip


def orbit_execution_status(c: Commander, origin: Origin, time_usec: int):
    """ORBIT_EXECUTION_STATUS as PX4 sends it while orbiting (None otherwise: nothing is sent): the radius [m], its
    sign the way round (positive clockwise), and the centre in MAV_FRAME_GLOBAL (lat, lon [1e-7 deg], AMSL [m])."""
    if c.mode != Mode.ORBIT:
        return None
    cm = c.cm
    lat, lon = _lat_lon_e7(origin, cm[ORBIT_X], cm[ORBIT_Y])
    radius = math.copysign(float(cm[ORBIT_R]), float(cm[ORBIT_V]))
    return mavlink.MAVLink_orbit_execution_status_message(time_usec, radius, mavlink.MAV_FRAME_GLOBAL, lat, lon,
                                                          float(origin.alt + cm[ORBIT_ALT]))  # fmt: skip


def battery_status(cm: np.ndarray) -> mavlink.MAVLink_battery_status_message:
    """``BATTERY_STATUS`` of the battery the commander knows (cm[BAT_*], from the plant's report): the plant's own
    frame's fields (:func:`quadsitl.hil.encode_battery`) with the charge state of the warning level, as PX4 sends
    it; without a battery (an ideal supply), every field unknown."""
    if math.isnan(cm[BAT_REMAINING]):
        return mavlink.MAVLink_battery_status_message(
            0, mavlink.MAV_BATTERY_FUNCTION_ALL, mavlink.MAV_BATTERY_TYPE_LIPO, 32767, [65535] * 10, -1, -1, -1, -1, 0,
            mavlink.MAV_BATTERY_CHARGE_STATE_UNDEFINED, [0] * 4, 0, 0,
        )  # fmt: skip
    buf = np.zeros(FRAME_MAX, dtype=np.uint8)
    n = hil.encode_battery(buf, 0, 1, 1, cm[BAT_V], cm[BAT_I], cm[BAT_MAH] * 3.6, cm[BAT_J], cm[BAT_REMAINING])
    msg = message_of(buf[:n].tobytes())
    msg.charge_state = CHARGE_STATES[int(cm[BAT_WARNING])]
    return msg


def sys_status(
    load: float = 0.0,
    errors: tuple[int, ...] = (0, 0, 0, 0, 0),
    has_state: bool = True,
    fence_breached: bool = False,
    cm: np.ndarray | None = None,
) -> mavlink.MAVLink_sys_status_message:
    """``SYS_STATUS``. Sensors gyro, accel, mag, absolute pressure and GPS, the control bits and the pre-arm
    check (MAV_SYS_STATUS_PREARM_CHECK) are present and enabled; the sensors and the pre-arm check are
    healthy only when ``has_state`` (a vehicle state arrives from the plant), the control bits always.
    MAVSDK's health reads these bits: gyro/accel/mag calibration ok, global and local position ok (GPS),
    armable (pre-arm).

    ``load`` is the fraction of the control period the tick used. The battery's fields and its present, enabled and
    (below the critical level) healthy bit come from the commander's state ``cm`` once a battery reports (else
    unknown: an ideal supply). ``errors``:
    errors_comm (bad frames on the ground link), errors_count1 (unknown messages), errors_count2 (refused
    setpoints and parameter values), errors_count3 (plant-link errors), errors_count4 (messages for
    another system or component); each saturates at 65535."""
    comm, c1, c2, c3, c4 = (min(max(int(e), 0), 65535) for e in (*errors, 0, 0, 0, 0, 0)[:5])
    health = HEALTH_ALWAYS | (HEALTH_WITH_STATE if has_state else 0)
    if fence_breached:  # the geofence's health: not in breach (autopilot.geofence)
        health &= ~mavlink.MAV_SYS_STATUS_GEOFENCE
    present, voltage, current, remaining = PRESENT, 65535, -1, -1
    if cm is not None and not math.isnan(cm[BAT_REMAINING]):
        present |= mavlink.MAV_SYS_STATUS_SENSOR_BATTERY
        health |= mavlink.MAV_SYS_STATUS_SENSOR_BATTERY if cm[BAT_WARNING] < 2 else 0
        mv, current, _, _, remaining = hil.battery_fields(cm[BAT_V], cm[BAT_I], cm[BAT_MAH] * 3.6, cm[BAT_J],
                                                          cm[BAT_REMAINING])  # BATTERY_STATUS's units  # fmt: skip
        voltage = min(mv, 65534)
    return mavlink.MAVLink_sys_status_message(
        present, present, health, stream_frames.clamp_int(float(load) * 1000, 0, 1000), voltage, current, remaining, 0,
        comm, c1, c2, c3, c4, 0, 0, 0,
    )  # fmt: skip


ARMING_NO_STATE = "Arming denied: no vehicle state (plant link down)"


def arming_check(has_state: bool) -> str:
    """The pre-arm check behind SYS_STATUS's MAV_SYS_STATUS_PREARM_CHECK: "" when arming may proceed,
    else why not (for COMMAND_ACK DENIED and its STATUSTEXT)."""
    return "" if has_state else ARMING_NO_STATE


def home_position(
    origin: Origin, x: float = 0.0, y: float = 0.0, z: float = 0.0, yaw: float = 0.0, time_usec: int = 0
) -> mavlink.MAVLink_home_position_message:
    """``HOME_POSITION`` of a home at local x, y, z [m, NED from ``origin``] with heading ``yaw`` [rad]:
    latitude and longitude [1e-7 deg] by PX4's projection, altitude AMSL [mm] = origin altitude − z, the
    local x, y, z as given, q = the heading as a quaternion [w, x, y, z] (PX4's), approach vector 0.
    The defaults put home at the origin. ``time_usec``: simulated time since start [µs]."""
    lat, lon = _lat_lon_e7(origin, x, y)
    q = [float(v) for v in euler_to_quaternion(0.0, 0.0, float(yaw))] if math.isfinite(yaw) else [1.0, 0, 0, 0]
    return mavlink.MAVLink_home_position_message(
        lat, lon, stream_frames.amsl_mm(float(origin.alt), float(z)), x, y, z, q, 0.0, 0.0, 0.0, max(int(time_usec), 0)
    )


def gps_global_origin(origin: Origin, time_usec: int = 0) -> mavlink.MAVLink_gps_global_origin_message:
    """``GPS_GLOBAL_ORIGIN``: where the local NED frame's origin is (latitude, longitude [1e-7 deg], altitude AMSL
    [mm]), as PX4 answers MAVSDK's ``get_gps_global_origin``. ``time_usec``: simulated time since start [µs]."""
    lat, lon = _lat_lon_e7(origin, 0.0, 0.0)
    return mavlink.MAVLink_gps_global_origin_message(lat, lon, stream_frames.amsl_mm(float(origin.alt), 0.0),
                                                     max(int(time_usec), 0))  # fmt: skip


CAPABILITIES = (
    mavlink.MAV_PROTOCOL_CAPABILITY_MAVLINK2
    | mavlink.MAV_PROTOCOL_CAPABILITY_SET_ATTITUDE_TARGET
    | mavlink.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_LOCAL_NED
    | mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE  # integer parameters as INT32, bytewise, as PX4
    # MAVSDK refuses a mission upload without MISSION_INT; it uses it for nothing else (no download on
    # connecting), so advertising it before the mission protocol exists is harmless.
    | mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_INT
    | mavlink.MAV_PROTOCOL_CAPABILITY_COMMAND_INT  # every command is taken as COMMAND_INT as well
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


def warm_up() -> None:
    """Compile (or load from numba's cache) the compiled code the Python-built messages call, before the first tick:
    every streamed message once, from a made-up snapshot."""
    from autopilot.streams import MessageStreams

    s = Snapshot(time_ms=0, state=VehicleState(), body_rates=(0.0, 0.0, 0.0), reference=Reference(0.0, 0.0, 0.0, 0.0),
                 u1=0.0, controls=(0.0, 0.0, 0.0, 0.0), reversible=False, max_total_thrust=1.0)  # fmt: skip
    for mid in MessageStreams(0.001, 50.0).defaults:
        build(mid, s, Commander(), Origin())
    # a message packed from Python (quadsitl.codec.pack: STATUSTEXT, parameters, command answers): its checksum's
    # entry from Python is compiled apart from the compiled codec's, and an autopilot compiling it at its first such
    # message was silent for more than the plant's 0.5 s (lost, then back)
    from quadsitl import codec, wire

    mav = wire.link(1, 1)
    codec.pack(mav.statustext_encode(mavlink.MAV_SEVERITY_INFO, b"warm"), mav)
