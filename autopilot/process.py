"""The autopilot process (``quadsitl autopilot``, ``python -m autopilot``): the loop and the wiring around the
compiled tick (:mod:`autopilot.tick`), the commander and the parameter table.

Sockets, like PX4 SITL's:

- the plant link (``--plant-listen``): answers each ODOMETRY with HIL_ACTUATOR_CONTROLS for the same
  ``time_usec``; in sensor mode (``--state sensors``, the default when the preset has a [sensors] section) each
  tick's HIL_SENSOR (and HIL_GPS), through the estimator (:mod:`autopilot.estimator`), whose estimate is flown and
  reported; the plant's ground truth (HIL_STATE_QUATERNION) goes to telemetry only. The link is served here (in
  compiled code, :mod:`autopilot.plant_loop`, once a plant is heard on an IPv4 socket).
- two ground-station links (:mod:`autopilot.ground_link`), each bound to a local port and streaming to a fixed
  remote address as well as to whoever talks to it: ``gcs`` (listens on 18570, streams to 14550, where
  QGroundControl and MAVProxy listen) and ``api`` (listens on 14580, streams to 14540, where MAVSDK and offboard
  scripts listen). MAVLink 2, PX4 conventions (:mod:`autopilot.gcs_messages`).

What arrives on the ground links goes through the receiver (:mod:`autopilot.receiver`) as typed records
(:mod:`autopilot.records`) to the commander, the commands (:mod:`autopilot.commands`), the parameters
(:mod:`autopilot.param_protocol`) and the missions; what goes out goes through the outbox (:mod:`autopilot.outbox`)
and the telemetry (:mod:`autopilot.telemetry_out`: the MAVLink streams and Zenoh).
"""

from __future__ import annotations

import argparse
import select
import sys
import threading
import time
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path

import numpy as np
import zenoh

from autopilot import (
    calibration,
    commander_state,
    commands,
    flight_log,
    gcs_messages,
    plant_link,
    plant_loop,
    plant_messages,
    plugin,
    setpoints,
    stream_frames,
)
from autopilot import tick as kernel
from autopilot.arguments import build_parser, check
from autopilot.calibration import Calibration
from autopilot.commander import Commander, CommanderSettings
from autopilot.commands import SUPPORTED_MODES
from autopilot.control_params import MEM_SIZE, MEM_U
from autopilot.estimator import Estimator
from autopilot.gains import GainError
from autopilot.gcs_messages import Home, Snapshot
from autopilot.ground_link import GcsLink, GroundLinks
from autopilot.log_protocol import LogServer
from autopilot.missions import Missions
from autopilot.offboard_lockstep import OffboardLockstep
from autopilot.onboard_log import OnboardLog
from autopilot.outbox import Outbox
from autopilot.param_protocol import ParamProtocol
from autopilot.params import CALIBRATION, ParamStore
from autopilot.plant_link import PlantLink
from autopilot.receiver import Receiver
from autopilot.records import (
    Command,
    Counters,
    FileTransfer,
    GroundHeartbeat,
    LogRequest,
    MissionMessage,
    ModeRequest,
    Routes,
)
from autopilot.stream_frames import StreamFrames
from autopilot.streams import MessageStreams, phase_of, spread_of
from autopilot.telemetry_out import BATCH_WALL, Streams, ZenohOut
from autopilot.tick import autopilot_tick, sensor_tick, warm_up
from quadsitl import codec, failures, fastio, wire
from quadsitl.cli_util import UsageError, parse_controller_params, with_state
from quadsitl.config import ConfigError, Preset, load_preset
from quadsitl.jit import favour_compile_time
from quadsitl.keys import param_values
from quadsitl.process_util import (
    bind_udp,
    parse_remote,
    say_ready,
    set_receive_timeout,
    start_process,
)
from quadsitl.state import Reference, VehicleState

mavlink = wire.mavlink
GCS_POLL = 0.002  # [s] wall: how often the ground-station sockets are asked for datagrams while the plant link is busy
# [s] wall: how often the wall-clock work runs (the heartbeat; the setpoint stream's, the ground link's and the
# mission transfers' clocks) while the plant link is busy, with the telemetry batch then due too (one trip to Python
# for both: each trip costs a real-time autopilot CPU, docs/performance.md).
HOUSEKEEPING = BATCH_WALL
GCS_BUDGET = 0.001  # [s] wall: the most time one reading of the ground-station sockets may take
# A log's download: at most this many LOG_DATA (90 bytes each) a burst, so many to a datagram (about 1.7 kB): bursts
# every GCS_POLL while one goes on
LOG_DATA_BURST, LOG_DATA_PER_DATAGRAM = 128, 16
CALIBRATION_SAMPLE = 0.004  # [s] wall: a calibration's samples, as PX4 SITL's 250 Hz IMU gives them


class Autopilot:
    """One vehicle's autopilot: the plant link, the ground links and what connects them to the commander and the
    compiled tick (module docstring)."""

    def __init__(self, preset: Preset, args: argparse.Namespace) -> None:
        self.period = preset.sim.period
        kind = args.controller or preset.controller.type
        plugged = plugin.load(kind) if plugin.is_plugin(kind) else None  # its parameters are MAVLink parameters
        self.params = ParamStore(preset, kind, CommanderSettings(setpoint_timeout=args.setpoint_timeout), plugged)
        for name, value in parse_controller_params(args.controller_param, kind).items():  # before the first tick
            param_id = next((p.param_id for p in plugged.parameters if name == p.name or name.upper() == p.param_id),
                            name.upper())  # fmt: skip
            reason = self.params.set(param_id, value)
            if reason:
                raise UsageError(f"--controller-param {name}={value:g}: {reason}")
        self.controller = self.params.build(self.params.applied())
        self.plug = self.controller.plug or plugin.no_plug()
        self.commander = Commander(self.params.base_settings)
        self.home = Home(*args.home) if args.home else Home()
        self.sensing = preset.sensors is not None  # fly on the estimate of the plant's sensors
        self.estimator: Estimator | None = None
        self.estimate_said = 0  # the estimator's status (kernel.ESTIMATE_*) last said to the ground stations
        if self.sensing:
            self.estimator = Estimator.for_sensors(preset.sensors, self.period, preset.vehicle.gravity)
        self.truth = np.full(codec.DECODED_SIZE, np.nan)  # the plant's ground truth of the last tick (sensor mode)
        self.hil_frame = np.zeros(codec.FRAME_MAX, dtype=np.uint8)  # one frame of a sensor datagram, being decoded
        self.origin = (self.home.lat, self.home.lon, self.home.alt)  # where the GPS's positions are taken from
        self.missions = Missions(self.origin)  # stored, transferred and flown
        self.system_id = args.system_id
        self.quiet = args.quiet
        self.label = f"autopilot {getattr(args, 'vehicle', 'v1')}"  # on stderr: a fleet's autopilots told apart
        self.counters = Counters()
        # The compiled tick's data: the decoded state, the command, forces, errors and Ωr of the last tick, and the
        # tick's bookkeeping (autopilot.tick); the plant's datagram and the answer are the plant link's
        self.st = np.zeros(codec.DECODED_SIZE)  # VehicleState's fields, then p, q, r
        self.scratch = np.zeros(codec.DECODED_SIZE)  # a state being decoded
        self.mem = np.zeros(MEM_SIZE)
        self.io = np.zeros(kernel.IO_SIZE, dtype=np.int64)
        self.io[kernel.LAST_USEC] = -1
        self.io[kernel.SYSTEM], self.io[kernel.COMPONENT] = self.system_id, wire.AUTOPILOT_COMPONENT_ID
        self.plant = PlantLink(args.plant_listen, self.period, self.system_id)
        links = []
        for name in ("gcs", "api"):
            remote = parse_remote(f"--{name}-remote", getattr(args, f"{name}_remote"))
            sock = bind_udp(f"--{name}-listen", getattr(args, f"{name}_listen"))
            rates = MessageStreams(self.period, args.telemetry_rate, phase_of(self.system_id),
                                   spread_of(self.system_id))  # fmt: skip
            links.append(GcsLink(name, sock, remote, rates, self.label))
        self.ground = GroundLinks(links, self.system_id, wire.AUTOPILOT_COMPONENT_ID, args.signing_key, self.io,
                                  self.counters)  # fmt: skip
        self.streams = links[0].streams  # for what every link's streams share: which ids are streamed
        session, pool = (None, None) if args.no_zenoh else ZenohOut.open(args)
        self.zenoh = ZenohOut(session, args.vehicle, self.sensing, args.telemetry_congestion, self.io, pool)
        self.outbox = Outbox(self.ground, self.counters, self.publish_plan)
        # The flight logs (autopilot.onboard_log), kept from the batches of telemetry records, and served (LOG_*)
        self.preset, self.kind = preset, kind
        self.onboard: OnboardLog | None = None
        logs = Path(args.logs) if args.logs else None
        if logs is not None:
            self.onboard = OnboardLog(logs, self.log_definitions, preset.actuators.max_thrust, self.origin,
                                      flight_log.logged_streams(self.sensing), self.period)  # fmt: skip
            self.zenoh.also(self.onboard.add)
            self.outbox.on_said = lambda severity, text: self.onboard.say(self.commander.now, severity, text)
        self.logs = LogServer(logs, lambda: self.onboard.path if self.onboard else None)
        self.calibration: Calibration | None = None  # the one running (MAV_CMD_PREFLIGHT_CALIBRATION)
        self.cancel_calibration = False  # asked to cancel it
        self.calibration_tick = -1  # the tick of its last sample (truth mode: one sample a tick at most)
        self.next_sample = 0.0  # [s] wall: when its next sample is taken
        self.calibration_heard = 0.0  # [s] wall: when it last had a sample
        self.gravity = preset.vehicle.gravity
        # The per-tick telemetry messages (autopilot.stream_frames) are built by the compiled tick and sent by the
        # compiled loop, on unsigned links (a signed link's frames are pymavlink's to sign: Python builds them all).
        frames = StreamFrames(len(links), self.origin, 4.0 * preset.actuators.max_thrust, preset.actuators.reversible)
        self.telemetry = Streams(self.ground, frames, self.io, self.plant.fast, args.signing_key is None, self.snapshot,
                                 self.commander, self.home)  # fmt: skip
        self.frames = frames
        self.param_protocol = ParamProtocol(self.params, self.outbox, self.apply_params)
        lead = args.offboard_lockstep
        self.pace = None if lead is None else OffboardLockstep(lead, self.period)  # autopilot.offboard_lockstep
        routes = Routes(trajectory=self.commander.on_trajectory, attitude=self.commander.on_attitude,
                        manual_control=self.commander.on_manual_control,
                        follow_target=self.commander.on_follow_target,
                        command=self.on_command, mode=self.on_mode, param_request=self.param_protocol.on_request,
                        param_set=self.param_protocol.on_set, mission=self.on_mission,
                        file_transfer=self.on_file_transfer, log=self.on_log,
                        ground_heartbeat=self.on_ground_heartbeat)  # fmt: skip
        self.receiver = Receiver(self.system_id, wire.AUTOPILOT_COMPONENT_ID, routes, self.outbox, self.counters,
                                 self.frame, lambda: self.controller.max_tilt, self.io, self.pace)  # fmt: skip
        self.last_heartbeat = 0.0
        self.heartbeat_tick = -1  # the tick flown when the last heartbeat went out
        self.gcs_heard: float | None = None  # wall time of the last ground-station heartbeat (None: never)
        self.gcs_lost = False
        self.load = 0.0  # fraction of the period the last tick took
        act = preset.actuators
        self.f_min, self.f_max, self.reversible = act.min_thrust, act.max_thrust, act.reversible
        self.ground_fds = fastio.pollfds([link.sock for link in links])  # asked by the compiled loop
        self.next_poll = 0.0  # [s] wall (time.monotonic): when the ground-station sockets are next read or asked
        self.next_chores = 0.0  # [s] wall (time.monotonic): when the wall-clock work is next due (begin sets it)
        self.pending: tuple[bytes, tuple[str, int]] | None = None  # an answer to the plant waiting for a setpoint
        self.refresh_streams()

    @property
    def links(self) -> list[GcsLink]:
        return self.ground.links

    @property
    def destinations(self) -> plant_loop.Destinations:
        return self.telemetry.destinations

    def refresh_streams(self) -> None:
        """After a change of the links' destinations or message intervals (:meth:`Streams.refresh`)."""
        self.telemetry.refresh()

    # ---- the plant link and the control tick ---------------------------------------------------

    def on_plant_datagram(self, nbytes: int, sender: tuple[str, int]) -> None:
        """A datagram from the plant (in ``self.plant.rx``), flown unless it comes from a stranger
        (:meth:`PlantLink.admit`)."""
        wall = time.monotonic()
        admitted = self.plant.admit(sender, wall)
        if admitted == plant_link.STRANGER:
            self.counters.plant += 1
            return
        if admitted == plant_link.NEW:
            self.io[kernel.LAST_USEC] = -1  # a new plant: its clock starts afresh
            self.io[kernel.NEXT_STREAM_TICK] = 0
        if self.plant.lost:
            self.plant.lost = False
            self.commander.plant_restored()
        started = time.perf_counter()
        if self.estimator is not None:
            flags = sensor_tick(self.plant.rx_array, nbytes, *self.tick_arguments())
        else:
            flags = autopilot_tick(self.plant.rx_array, nbytes, *self.tick_arguments())
        self._finish_tick(flags, nbytes, sender, wall)
        self.load = (time.perf_counter() - started) / self.period

    def tick_arguments(self) -> tuple:
        """The compiled tick's arguments after the datagram (autopilot.tick: autopilot_tick's, or in sensor mode
        sensor_tick's)."""
        ctl = self.controller
        common = (self.st, self.period, ctl.kind, self.plug, self.commander.cm, self.mem, ctl.v, ctl.c, self.f_min,
                  self.f_max, self.plant.tx, self.io, self.zenoh.batch.records, self.frames.out)  # fmt: skip
        if self.estimator is not None:
            return (self.hil_frame, self.truth, self.origin, self.estimator.arrays, *common)
        return (self.scratch, *common)

    def _finish_tick(self, flags: int, nbytes: int, sender: tuple[str, int], wall: float) -> None:
        """What follows the compiled tick in Python: the answer (or, with --offboard-lockstep, its wait for a
        setpoint), the mission executor, and what the flags leave to Python."""
        if self.receiver.release():
            self.outbox.announce(self.commander)
        if flags & kernel.ANSWER:
            if self.pace is not None and self._must_wait(wall):
                self.pending = (bytes(self.plant.tx_view[: self.io[kernel.TX_LEN]]), sender)
                self.zenoh.flush()  # the ground station sees at once the tick the clock waits at
            else:
                self.plant.answer(self.io, sender)
        if self.missions.flying:  # the mission executor, on simulated time, after the answer went out
            for out in self.missions.step(self.commander, self.commander.now):
                self.outbox.mission(out)
        if flags > kernel.ANSWER:
            self._after_tick(flags, nbytes, sender)

    def armed(self) -> None:
        """Just armed: in AUTO.MISSION the mission starts (:meth:`autopilot.missions.Missions.armed`); and a plant
        holding its clock until the vehicle arms is answered at once (:meth:`answer_armed`)."""
        for out in self.missions.armed(self.commander, self.commander.now):
            self.outbox.mission(out)
        self.answer_armed()

    def answer_armed(self) -> None:
        """Just armed, and the plant quiet for PLANT_HOLDING: a lockstep plant that holds its clock until the vehicle
        arms (``quadsitl plant --hold-until-armed``) waits for an answer saying armed. The answer to its last tick
        goes again at once (its forces as computed then, armed), instead of at the plant's next re-send; a plant
        that has moved on discards it as stale."""
        if self.plant.peer is None or self.io[kernel.LAST_USEC] < 0 or self.pending is not None:
            return
        if not self.plant.holding():
            return
        kernel.answer_again(int(self.io[kernel.LAST_USEC]), self.commander.cm, self.mem, self.f_max, self.plant.tx,
                            self.io)  # fmt: skip
        self.plant.answer(self.io, self.plant.peer)

    def serving(self) -> bool:
        """Whether the plant's ticks go to the compiled loop: a plant heard (an IPv4 one), not lost, and no mission
        flying (its executor steps in Python after each tick)."""
        return self.plant.address is not None and not self.plant.lost and not self.missions.flying

    def serve_bounds(self) -> tuple[float, int]:
        """Where the compiled loop gives the plant back to Python: (the wall-clock moment [s]: the wall-clock work at
        ``next_chores``, the next telemetry batch among it, a log's next burst, a calibration's next sample; the
        last tick it may answer itself)."""
        # With --offboard-lockstep the loop gives the tick before a held setpoint's to Python (Receiver.release)
        limit = plant_loop.NO_LIMIT
        if self.pace is not None:
            limit = min(self.pace.free_until(self._offboard()), self.pace.next_due() - 2)
            c = self.commander
            if c.armed and c.mode == wire.Mode.OFFBOARD and c.offboard_tick < 0:  # the flight's first tick is next:
                limit = min(limit, int(self.io[kernel.TICK]))  # Python's, which may hold the clock there
        next_chores = self.next_chores
        if self.logs.sending:  # a log's download: its next burst from Python after GCS_POLL
            next_chores = min(next_chores, time.monotonic() + GCS_POLL)
        if self.calibration is not None:  # a calibration: its next sample
            next_chores = min(next_chores, self.next_sample)
        return self.zenoh.deadline(next_chores), limit

    def serve_plant(self) -> int:
        """Serve the plant link in compiled code (:meth:`PlantLink.serve`) until Python has something to do
        (:meth:`serve_bounds`), and do it → the loop's status."""
        deadline, limit = self.serve_bounds()
        status, nbytes, flags, self.next_poll, wall = self.plant.serve(
            self.io, self.tick_arguments(), deadline, limit, self.destinations.out, self.ground_fds, self.next_poll,
            GCS_POLL,
        )  # fmt: skip
        return self.served(status, nbytes, flags, wall)

    def served(self, status: int, nbytes: int, flags: int, wall: float) -> int:
        """What the compiled loop (:mod:`autopilot.plant_loop`) gave back to Python at ``wall``: the rest of its tick,
        or a stranger's datagram → ``status``."""
        stats = self.plant.stats
        if stats[plant_loop.ANSWERED]:
            self.load = stats[plant_loop.TICK_NS] * 1e-9 / self.period
        if status == plant_loop.SENT:  # the answer went out in the loop: the rest of the tick
            if flags & kernel.FRAMES and self.destinations.count[0] >= 0:  # the loop sent them; some failed
                flags &= ~kernel.FRAMES
                self.telemetry.resend_failed()
            self._finish_tick(flags & ~kernel.ANSWER, nbytes, self.plant.peer, wall)
        elif status == plant_loop.TICKED:
            self._finish_tick(flags, nbytes, self.plant.peer, wall)
        elif status == plant_loop.STRANGER:
            self.on_plant_datagram(nbytes, fastio.address_of(self.plant.sender))
        return status

    def _after_tick(self, flags: int, nbytes: int, sender: tuple[str, int]) -> None:
        """What a tick leaves to Python, now and then: telemetry messages, announcements, a full batch, and the
        datagrams the compiled decoder does not take."""
        if flags & kernel.FRAMES:
            self.telemetry.send_frames()
        if flags & kernel.STREAM:
            self.telemetry.due(int(self.io[kernel.TICK]))
        if flags & kernel.EVENT_DUE:
            self.commander.announce(int(self.io[kernel.EVENT]))
        self.outbox.announce(self.commander)
        if flags & kernel.BATCH_FULL:
            self.zenoh.flush()
        if flags & kernel.REFUSED:
            self.counters.plant += 1  # a corrupt frame, or a state never to fly: the plant re-sends or moves on
        if flags & kernel.NOT_MINE:
            self._parse_slowly(nbytes, sender)
        if flags & kernel.ESTIMATOR_CHANGED:
            self._estimator_changed()

    def _estimator_changed(self) -> None:
        """The estimator aligned, diverged or recovered, or lost a sensor or heard it again: said to the ground
        stations; in flight a divergence, or the GPS lost, is the estimator failsafe (land), as PX4 lands when its
        position estimate is lost (docs/sensors.md#when-a-sensor-fails)."""
        status = int(self.io[kernel.ESTIMATE])
        came, went = status & ~self.estimate_said, self.estimate_said & ~status
        self.estimate_said = status
        if came & kernel.ESTIMATE_ALIGNED:
            self.outbox.say(mavlink.MAV_SEVERITY_INFO, "EKF aligned: attitude, altitude and position from the sensors")
        for bit, lost, back in SENSOR_NEWS:
            if came & bit:
                self.outbox.say(mavlink.MAV_SEVERITY_CRITICAL if bit & LANDS else mavlink.MAV_SEVERITY_WARNING, lost)
            elif went & bit:
                self.outbox.say(mavlink.MAV_SEVERITY_NOTICE, back)
        if came & kernel.ESTIMATE_DIVERGED:
            self.commander.estimator_failed()
        elif came & kernel.ESTIMATE_IMU_LOST:
            self.commander.estimator_failed("Attitude estimate lost: no IMU")
        elif came & kernel.ESTIMATE_GPS_LOST:
            self.commander.position_lost()
        self.outbox.announce(self.commander)

    def _parse_slowly(self, nbytes: int, sender: tuple[str, int]) -> None:
        """A plant datagram the compiled decoder does not take whole (:func:`autopilot.plant_messages.sort_out`):
        the per-tick messages of this mode flown, those of the other mode refused and said, the plant's
        STATUSTEXT relayed to the ground stations."""
        out = plant_messages.sort_out(self.plant.mav, bytes(self.plant.rx[:nbytes]), self.sensing)
        self.counters.plant += out.refused
        if out.other_mode:
            self.outbox.say_once("state-mode", plant_messages.MODE_MISMATCH[self.sensing])
        for datagram in out.datagrams:
            if len(datagram) < nbytes:  # not the datagram as it came, which the compiled decoder did not take
                self.plant.rx[: len(datagram)] = datagram
                self.on_plant_datagram(len(datagram), sender)
        if out.said is not None:  # the plant speaks (its state diverged, sitl.process)
            self.outbox.say(*out.said)

    # ---- what the vehicle knows ------------------------------------------------------------------

    def latest(self) -> tuple[int, VehicleState] | None:
        """The last tick flown: (tick, state); None before the first."""
        if self.io[kernel.LAST_USEC] < 0:
            return None
        return int(self.io[kernel.TICK]), VehicleState._make(self.st[:12].tolist())

    def state(self) -> VehicleState | None:
        """The state of the last tick flown (None before the first)."""
        latest = self.latest()
        return None if latest is None else latest[1]

    def snapshot(self) -> Snapshot | None:
        """The last tick, as the ground-station messages report it (None before the first): what the compiled tick
        shows of it (:func:`autopilot.stream_frames.tick_values`), and what only Python knows."""
        if self.io[kernel.LAST_USEC] < 0:
            return None
        x, rates, ref, _, _, _, target, controls, _ = stream_frames.tick_values(
            self.st, self.commander.cm, self.mem, self.frames.tel
        )
        return Snapshot(
            time_ms=round(int(self.io[kernel.TICK]) * self.period * 1000),
            state=VehicleState._make(x),
            body_rates=rates,
            reference=Reference._make(ref),
            u1=float(self.mem[MEM_U]),
            controls=controls,
            reversible=self.reversible,
            max_total_thrust=4.0 * self.f_max,
            load=self.load,
            errors=self.counters.as_tuple(),
            has_state=self.has_state(),
            home=self._home(),
            target=target,
            estimator=None if self.estimator is None else self.estimator.status(),
            imu=None if self.estimator is None else self.estimator.measurements(),
        )

    def _home(self) -> tuple[float, float, float, float]:
        """Home (where the vehicle armed) in the local frame: x, y, z [m] NED and heading [rad]."""
        x, y, alt = self.commander.home
        return x, y, -alt, self.commander.home_yaw

    def home_position(self):
        return gcs_messages.home_position(self.home, *self._home())

    def has_state(self) -> bool:
        """A vehicle state arrives from the plant (in sensor mode: the estimator has aligned and not diverged):
        SYS_STATUS's sensors are healthy, and arming may proceed."""
        if self.estimator is not None and int(self.io[kernel.ESTIMATE]) != kernel.ESTIMATE_ALIGNED:
            return False
        return self.latest() is not None and not self.plant.lost

    def frame(self) -> setpoints.Frame:
        """Where setpoints are measured from, and the limits they must keep (autopilot.setpoints)."""
        c, st = self.commander, self.commander.settings
        return setpoints.Frame(
            self.origin, c.home, float(self.st[8]), st.altitude_max, st.max_distance, st.xy_vel_max, st.z_vel_up,
            st.z_vel_dn, -1.0 if self.reversible else 0.0,
        )  # fmt: skip

    # ---- the records' routes ----------------------------------------------------------------------

    def on_command(self, r: Command) -> None:
        commands.run(self, r)

    def on_mode(self, r: ModeRequest) -> None:
        if r.mode is None:
            self.outbox.say_once("set_mode", f"Mode {r.custom_mode}: {SUPPORTED_MODES}")
            return
        _, reason = self.set_mode(r.mode)
        if reason:
            self.outbox.say(mavlink.MAV_SEVERITY_WARNING, reason)

    def set_mode(self, mode: wire.Mode) -> tuple[bool, str]:
        """A mode change from a ground station: AUTO.MISSION starts (or resumes) the mission; the rest are the
        commander's."""
        if mode != wire.Mode.MISSION:
            return self.commander.set_mode(mode)
        ok, reason, outs = self.missions.start(self.commander, self.commander.now)
        for out in outs:
            self.outbox.mission(out)
        return ok, reason

    def inject_failure(self, unit: int, kind: int, instance: int) -> tuple[bool, str]:
        """MAV_CMD_INJECT_FAILURE, checked (:mod:`quadsitl.failures`) → (taken, why not). A sensor's goes on to the
        plant, whose sensors fail physically from its next tick; a motor's is applied in the outputs, and a motor
        off in the air is COM_ACT_FAIL_ACT's business (:meth:`Commander.motors_failed`). Said in STATUSTEXT."""
        reason = failures.refusal(unit, kind, instance, self.sensing)
        if not reason and unit != failures.MOTOR and self.plant.peer is None:
            reason = f"Failure {failures.describe(unit, kind)}: no plant connected to fail it in"
        if reason:
            return False, reason
        what = failures.describe(unit, kind, instance)
        if unit == failures.MOTOR:
            off = failures.motors_off(int(self.commander.cm[commander_state.MOTORS_OFF]), kind, instance)
            self.commander.motors_failed(off, what)
        else:
            m = self.plant.mav.command_long_encode(wire.PLANT_SYSTEM_ID, wire.PLANT_COMPONENT_ID,
                                                   mavlink.MAV_CMD_INJECT_FAILURE, 0, unit, kind, instance, 0, 0, 0,
                                                   0)  # fmt: skip
            self.plant.sock.sendto(m.pack(self.plant.mav), self.plant.peer)
        severity = mavlink.MAV_SEVERITY_INFO if kind == failures.OK else mavlink.MAV_SEVERITY_WARNING
        self.outbox.say(severity, f"Failure injected: {what}")
        self.outbox.announce(self.commander)
        return True, ""

    def on_mission(self, r: MissionMessage) -> None:
        """A mission-protocol message, to the pure state machine (autopilot.mission_protocol); its answers out."""
        for out in self.missions.on_message(r.msg_id, r.sender, r.fields, time.monotonic()):
            self.outbox.mission(out)
        self.missions.sync(self.commander)  # a new geofence or rally points: flown from the next tick

    def on_file_transfer(self, r: FileTransfer) -> None:
        refusal = gcs_messages.ftp_refusal(r.payload)
        self.outbox.send(mavlink.MAVLink_file_transfer_protocol_message(0, *r.source, list(refusal)))

    def on_log(self, r: LogRequest) -> None:
        """The log protocol (:mod:`autopilot.log_protocol`): its answers on the link that asked."""
        f = r.fields
        if r.msg_id == mavlink.MAVLINK_MSG_ID_LOG_REQUEST_LIST:
            for entry in self.logs.on_request_list(f["start"], f["end"]):
                r.link.send(self.ground.pack(mavlink.MAVLink_log_entry_message(**entry)))
        elif r.msg_id == mavlink.MAVLINK_MSG_ID_LOG_REQUEST_DATA:
            if self.logs.on_request_data(f["id"], f["ofs"], f["count"], r.link):
                self.send_log_data()
        elif r.msg_id == mavlink.MAVLINK_MSG_ID_LOG_REQUEST_END:
            self.logs.stop()
        else:
            self.logs.on_erase()

    def send_log_data(self) -> None:
        """The next burst of a log's data (LOG_DATA), LOG_DATA_PER_DATAGRAM messages to a datagram."""
        link, burst = self.logs.pump(GCS_BUDGET, LOG_DATA_BURST)
        frames = [self.ground.pack(mavlink.MAVLink_log_data_message(**fields)) for fields in burst]
        for i in range(0, len(frames), LOG_DATA_PER_DATAGRAM):
            link.send(b"".join(frames[i : i + LOG_DATA_PER_DATAGRAM]))

    def log_definitions(self):
        """A new flight log's definitions: the parameters as they are now (autopilot.flight_log.definitions)."""
        return flight_log.definitions(self.preset, self.kind, self.sensing, self.origin,
                                      {name: value for _, name, value in self.params})  # fmt: skip

    def on_ground_heartbeat(self, r: GroundHeartbeat) -> None:
        self.gcs_heard = r.wall
        if self.gcs_lost:
            self.gcs_lost = False
            self.commander.datalink_restored()
            self.outbox.announce(self.commander)

    def apply_params(self) -> None:
        """Make the accepted parameter values the ones the next tick uses."""
        applied = self.params.applied()
        self.controller = self.params.build(applied)  # Ωr: the command in self.mem
        self.plug = self.controller.plug or plugin.no_plug()
        self.commander.settings = applied.settings
        if self.estimator is not None:
            cal = applied.calibration
            self.estimator.calibrate(cal.gyro_offset, calibration.board_rotation(cal))

    # ---- calibration (autopilot.calibration) -----------------------------------------------------------

    def calibrating(self) -> bool:
        return self.calibration is not None

    def calibrate(self, kind: str | None) -> tuple[int, str, None]:
        """MAV_CMD_PREFLIGHT_CALIBRATION, disarmed (:func:`autopilot.commands.preflight_calibration`): ``kind`` started
        (GYRO, MAG, ACCEL, LEVEL), the one running cancelled ("", which is also PX4's "RC calibration ended" when none
        runs), or one not run here refused (None)."""
        if kind == "":  # cancelled at its next sample: after this answer (MAVSDK's cancel() waits for it, holding
            self.cancel_calibration = self.calibration is not None  # the lock its "[cal]" texts' handler takes)
            return mavlink.MAV_RESULT_ACCEPTED, "", None
        if self.calibration is not None:
            return mavlink.MAV_RESULT_TEMPORARILY_REJECTED, f"Calibration: {self.calibration.kind} is running", None
        if kind is None:
            return mavlink.MAV_RESULT_UNSUPPORTED, calibration.NOT_RUN, None
        if not self.has_state():
            return mavlink.MAV_RESULT_TEMPORARILY_REJECTED, "Calibration: no sensor data yet", None
        self.calibration = Calibration(kind, self.params.applied().calibration, self.outbox.say)
        if self.estimator is not None:
            self.estimator.collect(True)
        self.next_sample = self.calibration_heard = time.monotonic() + CALIBRATION_SAMPLE
        return mavlink.MAV_RESULT_ACCEPTED, "", None

    def calibration_step(self) -> None:
        """The running calibration's next sample (sensor mode: the corrected IMU samples since the last, averaged;
        truth mode: the ideal sensors of the newest tick); when it ends, what it saved set and announced."""
        c, tick = self.calibration, int(self.io[kernel.TICK])
        if self.cancel_calibration:
            self.cancel_calibration = False
            c.cancel()
        if not c.done:
            roll, pitch = float(self.st[6]), float(self.st[7])
            wall = time.monotonic()
            if self.estimator is not None:
                taken = self.estimator.take()
                if taken is not None:
                    self.calibration_heard = wall
                    c.step(calibration.Sample(self.commander.now, *taken, roll, pitch))
            elif tick != self.calibration_tick:
                self.calibration_tick, self.calibration_heard = tick, wall
                rates = tuple(float(r) for r in self.st[codec.BODY_RATES : codec.BODY_RATES + 3])
                c.step(calibration.truth_sample(self.commander.now, roll, pitch, rates, self.gravity))
            if wall - self.calibration_heard > calibration.NO_DATA:
                c.no_data()
        if not c.done:
            return
        self.calibration = None
        if self.estimator is not None:
            self.estimator.collect(False)
        if c.saved is not None:
            for name, value in param_values(c.saved, CALIBRATION).items():
                if self.params.lookup(name)[2] != value and not self.params.set(name, value):
                    self.param_protocol.send(*self.params.lookup(name))
            self.apply_params()

    def publish_plan(self, again: bool = False) -> None:
        self.zenoh.publish_plan(self.missions, self.commander, again)

    # ---- the loop ------------------------------------------------------------------------------

    def heartbeat(self) -> None:
        self.outbox.send(gcs_messages.heartbeat(self.commander))
        self.outbox.mission(self.missions.protocol.mission_current())  # MISSION_CURRENT at 1 Hz, as PX4
        self.publish_plan(again=True)
        tick = int(self.io[kernel.TICK])
        still, self.heartbeat_tick = tick == self.heartbeat_tick, tick
        if not self.has_state() or still:
            # No new ticks, so no streams (no plant, or a lockstep plant holding its clock until the vehicle arms):
            # SYS_STATUS says here whether the vehicle may arm, and the last tick's records go out again.
            self.outbox.send(gcs_messages.sys_status(self.load, self.counters.as_tuple(), has_state=self.has_state(),
                                                     cm=self.commander.cm))  # fmt: skip
            self.zenoh.again()

    def poll_gcs(self) -> None:
        """What waits on the ground-station sockets (GroundLinks.read, within GCS_BUDGET), through the receiver.
        A new peer is streamed to from the next tick on."""
        for m, link, sender in self.ground.read(GCS_BUDGET, self.outbox.say_once):
            try:
                new_peer = sender not in link.peers
                link.peers[sender] = time.monotonic()
                if new_peer:
                    self.heartbeat()
                    self.refresh_streams()
                self.receiver.on_message(m, link)
                self.outbox.announce(self.commander)
            except Exception as exc:  # a bug must not take the vehicle down: report it, fly on
                print(f"{self.label}: error: handling {m.get_type()} from {sender}: {exc!r}", file=sys.stderr)

    def run(self, stop: threading.Event | None = None, ready: Callable[[], None] = say_ready) -> None:
        """The plant socket drives the loop (a blocking receive, so a tick waits on nothing else); the
        ground-station sockets are read every ``GCS_POLL`` seconds of wall time (by the compiled loop: when a
        datagram waits on them), the wall-clock work runs every ``HOUSEKEEPING``, and both whenever the plant is
        quiet. Until ``stop`` is set (a process hosting several vehicles, :mod:`autopilot.host`: the loop comes back
        to Python at least every ``HOUSEKEEPING``), or forever; ``ready`` once the first heartbeat is out."""
        self.begin(ready)
        receive = self.plant.wait
        while stop is None or not stop.is_set():
            status = -1
            if self.pending is not None:  # the wall-clock work goes on while the clock waits (the heartbeat)
                self.wait_for_setpoint()
            elif self.serving():
                status = self.serve_plant()  # the plant's ticks in compiled code, until Python's turn
            else:
                self.take_plant_datagram(receive)
            self.housekeeping(status)

    def take_plant_datagram(self, receive: Callable[[], tuple[int, tuple[str, int]]]) -> None:
        """The plant's next datagram through Python's loop: ``receive()`` → (its length, its sender) into
        ``self.plant.rx`` (BlockingIOError when none came), flown (:meth:`on_plant_datagram`)."""
        try:
            nbytes, sender = receive()
        except (BlockingIOError, InterruptedError):
            return
        self.on_plant_datagram(nbytes, sender)

    def begin(self, ready: Callable[[], None]) -> None:
        """Before the loop: the sockets' waits, the first heartbeat (ground stations see the vehicle from now on),
        then ``ready`` (a launcher that waits for it, quadsitl up, says so)."""
        set_receive_timeout(self.plant.sock, 0.02)
        for link in self.links:
            link.sock.setblocking(False)
        wall = time.monotonic()
        self.chores(wall)
        ready()
        self.next_chores = wall + HOUSEKEEPING

    def housekeeping(self, status: int) -> None:
        """After each turn of the loop (``status``: the compiled loop's, or −1): the plant's silence, the telemetry
        batch, the ground-station sockets, a log's download, a calibration's sample and the wall-clock work, each
        when it is due."""
        wall = time.monotonic()
        if self.plant.silent(wall):
            self.plant.lost = True
            self.commander.plant_lost()
            self.outbox.announce(self.commander)
        if self.zenoh.due(wall):
            self.zenoh.flush()
        if wall >= self.next_poll or status == plant_loop.GROUND:
            self.next_poll = wall + GCS_POLL
            self.poll_gcs()
        if self.logs.sending:
            self.send_log_data()
        if self.calibration is not None and wall >= self.next_sample:
            self.next_sample = wall + CALIBRATION_SAMPLE
            self.calibration_step()
        if wall >= self.next_chores:
            self.next_chores = wall + HOUSEKEEPING
            self.chores(wall)

    def chores(self, wall: float) -> None:
        """The wall-clock work: the telemetry batch when it is due before the next chores (a little early, so that
        the next is due with the chores after) or when no tick came since the last chores, the setpoint stream's,
        the mission transfers' and the datalink's clocks, and the heartbeat."""
        if self.zenoh.idle() or self.zenoh.due(wall, early=HOUSEKEEPING):
            self.zenoh.flush()
        self.zenoh.catch_up(wall)  # the newest records, turned away by the overview's period: owed
        self.commander.wall_clock(wall)
        for out in self.missions.protocol.tick(wall):  # re-requests and timeouts of mission transfers
            self.outbox.mission(out)
        timeout = self.commander.settings.datalink_timeout
        if self.gcs_heard is not None and not self.gcs_lost and wall - self.gcs_heard > timeout:
            self.gcs_lost = True
            self.commander.datalink_lost(timeout)
            self.outbox.announce(self.commander)
        if wall - self.last_heartbeat >= 1.0:
            self.last_heartbeat = wall
            self.heartbeat()
            if any([link.forget_silent(wall) for link in self.links]):
                self.refresh_streams()

    def _offboard(self) -> bool:
        """Flying offboard: armed in offboard mode, from the flight's first tick on (the compiled update sets it)."""
        c = self.commander
        return c.armed and c.mode == wire.Mode.OFFBOARD and c.offboard_tick >= 0

    def _must_wait(self, wall: float) -> bool:
        """``--offboard-lockstep``: whether the answer to the tick flown waits for a setpoint; for as long as the
        ground station is heard, within the datalink timeout (COM_DL_LOSS_T)."""
        self.pace.hold_max = self.commander.settings.datalink_timeout
        return self.pace.must_wait(int(self.io[kernel.TICK]), self._offboard(), wall, self.gcs_heard)

    def wait_for_setpoint(self) -> None:
        """``--offboard-lockstep``: the answer to the plant's tick waits (and with it the simulated clock) until
        an offboard setpoint made for a recent enough moment arrives, or the ground station has not been heard for
        the datalink timeout (:mod:`autopilot.offboard_lockstep`). The ground station sees the tick the clock waits at
        at once; the plant's re-sends of the tick wait in the socket (answered afterwards as any repeat is)."""
        if self.io[kernel.ROWS]:
            self.zenoh.flush()
        select.select([link.sock for link in self.links], [], [], GCS_POLL)
        wall = time.monotonic()
        self.poll_gcs()
        self.commander.wall_clock(wall)
        self.plant.heard = wall  # the plant waits for this answer: it is not lost
        if self.pending is not None and not self._must_wait(wall):
            buf, sender = self.pending
            self.pending = None
            self.plant.sock.sendto(buf, sender)

    def close(self) -> None:
        if self.pace is not None and self.pace.waits and (self.pace.gave_up_count or not self.quiet):
            p = self.pace
            print(f"{self.label}: --offboard-lockstep: the clock waited for a setpoint {p.waits} times, "
                  f"{p.waited:.3f} s of wall time in all ({p.gave_up_count} ran out of {p.hold_max:g} s)",
                  file=sys.stderr)  # fmt: skip
        self.zenoh.close()  # the last rows to the onboard log too
        if self.onboard is not None:
            self.onboard.close()
        self.logs.stop()
        self.plant.close()
        self.ground.close()


# A sensor the estimator lost (kernel.ESTIMATE_*_LOST), and heard again: what the ground stations are told.
SENSOR_NEWS = (
    (kernel.ESTIMATE_GPS_LOST, "GPS lost: position and velocity from the IMU alone", "GPS regained"),
    (kernel.ESTIMATE_BARO_LOST, "Barometer lost: altitude from the GPS", "Barometer regained"),
    (kernel.ESTIMATE_MAG_LOST, "Compass lost: heading from the gyro", "Compass regained"),
    (kernel.ESTIMATE_IMU_LOST, "IMU lost: attitude from its last samples", "IMU regained"),
)
LANDS = kernel.ESTIMATE_GPS_LOST | kernel.ESTIMATE_IMU_LOST  # losses that are the estimator failsafe, in the air


def warm_up_loops(modes: Iterable[bool] = (False, True)) -> None:
    """Compile into numba's cache (or load from it) the autopilot's compiled plant loop for each of ``modes`` (True:
    on sensors; the two loops' arguments' types differ): for a launcher to do once before it starts a fleet, whose
    autopilots then load it instead of each compiling it at once. Call :func:`autopilot.tick.warm_up` first for the
    same modes: the loop calls the tick, which it then loads."""
    for state in ("sensors" if sensing else "truth" for sensing in sorted(set(modes))):
        args = build_parser().parse_args(["--no-zenoh", "--plant-listen", "127.0.0.1:0", "--gcs-listen", "127.0.0.1:0",
                                          "--api-listen", "127.0.0.1:0", "--state", state])  # fmt: skip
        args.home, args.signing_key = None, None
        ap = Autopilot(with_state(load_preset("x500"), args), args)
        try:
            for unlocked in (False, True):  # a process of its own, and a host's (up --hosted)
                plant_loop.warm_up(ap.tick_arguments(), unlocked)
        finally:
            ap.close()


REFUSED = (UsageError, ConfigError, GainError, plugin.ControllerError, zenoh.ZError)
"""What :func:`open_autopilot` raises for options it refuses (said by :func:`refusal`)."""


def open_autopilot(args: argparse.Namespace, unlocked: bool = False) -> Autopilot:
    """The autopilot of these options, its per-tick code compiled (or loaded from numba's cache) before its first tick;
    one of :data:`REFUSED` for options it cannot fly. ``unlocked``: its plant loop lets go of Python's lock while it
    waits (a process hosting several vehicles in threads, :mod:`autopilot.host`)."""
    preset = with_state(load_preset(args.preset), args)
    check(args, preset)
    warm_up(preset.sensors is not None)  # its mode's tick compiled before the first (numba's cache: quick after once)
    ap = Autopilot(preset, args)
    ap.plant.unlocked = unlocked
    try:
        if ap.plant.fast:
            plant_loop.warm_up(ap.tick_arguments(), unlocked)
    except BaseException:
        ap.close()
        raise
    return ap


def refusal(prog: str, exc: BaseException) -> str:
    """The error line for an exception of :data:`REFUSED`."""
    if isinstance(exc, zenoh.ZError):
        return (f"{prog}: error: cannot open the Zenoh session (--zenoh-listen / --zenoh-connect / --zenoh-config): "
                f"{exc}")  # fmt: skip
    return f"{prog}: error: {exc}"


def main(argv: Sequence[str] | None = None) -> int:
    start_process()
    favour_compile_time()  # compiles at -O2: a first run's wait (docs/performance.md#compiling-on-first-run)
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        ap = open_autopilot(args)
    except REFUSED as exc:
        print(refusal(parser.prog, exc), file=sys.stderr)
        return 2
    try:
        ap.run()
    except KeyboardInterrupt:
        pass
    finally:
        ap.close()
    return 0
