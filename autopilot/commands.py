"""The MAV_CMDs the vehicle takes: one function each, from a :class:`autopilot.records.Command` to its result (a
MAV_RESULT), the reason of a refusal (said as a status text) and the message it asked for, if any. What a command
may use of the vehicle is :class:`Vehicle`; :func:`run` answers it (:class:`autopilot.outbox.Outbox`)."""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Protocol

from autopilot import calibration, gcs_messages, setpoints
from autopilot.commander import Commander
from autopilot.gcs_messages import Home, Snapshot
from autopilot.missions import Missions
from autopilot.outbox import Outbox
from autopilot.params import ParamStore
from autopilot.records import Command
from autopilot.streams import MessageStreams
from quadsitl import wire
from quadsitl.state import VehicleState

mavlink = wire.mavlink
ACCEPTED, DENIED = mavlink.MAV_RESULT_ACCEPTED, mavlink.MAV_RESULT_DENIED
UNSUPPORTED = mavlink.MAV_RESULT_UNSUPPORTED
FORCE_DISARM = 21196  # MAV_CMD_COMPONENT_ARM_DISARM param2 that forces a disarm in the air (PX4, MAVLink)
SUPPORTED_MODES = (
    "supported are offboard (6), takeoff (4/2), hold (4/3), mission (4/4), RTL (4/5), land (4/6), "
    "position (3), altitude (2), stabilized (7), orbit (3/1), "
    "follow me (4/8)"
)
Result = tuple[int, str, object]  # (MAV_RESULT, the reason of a refusal or "", the message asked for or None)


class Vehicle(Protocol):
    """What the commands use of the vehicle (:class:`autopilot.process.Autopilot`)."""

    system_id: int
    home: Home  # the local origin
    commander: Commander
    missions: Missions
    params: ParamStore
    outbox: Outbox
    streams: MessageStreams  # which messages the vehicle streams

    def has_state(self) -> bool: ...
    def state(self) -> VehicleState | None: ...
    def snapshot(self) -> Snapshot | None: ...
    def frame(self) -> setpoints.Frame: ...
    def home_position(self): ...
    def set_mode(self, mode: wire.Mode) -> tuple[bool, str]: ...
    def armed(self) -> None: ...
    def inject_failure(self, unit: int, kind: int, instance: int) -> tuple[bool, str]: ...
    def refresh_streams(self) -> None: ...
    def calibrate(self, kind: str | None) -> Result: ...
    def calibrating(self) -> bool: ...


def as_int(value: float) -> int:
    """A command parameter as an integer; −1 for NaN, infinities and values beyond 32 bits (never raises)."""
    return int(value) if math.isfinite(value) and abs(value) < 2**31 else -1


def _result(ok: bool, reason: str, reply: object = None) -> Result:
    return (ACCEPTED if ok else DENIED), reason, reply


def arm_disarm(v: Vehicle, c: Command) -> Result:
    """MAV_CMD_COMPONENT_ARM_DISARM: p1 1 arm (after the arming checks), 0 disarm (in the air only forced: p2)."""
    cm = v.commander
    if c.param(1) == 1.0:
        reason = "" if cm.armed else gcs_messages.arming_check(v.has_state())
        if not reason and not cm.armed and v.calibrating():
            reason = "Arming denied: calibration in progress"
        if not reason and not cm.armed and cm.mode == wire.Mode.MISSION:  # arming in AUTO.MISSION starts it
            reason = v.missions.refusal(cm)
            reason = f"Arming denied: {reason}" if reason else ""
        ok, reason = (False, reason) if reason else cm.arm()
        if ok:
            v.armed()
        return _result(ok, reason)
    if c.param(1) == 0.0:
        state = v.state()
        if state is not None and gcs_messages.in_air(cm, state) and as_int(c.param(2)) != FORCE_DISARM:
            return DENIED, f"Disarming denied: in the air (force with param2 = {FORCE_DISARM})", None
        cm.disarm()
        return ACCEPTED, "", None
    return DENIED, f"Arm/disarm: param1 {c.param(1):g} is neither 0 nor 1", None


def do_set_mode(v: Vehicle, c: Command) -> Result:
    """MAV_CMD_DO_SET_MODE: p1 the base mode (custom mode enabled), p2 PX4's main mode, p3 its sub mode."""
    mode = None
    if as_int(c.param(1)) & mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
        mode = wire.Mode.from_px4(((as_int(c.param(2)) & 0xFF) << 16) | ((as_int(c.param(3)) & 0xFF) << 24))
    if mode is None:
        return UNSUPPORTED, f"Mode main {c.param(2):g} sub {c.param(3):g}: {SUPPORTED_MODES}", None
    return _result(*v.set_mode(mode))


def mission_start(v: Vehicle, c: Command) -> Result:
    """MAV_CMD_MISSION_START: p1 the first item (0: where the mission is)."""
    first = as_int(c.param(1))
    if 0 < first < len(v.missions.protocol.items) and v.missions.executor is not None:
        v.missions.executor.set_current(first)
    return _result(*v.set_mode(wire.Mode.MISSION))


def nav_land(v: Vehicle, c: Command) -> Result:
    """MAV_CMD_NAV_LAND: land here."""
    return _result(*v.commander.set_mode(wire.Mode.LAND))


def nav_return_to_launch(v: Vehicle, c: Command) -> Result:
    """MAV_CMD_NAV_RETURN_TO_LAUNCH."""
    return _result(*v.commander.set_mode(wire.Mode.RTL))


def nav_takeoff(v: Vehicle, c: Command) -> Result:
    """MAV_CMD_NAV_TAKEOFF: param7 (COMMAND_INT: z) the altitude AMSL, NaN: MIS_TAKEOFF_ALT above here. An altitude
    below MIS_TAKEOFF_ALT above home (MAVProxy's ``takeoff 5`` means 5 m above the ground, PX4 reads 5 m AMSL) takes
    off to that minimum instead, and says so, as PX4's navigator does."""
    _, _, alt, frame = c.location()
    altitude, raised = None, False
    if math.isfinite(alt):
        altitude = setpoints.altitude_of(frame, alt, v.frame())
        lowest = v.commander.home[2] + v.commander.settings.takeoff_alt
        altitude, raised = max(altitude, lowest), altitude < lowest
    elif not math.isnan(alt):
        return DENIED, f"Takeoff: altitude {alt:g}; expected a finite number or NaN", None
    ok, reason = v.commander.takeoff(altitude)
    if ok and raised:
        v.outbox.say(mavlink.MAV_SEVERITY_WARNING,
                     f"Using minimum takeoff altitude: {v.commander.settings.takeoff_alt:.2f} m")  # fmt: skip
    return _result(ok, reason)


def do_reposition(v: Vehicle, c: Command) -> Result:
    """MAV_CMD_DO_REPOSITION (MAVSDK's goto_location): p1 speed [m/s] (≤ 0 or NaN: MPC_XY_CRUISE), p2 bit 0 switch
    to hold, p4 yaw [rad], then the location; NaN keeps a value, all NaN stops here."""
    lat, lon, alt, frame = c.location()
    try:
        x, y, altitude = setpoints.reposition(lat, lon, alt, frame, v.frame())
    except setpoints.SetpointError as exc:
        v.outbox.counters.refused += 1
        return DENIED, str(exc), None
    yaw = c.param(4)
    if math.isinf(yaw):
        return DENIED, f"Reposition: yaw {yaw:g}; expected radians or NaN (keep)", None
    speed, top = c.param(1), v.commander.settings.xy_vel_max
    if math.isfinite(speed) and speed > top:
        return DENIED, f"Reposition: speed {speed:g} m/s; allowed: up to {top:g} m/s (MPC_XY_VEL_MAX)", None
    hold = as_int(c.param(2)) > 0 and as_int(c.param(2)) & 1
    if all(math.isnan(value) for value in (lat, lon, alt, yaw)):  # stop here
        x, y, altitude = v.commander.position_target_here()
    if v.commander.outside_fence(x, y, altitude):  # accepted, and ignored, as PX4's navigator ignores it
        v.outbox.say(mavlink.MAV_SEVERITY_CRITICAL, "Reposition is outside geofence")
        return ACCEPTED, "", None
    return _result(*v.commander.reposition(x, y, altitude, yaw, speed, bool(hold)))


def do_orbit(v: Vehicle, c: Command) -> Result:
    """MAV_CMD_DO_ORBIT (MAVSDK's do_orbit): p1 radius [m] (its sign the way round: positive clockwise), p2 speed
    [m/s], p3 ORBIT_YAW_BEHAVIOUR, p4 orbits (0: for ever), then the centre; NaN keeps a value
    (:meth:`Commander.orbit`). Refused: TEMPORARILY_REJECTED on the ground, as PX4's "Orbit command rejected"; DENIED
    for a radius, speed, heading, count or centre out of range."""
    lat, lon, alt, _ = c.location()  # the altitude is AMSL whatever the frame, as PX4 reads DO_ORBIT (and MAVSDK
    # sends it: an AMSL altitude in MAV_FRAME_GLOBAL_RELATIVE_ALT)
    try:
        x, y, altitude = setpoints.reposition(lat, lon, alt, setpoints.GLOBAL, v.frame(), what="Orbit")
    except setpoints.SetpointError as exc:
        v.outbox.counters.refused += 1
        return DENIED, str(exc), None
    if v.commander.flying() and v.commander.outside_fence(x, y, altitude):  # as a reposition outside
        v.outbox.say(mavlink.MAV_SEVERITY_CRITICAL, "Orbit is outside geofence")
        return ACCEPTED, "", None
    ok, reason = v.commander.orbit(c.param(1), c.param(2), c.param(3), c.param(4), x, y, altitude)
    if not ok and reason.endswith("(take off first)"):
        return mavlink.MAV_RESULT_TEMPORARILY_REJECTED, reason, None
    return _result(ok, reason)


def do_change_speed(v: Vehicle, c: Command) -> Result:
    """MAV_CMD_DO_CHANGE_SPEED: p1 speed type (0 air, 1 ground: the horizontal speed), p2 speed [m/s] (−1 or −2: no
    change / default)."""
    kind, speed = as_int(c.param(1)), c.param(2)
    if kind not in (0, 1):
        return UNSUPPORTED, f"Change speed: speed type {c.param(1):g}; supported: 0, 1", None
    if speed in (-1.0, -2.0):
        speed = v.params.values["MPC_XY_CRUISE"] if speed == -2.0 else math.nan
    if math.isnan(speed):
        return ACCEPTED, "", None
    top = v.commander.settings.xy_vel_max
    if not (math.isfinite(speed) and 0.0 < speed <= top):
        return DENIED, f"Change speed: {speed:g} m/s; allowed: (0, {top:g}] m/s", None
    v.commander.change_speed(speed)
    return ACCEPTED, "", None


def do_set_mission_current(v: Vehicle, c: Command) -> Result:
    """MAV_CMD_DO_SET_MISSION_CURRENT: p1 the item, p2 1: reset the mission."""
    result, outs = v.missions.protocol.do_set_mission_current(as_int(c.param(1)), as_int(c.param(2)) == 1)
    if result == ACCEPTED and v.missions.executor is not None:
        v.missions.executor.set_current(v.missions.protocol.current)
    for out in outs:
        v.outbox.mission(out)
    return result, "", None


def request_autopilot_capabilities(v: Vehicle, c: Command) -> Result:
    """MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES: AUTOPILOT_VERSION."""
    return ACCEPTED, "", gcs_messages.autopilot_version(v.system_id)


def get_home_position(v: Vehicle, c: Command) -> Result:
    """MAV_CMD_GET_HOME_POSITION: HOME_POSITION."""
    return ACCEPTED, "", v.home_position()


def request_message(v: Vehicle, c: Command) -> Result:
    """MAV_CMD_REQUEST_MESSAGE: p1 the message id, sent once."""
    mid = as_int(c.param(1))
    if mid == mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION:
        return ACCEPTED, "", gcs_messages.autopilot_version(v.system_id)
    if mid == mavlink.MAVLINK_MSG_ID_HOME_POSITION:
        return ACCEPTED, "", v.home_position()
    if mid == mavlink.MAVLINK_MSG_ID_HEARTBEAT:
        return ACCEPTED, "", gcs_messages.heartbeat(v.commander)
    if mid == mavlink.MAVLINK_MSG_ID_GPS_GLOBAL_ORIGIN:
        return ACCEPTED, "", gcs_messages.gps_global_origin(v.home)
    if v.streams.supported(mid):
        snap = v.snapshot()
        msg = None if snap is None else gcs_messages.build(mid, snap, v.commander, v.home)
        if msg is None:  # no state yet, or nothing to say (ORBIT_EXECUTION_STATUS while not orbiting)
            return mavlink.MAV_RESULT_TEMPORARILY_REJECTED, "", None
        return ACCEPTED, "", msg
    return UNSUPPORTED, "", None


def set_message_interval(v: Vehicle, c: Command) -> Result:
    """MAV_CMD_SET_MESSAGE_INTERVAL: p1 the message id, p2 the interval [µs] (−1 stop, 0 default), on the link the
    command came on (as PX4)."""
    interval = c.param(2)
    reason = c.link.streams.set_interval(as_int(c.param(1)), interval) if math.isfinite(interval) else "NaN"
    v.refresh_streams()
    return (DENIED if reason else ACCEPTED), reason, None


def get_message_interval(v: Vehicle, c: Command) -> Result:
    """MAV_CMD_GET_MESSAGE_INTERVAL: p1 the message id → MESSAGE_INTERVAL on the command's link."""
    mid = as_int(c.param(1))
    if c.link.streams.supported(mid):
        return ACCEPTED, "", mavlink.MAVLink_message_interval_message(mid, c.link.streams.interval_us(mid))
    return DENIED, f"Message interval: message id {c.param(1):g} is not streamed", None


def inject_failure(v: Vehicle, c: Command) -> Result:
    """MAV_CMD_INJECT_FAILURE (PX4's failure injection; refused unless SYS_FAILURE_EN is 1): p1 the unit
    (FAILURE_UNIT_*), p2 the type (FAILURE_TYPE_*), p3 the instance (0: all). What the vehicle takes is
    :data:`autopilot.failures.TAKEN`; the rest is unsupported, naming what is taken."""
    if not v.commander.settings.failure_injection:
        return DENIED, "Failure injection disabled: set SYS_FAILURE_EN to 1", None
    ok, reason = v.inject_failure(as_int(c.param(1)), as_int(c.param(2)), as_int(c.param(3)))
    return (ACCEPTED if ok else UNSUPPORTED), reason, None


def preflight_calibration(v: Vehicle, c: Command) -> Result:
    """MAV_CMD_PREFLIGHT_CALIBRATION, as PX4's commander answers it (:mod:`autopilot.calibration`): p1 = 1 gyro,
    p2 = 1 magnetometer, p5 = 1 accelerometer, p5 = 2 level; all 0 cancels the one running. Armed, or while one
    runs: TEMPORARILY_REJECTED."""
    if v.commander.armed:
        return mavlink.MAV_RESULT_TEMPORARILY_REJECTED, "Calibration denied: armed", None
    return v.calibrate(calibration.which(tuple(c.param(i) for i in range(1, 8))))


COMMANDS: dict[int, Callable[[Vehicle, Command], Result]] = {
    mavlink.MAV_CMD_COMPONENT_ARM_DISARM: arm_disarm,
    mavlink.MAV_CMD_DO_SET_MODE: do_set_mode,
    mavlink.MAV_CMD_MISSION_START: mission_start,
    mavlink.MAV_CMD_NAV_LAND: nav_land,
    mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH: nav_return_to_launch,
    mavlink.MAV_CMD_NAV_TAKEOFF: nav_takeoff,
    mavlink.MAV_CMD_DO_REPOSITION: do_reposition,
    mavlink.MAV_CMD_DO_ORBIT: do_orbit,
    mavlink.MAV_CMD_DO_CHANGE_SPEED: do_change_speed,
    mavlink.MAV_CMD_DO_SET_MISSION_CURRENT: do_set_mission_current,
    mavlink.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES: request_autopilot_capabilities,
    mavlink.MAV_CMD_GET_HOME_POSITION: get_home_position,
    mavlink.MAV_CMD_REQUEST_MESSAGE: request_message,
    mavlink.MAV_CMD_SET_MESSAGE_INTERVAL: set_message_interval,
    mavlink.MAV_CMD_GET_MESSAGE_INTERVAL: get_message_interval,
    mavlink.MAV_CMD_INJECT_FAILURE: inject_failure,
    mavlink.MAV_CMD_PREFLIGHT_CALIBRATION: preflight_calibration,
}


def run(v: Vehicle, c: Command) -> None:
    """``c`` done (or refused) and answered: COMMAND_ACK, the message it asked for, the reason of a refusal."""
    handler = COMMANDS.get(c.command)
    result, reason, reply = handler(v, c) if handler is not None else (UNSUPPORTED, "", None)
    v.outbox.command_ack(c, result, reason, reply)
