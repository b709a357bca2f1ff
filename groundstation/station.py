"""The ground station (:class:`GroundStation`) of ``quadsitl gcs`` (the process: :mod:`groundstation.gcs`).

Connects over MAVLink (UDP), waits for the autopilot's heartbeat, streams setpoints before arming
(the PX4 offboard convention), arms, switches to offboard, flies the trajectory for ``--duration``
simulated seconds, then lands and waits for the disarm (:meth:`GroundStation.fly`). Its Zenoh subscriber logs the
telemetry to ``telemetry.csv``; its MAVLink link, both directions, goes to ``flight.tlog`` (each packet preceded by
an 8-byte big-endian microsecond timestamp, as MAVProxy and QGroundControl write it).

Setpoints are paced in simulated time (:mod:`groundstation.pacing`): one per 20 ms of the vehicle's time seen, and
at least every 100 ms of wall time, each the trajectory at that moment, stamped with it (time_boot_ms). With
``--setpoints-ahead S`` (``quadsitl fly``'s) they are the trajectory on the grid of :mod:`groundstation.setpoint_grid`,
sent up to S ahead of the vehicle's clock and stamped with the tick each is for; the autopilot flies each from that
tick and holds its clock until the ground station is ahead (:mod:`autopilot.offboard_lockstep`), so a flight is the
same to the byte on any machine. An attitude trajectory (:mod:`groundstation.trajectories`) sends a pair,
SET_ATTITUDE_TARGET and a z-only SET_POSITION_TARGET_LOCAL_NED; a position trajectory one SET_POSITION_TARGET_LOCAL_NED
in MAV_FRAME_LOCAL_NED with type_mask 2496 (position, velocity feed-forward and yaw). Before the switch to offboard
both send the trajectory's start (t = 0), so a position trajectory climbs and settles at its start point first.

A mission is flown by :class:`groundstation.mission_flight.MissionFlight`, a ground station of its own kind. A
flight's phases are :class:`Phase`'s.
"""

from __future__ import annotations

import argparse
import contextlib
import enum
import itertools
import json
import os
import socket
import struct
import sys
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import zenoh

from groundstation import mission_files, trajectories
from groundstation.logger import TelemetryLogger
from groundstation.mission_files import MISSION_DURATION
from groundstation.pacing import (
    LOOP,
    STEADY_LOOKAHEAD,
    WAIT_MOVING,
    ahead_setpoints,
    attitude_interval_us,
    holds_still,
    horizon,
    horizon_step,
    measured_pace,
    read_interval,
    setpoint_due,
)
from groundstation.progress import FlightProgress
from groundstation.setpoint_grid import POSITION_VELOCITY_YAW
from groundstation.telemetry_csv import write_csv
from quadsitl import telemetry, wire
from quadsitl.config import load_preset
from quadsitl.frames import euler_to_quaternion
from quadsitl.process_util import parse_address, readable_of
from quadsitl.state import Reference

mavlink = wire.mavlink
# SET_ATTITUDE_TARGET: the attitude alone (rates and thrust ignored; the altitude is a position target beside it)
MASK_ATTITUDE_ONLY = 1 | 2 | 4 | 64
MASK_Z_ONLY = 0b0000_1101_1111_1011  # SET_POSITION_TARGET_LOCAL_NED: only z (and yaw ignored: 1024, rate 2048)
MASK_POSITION_VELOCITY_YAW = POSITION_VELOCITY_YAW  # a position trajectory's (groundstation.setpoint_grid)
COMMAND_RETRY = 0.5  # [s] wall: a command is sent again until acknowledged (MAVSDK waits 0.5 s too)
# [s] wall: how long a refusal's COMMAND_ACK waits for its reason, the STATUSTEXT sent right after it (in chunks when
# long), before the ground station says it was refused
REASON_WAIT = 1.0
# [s] wall: after the flight, the ground station waits for telemetry still on its way until this long passes without
# a sample (a fixed 2 s could end while a loaded machine was still delivering a backlog)
TELEMETRY_QUIET = 2.0


UNNEEDED_STREAMS = (
    mavlink.MAVLINK_MSG_ID_ATTITUDE_QUATERNION,
    mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED,
    mavlink.MAVLINK_MSG_ID_ATTITUDE_TARGET,
    mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT,
    mavlink.MAVLINK_MSG_ID_GPS_RAW_INT,
    mavlink.MAVLINK_MSG_ID_POSITION_TARGET_LOCAL_NED,
    mavlink.MAVLINK_MSG_ID_SERVO_OUTPUT_RAW,
    mavlink.MAVLINK_MSG_ID_ACTUATOR_OUTPUT_STATUS,
    # The autopilot builds these in Python, each on a tick of its own (autopilot.streams): every one is a trip out of
    # its compiled loop while the plant waits (docs/performance.md#in-lockstep).
    mavlink.MAVLINK_MSG_ID_HOME_POSITION,
    mavlink.MAVLINK_MSG_ID_ESTIMATOR_STATUS,
    mavlink.MAVLINK_MSG_ID_EXTENDED_SYS_STATE,
)
# SYS_STATUS is read for its pre-arm check until the flight starts, and then not: it goes then.
UNNEEDED_IN_FLIGHT = (mavlink.MAVLINK_MSG_ID_SYS_STATUS,)


class GcsError(Exception):
    """A flight that cannot go on: the ground station says why in one line and exits with status 1."""


class Phase(enum.Enum):
    """Where a flight is. A trajectory: CONNECT (until the autopilot's heartbeat), PREARM (setpoints streaming, until
    the telemetry arrives and the pre-arm check passes), ARMING and OFFBOARD (in that order, or the other with
    ``--arm-at``), FLYING, LANDING, DONE. A mission: CONNECT, UPLOAD, PREARM, ARMING, STARTING (AUTO.MISSION),
    FLYING, LANDING (a mission that does not land itself), DONE. The value is the name messages give."""

    CONNECT = "connect"
    UPLOAD = "upload"
    PREARM = "prearm"
    ARMING = "arming"
    OFFBOARD = "offboard"
    STARTING = "starting"
    FLYING = "flying"
    LANDING = "landing"
    DONE = "done"


class GroundStation:
    """A ground station flying ``args``' trajectory (or, as :class:`groundstation.mission_flight.MissionFlight`, its
    mission): its MAVLink link to the autopilot, its Zenoh telemetry logger, its setpoints and their pacing, and
    what the flight leaves in ``--out`` (telemetry.csv, flight.tlog, rate.json)."""

    def __init__(self, args: argparse.Namespace) -> None:
        self.args = args
        self.preset = load_preset(args.preset)
        self.period = self.preset.sim.period
        self.mission = mission_files.load(args.mission) if args.mission else None
        if self.mission is not None:
            self.trajectory = None
            self.position = True
            self.duration = args.duration or MISSION_DURATION
        else:
            self.trajectory = trajectories.make(args.trajectory, self.preset.reference)
            self.position = isinstance(self.trajectory, trajectories.PositionTrajectory)
            natural = self.trajectory.duration if self.position else None
            self.duration = args.duration or natural or self.preset.sim.duration
        self.out = Path(args.out)
        self.out.mkdir(parents=True, exist_ok=True)
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.connect(parse_address("--connect", args.connect))
        self.sock.settimeout(0.005)
        self.mav = wire.link(wire.GCS_SYSTEM_ID, wire.GCS_COMPONENT_ID)
        if args.signing_key is not None:
            wire.enable_signing(self.mav, args.signing_key)
        self.tlog = open(self.out / "flight.tlog", "wb")  # noqa: SIM115 - closed in close()
        conf = telemetry.config_from_args(args)  # no shared memory: its channels would hold the pool (zenoh_shm)
        self.session = zenoh.open(conf)
        start = "armed" if self.mission is not None else "offboard"
        self.logger = TelemetryLogger(self.session, args.vehicle, self.period, start)
        self.sim_ms = 0  # the vehicle's time [ms] in its newest ATTITUDE (MAVLink comes before Zenoh's batches)
        self.ahead = round(args.setpoints_ahead / self.period)  # [ticks] --setpoints-ahead (0: off)
        self.end_ticks = round(self.duration / self.period)  # the flight's last tick, counted from its first
        self.next_moment = -1  # --setpoints-ahead: the tick the next setpoint is made for (−1: the flight's start)
        self.keep = horizon_step(self.ahead, self.period)  # --setpoints-ahead: the grid the horizon moves on [ticks]
        self.target = (args.target_system, wire.AUTOPILOT_COMPONENT_ID)
        self.armed = False
        self.armable = False  # SYS_STATUS says the pre-arm check passes (in sensor mode: once the estimator aligned)
        self.mode: wire.Mode | None = None
        self.heard = False
        self.acks: dict[int, int] = {}
        self.said: list[str] = []  # the vehicle's STATUSTEXTs since the last command sent
        self._chunks: dict[int, list[str]] = {}  # a STATUSTEXT's chunks by id, until its last
        self.flight_rate: tuple[float, float] | None = None
        self.progress: FlightProgress | None = None  # from the switch to offboard until landing
        self.last_read = 0.0  # monotonic time of the last socket read (poll)
        self.interval = LOOP  # [s] wall: from the last read to the next
        self.wait_data = 0.0  # [s] wall: > interval: the next read also waits for a datagram, up to this long
        self._pace_mark = (0.0, 0)  # (monotonic time, vehicle tick) the vehicle's pace is measured from
        self.pace = 0.0  # simulated seconds per wall second, over the last PACE_WINDOW (0: not known)
        # the mission: items requested (seq, legacy), the upload's MISSION_ACK
        self.requested: list[int] = []
        self.mission_ack: int | None = None
        self.upload_type = 0  # the mission_type being uploaded (0 mission, 1 geofence, 2 rally points)

    # ---- MAVLink ---------------------------------------------------------------------------------

    def _log(self, buf: bytes) -> None:
        self.tlog.write(struct.pack(">Q", int(time.time() * 1e6)) + buf)

    def send(self, msg: mavlink.MAVLink_message) -> None:
        """``msg`` to the autopilot, and to flight.tlog."""
        buf = msg.pack(self.mav)
        self._log(buf)
        with contextlib.suppress(ConnectionRefusedError):  # nobody listening yet; UDP
            self.sock.send(buf)

    def poll(self) -> None:
        """Read everything waiting, ``interval`` seconds after the last read (LOOP, or longer while the reference
        holds still: :func:`groundstation.pacing.read_interval`), and when ``wait_data`` is longer, not before a
        datagram comes either, until ``wait_data`` after the last read: between reads the datagrams wait in the socket
        (a ground station that woke for each one in a fast lockstep run would take a core from the lockstep processes
        each time: docs/performance.md#the-ground-station-in-lockstep)."""
        if self.wait_data > self.interval:
            readable_of([self.sock], self.last_read + self.wait_data - time.monotonic())
        time.sleep(max(0.0, self.last_read + self.interval - time.monotonic()))
        self.last_read = time.monotonic()
        self.read_waiting()

    def read_waiting(self) -> None:
        """Handle every datagram waiting on the socket (up to 1000), without waiting for more."""
        self.sock.settimeout(0.0)
        for _ in range(1000):
            try:
                data = self.sock.recv(65535)
            except (BlockingIOError, ConnectionRefusedError):
                return
            self._handle(data)

    def _handle(self, data: bytes) -> None:
        for m in self.mav.parse_buffer(data) or []:
            self._log(m.get_msgbuf())
            mid = m.get_msgId()
            if mid == mavlink.MAVLINK_MSG_ID_HEARTBEAT and m.get_srcComponent() == wire.AUTOPILOT_COMPONENT_ID:
                self.heard = True
                self.armed = bool(m.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED)
                self.mode = wire.Mode.from_px4(m.custom_mode)
            elif mid == mavlink.MAVLINK_MSG_ID_ATTITUDE:
                self.sim_ms = max(self.sim_ms, m.time_boot_ms)
            elif mid == mavlink.MAVLINK_MSG_ID_SYS_STATUS:
                self.armable = bool(m.onboard_control_sensors_health & mavlink.MAV_SYS_STATUS_PREARM_CHECK)
            elif mid == mavlink.MAVLINK_MSG_ID_COMMAND_ACK:
                self.acks[m.command] = m.result
            elif mid in (mavlink.MAVLINK_MSG_ID_MISSION_REQUEST_INT, mavlink.MAVLINK_MSG_ID_MISSION_REQUEST):
                if getattr(m, "mission_type", 0) == self.upload_type and m.target_system == wire.GCS_SYSTEM_ID:
                    self.requested.append(m.seq)
            elif mid == mavlink.MAVLINK_MSG_ID_MISSION_ACK:
                if getattr(m, "mission_type", 0) == self.upload_type and m.target_system == wire.GCS_SYSTEM_ID:
                    self.mission_ack = m.type
            elif mid == mavlink.MAVLINK_MSG_ID_STATUSTEXT:
                text = self._statustext(m)
                if text is not None:
                    self.said.append(text)  # a refusal's reason comes beside its COMMAND_ACK (until_accepted)
                    if not self.args.quiet:
                        print(f"gcs: vehicle says: {text}", file=sys.stderr)

    def _statustext(self, m) -> str | None:
        """A STATUSTEXT's whole text, its chunks joined (MAVLink 2: an ``id``, 50 characters a chunk, the last one
        shorter), or None while chunks are still to come."""
        if not m.id:
            return m.text
        parts = self._chunks.setdefault(m.id, [])
        parts.append(m.text)
        return "".join(self._chunks.pop(m.id)) if len(m.text) < 50 else None

    def send_setpoint(self, ref: Reference | trajectories.PositionSetpoint, ms: int | None = None) -> None:
        """One setpoint of the trajectory: a position setpoint, or an attitude + altitude pair; stamped ``ms``
        (time_boot_ms: the vehicle's time it is made for; default :meth:`stamp_ms`)."""
        if isinstance(ref, trajectories.PositionSetpoint):
            self.send_position_setpoint(ref, ms)
            return
        ts, tc = self.target
        q = euler_to_quaternion(ref.roll, ref.pitch, ref.yaw)
        ms, frame = self.stamp_ms() if ms is None else ms, mavlink.MAV_FRAME_LOCAL_NED
        self.send(mavlink.MAVLink_set_attitude_target_message(ms, ts, tc, MASK_ATTITUDE_ONLY, q, 0, 0, 0, 0.0))
        z = -ref.altitude  # NED: z down
        self.send(mavlink.MAVLink_set_position_target_local_ned_message(
            ms, ts, tc, frame, MASK_Z_ONLY, 0, 0, z, 0, 0, 0, 0, 0, 0, 0, 0))  # fmt: skip

    def send_position_setpoint(self, sp: trajectories.PositionSetpoint, ms: int | None = None) -> None:
        """SET_POSITION_TARGET_LOCAL_NED, frame LOCAL_NED: x, y [m] and z = −altitude, the velocity
        feed-forward vx, vy and vz = −climb [m/s], yaw [rad]; stamped ``ms`` (default :meth:`stamp_ms`)."""
        ts, tc = self.target
        ms, frame = self.stamp_ms() if ms is None else ms, mavlink.MAV_FRAME_LOCAL_NED
        self.send(mavlink.MAVLink_set_position_target_local_ned_message(
            ms, ts, tc, frame, MASK_POSITION_VELOCITY_YAW, sp.x, sp.y, -sp.altitude, sp.vx, sp.vy, -sp.climb,
            0, 0, 0, sp.yaw, 0))  # fmt: skip

    def send_ahead(self, last_sent: object) -> object:
        """``--setpoints-ahead``: the setpoints of the grid up to the horizon (:func:`groundstation.pacing.horizon`)
        not sent yet that go out (:func:`groundstation.pacing.ahead_setpoints`), each stamped with the tick it is
        made for. Returns the last setpoint sent. The horizon moves once per ``keep`` ticks of the vehicle's clock,
        so the ground station reads that often (:func:`groundstation.pacing.read_interval`); each setpoint costs the
        autopilot two trips out of its compiled loop, so a constant reference goes once per ``keep`` ticks."""
        start = self.logger.flight_start_tick
        furthest = horizon(start, self.vehicle_tick(), self.ahead, self.keep, start + self.end_ticks)
        sends, self.next_moment = ahead_setpoints(self.trajectory, self.period, start, self.end_ticks, self.keep,
                                                  self.next_moment, furthest, last_sent)  # fmt: skip
        for tick, sp in sends:
            self.send_setpoint(sp, self.ms_of(tick))
        return sends[-1][1] if sends else last_sent

    def measure_pace(self, now: float) -> float:
        """The vehicle's pace [simulated s per wall s] at wall time ``now`` [s], 0 until known
        (:func:`groundstation.pacing.measured_pace`)."""
        self.pace, self._pace_mark = measured_pace(now, self._pace_mark, self.vehicle_tick(), self.period, self.pace)
        return self.pace

    def read_timing(self, now: float, t: float, last_sent: object) -> tuple[float, float]:
        """In flight, at wall time ``now`` [s] and flight time ``t`` [s]: (``interval``, ``wait_data``) for the next
        read (:meth:`poll`). Sending ahead, once per move of the horizon: what goes out does not depend on when it
        is read. A reference that holds still (:func:`groundstation.pacing.holds_still`), by the vehicle's pace. A
        moving one, or the landing near (a change too), when a datagram comes."""
        if self.ahead and self.logger.flight_start_tick >= 0:
            return read_interval(self.measure_pace(now), self.keep * self.period), 0.0
        if t + STEADY_LOOKAHEAD < self.duration and holds_still(self.trajectory, t, last_sent):
            return read_interval(self.measure_pace(now)), 0.0
        return LOOP, WAIT_MOVING

    def vehicle_tick(self) -> int:
        """The vehicle's newest tick seen: in its telemetry (Zenoh, batched) or its ATTITUDE stream (MAVLink)."""
        return max(self.logger.last_tick, round(self.sim_ms / 1000.0 / self.period))

    def stamp_ms(self) -> int:
        """A setpoint's time_boot_ms [ms]: the vehicle's time of its newest tick seen, which the trajectory is
        sampled at (the autopilot's ``--offboard-lockstep`` holds its clock by it)."""
        return self.ms_of(self.vehicle_tick())

    def ms_of(self, tick: int) -> int:
        """The vehicle's time [ms] at ``tick``, as a time_boot_ms (uint32)."""
        return max(0, round(tick * self.period * 1000)) & 0xFFFFFFFF

    def flown(self, flight_t: float) -> bool:
        """The trajectory is flown: ``flight_t`` [s] reached the duration; with ``--setpoints-ahead``, the vehicle's
        clock stands at the tick after the last (where its clock holds), so the landing comes at the same tick in
        every run."""
        if self.ahead and self.logger.flight_start_tick >= 0:
            return self.vehicle_tick() - self.logger.flight_start_tick >= self.end_ticks + 1
        return flight_t >= self.duration

    def landed_early(self) -> bool:
        """The telemetry says the vehicle disarmed after the offboard flight started (a failsafe's landing): the
        trajectory cannot be flown to its end, and a lockstep plant would hold its clock until the vehicle arms."""
        status = self.logger.last_status
        start = self.logger.flight_start_tick
        return status is not None and start >= 0 and not status["armed"] and status["tick"] > start

    def trajectory_time(self) -> float:
        """Flight time [s] of the vehicle's newest tick seen (0 before the flight starts)."""
        return max(0.0, self.logger.flight_time(self.vehicle_tick()))

    def take_link(self) -> None:
        """On connecting: the streams this ground station reads on its link (SYS_STATUS, until armed) at their default
        rates, since a ground station before it on the same link may have stopped them (as this one does in flight),
        and the ones it does not read stopped."""
        for msg_id in UNNEEDED_IN_FLIGHT:
            self.command(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, msg_id, 0)
        self.stop_streams(UNNEEDED_STREAMS)

    def stop_streams(self, msg_ids: Sequence[int]) -> None:
        """Ask the vehicle to stop streaming ``msg_ids`` on this link (MAV_CMD_SET_MESSAGE_INTERVAL, −1)."""
        for msg_id in msg_ids:
            self.command(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, msg_id, -1)

    def command(self, command: int, *params: float) -> None:
        """COMMAND_LONG ``command`` with ``params`` (the rest 0), its last COMMAND_ACK forgotten."""
        p = list(params) + [0.0] * (7 - len(params))
        self.acks.pop(command, None)
        self.send(mavlink.MAVLink_command_long_message(*self.target, command, 0, *p))

    # ---- the flight ------------------------------------------------------------------------------

    def until_accepted(
        self, command: int, what: str, now: float, last_sent: float, *params: float
    ) -> tuple[bool, float]:
        """Send ``command`` every COMMAND_RETRY seconds of wall time until its COMMAND_ACK: (accepted, when it was
        last sent). A refusal raises :class:`GcsError` naming ``what``."""
        result = self.acks.get(command)
        if result == mavlink.MAV_RESULT_ACCEPTED:
            return True, last_sent
        if result is not None:
            end = time.monotonic() + REASON_WAIT
            while not self.said and (left := end - time.monotonic()) > 0:  # its reason comes right after it
                if readable_of([self.sock], left):
                    self.read_waiting()
            why = f": the vehicle says {self.said[-1]!r}" if self.said else ""
            raise GcsError(f"{what} refused (MAV_RESULT {result}){why}")
        if now - last_sent > COMMAND_RETRY:
            self.said.clear()
            self.command(command, *params)
            last_sent = now
        return False, last_sent

    def heartbeat(self, now: float, last: float) -> float:
        """This ground station's HEARTBEAT, once a second of wall time: when it was last sent [s, wall]."""
        if now - last < 1.0:
            return last
        hb = mavlink.MAVLink_heartbeat_message
        self.send(hb(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, mavlink.MAV_STATE_ACTIVE, 3))
        return now

    def fly(self) -> int:
        """Fly the trajectory to its landing and disarm; write the results (:meth:`finish`) → the exit status."""
        args = self.args
        phase = Phase.CONNECT
        deadline = time.monotonic() + args.timeout
        last_sp_ms, last_sp_wall, last_hb, last_cmd = -1e9, 0.0, 0.0, 0.0
        last_sp = None
        setpoints_sent = 0
        wall_start, flight_wall_start = time.monotonic(), None
        arm_tick = None if args.arm_at is None else round(args.arm_at / self.period)
        order = (Phase.ARMING, Phase.OFFBOARD, Phase.FLYING) if arm_tick is None else (
            Phase.OFFBOARD, Phase.ARMING, Phase.FLYING)  # fmt: skip
        while phase is not Phase.DONE:
            now = time.monotonic()
            if now > deadline:
                raise GcsError(f"timed out after {args.timeout:g} s in phase '{phase.value}'")
            self.poll()
            self.logger.drain()
            last_hb = self.heartbeat(now, last_hb)
            # By ATTITUDE as well as the Zenoh batches (up to 512 ticks each): the end is seen on time.
            flight_t = self.logger.flight_time(self.vehicle_tick())
            self.interval, self.wait_data = LOOP, 0.0
            if phase in (Phase.PREARM, Phase.ARMING, Phase.OFFBOARD, Phase.FLYING):
                t = self.trajectory_time()
                sp, since = self.trajectory(t), self.stamp_ms() - last_sp_ms
                if phase is Phase.FLYING:
                    self.interval, self.wait_data = self.read_timing(now, t, last_sp)
                if phase is Phase.FLYING and self.ahead and self.logger.flight_start_tick >= 0:
                    last_sp = self.send_ahead(last_sp)
                elif setpoint_due(since, sp != last_sp, now - last_sp_wall):
                    self.send_setpoint(sp)
                    last_sp, last_sp_ms, last_sp_wall = sp, self.stamp_ms(), now
                    setpoints_sent += 1
            if phase is Phase.CONNECT and self.heard:
                phase = Phase.PREARM
                # This ground station logs telemetry from Zenoh and paces itself by it; ATTITUDE goes on to the
                # .tlog, the other MAVLink streams on its link would only cost both ends CPU at a lockstep run's rate.
                self.take_link()
                if self.ahead:
                    interval = attitude_interval_us(args.setpoints_ahead)
                    self.command(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, mavlink.MAVLINK_MSG_ID_ATTITUDE, interval)
            elif (phase is Phase.PREARM and setpoints_sent >= 5 and self.logger.last_status is not None
                  and self.armable):  # fmt: skip
                # Arm only once the Zenoh telemetry reaches the logger (never fly what cannot be recorded) and the
                # vehicle says it may arm (SYS_STATUS's pre-arm check, as QGroundControl and MAVSDK wait for it).
                # With --arm-at, once the vehicle's clock stands there (its plant holds it until the vehicle
                # arms), in offboard first: the flight then starts at the same tick in every run.
                if arm_tick is None or self.logger.last_tick >= arm_tick:
                    phase, last_cmd = order[0], 0.0
            elif phase is Phase.ARMING:
                done, last_cmd = self.until_accepted(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, "arming", now, last_cmd, 1.0)
                if done:
                    phase, last_cmd = order[order.index(phase) + 1], 0.0
            elif phase is Phase.OFFBOARD:
                done, last_cmd = self.until_accepted(mavlink.MAV_CMD_DO_SET_MODE, "offboard mode", now, last_cmd,
                                                     mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 6, 0)  # fmt: skip
                if done:
                    phase, last_cmd = order[order.index(phase) + 1], 0.0
            if phase is Phase.FLYING and self.progress is None:
                self.stop_streams(UNNEEDED_IN_FLIGHT)
                flight_wall_start = now
                self.progress = FlightProgress(self.duration, enabled=not args.quiet, label="gcs: flight")
            elif phase is Phase.FLYING and self.landed_early():
                said = f": the vehicle said {'; '.join(repr(t) for t in self.said[-3:])}" if self.said else ""
                raise GcsError(f"the vehicle disarmed at t = {flight_t:.2f} s of the flight's {self.duration:g} s, "
                               f"before its end (failsafe {self.logger.last_status['failsafe']}){said}")  # fmt: skip
            elif phase is Phase.FLYING and self.flown(flight_t):
                phase, last_cmd = Phase.LANDING, 0.0
                self.flight_rate = (flight_t, now - flight_wall_start)  # simulated s flown, wall s
                self.progress.update(flight_t)
                self.progress.close()
            elif phase is Phase.LANDING:
                # Disarmed as the telemetry says, tick by tick: the 1 Hz (wall) heartbeat may not have come
                # since arming in a short sped-up flight, and would end the flight before the landing.
                status = self.logger.last_status
                landed = status is not None and status["mode"] == wire.Mode.LAND and not status["armed"]
                if landed and self.acks.get(mavlink.MAV_CMD_NAV_LAND) == mavlink.MAV_RESULT_ACCEPTED:
                    phase = Phase.DONE
                elif now - last_cmd > COMMAND_RETRY and self.acks.get(mavlink.MAV_CMD_NAV_LAND) is None:
                    self.command(mavlink.MAV_CMD_NAV_LAND)
                    last_cmd = now
            if phase is Phase.FLYING:
                self.progress.update(flight_t)
        return self.finish(time.monotonic() - wall_start)

    def finish(self, wall: float) -> int:
        """The flight over after ``wall`` [s] of wall time: telemetry.csv (every tick flown, waited for) and rate.json
        written, one line said → 0, or 1 when telemetry ticks never arrived (said: which)."""
        n = round(self.duration / self.period)
        self.logger.wait_for(n, TELEMETRY_QUIET)  # what is still on its way, while it keeps coming
        logged = self.logger.rows()
        missing = [k for k in range(n) if k not in logged]
        rows = np.array([logged[k] for k in range(n) if k in logged])
        write_csv(self.out / "telemetry.csv", rows)
        if self.flight_rate is not None:
            sim, wall_flown = self.flight_rate
            start = self.logger.flight_start_tick
            pace = self.logger.pace(start, start + round(sim / self.period))
            if pace is not None:  # the vehicle's own pace, by its telemetry's publication times (TelemetryLogger.pace)
                sim, wall_flown = pace[0] * self.period, pace[1]
            rate = {"simulated_s": sim, "wall_s": wall_flown, "ticks_per_s": sim / self.period / max(wall_flown, 1e-9),
                    "real_time_factor": sim / max(wall_flown, 1e-9)}  # fmt: skip
            (self.out / "rate.json").write_text(json.dumps(rate, indent=2) + "\n")
        if not self.args.quiet:
            print(f"gcs: landed and disarmed; {len(rows)} telemetry rows for {n} ticks, "
                  f"{len(missing)} missing; wall time {wall:.1f} s", file=sys.stderr)  # fmt: skip
        if missing:
            gaps = 1 + sum(b - a > 1 for a, b in itertools.pairwise(missing))
            lacks = ", ".join(f"{stream} {count}" for stream, count in self.logger.absent(n).items())
            print(f"gcs: error: {len(missing)} telemetry ticks never arrived (first: {missing[0]}, last: "
                  f"{missing[-1]}, in {gaps} gap(s); ticks each stream lacks: {lacks})", file=sys.stderr)  # fmt: skip
            return 1
        return 0

    def save_partial(self, reason: str = "interrupted") -> int:
        """On SIGINT/SIGTERM (or a flight cut short, ``reason``): the flight so far, flushed. telemetry.csv gets
        every tick flown up to the last one whose four streams all arrived (a gap-free prefix); the .tlog is
        flushed to disk."""
        self.stop_progress()
        deadline = time.monotonic() + 0.3  # what is already on its way
        while time.monotonic() < deadline:
            self.logger.drain()
            time.sleep(0.02)
        logged = self.logger.rows()
        n = 0
        while n in logged:
            n += 1
        write_csv(self.out / "telemetry.csv", np.array([logged[k] for k in range(n)]))
        self.tlog.flush()
        os.fsync(self.tlog.fileno())
        print(f"gcs: {reason}; telemetry.csv has the {n} ticks flown so far, flight.tlog is flushed",
              file=sys.stderr)  # fmt: skip
        return n

    def stop_progress(self) -> None:
        """Take the progress bar off the terminal before an error or interruption is reported (a no-op
        once the flight is complete)."""
        if self.progress is not None:
            self.progress.close(completed=False)

    def close(self) -> None:
        """Everything this ground station opened closed: the progress bar, the logger, Zenoh, the .tlog, the link."""
        self.stop_progress()
        self.logger.close()
        self.session.close()
        self.tlog.close()
        self.sock.close()
