"""The ground station (``quadsitl gcs``, ``python -m groundstation``).

Connects over MAVLink (UDP), waits for the autopilot's heartbeat, streams setpoints before arming
(the PX4 offboard convention), arms, switches to offboard, flies the trajectory for ``--duration``
simulated seconds, then lands and waits for the disarm. Its Zenoh subscriber logs the telemetry to
``telemetry.csv``; its MAVLink link, both directions, goes to ``flight.tlog`` (each packet preceded by
an 8-byte big-endian microsecond timestamp, as MAVProxy and QGroundControl write it).

Setpoints are paced in simulated time: one per 20 ms of the vehicle's time seen (its ATTITUDE stream or its
Zenoh telemetry, whichever is newer), and at least every 100 ms of wall time, so a sped-up lockstep run never
starves the stream. Each is the trajectory at that moment and is stamped with it (time_boot_ms). With
``--setpoints-ahead S`` (``quadsitl fly``'s 1.5 s, its autopilot on ``--offboard-lockstep 0``) the flight's setpoints
are instead the trajectory at every SETPOINT_MS of the flight, sent up to S ahead of the vehicle's clock (on a grid of
AHEAD_KEEPALIVE) and stamped with the tick each is for; the autopilot flies each from that tick and holds its clock
until the ground station is ahead (:mod:`autopilot.offboard_lockstep`), so a flight is the same to the byte on any
machine. An attitude trajectory (:mod:`groundstation.trajectories`) sends a pair, SET_ATTITUDE_TARGET and a z-only
SET_POSITION_TARGET_LOCAL_NED; a position trajectory one SET_POSITION_TARGET_LOCAL_NED in MAV_FRAME_LOCAL_NED with
type_mask 2496 (position, velocity feed-forward and yaw). Before the switch to offboard both send the trajectory's
start (t = 0), so a position trajectory climbs and settles at its start point first.

With ``--mission FILE`` (:mod:`groundstation.mission_files`) it flies a mission instead, through the mission
protocol: ``MISSION_COUNT``, each ``MISSION_REQUEST_INT`` (or legacy ``MISSION_REQUEST``, re-requests too)
answered with its ``MISSION_ITEM_INT``, until ``MISSION_ACK`` ACCEPTED (any other ``MISSION_ACK`` fails the
flight, naming the result); then arm, AUTO.MISSION (``DO_SET_MODE`` 4/4), and watch ``MISSION_ITEM_REACHED``
and ``MISSION_CURRENT``. A mission that ends with ``NAV_RETURN_TO_LAUNCH`` or ``NAV_LAND`` is over when the
vehicle has landed and disarmed; any other is landed where it ends (``MAV_CMD_NAV_LAND``) once
``MISSION_CURRENT`` says complete (mission_state 5). ``--duration`` bounds the mission in simulated seconds.
``mission.json`` gets the items and the simulated time (t of telemetry.csv, 0 at arming) at which each
``MISSION_ITEM_REACHED`` arrived.
"""

from __future__ import annotations

import argparse
import contextlib
import itertools
import json
import os
import socket
import struct
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np
import zenoh

from groundstation import mission_files, trajectories
from groundstation.logger import TelemetryLogger
from groundstation.mission_files import MISSION_DURATION
from groundstation.progress import FlightProgress
from groundstation.setpoint_grid import POSITION_VELOCITY_YAW, SETPOINT_MS, next_moment, setpoint_step
from groundstation.telemetry_csv import write_csv
from quadsitl import telemetry, wire
from quadsitl.cli_util import UsageError, check_duration, parse_floats
from quadsitl.config import ConfigError, load_preset
from quadsitl.frames import PX4_HOME, euler_to_quaternion
from quadsitl.process_util import parse_address, readable_of, start_process, stop_status
from quadsitl.state import Reference

mavlink = wire.mavlink
MASK_IGNORE_RATES = 1 | 2 | 4  # SET_ATTITUDE_TARGET: attitude and thrust fields used
MASK_Z_ONLY = 0b0000_1101_1111_1011  # SET_POSITION_TARGET_LOCAL_NED: only z (and yaw ignored: 1024, rate 2048)
MASK_POSITION_VELOCITY_YAW = POSITION_VELOCITY_YAW  # a position trajectory's (groundstation.setpoint_grid)
MISSION_STATE_COMPLETE = 5
UPLOAD_RETRY = 1.0  # [s] wall: MISSION_COUNT again when the vehicle has not asked for an item
UPLOAD_TIMEOUT = 10.0  # [s] wall: give the upload up
COMMAND_RETRY = 0.5  # [s] wall: a command is sent again until acknowledged (MAVSDK waits 0.5 s too)
LOOP = 0.002  # [s] wall: how often at most the ground station reads its socket and Zenoh channels, and may send
# Each wake-up takes one of the two cores from the lockstep processes for a moment: 500 a second cost `fly` 7-12 % of
# its ticks (docs/performance.md). While the reference moves, a read finds something new only once the vehicle's
# time seen has moved, by the 50 Hz ATTITUDE (10 Hz with fly's --setpoints-ahead, where no setpoint waits for a read)
# or a Zenoh batch: the ground station reads when a datagram comes, at most every LOOP and at least every WAIT_MOVING
# of wall time (a vehicle that runs below 10x real time wakes it less often than LOOP's 500 times a second, and a
# changed setpoint goes as soon as the vehicle's time it is for is seen; WAIT_MOVING is longer than the 50 Hz
# ATTITUDE's period down to 0.4x real time, and short against KEEPALIVE_WALL).
# While the reference holds still (the paper's step, a hover), nothing it sends changes: it reads every STEADY_SIM of
# the vehicle's time instead, between LOOP and LOOP_STEADY of wall time. The keep-alive then goes every STEADY_SIM
# (not KEEPALIVE_MS), well within the vehicle's --offboard-lockstep lead (0.5 s) and setpoint timeout (1 s); the
# reference is looked at STEADY_LOOKAHEAD ahead, so a step is read for as a moving reference is.
LOOP_STEADY, STEADY_SIM, STEADY_LOOKAHEAD = 0.010, 0.15, 1.0  # [s] wall, simulated, simulated
WAIT_MOVING = 0.050  # [s] wall
# Setpoints: a changed one at most every SETPOINT_MS of the vehicle's time (50 Hz), the same one again every
# KEEPALIVE_MS (10 Hz; the vehicle's setpoint timeout is 1 s, its --offboard-lockstep lead 0.5 s), and at least
# every KEEPALIVE_WALL of wall time (a vehicle whose clock does not move still hears the stream). A constant
# reference (the paper's step) sent 50 times a simulated second cost both ends a share of their cores for nothing:
# at 25x real time, 2,500 messages a second built here and parsed by the autopilot's Python.
KEEPALIVE_MS, KEEPALIVE_WALL = 100, 0.1
PACE_WINDOW = 0.05  # [s] wall: the vehicle's pace is measured over this long
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
    # its compiled loop while the plant waits, 135-177 µs each in a lockstep flight (docs/performance.md).
    mavlink.MAVLINK_MSG_ID_HOME_POSITION,
    mavlink.MAVLINK_MSG_ID_ESTIMATOR_STATUS,
    mavlink.MAVLINK_MSG_ID_EXTENDED_SYS_STATE,
)
# SYS_STATUS is read for its pre-arm check until the flight starts, and then not: it goes then.
UNNEEDED_IN_FLIGHT = (mavlink.MAVLINK_MSG_ID_SYS_STATUS,)
# With --setpoints-ahead, each setpoint is made for its own tick of the trajectory's grid, so the vehicle's clock is
# read only to know how far ahead to send: ATTITUDE (which carries it) at AHEAD_CLOCK_READS per lead, at most every
# ATTITUDE_AHEAD_MAX_MS of the vehicle's time (10 Hz at fly's 1.5 s) and never more often than the 50 Hz default.
# Parsing and logging it at 50 Hz took most of the ground station's CPU in a lockstep flight, on the cores the two
# loops share: at 10 Hz `fly` flew 11-18 % more ticks a second (ten interleaved pairs, twice; docs/performance.md).
AHEAD_CLOCK_READS, ATTITUDE_AHEAD_MAX_MS = 5, 100
# [s] simulated: with --setpoints-ahead, the horizon (the furthest setpoint sent) moves on a grid of this step, counted
# from the flight's start, and a constant reference goes again once per step: half the vehicle's 1 s setpoint timeout,
# on its own clock. The ground station reads once per step of the vehicle's clock (within LOOP and LOOP_STEADY of wall
# time); the clock stays the lead less one step short of the horizon (fly's 1.5 s lead: 1 s). With a 0.5 s lead and
# the horizon topped up at each read (every 0.15 s of the vehicle's time), it woke 400-500 times a second at 60-80x
# real time, each wake about 250 us of a core the lockstep pair needed, and the clock still waited for it 6-13 times
# in a 10 s flight (docs/performance.md).
AHEAD_KEEPALIVE = 0.5


def attitude_interval_us(lead: float) -> int:
    """The ATTITUDE interval [µs] a ground station that sends setpoints ``lead`` [s] ahead asks for."""
    ms = min(ATTITUDE_AHEAD_MAX_MS, max(SETPOINT_MS, round(1000.0 * lead / AHEAD_CLOCK_READS)))
    return 1000 * ms


class GcsError(Exception):
    pass


def holds_still(trajectory: Callable[[float], object], t: float, last_sent: object) -> bool:
    """True when the reference at flight time ``t`` [s] is the one last sent and is still that one STEADY_LOOKAHEAD
    later: the ground station may read less often (a step ahead is read at LOOP's pace, from a second before it)."""
    sp = trajectory(t)
    return sp == last_sent and trajectory(t + STEADY_LOOKAHEAD) == sp


def read_interval(pace: float, sim: float = STEADY_SIM) -> float:
    """The wall time [s] from one read to the next while the reference holds still (or, with --setpoints-ahead, in
    flight: ``sim`` is then the horizon's grid), for a vehicle whose clock runs ``pace`` simulated seconds per wall
    second (0: not known): ``sim`` [s] of its time, between LOOP and LOOP_STEADY."""
    return LOOP if pace <= 0.0 else min(LOOP_STEADY, max(LOOP, sim / pace))


def horizon_step(ahead: int, period: float) -> int:
    """With --setpoints-ahead ``ahead`` [ticks of ``period`` s]: the step [ticks] of the grid the horizon moves on,
    AHEAD_KEEPALIVE or half the lead if shorter, a whole number of :func:`setpoint_step`'s."""
    step = setpoint_step(period)
    return max(step, min(round(AHEAD_KEEPALIVE / period), ahead // 2) // step * step)


def ack_name(result: int) -> str:
    """A MAV_MISSION_RESULT as its name and number (``MAV_MISSION_UNSUPPORTED (3)``)."""
    entry = mavlink.enums["MAV_MISSION_RESULT"].get(result)
    return f"{entry.name if entry else 'unknown'} ({result})"


class GroundStation:
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
        conf = telemetry.config_from_args(args)
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
        self.flight_rate: tuple[float, float] | None = None
        self.progress: FlightProgress | None = None  # from the switch to offboard until landing
        self.last_read = 0.0  # monotonic time of the last socket read (poll)
        self.interval = LOOP  # [s] wall: from the last read to the next
        self.wait_data = 0.0  # [s] wall: > interval: the next read also waits for a datagram, up to this long
        self._pace_mark = (0.0, 0)  # (monotonic time, vehicle tick) the vehicle's pace is measured from
        self.pace = 0.0  # simulated seconds per wall second, over the last PACE_WINDOW (0: not known)
        # the mission: items requested (seq, legacy), the upload's MISSION_ACK, MISSION_CURRENT, reached items
        self.requested: list[int] = []
        self.mission_ack: int | None = None
        self.mission_state: tuple[int, int] | None = None  # (seq, mission_state) of the last MISSION_CURRENT
        self.reached: list[dict] = []  # {"seq", "t"}: t stamped from the telemetry once it is drained

    # ---- MAVLink ---------------------------------------------------------------------------------

    def _log(self, buf: bytes) -> None:
        self.tlog.write(struct.pack(">Q", int(time.time() * 1e6)) + buf)

    def send(self, msg) -> None:
        buf = msg.pack(self.mav)
        self._log(buf)
        with contextlib.suppress(ConnectionRefusedError):  # nobody listening yet; UDP
            self.sock.send(buf)

    def poll(self) -> None:
        """Read everything waiting, ``interval`` seconds after the last read (LOOP, or longer while the reference
        holds still: :func:`read_interval`), and when ``wait_data`` is longer, not before a datagram comes either,
        until ``wait_data`` after the last read: between reads the datagrams wait in the socket (a ground station
        that woke for each one at 25x real time would take a core from the lockstep processes each time)."""
        if self.wait_data > self.interval:
            readable_of([self.sock], self.last_read + self.wait_data - time.monotonic())
        time.sleep(max(0.0, self.last_read + self.interval - time.monotonic()))
        self.last_read = time.monotonic()
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
                if getattr(m, "mission_type", 0) == 0 and m.target_system == wire.GCS_SYSTEM_ID:
                    self.requested.append(m.seq)
            elif mid == mavlink.MAVLINK_MSG_ID_MISSION_ACK:
                if getattr(m, "mission_type", 0) == 0 and m.target_system == wire.GCS_SYSTEM_ID:
                    self.mission_ack = m.type
            elif mid == mavlink.MAVLINK_MSG_ID_MISSION_CURRENT:
                self.mission_state = (m.seq, getattr(m, "mission_state", 0))
            elif mid == mavlink.MAVLINK_MSG_ID_MISSION_ITEM_REACHED:
                if not any(r["seq"] == m.seq and r["t"] is None for r in self.reached):
                    self.reached.append({"seq": m.seq, "t": None})
            elif mid == mavlink.MAVLINK_MSG_ID_STATUSTEXT and not self.args.quiet:
                print(f"gcs: vehicle says: {m.text}", file=sys.stderr)

    def send_setpoint(self, ref: Reference | trajectories.PositionSetpoint, ms: int | None = None) -> None:
        """One setpoint of the trajectory: a position setpoint, or an attitude + altitude pair; stamped ``ms``
        (time_boot_ms: the vehicle's time it is made for; default :meth:`stamp_ms`)."""
        if isinstance(ref, trajectories.PositionSetpoint):
            self.send_position_setpoint(ref, ms)
            return
        ts, tc = self.target
        q = euler_to_quaternion(ref.roll, ref.pitch, ref.yaw)
        ms, frame = self.stamp_ms() if ms is None else ms, mavlink.MAV_FRAME_LOCAL_NED
        self.send(mavlink.MAVLink_set_attitude_target_message(ms, ts, tc, MASK_IGNORE_RATES, q, 0, 0, 0, 0.5))
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
        """``--setpoints-ahead``: the trajectory at every SETPOINT_MS of the flight, each stamped with the tick it is
        made for, up to the horizon: the last moment of the AHEAD_KEEPALIVE grid (counted from the flight's start)
        within the lead of the vehicle's newest tick seen. Of those, the ones that change the reference and each
        moment of the AHEAD_KEEPALIVE grid go out: a constant reference goes once per AHEAD_KEEPALIVE of the vehicle's
        time, and the furthest sent tells the vehicle's clock how far it may go (autopilot.offboard_lockstep holds each
        until its tick). The flight's last is made for two ticks past its end: the clock then holds at the tick after
        the end until the landing is asked for. Returns the last setpoint sent.

        The horizon moves once per AHEAD_KEEPALIVE of the vehicle's clock, so the ground station reads that often
        (:func:`read_interval`), and the clock, which cannot pass the furthest setpoint sent, is then still the
        lead less AHEAD_KEEPALIVE short of it: it waits only for a ground station that is that late. Each setpoint
        costs the autopilot two trips out of its compiled loop (pymavlink parses it when it comes, Python flies it
        at its tick): a constant reference sent at every read (every LOOP) cost a lockstep flight about 15 % of its
        time. Every setpoint up to the furthest went out before it, so what the vehicle flies is the same."""
        start = self.logger.flight_start_tick
        if self.next_moment < 0:
            self.next_moment = start
        end, step, keep = start + self.end_ticks, setpoint_step(self.period), self.keep
        horizon = min(start + (self.vehicle_tick() + self.ahead - start) // keep * keep, end + 2)
        while self.next_moment <= horizon:
            g = self.next_moment
            sp = self.trajectory(min(g - start, self.end_ticks) * self.period)
            self.next_moment = start + next_moment(g - start, self.end_ticks, step)
            if sp != last_sent or (g - start) % keep == 0 or self.next_moment > horizon:
                self.send_setpoint(sp, self.ms_of(g))
                last_sent = sp
        return last_sent

    def measure_pace(self, now: float) -> float:
        """The vehicle's pace [simulated s per wall s] over the last PACE_WINDOW of wall time (its ticks arrive in
        batches: a shorter window would read 0 or a burst); 0 until known."""
        since, tick = self._pace_mark
        if now - since >= PACE_WINDOW:
            newest = self.vehicle_tick()
            self.pace = (newest - tick) * self.period / (now - since) if since else 0.0
            self._pace_mark = (now, newest)
        return self.pace

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

    def trajectory_time(self) -> float:
        """Flight time [s] of the vehicle's newest tick seen (0 before the flight starts)."""
        return max(0.0, self.logger.flight_time(self.vehicle_tick()))

    def stop_streams(self, msg_ids: Sequence[int]) -> None:
        """Ask the vehicle to stop streaming ``msg_ids`` on this link (MAV_CMD_SET_MESSAGE_INTERVAL, −1)."""
        for msg_id in msg_ids:
            self.command(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, msg_id, -1)

    def command(self, command: int, *params: float) -> None:
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
            raise GcsError(f"{what} refused (MAV_RESULT {result})")
        if now - last_sent > COMMAND_RETRY:
            self.command(command, *params)
            last_sent = now
        return False, last_sent

    def fly(self) -> int:
        if self.mission is not None:
            return self.fly_mission()
        args = self.args
        phase = "connect"
        deadline = time.monotonic() + args.timeout
        last_sp_ms, last_sp_wall, last_hb, last_cmd = -1e9, 0.0, 0.0, 0.0
        last_sp = None
        setpoints_sent = 0
        wall_start, flight_wall_start = time.monotonic(), None
        arm_tick = None if args.arm_at is None else round(args.arm_at / self.period)
        order = ("arming", "offboard", "flying") if arm_tick is None else ("offboard", "arming", "flying")
        while phase != "done":
            now = time.monotonic()
            if now > deadline:
                raise GcsError(f"timed out after {args.timeout:g} s in phase '{phase}'")
            self.poll()
            self.logger.drain()
            if now - last_hb >= 1.0:
                last_hb = now
                hb = mavlink.MAVLink_heartbeat_message
                self.send(hb(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, mavlink.MAV_STATE_ACTIVE, 3))
            # By ATTITUDE as well as the Zenoh batches (up to 512 ticks each): the end is seen on time.
            flight_t = self.logger.flight_time(self.vehicle_tick())
            self.interval, self.wait_data = LOOP, 0.0
            if phase in ("prearm", "arming", "offboard", "flying"):
                t = self.trajectory_time()
                sp, since = self.trajectory(t), self.stamp_ms() - last_sp_ms
                ending = t + STEADY_LOOKAHEAD >= self.duration  # the landing is a change too: read as for a move
                if phase == "flying" and self.ahead and self.logger.flight_start_tick >= 0:
                    # what goes out does not depend on when it is read: once per move of the horizon (send_ahead)
                    self.interval = read_interval(self.measure_pace(now), self.keep * self.period)
                elif phase == "flying" and not ending and holds_still(self.trajectory, t, last_sp):
                    self.interval = read_interval(self.measure_pace(now))
                elif phase == "flying":
                    self.wait_data = WAIT_MOVING
                if phase == "flying" and self.ahead and self.logger.flight_start_tick >= 0:
                    last_sp = self.send_ahead(last_sp)
                elif (
                    (since >= SETPOINT_MS and sp != last_sp)
                    or since >= KEEPALIVE_MS
                    or now - last_sp_wall >= KEEPALIVE_WALL
                ):
                    self.send_setpoint(sp)
                    last_sp, last_sp_ms, last_sp_wall = sp, self.stamp_ms(), now
                    setpoints_sent += 1
            if phase == "connect" and self.heard:
                phase = "prearm"
                # This ground station logs telemetry from Zenoh and paces itself by it; ATTITUDE goes on to the
                # .tlog, the other MAVLink streams on its link would only cost both ends CPU at 10,000 ticks/s.
                self.stop_streams(UNNEEDED_STREAMS)
                if self.ahead:
                    interval = attitude_interval_us(args.setpoints_ahead)
                    self.command(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, mavlink.MAVLINK_MSG_ID_ATTITUDE, interval)
            elif phase == "prearm" and setpoints_sent >= 5 and self.logger.last_status is not None and self.armable:
                # Arm only once the Zenoh telemetry reaches the logger (never fly what cannot be recorded) and the
                # vehicle says it may arm (SYS_STATUS's pre-arm check, as QGroundControl and MAVSDK wait for it).
                # With --arm-at, once the vehicle's clock stands there (its plant holds it until the vehicle
                # arms), in offboard first: the flight then starts at the same tick in every run.
                if arm_tick is None or self.logger.last_tick >= arm_tick:
                    phase, last_cmd = order[0], 0.0
            elif phase == "arming":
                done, last_cmd = self.until_accepted(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, "arming", now, last_cmd, 1.0)
                if done:
                    phase, last_cmd = order[order.index(phase) + 1], 0.0
            elif phase == "offboard":
                done, last_cmd = self.until_accepted(mavlink.MAV_CMD_DO_SET_MODE, "offboard mode", now, last_cmd,
                                                     mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 6, 0)  # fmt: skip
                if done:
                    phase, last_cmd = order[order.index(phase) + 1], 0.0
            if phase == "flying" and self.progress is None:
                self.stop_streams(UNNEEDED_IN_FLIGHT)
                flight_wall_start = now
                self.progress = FlightProgress(self.duration, enabled=not args.quiet, label="gcs: flight")
            elif phase == "flying" and self.flown(flight_t):
                phase, last_cmd = "landing", 0.0
                self.flight_rate = (flight_t, now - flight_wall_start)  # simulated s flown, wall s
                self.progress.update(flight_t)
                self.progress.close()
            elif phase == "landing":
                # Disarmed as the telemetry says, tick by tick: the 1 Hz (wall) heartbeat may not have come
                # since arming in a short sped-up flight, and would end the flight before the landing.
                status = self.logger.last_status
                landed = status is not None and status["mode"] == wire.Mode.LAND and not status["armed"]
                if landed and self.acks.get(mavlink.MAV_CMD_NAV_LAND) == mavlink.MAV_RESULT_ACCEPTED:
                    phase = "done"
                elif now - last_cmd > COMMAND_RETRY and self.acks.get(mavlink.MAV_CMD_NAV_LAND) is None:
                    self.command(mavlink.MAV_CMD_NAV_LAND)
                    last_cmd = now
            if phase == "flying":
                self.progress.update(flight_t)
        return self.finish(time.monotonic() - wall_start)

    # ---- a mission -------------------------------------------------------------------------------

    def send_mission_item(self, seq: int) -> None:
        fields = self.mission.items[seq].message_fields()
        self.send(mavlink.MAVLink_mission_item_int_message(*self.target, **fields))

    def fly_mission(self) -> int:
        """Upload the mission through the protocol, arm, start it (AUTO.MISSION), fly it to its end and land."""
        args, mission = self.args, self.mission
        n_items = len(mission.items)
        phase = "connect"
        deadline = time.monotonic() + args.timeout
        last_hb, last_cmd, upload_start = 0.0, 0.0, 0.0
        wall_start, flight_wall_start = time.monotonic(), None
        while phase != "done":
            now = time.monotonic()
            if now > deadline:
                raise GcsError(f"timed out after {args.timeout:g} s (wall) in phase '{phase}'")
            self.poll()
            self.logger.drain()
            flight_t = self.logger.flight_time()
            for r in self.reached:
                if r["t"] is None:
                    r["t"] = round(max(flight_t, 0.0), 6)
            if now - last_hb >= 1.0:
                last_hb = now
                hb = mavlink.MAVLink_heartbeat_message
                self.send(hb(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, mavlink.MAV_STATE_ACTIVE, 3))
            if phase == "connect" and self.heard:
                self.stop_streams(UNNEEDED_STREAMS)
                phase, upload_start, last_cmd = "upload", now, 0.0
            elif phase == "upload":
                for seq in self.requested:
                    if 0 <= seq < n_items:
                        self.send_mission_item(seq)
                if self.requested:
                    last_cmd = now  # the vehicle is asking: the transfer is under way
                self.requested.clear()
                if self.mission_ack is not None:
                    if self.mission_ack != mavlink.MAV_MISSION_ACCEPTED:
                        raise GcsError(f"the vehicle refused the mission: MISSION_ACK {ack_name(self.mission_ack)}")
                    if not args.quiet:
                        print(f"gcs: uploaded {n_items} mission items from {mission.path}", file=sys.stderr)
                    phase = "prearm"
                elif now - upload_start > UPLOAD_TIMEOUT:
                    raise GcsError(f"the mission upload did not complete within {UPLOAD_TIMEOUT:g} s")
                elif now - last_cmd > UPLOAD_RETRY:
                    self.send(mavlink.MAVLink_mission_count_message(*self.target, n_items, 0))
                    last_cmd = now
            elif phase == "prearm" and self.logger.last_status is not None and self.armable:
                phase, last_cmd = "arming", 0.0  # never fly what cannot be recorded, nor arm before the pre-arm check
            elif phase == "arming":
                done, last_cmd = self.until_accepted(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, "arming", now, last_cmd, 1.0)
                if done:
                    phase, last_cmd = "starting", 0.0
            elif phase == "starting":
                done, last_cmd = self.until_accepted(mavlink.MAV_CMD_DO_SET_MODE, "mission mode", now, last_cmd,
                                                     mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 4, 4)  # fmt: skip
                if done:
                    self.stop_streams(UNNEEDED_IN_FLIGHT)
                    phase, flight_wall_start = "flying", now
                    self.progress = FlightProgress(self.duration, enabled=not args.quiet, label="gcs: mission")
            elif phase in ("flying", "landing"):
                status = self.logger.last_status
                if status is not None and not status["armed"] and self.logger.last_armed_tick >= 0:
                    self.flight_rate = (flight_t, now - flight_wall_start)
                    self.progress.update(flight_t)
                    self.progress.close()
                    phase = "done"
                elif flight_t > self.duration:  # keep what was flown: the telemetry and the items reached
                    message = self._unfinished(flight_t)
                    self.save_partial("the mission overran --duration")
                    self.write_mission_json(disarmed=False)
                    raise GcsError(message)
                elif phase == "flying":
                    self.progress.update(flight_t)
                    complete = self.mission_state is not None and self.mission_state[1] == MISSION_STATE_COMPLETE
                    if complete and not mission.lands:
                        phase, last_cmd = "landing", 0.0
                elif (
                    now - last_cmd > COMMAND_RETRY
                    and self.acks.get(mavlink.MAV_CMD_NAV_LAND) != mavlink.MAV_RESULT_ACCEPTED
                ):
                    if self.acks.get(mavlink.MAV_CMD_NAV_LAND) not in (None, mavlink.MAV_RESULT_ACCEPTED):
                        raise GcsError(f"landing refused (MAV_RESULT {self.acks[mavlink.MAV_CMD_NAV_LAND]})")
                    self.command(mavlink.MAV_CMD_NAV_LAND)
                    last_cmd = now
        # the flight: every armed tick, up to the disarm
        self.duration = (self.logger.last_armed_tick - self.logger.flight_start_tick + 1) * self.period
        self.write_mission_json()
        return self.finish(time.monotonic() - wall_start)

    def _unfinished(self, flight_t: float) -> str:
        where = "no MISSION_CURRENT yet"
        if self.mission_state is not None:
            seq, state = self.mission_state
            where = f"current item {seq} of {len(self.mission.items)}, mission_state {state}"
        return (f"the mission did not end within --duration {self.duration:g} simulated s ({where}, "
                f"{len({r['seq'] for r in self.reached})} items reached, after {flight_t:.1f} s)")  # fmt: skip

    def write_mission_json(self, disarmed: bool = True) -> None:
        """mission.json (:func:`groundstation.mission_files.report`): the reached times are telemetry.csv's t (0 at
        arming) when each MISSION_ITEM_REACHED arrived; ``disarmed`` False for a flight cut short."""
        doc = mission_files.report(self.mission, self.args.home or PX4_HOME, self.reached,
                                   self.duration if disarmed else None)  # fmt: skip
        (self.out / "mission.json").write_text(json.dumps(doc, indent=2) + "\n")

    def finish(self, wall: float) -> int:
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
        self.stop_progress()
        self.logger.close()
        self.session.close()
        self.tlog.close()
        self.sock.close()


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="quadsitl gcs",
        description="Ground station: fly a reference trajectory over MAVLink, log telemetry from Zenoh.",
        epilog="examples:\n  quadsitl gcs --connect 127.0.0.1:14580 --zenoh-connect tcp/127.0.0.1:7447 --out runs/gcs\n"
        "  quadsitl gcs --trajectory sine --duration 10 --zenoh-connect tcp/127.0.0.1:7447",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--preset", default="paper", help="preset for T and the step reference (default: paper)")
    p.add_argument(
        "--connect",
        default="127.0.0.1:14580",
        metavar="HOST:PORT",
        help="the autopilot's ground-station address (default: 127.0.0.1:14580)",
    )
    p.add_argument("--target-system", type=int, default=1, help="the autopilot's MAVLink system id (default 1)")
    p.add_argument(
        "--trajectory",
        default="step",
        help="attitude: step (default), ramp, sine or a CSV file t,altitude,roll,pitch,yaw; position (offboard "
        "position setpoints): circle[:radius=M,period=S,altitude=M,hold=S,yaw=RAD|travel], figure8[:size=M,...] "
        "or a CSV file t,x,y,altitude,yaw",
    )
    p.add_argument(
        "--duration",
        type=float,
        metavar="S",
        help="simulated seconds of flight (default: a position trajectory's own length, else the preset's)",
    )
    p.add_argument(
        "--mission",
        metavar="FILE",
        help="fly a mission instead: a QGroundControl .plan, a waypoint CSV lat,lon,altitude[,hold,radius,yaw] or a "
        "QGC WPL 110 file, uploaded through the mission protocol (--duration then bounds it: default 900 s)",
    )
    p.add_argument(
        "--home",
        metavar="LAT,LON,ALT",
        help="the autopilot's origin, for mission.json's north/east (default: PX4 SITL's, 47.397742,8.545594,488)",
    )
    p.add_argument(
        "--arm-at",
        type=float,
        metavar="S",
        help="switch to offboard and arm once the vehicle's clock reaches S simulated seconds (its lockstep plant "
        "holding there with --hold-until-armed): the flight starts at the same tick in every run",
    )
    p.add_argument(
        "--setpoints-ahead",
        type=float,
        default=0.0,
        metavar="S",
        help="send the trajectory up to S simulated seconds ahead of the vehicle's clock, each setpoint stamped with "
        "the moment it is for, to an autopilot that flies each from that moment (quadsitl autopilot "
        "--offboard-lockstep, as quadsitl fly runs both): the flight is the same to the byte on any machine "
        "(default 0: each setpoint is for the vehicle's newest moment seen, flown as it comes)",
    )
    p.add_argument("--out", default="runs/gcs", metavar="DIR", help="where telemetry.csv and flight.tlog go")
    p.add_argument("--timeout", type=float, default=600.0, metavar="S", help="give up after S wall seconds")
    p.add_argument("--quiet", "-q", action="store_true")
    p.add_argument("--signing-key", metavar="HEX|FILE", help=f"sign the MAVLink link (default: ${wire.SIGNING_ENV})")
    telemetry.add_zenoh_arguments(p)
    return p


def main(argv: Sequence[str] | None = None) -> int:
    start_process(quiet_gc=False)
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        check_duration(args.duration)
        if not 0.0 <= args.setpoints_ahead <= 10.0:  # (NaN too)
            raise UsageError(f"--setpoints-ahead {args.setpoints_ahead!r}: expected a number in [0, 10]")
        args.signing_key = wire.resolve_signing_key(args.signing_key)
        args.home = parse_floats("--home", args.home, 3) if args.home else None
        gcs = GroundStation(args)
    except (UsageError, ConfigError) as exc:
        print(f"{parser.prog}: error: {exc}", file=sys.stderr)
        return 2
    try:
        return gcs.fly()
    except GcsError as exc:
        gcs.stop_progress()
        print(f"{parser.prog}: error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt as exc:  # SIGINT or SIGTERM (StopRequested): an unfinished flight, logs saved
        gcs.save_partial()
        return stop_status(exc)
    finally:
        gcs.close()
