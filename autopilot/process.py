"""The autopilot process (``quadsitl autopilot``, ``python -m autopilot``): a thin shell around the
controller, the commander and the parameter table.

Sockets, like PX4 SITL's:

- the plant link (``--plant-listen``): answers each ODOMETRY with HIL_ACTUATOR_CONTROLS for the same
  ``time_usec``; in sensor mode (``--state sensors``, the default when the preset has a [sensors] section) each
  tick's HIL_SENSOR (and HIL_GPS), through the estimator (:mod:`autopilot.estimator`), whose estimate is flown and
  reported; the plant's ground truth (HIL_STATE_QUATERNION) goes to telemetry only;
- two ground-station links, each bound to a local port and streaming to a fixed remote address as well as
  to whoever talks to it: ``gcs`` (listens on 18570, streams to 14550, where QGroundControl and MAVProxy
  listen) and ``api`` (listens on 14580, streams to 14540, where MAVSDK and offboard scripts listen).
  MAVLink 2, PX4 conventions (:mod:`autopilot.gcs_messages`).

Every control tick it publishes state, reference, actuators and status to Zenoh
(:mod:`quadsitl.telemetry`). By default publishing drops rather than blocks, so the loop never waits on a
subscriber; ``--telemetry-congestion block`` (``quadsitl fly`` and formation flights) makes a full link hold the
lockstep clock instead, so that no tick is lost to the logger.
"""

from __future__ import annotations

import argparse
import math
import os
import select
import socket
import sys
import time
from collections.abc import Sequence

import numpy as np
import zenoh

from autopilot import gcs_messages, mission_protocol, plant_loop, plugin, setpoints
from autopilot import tick as kernel
from autopilot.commander import Commander, CommanderSettings
from autopilot.control_params import MEM_FORCES, MEM_SIZE, MEM_U
from autopilot.estimator import Estimator
from autopilot.gains import GainError
from autopilot.gcs_messages import Home, Snapshot
from autopilot.missions import Missions
from autopilot.offboard_lockstep import OffboardLockstep
from autopilot.params import ParamStore
from autopilot.stream_frames import COMPILED as COMPILED_STREAMS
from autopilot.stream_frames import StreamFrames
from autopilot.streams import MessageStreams, phase_of, spread_of
from autopilot.tick import Batch, autopilot_tick, sensor_tick, warm_up
from quadsitl import codec, fastio, telemetry, wire
from quadsitl.cli_util import (
    UsageError,
    add_preset_arguments,
    add_state_arguments,
    check_range,
    check_system_id,
    parse_controller_params,
    parse_home,
    with_state,
)
from quadsitl.compiled_frames import quaternion_to_euler
from quadsitl.config import ConfigError, Preset, load_preset
from quadsitl.process_util import (
    HOT_AFTER,
    PATIENCE,
    PaceGauge,
    SpinThenBlock,
    bind_udp,
    parse_remote,
    set_receive_timeout,
    start_process,
)
from quadsitl.state import Reference, VehicleState

mavlink = wire.mavlink
PEER_TIMEOUT = 30.0  # [s] wall: stop streaming to a peer that has been silent this long
FORCE_DISARM = 21196  # MAV_CMD_COMPONENT_ARM_DISARM param2 that forces a disarm in the air (PX4, MAVLink)
# [s] wall: Zenoh telemetry goes out at least this often (every 20 ticks at 1 kHz real time; 50 samples a second per
# stream, more than a dashboard draws). Each batch wakes Zenoh's threads here and in every subscriber, on the cores a
# lockstep pair needs: 5 ms cost `fly` about a tenth of its ticks (docs/performance.md).
BATCH_WALL = 0.020
# And at the latest after this many ticks: a lockstep run at 50,000-80,000 ticks/s fills 512 in 6-10 ms, each batch a
# trip out of the compiled loop here and four samples the ground station's Python takes; 2048 (a state sample of
# 229 kB, four of Zenoh's 64 kB batches) made `fly` 5 % faster (16 interleaved pairs, docs/performance.md).
BATCH_TICKS = 2048
# --telemetry-congestion: what a full-rate telemetry put does when a subscriber's link has no room (Zenoh's congestion
# control; DROP waits 1 ms for room first). The overview's slow copies always drop: they are a view, not a record.
CONGESTION = {"drop": zenoh.CongestionControl.DROP, "block": zenoh.CongestionControl.BLOCK}
PLANT_LOST_AFTER = 0.5  # [s] wall without a vehicle state: the plant link is lost (failsafe)
PLANT_SILENCE = 1.0  # [s] wall: after this long without the locked plant, another plant may take the link
PLANT_HOLDING = 0.005  # [s] wall: a plant quiet this long may be holding its clock (_answer_armed)
NO_STREAMS = 2**40  # [ticks] how far off the next telemetry message is when no link has a destination
GCS_POLL = 0.002  # [s] wall: how often the ground-station sockets are asked for datagrams while the plant link is busy
# [s] wall: how often the wall-clock work runs (the heartbeat; the setpoint stream's, the ground link's and the
# mission transfers' clocks) while the plant link is busy, with the telemetry batch then due too (one trip to Python
# for both). Each trip costs a real-time autopilot 50-100 us of CPU: when the ground sockets were read every 2 ms
# in Python, the trips took a third of its CPU.
HOUSEKEEPING = BATCH_WALL
GCS_BUDGET = 0.001  # [s] wall: the most time one reading of the ground-station sockets may take
QUATERNION_TOLERANCE = 0.1  # |q|² − 1 within this: normalised; beyond: refused
MISSION_MESSAGES = frozenset(
    getattr(mavlink, f"MAVLINK_MSG_ID_MISSION_{name}")
    for name in (
        "COUNT",
        "ITEM",
        "ITEM_INT",
        "REQUEST_LIST",
        "REQUEST",
        "REQUEST_INT",
        "ACK",
        "CLEAR_ALL",
        "SET_CURRENT",
    )
)
OFFBOARD_SETPOINTS = frozenset((mavlink.MAVLINK_MSG_ID_SET_ATTITUDE_TARGET,
                                mavlink.MAVLINK_MSG_ID_SET_POSITION_TARGET_LOCAL_NED,
                                mavlink.MAVLINK_MSG_ID_SET_POSITION_TARGET_GLOBAL_INT))  # fmt: skip
SENSOR_MESSAGES = frozenset((mavlink.MAVLINK_MSG_ID_HIL_SENSOR, mavlink.MAVLINK_MSG_ID_HIL_GPS,
                             mavlink.MAVLINK_MSG_ID_HIL_STATE_QUATERNION))  # fmt: skip
MODE_MISMATCH = {
    False: "Plant sends sensors (HIL_SENSOR); this autopilot flies on the true state: start both with --state sensors",
    True: "Plant sends the true state (ODOMETRY); this autopilot flies on sensors: start both with --state sensors",
}
SUPPORTED_MODES = "supported are offboard (6), takeoff (4/2), hold (4/3), mission (4/4), RTL (4/5), land (4/6)"


def as_int(value: float) -> int:
    """A command parameter as an integer; −1 for NaN, infinities and values beyond 32 bits (never raises)."""
    return int(value) if math.isfinite(value) and abs(value) < 2**31 else -1


class GcsLink:
    """One ground-station socket: a bound local address, an optional fixed remote, learned peers, and
    its own message intervals (SET_MESSAGE_INTERVAL applies to the link it arrives on, as in PX4)."""

    def __init__(self, name: str, sock: socket.socket, remote: tuple[str, int] | None, streams: MessageStreams,
                 label: str = "autopilot") -> None:  # fmt: skip
        self.name, self.sock, self.remote, self.streams = name, sock, remote, streams
        self.label = label  # who says so on stderr: "autopilot v2"
        self.peers: dict[tuple[str, int], float] = {}  # address → wall time last heard
        self.send_errors = 0  # datagrams the OS refused to send (a peer gone, a remote this socket cannot reach)
        self._told: set[tuple[tuple[str, int], int | None]] = set()  # (destination, errno) already reported

    def send(self, buf: bytes, to: list[tuple[str, int]] | None = None) -> bool:
        """``buf`` to every destination (or those in ``to``) → False when a learned peer was dropped. A send the OS
        refuses drops a learned peer (it is heard again if it comes back) and is counted; each destination's first
        failure of a kind is one line on stderr, so a remote this link cannot reach (a loopback-bound socket and
        another host's address: EINVAL) is never silent, and a flight controller never stops for it."""
        peers = len(self.peers)
        for peer in self.destinations() if to is None else to:
            try:
                self.sock.sendto(buf, peer)
            except OSError as exc:
                self.peers.pop(peer, None)
                self.send_errors += 1
                if (peer, exc.errno) not in self._told:
                    self._told.add((peer, exc.errno))
                    host, port = self.sock.getsockname()[:2]
                    why = exc.strerror or exc
                    print(f"{self.label}: {self.name} link: cannot send to {peer[0]}:{peer[1]} from {host}:{port}: "
                          f"{why} (said once for this destination and error)", file=sys.stderr)  # fmt: skip
        return len(self.peers) == peers

    def destinations(self) -> list[tuple[str, int]]:
        out = list(self.peers)
        if self.remote is not None and self.remote not in self.peers:
            out.append(self.remote)
        return out

    def forget_silent(self, now: float) -> bool:
        """Forget the peers not heard for PEER_TIMEOUT → whether any was."""
        silent = [peer for peer, seen in self.peers.items() if now - seen > PEER_TIMEOUT]
        for peer in silent:
            del self.peers[peer]
        return bool(silent)


class Autopilot:
    def __init__(self, preset: Preset, args: argparse.Namespace) -> None:
        self.period = preset.sim.period
        kind = args.controller or preset.controller.type
        settings = CommanderSettings(setpoint_timeout=args.setpoint_timeout)
        plugged = plugin.load(kind) if plugin.is_plugin(kind) else None  # its parameters are MAVLink parameters
        self.params = ParamStore(preset, kind, settings, plugged)
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
        if self.sensing:
            s = preset.sensors
            self.estimator = Estimator.for_field(self.period, preset.vehicle.gravity, s.mag_strength_gauss,
                                                 s.mag_declination_deg, s.mag_inclination_deg)  # fmt: skip
        self.truth = np.full(codec.DECODED_SIZE, np.nan)  # the plant's ground truth of the last tick (sensor mode)
        self.hil_frame = np.zeros(codec.FRAME_MAX, dtype=np.uint8)  # one frame of a sensor datagram, being decoded
        self.origin = (self.home.lat, self.home.lon, self.home.alt)  # where the GPS's positions are taken from
        self.missions = Missions((self.home.lat, self.home.lon, self.home.alt))  # stored, transferred and flown
        self.sysid = args.system_id
        self.quiet = args.quiet
        self.label = f"autopilot {getattr(args, 'vehicle', 'v1')}"  # on stderr: a fleet's autopilots told apart
        self.compid = wire.AUTOPILOT_COMPONENT_ID
        self.mav = wire.link(self.sysid, self.compid)  # the plant link's fallback parser
        self.signing_key: bytes | None = args.signing_key
        self.gcs_mav = self._gcs_link()  # ground-station links: signed when a key is given
        self.sensor_dropped = 0  # sensor samples with a NaN or an infinity (sensor mode), never used
        self.rx = bytearray(65535)  # the plant link's datagrams, read in place by the compiled decoder
        self.rx_array = np.frombuffer(self.rx, dtype=np.uint8)
        self.tx = np.zeros(codec.FRAME_MAX, dtype=np.uint8)  # the answer, written by control_tick
        self.tx_view = memoryview(self.tx)  # type: ignore[arg-type]
        self.st = np.zeros(codec.DECODED_SIZE)  # the decoded state (VehicleState fields, then p, q, r)
        self.scratch = np.zeros(codec.DECODED_SIZE)  # a state being decoded
        self.mem = np.zeros(MEM_SIZE)  # the command, forces, errors and Ωr of the last tick (autopilot.tick)
        self.plant_sock = bind_udp("--plant-listen", args.plant_listen)
        self.links: list[GcsLink] = []
        for name in ("gcs", "api"):
            remote = parse_remote(f"--{name}-remote", getattr(args, f"{name}_remote"))
            sock = bind_udp(f"--{name}-listen", getattr(args, f"{name}_listen"))
            streams = MessageStreams(self.period, args.telemetry_rate, phase_of(self.sysid), spread_of(self.sysid))
            self.links.append(GcsLink(name, sock, remote, streams, self.label))
        self.streams = self.links[0].streams  # for what every link's streams share: which ids are streamed
        # The per-tick telemetry messages (autopilot.stream_frames) are built by the compiled tick and sent by the
        # compiled loop, on unsigned links (a signed link's frames are pymavlink's to sign: Python builds them all).
        self.compiled_streams = self.signing_key is None
        self.frames = StreamFrames(len(self.links), (self.home.lat, self.home.lon, self.home.alt),
                                   4.0 * preset.actuators.max_thrust)  # fmt: skip
        self.destinations = plant_loop.Destinations()
        self.last_heartbeat = 0.0
        self.heartbeat_tick = -1  # the tick flown when the last heartbeat went out
        self.last_records: dict[str, bytes] = {}  # each Zenoh stream's last record published
        # Input counters, reported in SYS_STATUS (errors_comm, errors_count1..4):
        self.errors_comm = 0  # ground-station datagrams that are not MAVLink or fail their CRC
        self.unknown = 0  # well-formed messages we do not handle (ignored)
        self.refused = 0  # setpoints and parameter values refused by validation
        self.errors_plant = 0  # plant-link datagrams that are corrupt, non-finite, or from a stranger
        self.not_for_us = 0  # messages addressed to another system or component (ignored)
        self.plant_peer: tuple[str, int] | None = None  # the plant the link is locked to
        self.plant_heard = 0.0  # wall time its last datagram arrived
        self.plant_lost = False
        self.gcs_heard: float | None = None  # wall time of the last ground-station heartbeat (None: never)
        self.gcs_lost = False
        self.load = 0.0  # fraction of the period the last tick took
        self.chunk_id = 0
        self.said: dict[str, float] = {}  # topic → wall time of the last such warning
        act = preset.actuators
        self.f_min, self.f_max, self.reversible = act.min_thrust, act.max_thrust, act.reversible
        # Polls while the plant answers fast, with patience where nothing paces the plant (measured from the ticks'
        # pace: serve_plant), without where something does (real time, --speed below 2)
        self.plant_wait = SpinThenBlock(self.plant_sock.recvfrom_into, self.rx, patience=PATIENCE)
        self.plant_pace = PaceGauge(self.period)
        # The plant link served in compiled code (autopilot.plant_loop), once a plant is heard on an IPv4 socket:
        self.fast = fastio.compiled_loops() and self.plant_sock.family == socket.AF_INET
        self.plant_address: np.ndarray | None = None  # the locked plant's sockaddr (fast only)
        self.sender = np.zeros(fastio.SOCKADDR_IN, dtype=np.uint8)  # where a datagram came from (fast only)
        self.sender_len = np.zeros(1, dtype=np.int32)
        self.loop_stats = np.zeros(plant_loop.STATS_SIZE, dtype=np.int64)
        self.ground_fds = fastio.pollfds([link.sock for link in self.links])  # asked by the compiled loop
        self.next_poll = 0.0  # [s] wall (time.monotonic): when the ground-station sockets are next read or asked
        lead = args.offboard_lockstep
        self.pace = None if lead is None else OffboardLockstep(lead, self.period)  # autopilot.offboard_lockstep
        self.pending: tuple[bytes, tuple[str, int]] | None = None  # an answer to the plant waiting for a setpoint
        self.session = None
        self.pubs: dict[str, zenoh.Publisher] = {}
        self.slow: telemetry.SlowCopies | None = None  # the overview (quadsitl/<vehicle>/slow/<stream>)
        self.plan_pub: zenoh.Publisher | None = None  # quadsitl/<vehicle>/mission: the plan, for maps
        self.plan_published: tuple = ()  # what the last mission document said (version, current, state, home)
        self.batch = Batch(BATCH_TICKS)
        self.io = np.zeros(kernel.IO_SIZE, dtype=np.int64)  # the tick's bookkeeping (autopilot.tick)
        self.io[kernel.LAST_USEC] = -1
        self.io[kernel.SYSTEM], self.io[kernel.COMPONENT] = self.sysid, self.compid
        self.last_flush = 0.0
        if not args.no_zenoh:
            conf = telemetry.config_from_args(args)
            if not args.zenoh_config:  # samples carry their publication time: subscribers can measure latency
                conf.insert_json5("timestamping/enabled", "true")
                # Room for 16 batches (Zenoh's most; its default is 2) before a put drops: Zenoh's sending
                # thread shares two cores with a lockstep pair that polls, and may wait a few ms for one.
                conf.insert_json5("transport/link/tx/queue/size/data", "16")
            self.session = zenoh.open(conf)
            for stream in (*telemetry.STREAMS, *([telemetry.TRUTH] if self.sensing else [])):
                self.pubs[stream] = self.session.declare_publisher(
                    telemetry.key(args.vehicle, stream),
                    encoding=telemetry.encoding(stream),
                    congestion_control=CONGESTION[args.telemetry_congestion],
                )
            self.io[kernel.CAPACITY] = BATCH_TICKS  # records are batched only while there is a session
            self.slow = telemetry.SlowCopies(self.session, args.vehicle)
            self.plan_pub = self.session.declare_publisher(
                telemetry.key(args.vehicle, telemetry.MISSION), encoding=telemetry.mission_encoding()
            )
        self.refresh_streams()

    # ---- the control tick ----------------------------------------------------------------------

    def on_plant_datagram(self, nbytes: int, sender: tuple[str, int]) -> None:
        """A datagram from the plant (in ``self.rx``). The plant link is locked to the first plant that talks
        to it; another sender is a stranger and is dropped, until the locked plant has been silent for
        PLANT_SILENCE (then a restarted plant, on a new port, takes over)."""
        wall = time.monotonic()
        if sender != self.plant_peer:
            if self.plant_peer is not None and wall - self.plant_heard < PLANT_SILENCE:
                self.errors_plant += 1
                return
            self.plant_peer = sender
            self.plant_address = fastio.sockaddr(sender) if self.fast else None
            self.io[kernel.LAST_USEC] = -1  # a new plant: its clock starts afresh
            self.io[kernel.NEXT_STREAM_TICK] = 0
        self.plant_heard = wall
        if self.plant_lost:
            self.plant_lost = False
            self.commander.plant_restored()
        started = time.perf_counter()
        if self.estimator is not None:
            flags = sensor_tick(self.rx_array, nbytes, *self.tick_arguments())
        else:
            flags = autopilot_tick(self.rx_array, nbytes, *self.tick_arguments())
        self._finish_tick(flags, nbytes, sender, wall)
        self.load = (time.perf_counter() - started) / self.period

    def tick_arguments(self) -> tuple:
        """The compiled tick's arguments after the datagram (autopilot.tick: autopilot_tick's, or in sensor mode
        sensor_tick's)."""
        ctl = self.controller
        common = (self.st, self.period, ctl.kind, self.plug, self.commander.cm, self.mem, ctl.v, ctl.c, self.f_min,
                  self.f_max, self.tx, self.io, self.batch.records, self.frames.out)  # fmt: skip
        if self.estimator is not None:
            return (self.hil_frame, self.truth, self.origin, self.estimator.arrays, *common)
        return (self.scratch, *common)

    def _finish_tick(self, flags: int, nbytes: int, sender: tuple[str, int], wall: float) -> None:
        """What follows the compiled tick in Python: the answer (or, with --offboard-lockstep, its wait for a
        setpoint), the mission executor, and what the flags leave to Python."""
        self._fly_held()
        if flags & kernel.ANSWER:
            if self.pace is not None and self.pace.must_wait(int(self.io[kernel.TICK]), self._offboard(), wall):
                self.pending = (bytes(self.tx_view[: self.io[kernel.TX_LEN]]), sender)
                self.flush_telemetry()  # the ground station sees at once the tick the clock waits at
            else:
                self.plant_sock.sendto(self.tx_view[: self.io[kernel.TX_LEN]], sender)
        if self.missions.flying:  # the mission executor, on simulated time, after the answer went out
            for out in self.missions.step(self.commander, self.commander.now):
                self._send_mission(out)
        if flags > kernel.ANSWER:
            self._after_tick(flags, nbytes, sender)

    def _send_frames(self) -> None:
        """The telemetry datagrams the tick built (kernel.FRAMES), sent from Python: each link's to its
        destinations."""
        dropped = False
        for i, link in enumerate(self.links):
            if self.frames.lens[i]:
                dropped |= not link.send(self.frames.datagram(i))
        if dropped:
            self.refresh_streams()

    def refresh_streams(self) -> None:
        """After a change of the links' destinations or message intervals: which per-tick messages the compiled
        tick builds for each link (those with somewhere to send), where the compiled loop sends them, and when
        Python's next messages are due."""
        entries: list | None = []
        for i, link in enumerate(self.links):
            live = link.remote is not None or bool(link.peers)
            for slot, mid in enumerate(COMPILED_STREAMS):
                interval, phase = link.streams.schedule(mid)
                self.frames.sched[i, slot] = (interval if live and self.compiled_streams else 0), phase
            if entries is not None and live:
                if link.sock.family != socket.AF_INET:
                    entries = None
                    continue
                try:
                    for peer in link.destinations():
                        fastio.sockaddr(peer)  # an IPv4 address in dotted form (else OSError: Python sends)
                        entries.append((i, link.sock.fileno(), peer))
                except OSError:
                    entries = None
        self.destinations.set(entries if self.fast else None)
        self.io[kernel.NEXT_STREAM_TICK] = 0  # recomputed at the next tick

    def _answer_armed(self) -> None:
        """Just armed, and the plant quiet for PLANT_HOLDING: a lockstep plant that holds its clock until the vehicle
        arms (``quadsitl plant --hold-until-armed``) waits for an answer saying armed. The answer to its last tick
        goes again at once (its forces as computed then, armed), instead of at the plant's next re-send, 50 ms
        later; a plant that has moved on discards it as stale."""
        if self.plant_peer is None or self.io[kernel.LAST_USEC] < 0 or self.pending is not None:
            return
        if time.monotonic() - self.plant_heard < PLANT_HOLDING:
            return
        kernel.answer_again(int(self.io[kernel.LAST_USEC]), self.commander.cm, self.mem, self.f_max, self.tx, self.io)
        self.plant_sock.sendto(self.tx_view[: self.io[kernel.TX_LEN]], self.plant_peer)

    def serve_plant(self, next_chores: float) -> int:
        """Serve the plant link in compiled code (:mod:`autopilot.plant_loop`) until Python has something to do
        (a tick whose flags need it, a stranger's datagram, the wall-clock work at ``next_chores`` or the next
        telemetry batch, a datagram on a ground-station socket, a quiet plant), and do it → the loop's status. The
        loop asks the ground-station sockets from ``self.next_poll`` on and moves it."""
        wait, stats = self.plant_wait, self.loop_stats
        stats[:] = 0
        stats[plant_loop.SHORT] = wait.short
        stats[plant_loop.NEXT_GROUND] = int(self.next_poll * 1e9)
        polling = wait.polling()
        deadline = min(next_chores, self.last_flush + BATCH_WALL if self.io[kernel.ROWS] else next_chores)
        # With --offboard-lockstep the loop gives the tick before a held setpoint's to Python (_fly_held)
        limit = plant_loop.NO_LIMIT
        if self.pace is not None:
            limit = min(self.pace.free_until(self._offboard()), self.pace.next_due() - 2)
            c = self.commander
            if c.armed and c.mode == wire.Mode.OFFBOARD and c.offboard_tick < 0:  # the flight's first tick is next:
                limit = min(limit, int(self.io[kernel.TICK]))  # Python's, which may hold the clock there
        status, nbytes, flags = plant_loop.serve(
            self.plant_sock.fileno(), self.rx_array, self.sender, self.sender_len, self.plant_address, self.tx, self.io,
            self.tick_arguments(), int(deadline * 1e9), polling, int(wait.budget * 1e9),
            int(wait.patience * 1e9), HOT_AFTER, limit, stats, self.destinations.out, self.ground_fds,
            int(GCS_POLL * 1e9),
        )  # fmt: skip
        if status == plant_loop.SENT or status == plant_loop.DUE:
            # Python's turn (the tick's Python-built messages, the telemetry batch, the wall-clock work), the answer
            # already out: first the fleet-mates waiting for this core answer their ticks. sched_yield puts this
            # process behind them (under SCHED_FIFO, at the end of its priority's queue, where nothing else would
            # take the core from it until it blocks). Eight vehicles in real time under SCHED_FIFO, cores awake,
            # dashboard open, four interleaved pairs: 0.08-0.26 % of their periods missed outside the host's stalls
            # with it, 0.64-3.4 % without (docs/fleets.md).
            os.sched_yield()
        wall = time.monotonic()
        self.next_poll = stats[plant_loop.NEXT_GROUND] * 1e-9
        wait.tally(int(stats[plant_loop.POLLED]), int(stats[plant_loop.LATE]), polling and status == plant_loop.QUIET,
                   int(stats[plant_loop.BLOCKED]), int(stats[plant_loop.SHORT]))  # fmt: skip
        if stats[plant_loop.ANSWERED]:
            self.plant_heard = wall
            self.load = stats[plant_loop.TICK_NS] * 1e-9 / self.period
        pace = self.plant_pace.update(int(self.io[kernel.TICK]), wall)
        if pace is not None:
            wait.be_patient(PaceGauge.patience(pace))
        if status == plant_loop.SENT:  # the answer went out in the loop: the rest of the tick
            if flags & kernel.FRAMES and self.destinations.count[0] >= 0:  # the loop sent them; some failed
                flags &= ~kernel.FRAMES
                for i, peer in self.destinations.failed():
                    self.links[i].send(self.frames.datagram(i), to=[peer])  # said and dropped as any failed send
                self.refresh_streams()
            self._finish_tick(flags & ~kernel.ANSWER, nbytes, self.plant_peer, wall)
        elif status == plant_loop.TICKED:
            self.plant_heard = wall
            self._finish_tick(flags, nbytes, self.plant_peer, wall)
        elif status == plant_loop.STRANGER:
            self.on_plant_datagram(nbytes, fastio.address_of(self.sender))
        return status

    def _after_tick(self, flags: int, nbytes: int, sender: tuple[str, int]) -> None:
        """What a tick leaves to Python, now and then: telemetry messages, announcements, a full batch, and the
        datagrams the compiled decoder does not take."""
        if flags & kernel.FRAMES:
            self._send_frames()
        if flags & kernel.STREAM:
            self._stream(int(self.io[kernel.TICK]))
        if flags & kernel.EVENT_DUE:
            self.commander.announce(int(self.io[kernel.EVENT]))
        if self.commander.messages:
            self._announce_commander()
        if flags & kernel.BATCH_FULL:
            self.flush_telemetry()
        if flags & kernel.REFUSED:
            self.errors_plant += 1  # a corrupt frame, or a state never to fly: the plant re-sends or moves on
        if flags & kernel.NOT_MINE:
            self._parse_slowly(nbytes, sender)
        if flags & kernel.ESTIMATOR_CHANGED:
            self._estimator_changed()

    def _estimator_changed(self) -> None:
        """The estimator aligned, diverged, or recovered: said to the ground stations; a divergence in flight is
        the estimator failsafe (land)."""
        status = int(self.io[kernel.ESTIMATE])
        if status & kernel.ESTIMATE_DIVERGED:
            self.commander.estimator_failed()
        elif status & kernel.ESTIMATE_ALIGNED:
            self._say(mavlink.MAV_SEVERITY_INFO, "EKF aligned: attitude, altitude and position from the sensors")
        self._announce_commander()

    def _parse_slowly(self, nbytes: int, sender: tuple[str, int]) -> None:
        """A plant datagram the compiled decoder does not take whole (other messages with it, signed frames):
        pymavlink's to parse. The per-tick messages of this autopilot's mode are re-framed alone for the compiled
        path (ODOMETRY; in sensor mode HIL_SENSOR, HIL_GPS and HIL_STATE_QUATERNION together); those of the other
        mode are refused and said. The plant's STATUSTEXT (all its chunks in one datagram: the plant's state
        diverged and the plant stopped, :mod:`sitl.process`) goes on to the ground stations as one text."""
        try:
            msgs = self.mav.parse_buffer(bytes(self.rx[:nbytes])) or []
        except mavlink.MAVError:
            self.errors_plant += 1
            return
        said, frames = [], []
        mine = SENSOR_MESSAGES if self.sensing else {mavlink.MAVLINK_MSG_ID_ODOMETRY}
        theirs = {mavlink.MAVLINK_MSG_ID_ODOMETRY} if self.sensing else SENSOR_MESSAGES
        for msg in msgs:
            mid = msg.get_msgId()
            if mid in mine:
                frames.append(msg.pack(wire.link(msg.get_srcSystem(), msg.get_srcComponent())))
            elif mid in theirs:
                self.errors_plant += 1
                self._say_once("state-mode", MODE_MISMATCH[self.sensing])
            elif mid == mavlink.MAVLINK_MSG_ID_STATUSTEXT:
                said.append(msg)
        # Re-framed for the compiled path: each ODOMETRY alone, a tick's sensor messages together (when that is
        # not the datagram as it came, which the compiled decoder did not take).
        for datagram in [b"".join(frames)] if self.sensing and frames else frames:
            if len(datagram) < nbytes:
                self.rx[: len(datagram)] = datagram
                self.on_plant_datagram(len(datagram), sender)
        if said:  # the plant speaks (its state diverged, sitl.process): relayed to the ground stations, whole
            text = "".join(m.text for m in sorted(said, key=lambda m: m.chunk_seq))
            self._say(min(m.severity for m in said), text)

    def latest(self) -> tuple[int, VehicleState, Reference] | None:
        """The last tick flown: (tick, state, the reference flown or held); None before the first."""
        if self.io[kernel.LAST_USEC] < 0:
            return None
        c = self.commander
        return int(self.io[kernel.TICK]), VehicleState._make(self.st[:12].tolist()), c.reference if c.armed else c.hold

    def _stream(self, tick: int) -> None:
        """The telemetry messages due at ``tick`` on each link that the compiled tick does not build."""
        snap, built = None, {}
        skip = COMPILED_STREAMS if self.compiled_streams else ()
        self.gcs_mav.seq = int(self.io[kernel.GCS_SEQ])
        for link in self.links:
            if link.remote is None and not link.peers:
                continue
            frames = []
            for mid in link.streams.due(tick, skip):
                if mid not in built:
                    snap = snap or self._snapshot()
                    built[mid] = codec.pack(gcs_messages.build(mid, snap, self.commander, self.home), self.gcs_mav)
                frames.append(built[mid])
            if frames and not link.send(b"".join(frames)):  # one datagram per link and tick, as PX4 fills its buffer
                self.refresh_streams()
        self.io[kernel.GCS_SEQ] = self.gcs_mav.seq
        # Only links with somewhere to send count (a link nobody listens on would call Python every few ticks for
        # nothing); a new peer starts the streams again (on_gcs).
        self.io[kernel.NEXT_STREAM_TICK] = min(
            (link.streams.next_due(tick, skip) for link in self.links if link.remote is not None or link.peers),
            default=tick + NO_STREAMS,
        )

    def flush_telemetry(self) -> None:
        """Publish the batched records (every stream gets the same ticks)."""
        rows = int(self.io[kernel.ROWS])
        if rows:
            for stream, pub in self.pubs.items():
                payload = self.batch.payload(stream, rows)
                pub.put(payload)
                self.last_records[stream] = payload[-self.batch.regions[stream][1] :]
            self.io[kernel.ROWS] = 0
        self.last_flush = time.monotonic()
        if rows and self.slow is not None:
            self.slow.offer(self.last_records.get, self.last_flush)

    def _snapshot(self) -> Snapshot | None:
        latest = self.latest()
        if latest is None:
            return None
        tick, state, ref = latest
        forces = self.mem[MEM_FORCES : MEM_FORCES + 4].tolist()
        return Snapshot(
            time_ms=round(tick * self.period * 1000),
            state=state,
            body_rates=tuple(self.st[codec.BODY_RATES : codec.BODY_RATES + 3].tolist()),
            reference=ref,
            u1=float(self.mem[MEM_U]),
            controls=tuple(f / self.f_max for f in forces),
            reversible=self.reversible,
            max_total_thrust=4.0 * self.f_max,
            load=self.load,
            errors=self.errors,
            has_state=self.has_state(),
            home=self._home(),
            target=self.commander.target if self.commander.armed else (math.nan,) * 4 + (ref.altitude, math.nan),
            estimator=None if self.estimator is None else self.estimator.status(),
        )

    def _home(self) -> tuple[float, float, float, float]:
        """Home (where the vehicle armed) in the local frame: x, y, z [m] NED and heading [rad]."""
        x, y, alt = self.commander.home
        return x, y, -alt, self.commander.home_yaw

    def _home_position(self):
        return gcs_messages.home_position(self.home, *self._home())

    @property
    def errors(self) -> tuple[int, int, int, int, int]:
        return self.errors_comm, self.unknown, self.refused, self.errors_plant, self.not_for_us

    def has_state(self) -> bool:
        """A vehicle state arrives from the plant (in sensor mode: the estimator has aligned and not diverged):
        SYS_STATUS's sensors are healthy, and arming may proceed."""
        if self.estimator is not None and int(self.io[kernel.ESTIMATE]) != kernel.ESTIMATE_ALIGNED:
            return False
        return self.latest() is not None and not self.plant_lost

    # ---- the ground-station links --------------------------------------------------------------

    def _send_gcs(self, msg) -> None:
        self.gcs_mav.seq = int(self.io[kernel.GCS_SEQ])  # one sequence with the frames the tick builds
        buf = codec.pack(msg, self.gcs_mav)
        self.io[kernel.GCS_SEQ] = self.gcs_mav.seq
        for link in self.links:
            link.send(buf)

    def _say(self, severity: int, text: str) -> None:
        self.chunk_id = self.chunk_id % 65535 + 1
        for msg in gcs_messages.statustext(severity, text, self.chunk_id):
            self._send_gcs(msg)

    def _refuse(self, topic: str, text: str) -> None:
        """A refused input: counted, and said (at most every few seconds per kind); the last valid
        setpoint stays in force."""
        self.refused += 1
        self._say_once(topic, text)

    def _say_once(self, topic: str, text: str, every: float = 5.0) -> None:
        """A warning about a repeated input (a stream of unsupported setpoints): at most once per ``every`` s."""
        now = time.monotonic()
        if now - self.said.get(topic, -math.inf) >= every:
            self.said[topic] = now
            self._say(mavlink.MAV_SEVERITY_WARNING, text)

    def _announce_commander(self) -> None:
        if self.commander.messages:
            for severity, text in self.commander.messages:
                self._say(severity, text)
            self.commander.messages.clear()

    def heartbeat(self) -> None:
        self._send_gcs(gcs_messages.heartbeat(self.commander))
        self._send_mission(self.missions.protocol.mission_current())  # MISSION_CURRENT at 1 Hz, as PX4
        self.publish_plan(again=True)
        tick = int(self.io[kernel.TICK])
        still, self.heartbeat_tick = tick == self.heartbeat_tick, tick
        if not self.has_state() or still:
            # No new ticks, so no streams (no plant, or a lockstep plant holding its clock until the vehicle arms):
            # SYS_STATUS says here whether the vehicle may arm, and the last tick's telemetry records go out again,
            # so a subscriber that joined since sees the vehicle (the same tick again: a join by tick keeps one).
            self._send_gcs(gcs_messages.sys_status(self.load, self.errors, has_state=self.has_state()))
            for stream, record in self.last_records.items():
                self.pubs[stream].put(record)
            if self.slow is not None:
                self.slow.offer(self.last_records.get, time.monotonic())

    def on_gcs(self, m, link: GcsLink, sender: tuple[str, int]) -> None:
        new_peer = sender not in link.peers
        link.peers[sender] = time.monotonic()
        if new_peer:
            self.heartbeat()
            self.refresh_streams()  # its streams start at the next tick
        mid = m.get_msgId()
        if not hasattr(m, "target_system"):
            if mid != mavlink.MAVLINK_MSG_ID_HEARTBEAT:
                self.unknown += 1
            elif m.type == mavlink.MAV_TYPE_GCS:
                self.gcs_heard = time.monotonic()
                if self.gcs_lost:
                    self.gcs_lost = False
                    self.commander.datalink_restored()
                    self._announce_commander()
            return
        if mid in MISSION_MESSAGES:
            if mission_protocol.addressed_to(m.target_system, m.target_component, self.sysid, self.compid):
                self._mission(m, mid)
            else:
                self.not_for_us += 1
            return
        if not self._for_me(m.target_system, getattr(m, "target_component", 0)):  # SET_MODE has no component
            self.not_for_us += 1
            return
        if self.pace is not None and mid in OFFBOARD_SETPOINTS:
            self.pace.stamp(m.time_boot_ms)
            if self.pace.hold(self.pace.tick_of(m.time_boot_ms), int(self.io[kernel.TICK]), m):
                return  # made for a later tick: flown from it (_fly_held)
        if mid in (mavlink.MAVLINK_MSG_ID_COMMAND_LONG, mavlink.MAVLINK_MSG_ID_COMMAND_INT):
            self._command(m, link)
        elif mid in OFFBOARD_SETPOINTS:
            self._fly_setpoint(m, mid)
        elif mid == mavlink.MAVLINK_MSG_ID_SET_MODE:  # QGroundControl's way to PX4 modes (no acknowledgement)
            mode = (
                wire.Mode.from_px4(m.custom_mode) if m.base_mode & mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED else None
            )
            if mode is None:
                self._say_once("set_mode", f"Mode {m.custom_mode}: {SUPPORTED_MODES}")
            else:
                _, reason = self._set_mode(mode)
                if reason:
                    self._say(mavlink.MAV_SEVERITY_WARNING, reason)
        elif mid == mavlink.MAVLINK_MSG_ID_PARAM_REQUEST_LIST:
            for index, name, value in self.params:
                self._send_param(index, name, value)
        elif mid == mavlink.MAVLINK_MSG_ID_PARAM_REQUEST_READ:
            found = self.params.lookup(m.param_id, m.param_index)
            if found is not None:
                self._send_param(*found)
        elif mid == mavlink.MAVLINK_MSG_ID_PARAM_SET:
            self._param_set(m)
        elif mid == mavlink.MAVLINK_MSG_ID_FILE_TRANSFER_PROTOCOL and len(m.payload) >= 12:
            refusal = gcs_messages.ftp_refusal(m.payload)
            self._send_gcs(mavlink.MAVLink_file_transfer_protocol_message(0, m.get_srcSystem(), m.get_srcComponent(),
                                                                          list(refusal)))  # fmt: skip
        else:
            self.unknown += 1
        self._announce_commander()

    def _fly_setpoint(self, m, mid: int) -> None:
        """An offboard setpoint, to the commander."""
        if mid == mavlink.MAVLINK_MSG_ID_SET_ATTITUDE_TARGET:
            self._attitude_target(m)
        elif mid == mavlink.MAVLINK_MSG_ID_SET_POSITION_TARGET_LOCAL_NED:
            self._position_target(m, (m.x, m.y, m.z))
        else:
            self._position_target(m, (float(m.lat_int), float(m.lon_int), m.alt))

    def _fly_held(self) -> None:
        """``--offboard-lockstep``: the setpoints held for the next tick (or before) go to the commander now, between
        the tick just flown and the next (autopilot.offboard_lockstep)."""
        if self.pace is not None and self.pace.held:
            for m in self.pace.due(int(self.io[kernel.TICK]) + 1):
                self._fly_setpoint(m, m.get_msgId())
            self._announce_commander()

    def _set_mode(self, mode: wire.Mode) -> tuple[bool, str]:
        """A mode change from a ground station: AUTO.MISSION starts (or resumes) the mission; the rest are the
        commander's."""
        if mode != wire.Mode.MISSION:
            return self.commander.set_mode(mode)
        ok, reason, outs = self.missions.start(self.commander, self.commander.now)
        for out in outs:
            self._send_mission(out)
        return ok, reason

    def _mission(self, m, mid: int) -> None:
        """A mission-protocol message, to the pure state machine (autopilot.mission_protocol); its answers out."""
        p, sender, now = self.missions.protocol, (m.get_srcSystem(), m.get_srcComponent()), time.monotonic()
        if mid == mavlink.MAVLINK_MSG_ID_MISSION_COUNT:
            outs = p.on_count(sender, m.count, m.mission_type, now)
        elif mid in (mavlink.MAVLINK_MSG_ID_MISSION_ITEM_INT, mavlink.MAVLINK_MSG_ID_MISSION_ITEM):
            outs = p.on_item(sender, m.to_dict(), now, legacy=mid == mavlink.MAVLINK_MSG_ID_MISSION_ITEM)
        elif mid == mavlink.MAVLINK_MSG_ID_MISSION_REQUEST_LIST:
            outs = p.on_request_list(sender, m.mission_type, now)
        elif mid in (mavlink.MAVLINK_MSG_ID_MISSION_REQUEST_INT, mavlink.MAVLINK_MSG_ID_MISSION_REQUEST):
            outs = p.on_request(
                sender, m.seq, m.mission_type, now, legacy=mid == mavlink.MAVLINK_MSG_ID_MISSION_REQUEST
            )
        elif mid == mavlink.MAVLINK_MSG_ID_MISSION_ACK:
            outs = p.on_ack(sender, m.type, m.mission_type, now)
        elif mid == mavlink.MAVLINK_MSG_ID_MISSION_CLEAR_ALL:
            outs = p.on_clear_all(sender, m.mission_type, now)
        else:  # MISSION_SET_CURRENT
            outs = p.on_set_current(sender, m.seq, now)
        for out in outs:
            self._send_mission(out)

    def _send_mission(self, out: mission_protocol.Out) -> None:
        if out.kind == "STATUSTEXT":
            self._say(out.fields["severity"], out.fields["text"])
        else:
            self._send_gcs(getattr(mavlink, f"MAVLink_{out.kind.lower()}_message")(**out.kwargs()))
            if out.kind in ("MISSION_ACK", "MISSION_CURRENT"):  # an upload or clear ended; progress
                self.publish_plan()

    def publish_plan(self, again: bool = False) -> None:
        """The mission document on Zenoh (quadsitl.telemetry): when the plan, its current item, its state or
        home changed, or ``again`` (once a second, for subscribers that join late)."""
        if self.plan_pub is None:
            return
        p = self.missions.protocol
        now = (p.version, p.current, p.mission_state, self.commander.home)
        if now == self.plan_published and not again:
            return
        self.plan_published = now
        self.plan_pub.put(telemetry.encode_mission(p.version, p.current, p.mission_state,
                                                   self.missions.plan(self.commander)))  # fmt: skip

    def _for_me(self, system: int, component: int) -> bool:
        return system in (0, self.sysid) and component in (0, self.compid)

    def frame(self) -> setpoints.Frame:
        """Where setpoints are measured from, and the limits they must keep (autopilot.setpoints)."""
        c, st = self.commander, self.commander.settings
        return setpoints.Frame(
            (self.home.lat, self.home.lon, self.home.alt), c.home, float(self.st[8]), st.altitude_max,
            st.max_distance, st.xy_vel_max, st.z_vel_up, st.z_vel_dn,
        )  # fmt: skip

    def _position_target(self, m, pos: tuple[float, float, float]) -> None:
        """SET_POSITION_TARGET_LOCAL_NED or _GLOBAL_INT: refused with a reason, or handed to the commander."""
        try:
            groups = setpoints.position_target(m.coordinate_frame, m.type_mask, pos, (m.vx, m.vy, m.vz),
                                               (m.afx, m.afy, m.afz), m.yaw, m.yaw_rate, self.frame())  # fmt: skip
        except setpoints.SetpointError as exc:
            self._refuse(f"position {exc.kind}", str(exc))
            return
        self.commander.on_position_setpoint(*groups, wall=time.monotonic())

    def _attitude_target(self, m) -> None:
        """SET_ATTITUDE_TARGET: the attitude reference. type_mask 128 (attitude ignored) carries no
        attitude we can fly (no body-rate control here), so it is not a setpoint. The thrust field is
        always ignored: in offboard an altitude reference always exists and the altitude loop makes u1."""
        if m.type_mask & 128:
            self._say_once("rates", "Attitude setpoint ignored: body-rate setpoints (type_mask 128) not supported")
            return
        q = m.q
        n2 = sum(x * x for x in q) if all(map(math.isfinite, q)) else math.nan
        if not abs(n2 - 1.0) < QUATERNION_TOLERANCE:  # False for NaN too
            self._refuse("quat", f"Attitude setpoint refused: |q|^2 = {n2:.3g}, not a unit quaternion")
            return
        n = math.sqrt(n2)
        roll, pitch, yaw = quaternion_to_euler(*(x / n for x in q))
        tilt = self.controller.max_tilt
        if abs(roll) > tilt or abs(pitch) > tilt:
            self._refuse("tilt", f"Attitude setpoint refused: roll {roll:.3f}, pitch {pitch:.3f} rad beyond "
                                 f"ATT_TILT_MAX {tilt:.3f} rad")  # fmt: skip
            return
        self.commander.on_attitude_setpoint(roll, pitch, yaw, wall=time.monotonic())

    # ---- parameters ----------------------------------------------------------------------------

    def _send_param(self, index: int, name: str, value: float) -> None:
        self._send_gcs(
            mavlink.MAVLink_param_value_message(
                name.encode(), value, mavlink.MAV_PARAM_TYPE_REAL32, len(self.params), index
            )
        )

    def _param_set(self, m) -> None:
        name = m.param_id
        reason = self.params.set(name, m.param_value)
        found = self.params.lookup(name)
        if found is None:
            self._say(mavlink.MAV_SEVERITY_WARNING, f"Param set refused: {reason}")
            return
        if reason:
            self.refused += 1
        else:
            self._apply_params()
        self._send_param(*found)  # the value in force: the new one, or the unchanged one when refused
        if reason:
            self._say(mavlink.MAV_SEVERITY_WARNING, f"Param set refused: {reason}")

    def _apply_params(self) -> None:
        """Make the accepted parameter values the ones the next tick uses."""
        applied = self.params.applied()
        self.controller = self.params.build(applied)  # Ωr: the command in self.mem
        self.plug = self.controller.plug or plugin.no_plug()
        self.commander.settings = applied.settings

    # ---- commands ------------------------------------------------------------------------------

    def _command(self, m, link: GcsLink) -> None:
        c = self.commander
        accepted, denied = mavlink.MAV_RESULT_ACCEPTED, mavlink.MAV_RESULT_DENIED
        result, reason, reply = accepted, "", None
        cmd = m.command
        if cmd == mavlink.MAV_CMD_COMPONENT_ARM_DISARM:
            if m.param1 == 1.0:
                reason = "" if c.armed else gcs_messages.arming_check(self.has_state())
                ok, reason = (False, reason) if reason else c.arm()
                result = accepted if ok else denied
                if ok:
                    self._answer_armed()
            elif m.param1 == 0.0:
                latest = self.latest()
                in_air = latest is not None and gcs_messages.in_air(c, latest[1])
                if in_air and as_int(m.param2) != FORCE_DISARM:
                    result, reason = denied, f"Disarming denied: in the air (force with param2 = {FORCE_DISARM})"
                else:
                    c.disarm()
            else:
                result, reason = denied, f"Arm/disarm: param1 {m.param1:g} is neither 0 nor 1"
        elif cmd == mavlink.MAV_CMD_DO_SET_MODE:
            mode = None
            if as_int(m.param1) & mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
                mode = wire.Mode.from_px4(((as_int(m.param2) & 0xFF) << 16) | ((as_int(m.param3) & 0xFF) << 24))
            if mode is None:
                result = mavlink.MAV_RESULT_UNSUPPORTED
                reason = f"Mode main {m.param2:g} sub {m.param3:g}: {SUPPORTED_MODES}"
            else:
                ok, reason = self._set_mode(mode)
                result = accepted if ok else denied
        elif cmd == mavlink.MAV_CMD_MISSION_START:
            first = as_int(m.param1)
            if 0 < first < len(self.missions.protocol.items) and self.missions.executor is not None:
                self.missions.executor.set_current(first)
            ok, reason = self._set_mode(wire.Mode.MISSION)
            result = accepted if ok else denied
        elif cmd == mavlink.MAV_CMD_NAV_LAND:
            ok, reason = c.set_mode(wire.Mode.LAND)
            result = accepted if ok else denied
        elif cmd == mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH:
            ok, reason = c.set_mode(wire.Mode.RTL)
            result = accepted if ok else denied
        elif cmd == mavlink.MAV_CMD_NAV_TAKEOFF:
            result, reason = self._takeoff(m)
        elif cmd == mavlink.MAV_CMD_DO_REPOSITION:
            result, reason = self._reposition(m)
        elif cmd == mavlink.MAV_CMD_DO_CHANGE_SPEED:
            result, reason = self._change_speed(m)
        elif cmd == mavlink.MAV_CMD_DO_SET_MISSION_CURRENT:
            result, outs = self.missions.protocol.do_set_mission_current(as_int(m.param1), as_int(m.param2) == 1)
            if result == mavlink.MAV_RESULT_ACCEPTED and self.missions.executor is not None:
                self.missions.executor.set_current(self.missions.protocol.current)
            for out in outs:
                self._send_mission(out)
        elif cmd == mavlink.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES:
            reply = gcs_messages.autopilot_version(self.sysid)
        elif cmd == mavlink.MAV_CMD_GET_HOME_POSITION:
            reply = self._home_position()
        elif cmd == mavlink.MAV_CMD_REQUEST_MESSAGE:
            result, reason, reply = self._requested(m.param1)
        elif cmd == mavlink.MAV_CMD_SET_MESSAGE_INTERVAL:
            reason = link.streams.set_interval(as_int(m.param1), m.param2) if math.isfinite(m.param2) else "NaN"
            result = denied if reason else accepted
            self.refresh_streams()
        elif cmd == mavlink.MAV_CMD_GET_MESSAGE_INTERVAL:
            mid = as_int(m.param1)
            if link.streams.supported(mid):
                reply = mavlink.MAVLink_message_interval_message(mid, link.streams.interval_us(mid))
            else:
                result, reason = denied, f"Message interval: message id {m.param1:g} is not streamed"
        else:
            result = mavlink.MAV_RESULT_UNSUPPORTED
        self._send_gcs(mavlink.MAVLink_command_ack_message(cmd, result, 0, 0, m.get_srcSystem(), m.get_srcComponent()))
        if reply is not None:
            self._send_gcs(reply)
        if reason:  # the same reason at most once a second: a flood of bad commands is not a flood of texts
            self._say_once(reason, reason, every=1.0)

    @staticmethod
    def _location(m) -> tuple[float, float, float, int]:
        """A command's (latitude, longitude [deg], altitude [m], frame): COMMAND_INT's x, y (1e7 deg; INT32_MAX:
        none) and z, or COMMAND_LONG's params 5–7 (a global frame, AMSL). NaN where not given."""
        if m.get_msgId() == mavlink.MAVLINK_MSG_ID_COMMAND_INT:
            lat = math.nan if m.x == setpoints.INT32_MAX else m.x * 1e-7
            lon = math.nan if m.y == setpoints.INT32_MAX else m.y * 1e-7
            return lat, lon, m.z, m.frame
        return m.param5, m.param6, m.param7, setpoints.GLOBAL

    def _takeoff(self, m) -> tuple[int, str]:
        """MAV_CMD_NAV_TAKEOFF: param7 (COMMAND_INT: z) the altitude AMSL, NaN: MIS_TAKEOFF_ALT above here."""
        _, _, alt, frame = self._location(m)
        altitude = None
        if math.isfinite(alt):
            altitude = setpoints.altitude_of(frame, alt, self.frame())
        elif not math.isnan(alt):
            return mavlink.MAV_RESULT_DENIED, f"Takeoff: altitude {alt:g}; expected a finite number or NaN"
        ok, reason = self.commander.takeoff(altitude)
        return (mavlink.MAV_RESULT_ACCEPTED if ok else mavlink.MAV_RESULT_DENIED), reason

    def _reposition(self, m) -> tuple[int, str]:
        """MAV_CMD_DO_REPOSITION (MAVSDK's goto_location): p1 speed [m/s] (≤ 0 or NaN: MPC_XY_CRUISE), p2 bit 0
        switch to hold, p4 yaw [rad], then the location; NaN keeps a value, all NaN stops here."""
        lat, lon, alt, frame = self._location(m)
        try:
            x, y, altitude = setpoints.reposition(lat, lon, alt, frame, self.frame())
        except setpoints.SetpointError as exc:
            self.refused += 1
            return mavlink.MAV_RESULT_DENIED, str(exc)
        yaw = m.param4
        if math.isinf(yaw):
            return mavlink.MAV_RESULT_DENIED, f"Reposition: yaw {yaw:g}; expected radians or NaN (keep)"
        speed, top = m.param1, self.commander.settings.xy_vel_max
        if math.isfinite(speed) and speed > top:
            return (
                mavlink.MAV_RESULT_DENIED,
                f"Reposition: speed {speed:g} m/s; allowed: up to {top:g} m/s (MPC_XY_VEL_MAX)",
            )
        hold = as_int(m.param2) > 0 and as_int(m.param2) & 1
        if all(math.isnan(v) for v in (lat, lon, alt, yaw)):  # stop here
            x, y, altitude = self.commander.position_target_here()
        ok, reason = self.commander.reposition(x, y, altitude, yaw, speed, bool(hold))
        return (mavlink.MAV_RESULT_ACCEPTED if ok else mavlink.MAV_RESULT_DENIED), reason

    def _change_speed(self, m) -> tuple[int, str]:
        """MAV_CMD_DO_CHANGE_SPEED: p1 speed type (0 air, 1 ground: the horizontal speed), p2 speed [m/s] (−1 or
        −2: no change / default)."""
        kind, speed = as_int(m.param1), m.param2
        if kind not in (0, 1):
            return mavlink.MAV_RESULT_UNSUPPORTED, f"Change speed: speed type {m.param1:g}; supported: 0, 1"
        if speed in (-1.0, -2.0):
            speed = self.params.values["MPC_XY_CRUISE"] if speed == -2.0 else math.nan
        if math.isnan(speed):
            return mavlink.MAV_RESULT_ACCEPTED, ""
        top = self.commander.settings.xy_vel_max
        if not (math.isfinite(speed) and 0.0 < speed <= top):
            return mavlink.MAV_RESULT_DENIED, f"Change speed: {speed:g} m/s; allowed: (0, {top:g}] m/s"
        self.commander.change_speed(speed)
        return mavlink.MAV_RESULT_ACCEPTED, ""

    def _requested(self, msg_id: float) -> tuple[int, str, object]:
        """MAV_CMD_REQUEST_MESSAGE: (result, reason, the message to send)."""
        mid = as_int(msg_id)
        if mid == mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION:
            return mavlink.MAV_RESULT_ACCEPTED, "", gcs_messages.autopilot_version(self.sysid)
        if mid == mavlink.MAVLINK_MSG_ID_HOME_POSITION:
            return mavlink.MAV_RESULT_ACCEPTED, "", self._home_position()
        if mid == mavlink.MAVLINK_MSG_ID_HEARTBEAT:
            return mavlink.MAV_RESULT_ACCEPTED, "", gcs_messages.heartbeat(self.commander)
        if self.streams.supported(mid):
            snap = self._snapshot()
            if snap is None:
                return mavlink.MAV_RESULT_TEMPORARILY_REJECTED, "", None
            return mavlink.MAV_RESULT_ACCEPTED, "", gcs_messages.build(mid, snap, self.commander, self.home)
        return mavlink.MAV_RESULT_UNSUPPORTED, "", None

    # ---- the loop ------------------------------------------------------------------------------

    def run(self) -> None:
        """The plant socket drives the loop (a blocking receive, so a tick waits on nothing else); the
        ground-station sockets are read every ``GCS_POLL`` seconds of wall time (by the compiled loop: when a
        datagram waits on them), the wall-clock work runs every ``HOUSEKEEPING``, and both whenever the plant is
        quiet."""
        set_receive_timeout(self.plant_sock, 0.02)
        for link in self.links:
            link.sock.setblocking(False)
        next_chores = 0.0
        receive = self.plant_wait
        while True:
            if self.pending is not None:
                self.wait_for_setpoint()
                continue
            status = -1
            if self.plant_address is not None and not self.plant_lost and not self.missions.flying:
                status = self.serve_plant(next_chores)  # the plant's ticks in compiled code, until Python's turn
            else:
                try:
                    nbytes, sender = receive()
                except (BlockingIOError, InterruptedError):
                    nbytes = -1
                if nbytes >= 0:
                    self.on_plant_datagram(nbytes, sender)
            wall = time.monotonic()
            if self.plant_peer is not None and not self.plant_lost and wall - self.plant_heard > PLANT_LOST_AFTER:
                self.plant_lost = True
                self.commander.plant_lost()
                self._announce_commander()
            if self.io[kernel.ROWS] and wall - self.last_flush >= BATCH_WALL:
                self.flush_telemetry()
            if wall >= self.next_poll or status == plant_loop.GROUND:
                self.next_poll = wall + GCS_POLL
                self.poll_gcs()
            if wall >= next_chores:
                next_chores = wall + HOUSEKEEPING
                if self.io[kernel.ROWS]:
                    self.flush_telemetry()  # a little early, so that the next batch is due with the next chores
                if self.slow is not None:  # the newest records, turned away by the overview's period: owed
                    self.slow.catch_up(self.last_records.get, wall)
                self.commander.wall_clock(wall)
                for out in self.missions.protocol.tick(wall):  # re-requests and timeouts of mission transfers
                    self._send_mission(out)
                timeout = self.commander.settings.datalink_timeout
                if self.gcs_heard is not None and not self.gcs_lost and wall - self.gcs_heard > timeout:
                    self.gcs_lost = True
                    self.commander.datalink_lost(timeout)
                    self._announce_commander()
                if wall - self.last_heartbeat >= 1.0:
                    self.last_heartbeat = wall
                    self.heartbeat()
                    if any([link.forget_silent(wall) for link in self.links]):
                        self.refresh_streams()

    def _offboard(self) -> bool:
        """Flying offboard: armed in offboard mode, from the flight's first tick on (the compiled update sets it)."""
        c = self.commander
        return c.armed and c.mode == wire.Mode.OFFBOARD and c.offboard_tick >= 0

    def wait_for_setpoint(self) -> None:
        """``--offboard-lockstep``: the answer to the plant's tick waits (and with it the simulated clock) until
        an offboard setpoint made for a recent enough moment arrives, or HOLD_MAX of wall time has passed
        (:mod:`autopilot.offboard_lockstep`). The ground station sees the tick the clock waits at at once; the
        plant's re-sends of the tick wait in the socket (answered afterwards as any repeat is)."""
        if self.io[kernel.ROWS]:
            self.flush_telemetry()
        select.select([link.sock for link in self.links], [], [], GCS_POLL)
        wall = time.monotonic()
        self.poll_gcs()
        self.commander.wall_clock(wall)
        self.plant_heard = wall  # the plant waits for this answer: it is not lost
        if self.pending is not None and not self.pace.must_wait(int(self.io[kernel.TICK]), self._offboard(), wall):
            buf, sender = self.pending
            self.pending = None
            self.plant_sock.sendto(buf, sender)

    def _gcs_link(self, old: mavlink.MAVLink | None = None) -> mavlink.MAVLink:
        """A fresh ground-link parser/packer; with a key, signed (and keeping the old one's signing
        state, so replay protection and the refusal count survive a reset)."""
        mav = wire.link(self.sysid, self.compid)
        if self.signing_key is not None:
            wire.enable_signing(mav, self.signing_key)
            if old is not None:
                mav.signing = old.signing
        return mav

    def poll_gcs(self) -> None:
        """What waits on the ground-station sockets, up to GCS_BUDGET seconds of work per call: a flood of
        datagrams (hostile or not) waits in the socket buffers, or overflows it, while the plant link is
        serviced between polls; it never starves the control loop."""
        deadline = time.perf_counter() + GCS_BUDGET
        for link in self.links:
            while time.perf_counter() < deadline:
                try:
                    data, sender = link.sock.recvfrom(65535)
                except (BlockingIOError, InterruptedError):
                    break
                except OSError:
                    break  # e.g. an ICMP error reported on the socket: nothing to read
                refused_before = wire.signing_refusals(self.gcs_mav)
                try:
                    msgs = self.gcs_mav.parse_buffer(data) or []
                except Exception:  # pymavlink raises MAVError, and others on hostile bytes: never crash
                    self.errors_comm += 1
                    self.gcs_mav = self._gcs_link(self.gcs_mav)  # a parser in an unknown state: start over
                    continue
                if wire.signing_refusals(self.gcs_mav) > refused_before:
                    self._say_once("signing", f"Unsigned or badly signed message refused from {sender[0]} "
                                              f"({wire.signing_refusals(self.gcs_mav)} so far)")  # fmt: skip
                for m in msgs:
                    if m.get_type() == "BAD_DATA":
                        self.errors_comm += 1
                        continue
                    try:
                        self.on_gcs(m, link, sender)
                    except Exception as exc:  # a bug must not take the vehicle down: report it, fly on
                        print(f"{self.label}: error: handling {m.get_type()} from {sender}: {exc!r}", file=sys.stderr)

    def close(self) -> None:
        if self.pace is not None and self.pace.waits and (self.pace.gave_up_count or not self.quiet):
            p = self.pace
            print(f"{self.label}: --offboard-lockstep: the clock waited for a setpoint {p.waits} times, "
                  f"{p.waited:.3f} s of wall time in all ({p.gave_up_count} ran out of {p.hold_max:g} s)",
                  file=sys.stderr)  # fmt: skip
        if self.pubs:
            self.flush_telemetry()
        if self.slow is not None and self.slow.owed:  # the overview ends on the last record
            self.slow.offer(self.last_records.get, time.monotonic(), force=True)
        slow = list(self.slow.pubs.values()) if self.slow else []
        for pub in (*self.pubs.values(), *slow, *([self.plan_pub] if self.plan_pub else [])):
            pub.undeclare()
        if self.session is not None:
            self.session.close()
        self.plant_sock.close()
        for link in self.links:
            link.sock.close()


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="quadsitl autopilot",
        description="The autopilot: discrete backstepping (or PD) control loop, MAVLink to the plant and to "
        "ground stations (PX4 SITL's ports and conventions), telemetry to Zenoh.",
        epilog="examples:\n  quadsitl autopilot --preset paper\n"
        "  quadsitl autopilot --preset x500 --controller pd --zenoh-listen tcp/127.0.0.1:7447\n"
        "  quadsitl autopilot --gcs-remote none --api-listen 127.0.0.1:24580 --api-remote none",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_preset_arguments(p)
    add_state_arguments(p)
    p.add_argument(
        "--plant-listen",
        default="127.0.0.1:14560",
        metavar="HOST:PORT",
        help="UDP address for the plant link (default: 127.0.0.1:14560)",
    )
    for name, listen, remote, who in (
        ("gcs", 18570, 14550, "ground stations: QGroundControl, MAVProxy"),
        ("api", 14580, 14540, "offboard APIs: MAVSDK, scripts"),
    ):
        p.add_argument(
            f"--{name}-listen",
            default=f"127.0.0.1:{listen}",
            metavar="HOST:PORT",
            help=f"local UDP address of the {name} link, for {who} (default: 127.0.0.1:{listen})",
        )
        p.add_argument(
            f"--{name}-remote",
            default=f"127.0.0.1:{remote}",
            metavar="HOST:PORT|none",
            help=f"where the {name} link streams even before anyone talks to it (default: 127.0.0.1:{remote})",
        )
    p.add_argument("--system-id", type=int, default=1, help="MAVLink system id (default: 1)")
    p.add_argument(
        "--home",
        metavar="LAT,LON,ALT",
        help="home position: degrees, degrees, metres AMSL (default: PX4 SITL's, 47.397742,8.545594,488)",
    )
    p.add_argument(
        "--telemetry-rate",
        type=float,
        default=50.0,
        metavar="HZ",
        help="ATTITUDE, ATTITUDE_QUATERNION, LOCAL_POSITION_NED, ATTITUDE_TARGET rate in simulated time "
        "(default: 50; MAV_CMD_SET_MESSAGE_INTERVAL changes any stream)",
    )
    p.add_argument(
        "--setpoint-timeout",
        type=float,
        default=1.0,
        metavar="S",
        help="offboard setpoint loss failsafe, simulated seconds (default: 1; parameter COM_OF_LOSS_T)",
    )
    p.add_argument(
        "--offboard-lockstep",
        type=float,
        metavar="S",
        help="lockstep, for a ground station that stamps its offboard setpoints' time_boot_ms with this vehicle's "
        "clock (quadsitl fly's): answer no plant tick more than S simulated seconds after the moment the newest "
        "setpoint was made for, waiting at most 0.25 s of wall time per setpoint, so a ground station that falls "
        "behind a sped-up run holds its clock (default: off, as PX4)",
    )
    p.add_argument(
        "--signing-key",
        metavar="HEX|FILE",
        help="MAVLink 2 signing on the ground-station links: 64 hex digits or a file holding them; unsigned, "
        f"wrongly signed and replayed messages are refused (default: ${wire.SIGNING_ENV}, else no signing). "
        "A file or the environment keeps the key out of the process list",
    )
    telemetry.add_zenoh_arguments(p)
    p.add_argument("--no-zenoh", action="store_true", help="do not publish telemetry to Zenoh")
    p.add_argument(
        "--quiet",
        "-q",
        action="store_true",
        help="no note on exit of how often the --offboard-lockstep clock waited, unless a wait ran out",
    )
    p.add_argument(
        "--telemetry-congestion",
        choices=tuple(CONGESTION),
        default="drop",
        help="when a telemetry subscriber's link is full: drop the record (default: the vehicle never waits for a "
        "subscriber), or block until there is room, so that every subscriber gets every tick (a lockstep run whose "
        "logger must have them all, as quadsitl fly's; a subscriber that falls behind then holds the clock)",
    )
    return p


def warm_up_loops() -> None:
    """Compile into numba's cache (or load from it) the autopilot's compiled plant loop for both of its modes, whose
    arguments' types differ (truth and sensors), with what an autopilot process makes on the way (its controllers'
    own steps): for a launcher to do once before it starts a fleet, whose autopilots then load it instead of each
    compiling it at once. Call :func:`autopilot.tick.warm_up` first: the loop calls the tick, which it then loads."""
    for state in ("truth", "sensors"):
        args = build_parser().parse_args(["--no-zenoh", "--plant-listen", "127.0.0.1:0", "--gcs-listen", "127.0.0.1:0",
                                          "--api-listen", "127.0.0.1:0", "--state", state])  # fmt: skip
        args.home, args.signing_key = None, None
        ap = Autopilot(with_state(load_preset("x500"), args), args)
        try:
            plant_loop.warm_up(ap.tick_arguments())
        finally:
            ap.close()


def main(argv: Sequence[str] | None = None) -> int:
    start_process()
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        preset = with_state(load_preset(args.preset), args)
        check_range("--telemetry-rate", args.telemetry_rate, 0.0, 1.0 / preset.sim.period)
        check_range("--setpoint-timeout", args.setpoint_timeout, 0.0, 3600.0)
        # 0: a ground station that sends its setpoints ahead (quadsitl gcs --setpoints-ahead); NaN is refused too
        if args.offboard_lockstep is not None and not 0.0 <= args.offboard_lockstep <= 60.0:
            raise UsageError(f"--offboard-lockstep {args.offboard_lockstep!r}: expected a number in [0, 60]")
        check_system_id(args.system_id)
        args.home = parse_home(args.home)
        args.signing_key = wire.resolve_signing_key(args.signing_key)
        warm_up()  # compiled before the first tick (numba's cache makes this quick after the first run)
        ap = Autopilot(preset, args)
        if ap.fast:
            plant_loop.warm_up(ap.tick_arguments())
    except (UsageError, ConfigError, GainError, plugin.ControllerError) as exc:
        print(f"{parser.prog}: error: {exc}", file=sys.stderr)
        return 2
    except zenoh.ZError as exc:
        print(f"{parser.prog}: error: cannot open the Zenoh session (--zenoh-listen / --zenoh-connect / "
              f"--zenoh-config): {exc}", file=sys.stderr)  # fmt: skip
        return 2
    try:
        ap.run()
    except KeyboardInterrupt:
        pass
    finally:
        ap.close()
    return 0
