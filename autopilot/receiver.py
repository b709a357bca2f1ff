"""The ground-station receiver, as PX4's ``mavlink_receiver``: each MAVLink message has one handler, which checks who
it is for and turns it into a typed record (:mod:`autopilot.records`) delivered to the record's route; a message it
cannot fly is refused with a reason (:class:`autopilot.outbox.Outbox`). It never calls control code.

Offboard setpoints of a ground station that paces them by the vehicle's clock (``--offboard-lockstep``,
:mod:`autopilot.offboard_lockstep`) are held here until the tick they were made for, then delivered.
"""

from __future__ import annotations

import math
import struct
import time
from collections.abc import Callable

import numpy as np

from autopilot import mission_protocol, missions, setpoints
from autopilot import tick as kernel
from autopilot.offboard_lockstep import OffboardLockstep
from autopilot.outbox import Outbox
from autopilot.records import (
    AttitudeSetpoint,
    Command,
    Counters,
    FileTransfer,
    FollowTarget,
    GroundHeartbeat,
    LogRequest,
    ManualControl,
    MissionMessage,
    ModeRequest,
    ParamRequest,
    ParamSet,
    Routes,
    TrajectorySetpoint,
)
from quadsitl import codec, wire
from quadsitl.compiled_frames import geodetic_to_ned, quaternion_to_euler

mavlink = wire.mavlink
QUATERNION_TOLERANCE = 0.1  # |q|² − 1 within this: normalised; beyond: refused
# SET_ATTITUDE_TARGET's type_mask bits (ATTITUDE_TARGET_TYPEMASK): the attitude is ignored (body rates alone); the
# thrust is ignored; the thrust is the extension field thrust_body (x, y, z in the body frame) instead.
RATES_ONLY, THROTTLE_IGNORE, THRUST_BODY_SET = 128, 64, 32
STICK_FULL = 1000  # MANUAL_CONTROL's full deflection (x, y, r: ±1000; z, throttle: 0..1000)
AXIS_UNUSED = 32767  # INT16_MAX: MANUAL_CONTROL's "this axis is invalid"
THRUST_BODY_AT = 39  # [bytes] where SET_ATTITUDE_TARGET's thrust_body extension starts in its payload
FTP_HEADER = 12  # bytes of a FILE_TRANSFER_PROTOCOL payload's header: shorter is not a request
LOG_MESSAGES = (mavlink.MAVLINK_MSG_ID_LOG_REQUEST_LIST, mavlink.MAVLINK_MSG_ID_LOG_REQUEST_DATA,
                mavlink.MAVLINK_MSG_ID_LOG_REQUEST_END, mavlink.MAVLINK_MSG_ID_LOG_ERASE)  # fmt: skip
OFFBOARD_SETPOINTS = frozenset((mavlink.MAVLINK_MSG_ID_SET_ATTITUDE_TARGET,
                                mavlink.MAVLINK_MSG_ID_SET_POSITION_TARGET_LOCAL_NED,
                                mavlink.MAVLINK_MSG_ID_SET_POSITION_TARGET_GLOBAL_INT))  # fmt: skip


class Receiver:
    """Messages from the ground links → records to ``routes``. ``frame()`` is where setpoints are measured from and
    the limits they keep (:class:`autopilot.setpoints.Frame`), ``max_tilt()`` the attitude setpoints' limit [rad];
    ``io`` the tick's bookkeeping (the tick flown, for held setpoints)."""

    def __init__(self, system: int, component: int, routes: Routes, outbox: Outbox, counters: Counters,
                 frame: Callable[[], setpoints.Frame], max_tilt: Callable[[], float], io: np.ndarray,
                 pace: OffboardLockstep | None = None) -> None:  # fmt: skip
        self.system, self.component, self.routes, self.outbox = system, component, routes, outbox
        self.counters, self.frame, self.max_tilt, self.io, self.pace = counters, frame, max_tilt, io, pace
        self.handlers: dict[int, Callable] = {
            mavlink.MAVLINK_MSG_ID_COMMAND_LONG: self._command,
            mavlink.MAVLINK_MSG_ID_COMMAND_INT: self._command,
            mavlink.MAVLINK_MSG_ID_SET_ATTITUDE_TARGET: self._attitude_target,
            mavlink.MAVLINK_MSG_ID_SET_POSITION_TARGET_LOCAL_NED: self._position_target_local,
            mavlink.MAVLINK_MSG_ID_SET_POSITION_TARGET_GLOBAL_INT: self._position_target_global,
            mavlink.MAVLINK_MSG_ID_SET_MODE: self._set_mode,
            mavlink.MAVLINK_MSG_ID_PARAM_REQUEST_LIST: self._param_request_list,
            mavlink.MAVLINK_MSG_ID_PARAM_REQUEST_READ: self._param_request_read,
            mavlink.MAVLINK_MSG_ID_PARAM_SET: self._param_set,
            mavlink.MAVLINK_MSG_ID_FILE_TRANSFER_PROTOCOL: self._file_transfer,
            **dict.fromkeys(LOG_MESSAGES, self._log),
        }

    def on_message(self, m, link) -> None:
        """One message from ``link``: to its handler, when it is for this vehicle and one we take."""
        mid = m.get_msgId()
        if mid == mavlink.MAVLINK_MSG_ID_MANUAL_CONTROL:  # its target is ``target``, a system alone (0: any)
            if m.target in (0, self.system):
                self._manual_control(m, link)
            else:
                self.counters.not_for_us += 1
            return
        if mid == mavlink.MAVLINK_MSG_ID_FOLLOW_TARGET:  # a broadcast: follow-me's target
            self._follow_target(m)
            return
        if not hasattr(m, "target_system"):  # broadcasts: a ground station's heartbeat is a sign of the datalink
            if mid != mavlink.MAVLINK_MSG_ID_HEARTBEAT:
                self.counters.unknown += 1
            elif m.type == mavlink.MAV_TYPE_GCS:
                self.routes.deliver(GroundHeartbeat(time.monotonic()))
            return
        if mid in missions.MESSAGES:
            if mission_protocol.addressed_to(m.target_system, m.target_component, self.system, self.component):
                self.routes.deliver(MissionMessage(mid, (m.get_srcSystem(), m.get_srcComponent()), m.to_dict()))
            else:
                self.counters.not_for_us += 1
            return
        if not self._for_me(m.target_system, getattr(m, "target_component", 0)):  # SET_MODE has no component
            self.counters.not_for_us += 1
            return
        if self.pace is not None and mid in OFFBOARD_SETPOINTS:
            self.pace.stamp(m.time_boot_ms)
            if self.pace.hold(self.pace.tick_of(m.time_boot_ms), int(self.io[kernel.TICK]), m):
                return  # made for a later tick: delivered from it (release)
        handler = self.handlers.get(mid)
        if handler is None:
            self.counters.unknown += 1
        else:
            handler(m, link)

    def release(self) -> bool:
        """``--offboard-lockstep``: the setpoints held for the next tick (or before) delivered now, between the tick
        just flown and the next → whether any was held."""
        if self.pace is None or not self.pace.held:
            return False
        for m in self.pace.due(int(self.io[kernel.TICK]) + 1):
            self.handlers[m.get_msgId()](m, None)
        return True

    def _for_me(self, system: int, component: int) -> bool:
        return system in (0, self.system) and component in (0, self.component)

    # ---- one handler per message -------------------------------------------------------------------

    def _command(self, m, link) -> None:
        is_int = m.get_msgId() == mavlink.MAVLINK_MSG_ID_COMMAND_INT
        if is_int:
            params = (m.param1, m.param2, m.param3, m.param4, float(m.x), float(m.y), m.z)
            frame = m.frame
        else:
            params = (m.param1, m.param2, m.param3, m.param4, m.param5, m.param6, m.param7)
            frame = setpoints.GLOBAL
        self.routes.deliver(Command(m.command, params, frame, is_int, (m.get_srcSystem(), m.get_srcComponent()),
                                    link))  # fmt: skip

    def _position_target_local(self, m, link) -> None:
        self._position_target(m, (m.x, m.y, m.z))

    def _position_target_global(self, m, link) -> None:
        self._position_target(m, (float(m.lat_int), float(m.lon_int), m.alt))

    def _position_target(self, m, pos: tuple[float, float, float]) -> None:
        """SET_POSITION_TARGET_LOCAL_NED or _GLOBAL_INT: refused with a reason, or a trajectory setpoint."""
        try:
            groups = setpoints.position_target(m.coordinate_frame, m.type_mask, pos, (m.vx, m.vy, m.vz),
                                               (m.afx, m.afy, m.afz), m.yaw, m.yaw_rate, self.frame())  # fmt: skip
        except setpoints.SetpointError as exc:
            self.outbox.refuse(f"position {exc.kind}", str(exc))
            return
        self.routes.deliver(TrajectorySetpoint(*groups, wall=time.monotonic()))

    def _attitude_target(self, m, link) -> None:
        """SET_ATTITUDE_TARGET: the attitude reference and, as PX4 reads it, the normalised collective thrust (its
        ``thrust``, or ``thrust_body`` when type_mask sets THRUST_BODY_SET; ignored with THROTTLE_IGNORE: the vertical
        setpoint stays as it was). type_mask 128 (attitude ignored) carries no attitude we can fly (no body-rate
        control here), so it is not a setpoint."""
        if m.type_mask & RATES_ONLY:
            self.outbox.say_once("rates", "Attitude setpoint ignored: body-rate setpoints (type_mask 128) not "
                                          "supported")  # fmt: skip
            return
        q = m.q
        n2 = sum(x * x for x in q) if all(map(math.isfinite, q)) else math.nan
        if not abs(n2 - 1.0) < QUATERNION_TOLERANCE:  # False for NaN too
            self.outbox.refuse("quat", f"Attitude setpoint refused: |q|^2 = {n2:.3g}, not a unit quaternion")
            return
        n = math.sqrt(n2)
        roll, pitch, yaw = quaternion_to_euler(*(x / n for x in q))
        tilt = self.max_tilt()
        if abs(roll) > tilt or abs(pitch) > tilt:
            self.outbox.refuse("tilt", f"Attitude setpoint refused: roll {roll:.3f}, pitch {pitch:.3f} rad beyond "
                                       f"ATT_TILT_MAX {tilt:.3f} rad")  # fmt: skip
            return
        thrust = self._thrust(m)
        if thrust is not None:
            self.routes.deliver(AttitudeSetpoint(roll, pitch, yaw, wall=time.monotonic(), thrust=thrust))

    def _thrust(self, m) -> float | None:
        """SET_ATTITUDE_TARGET's normalised collective thrust (NaN: ignored), or None when refused (said why)."""
        if m.type_mask & THRUST_BODY_SET:
            tx, ty, tz = thrust_body(m)
            if tx != 0.0 or ty != 0.0:
                why = f"thrust_body x {tx:g}, y {ty:g}; a quadrotor's thrust is along its body z axis alone (x = y = 0)"
                self.outbox.refuse("thrust_body", f"Attitude setpoint refused: {why}")
                return None
            value, field = -tz, "-thrust_body z"
        elif m.type_mask & THROTTLE_IGNORE:
            return math.nan
        else:
            value, field = m.thrust, "thrust"
        low = self.frame().thrust_low
        if not low <= value <= 1.0:  # False for NaN too
            self.outbox.refuse("thrust", f"Attitude setpoint refused: {field} {value:g}; allowed: [{low:g}, 1] "
                                         f"(normalised collective thrust)")  # fmt: skip
            return None
        return value

    def _manual_control(self, m, link) -> None:
        """MANUAL_CONTROL: the sticks, as PX4 reads them (:class:`autopilot.records.ManualControl`). An axis beyond its
        range (x, y, r: ±1000; z: 0..1000) refuses the whole message, said once, and the sticks stay as they were: no
        stick is flown clipped, and a refused message is no sign of life for the sticks' loss."""
        axes = {"x": m.x, "y": m.y, "z": m.z, "r": m.r}
        bad = [f"{name} {value}" for name, value in axes.items() if value != AXIS_UNUSED
               and not (0 if name == "z" else -STICK_FULL) <= value <= STICK_FULL]  # fmt: skip
        if bad:
            self.outbox.refuse("manual_control", f"MANUAL_CONTROL refused: {', '.join(bad)}; allowed: x, y, r in "
                                                 f"[-{STICK_FULL}, {STICK_FULL}], z in [0, {STICK_FULL}]")  # fmt: skip
            return

        def axis(value: int, centre: float = 0.0) -> float:
            return centre if value == AXIS_UNUSED else value / STICK_FULL

        throttle = 2.0 * axis(m.z, 0.5) - 1.0  # PX4: z 0..1000 → −1..1
        self.routes.deliver(ManualControl(axis(m.x), axis(m.y), throttle, axis(m.r), wall=time.monotonic()))

    def _follow_target(self, m) -> None:
        """FOLLOW_TARGET: the target's position (lat, lon [1e-7 deg], alt AMSL [m]) and velocity (NED [m/s], NaN or
        all three needed), as PX4 reads it, in local NED; one with a position out of range, or not finite, refused."""
        lat, lon, alt = m.lat * 1e-7, m.lon * 1e-7, m.alt
        if not (-90.0 <= lat <= 90.0 and -180.0 <= lon <= 180.0 and math.isfinite(alt)):
            why = f"lat {lat:g}, lon {lon:g} deg, alt {alt:g} m"
            self.outbox.refuse("follow_target", f"FOLLOW_TARGET refused: {why}; allowed: lat [-90, 90], lon "
                                                "[-180, 180], a finite altitude")  # fmt: skip
            return
        vel = tuple(m.vel)
        if not all(map(math.isfinite, vel)):
            vel = (math.nan,) * 3
        f = self.frame()
        x, y = geodetic_to_ned(lat, lon, f.origin[0], f.origin[1])
        altitude = setpoints.altitude_of(setpoints.GLOBAL, alt, f)  # AMSL → above the local origin
        self.routes.deliver(FollowTarget(x, y, altitude, vel[0], vel[1], -vel[2], wall=time.monotonic()))

    def _set_mode(self, m, link) -> None:
        """SET_MODE, QGroundControl's way to PX4 modes (no acknowledgement)."""
        custom = m.base_mode & mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
        self.routes.deliver(ModeRequest(wire.Mode.from_px4(m.custom_mode) if custom else None, m.custom_mode))

    def _param_request_list(self, m, link) -> None:
        self.routes.deliver(ParamRequest(None))

    def _param_request_read(self, m, link) -> None:
        self.routes.deliver(ParamRequest(m.param_id, m.param_index))

    def _param_set(self, m, link) -> None:
        value = wire.param_from_wire(m.param_value, m.param_type)  # an integer's bytes, as PX4 takes them
        self.routes.deliver(ParamSet(m.param_id, value, (m.get_srcSystem(), m.get_srcComponent())))

    def _log(self, m, link) -> None:
        self.routes.deliver(LogRequest(m.get_msgId(), m.to_dict(), link))

    def _file_transfer(self, m, link) -> None:
        if len(m.payload) >= FTP_HEADER:
            self.routes.deliver(FileTransfer(bytes(m.payload), (m.get_srcSystem(), m.get_srcComponent())))
        else:
            self.counters.unknown += 1


def thrust_body(m) -> tuple[float, float, float]:
    """SET_ATTITUDE_TARGET's ``thrust_body`` (a MAVLink 2 extension our pymavlink's dialect predates), read from the
    frame: three float32 after the 39 bytes of the base payload, zeros where MAVLink 2 truncated them."""
    frame = bytes(m.get_msgbuf())
    if not frame or frame[0] != codec.MAVLINK2_STX:
        return 0.0, 0.0, 0.0
    payload = frame[codec.HEADER_SIZE : codec.HEADER_SIZE + frame[1]]
    ext = payload[THRUST_BODY_AT : THRUST_BODY_AT + 12].ljust(12, b"\0")
    return struct.unpack("<3f", ext)
