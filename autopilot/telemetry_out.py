"""Telemetry out of the autopilot: the ground links' MAVLink streams (:class:`Streams`: the per-tick messages the
compiled tick builds, and the rest built here) and the Zenoh records (:class:`ZenohOut`: each tick's state,
reference, actuators and status in batches, the overview's slow copies, the mission plan for maps).

Zenoh publishing drops rather than blocks by default, so the loop never waits on a subscriber;
``--telemetry-congestion block`` (``quadsitl fly`` and formation flights) makes a full link hold the lockstep clock
instead, so that no tick is lost to the logger.
"""

from __future__ import annotations

import socket
import time
from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np
import zenoh

from autopilot import gcs_messages, plant_loop
from autopilot import tick as kernel
from autopilot.commander import Commander
from autopilot.gcs_messages import Home, Snapshot
from autopilot.ground_link import GroundLinks
from autopilot.missions import Missions
from autopilot.stream_frames import COMPILED as COMPILED_STREAMS
from autopilot.stream_frames import StreamFrames
from autopilot.tick import Batch
from quadsitl import fastio, telemetry, zenoh_shm

if TYPE_CHECKING:
    from zenoh.shm import ShmProvider

# [s] wall: Zenoh telemetry goes out at least this often (every 20 ticks at 1 kHz real time, more samples than a
# dashboard draws); each batch wakes Zenoh's threads on the cores a lockstep pair needs
# (docs/performance.md#telemetry-batches).
BATCH_WALL = 0.020
# A run faster than twice real time (more than FAST_ROWS ticks in BATCH_WALL) batches FAST_BATCH_WALL instead: each
# batch costs every subscriber a wake-up and its callbacks, and its host a put per stream, whatever it holds
# (docs/performance.md#fan-out, #a-hosted-fleet-in-lockstep).
FAST_ROWS = 40
FAST_BATCH_WALL = 0.100
# And at the latest after this many ticks: each batch is a trip out of the compiled loop here and a few samples the
# ground station's Python takes, so fewer, larger batches make a lockstep run faster
# (docs/performance.md#telemetry-batches).
BATCH_TICKS = 4096  # [ticks] resident in a fleet's vehicle once filled (docs/performance.md#fan-out)
# --telemetry-congestion: what a full-rate telemetry put does when a subscriber's link has no room (Zenoh's congestion
# control; DROP waits 1 ms for room first). The overview's slow copies always drop: they are a view, not a record.
CONGESTION = {"drop": zenoh.CongestionControl.DROP, "block": zenoh.CongestionControl.BLOCK}
NO_STREAMS = 2**40  # [ticks] how far off the next telemetry message is when no link has a destination


class Streams:
    """Each ground link's MAVLink telemetry: which per-tick messages the compiled tick builds for which link (those
    with somewhere to send; none on a signed link, whose frames pymavlink signs), where the compiled loop sends them
    (``destinations``, IPv4 only), and the messages built here when they are due (``snapshot()``: the last tick)."""

    def __init__(self, ground: GroundLinks, frames: StreamFrames, io: np.ndarray, fast: bool, compiled: bool,
                 snapshot: Callable[[], Snapshot | None], commander: Commander, home: Home) -> None:  # fmt: skip
        self.ground, self.frames, self.io, self.fast, self.compiled = ground, frames, io, fast, compiled
        self.snapshot, self.commander, self.home = snapshot, commander, home
        self.destinations = plant_loop.Destinations()

    def refresh(self) -> None:
        """After a change of the links' destinations or message intervals: which per-tick messages the compiled
        tick builds for each link, where the compiled loop sends them, and when the next messages built here are
        due."""
        entries: list | None = []
        for i, link in enumerate(self.ground):
            live = link.remote is not None or bool(link.peers)
            for slot, mid in enumerate(COMPILED_STREAMS):
                interval, phase = link.streams.schedule(mid)
                self.frames.sched[i, slot] = (interval if live and self.compiled else 0), phase
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

    def send_frames(self) -> None:
        """The per-tick messages the tick built (kernel.FRAMES), sent from Python: each link's to its destinations."""
        dropped = False
        for i, link in enumerate(self.ground):
            if self.frames.lens[i]:
                dropped |= not link.send(self.frames.datagram(i))
        if dropped:
            self.refresh()

    def resend_failed(self) -> None:
        """The per-tick messages the compiled loop could not send: sent from Python (said and dropped as any failed
        send)."""
        for i, peer in self.destinations.failed():
            self.ground[i].send(self.frames.datagram(i), to=[peer])
        self.refresh()

    def due(self, tick: int) -> None:
        """The messages due at ``tick`` on each link that the compiled tick does not build: one datagram per link."""
        snap, built = None, {}
        skip = COMPILED_STREAMS if self.compiled else ()
        for link in self.ground:
            if link.remote is None and not link.peers:
                continue
            frames = []
            for mid in link.streams.due(tick, skip):
                if mid not in built:
                    snap = snap or self.snapshot()
                    msg = gcs_messages.build(mid, snap, self.commander, self.home)  # None: not now (an orbit's)
                    built[mid] = b"" if msg is None else self.ground.pack(msg)
                frames.append(built[mid])
            if frames and not link.send(b"".join(frames)):  # one datagram per link and tick, as PX4 fills its buffer
                self.refresh()
        # Only links with somewhere to send count (a link nobody listens on would call Python every few ticks for
        # nothing); a new peer starts the streams again.
        self.io[kernel.NEXT_STREAM_TICK] = min(
            (link.streams.next_due(tick, skip) for link in self.ground if link.remote is not None or link.peers),
            default=tick + NO_STREAMS,
        )


class ZenohOut:
    """The vehicle's Zenoh publishers (:mod:`quadsitl.telemetry`): the per-tick records, batched by the compiled tick
    in ``batch`` (io[ROWS] rows), the overview's slow copies, and the mission document. ``session`` None: nothing is
    published (``--no-zenoh``), and the tick batches nothing."""

    def __init__(self, session: zenoh.Session | None, vehicle: str, sensing: bool, congestion: str,
                 io: np.ndarray, pool: ShmProvider | None = None) -> None:  # fmt: skip
        self.session, self.io, self.pool = session, io, pool  # pool: batches through shared memory (zenoh_shm)
        self.pubs: dict[str, zenoh.Publisher] = {}
        self.slow: telemetry.Overview | None = None  # the overview (quadsitl/<vehicle>/slow/overview)
        self.plan_pub: zenoh.Publisher | None = None  # quadsitl/<vehicle>/mission: the plan, for maps
        self.plan_published: tuple = ()  # what the last mission document said (version, current, state, home)
        self.batch = Batch(BATCH_TICKS)
        self.last_records: dict[str, bytes] = {}  # each stream's last record published
        self.last_flush = 0.0
        self.tick_seen = -1  # the tick when idle() last looked
        self.readers: list[Callable[[Batch, int], None]] = []  # the batch's other readers (the onboard log)
        if session is None:
            return
        for stream in (*telemetry.STREAMS, *(telemetry.SENSING if sensing else ())):
            self.pubs[stream] = session.declare_publisher(telemetry.key(vehicle, stream),
                                                          encoding=telemetry.encoding(stream),
                                                          congestion_control=CONGESTION[congestion])  # fmt: skip
        io[kernel.CAPACITY] = BATCH_TICKS  # records are batched only while there is a session
        self.slow = telemetry.Overview(session, vehicle)
        self.plan_pub = session.declare_publisher(telemetry.key(vehicle, telemetry.MISSION),
                                                  encoding=telemetry.mission_encoding(),
                                                  congestion_control=CONGESTION[congestion])  # fmt: skip

    def also(self, reader: Callable[[Batch, int], None]) -> None:
        """``reader(batch, rows)`` reads every batch too, before it is emptied: records are batched from now on."""
        self.readers.append(reader)
        self.io[kernel.CAPACITY] = BATCH_TICKS

    @staticmethod
    def open(args) -> tuple[zenoh.Session, ShmProvider | None]:
        """The Zenoh session of the command line's options; samples carry their publication time (subscribers can
        measure latency); with shared memory on, the process's pool for the batches (:mod:`quadsitl.zenoh_shm`)."""
        conf = telemetry.config_from_args(args, shared_memory=True)
        shared = zenoh_shm.enabled(conf)
        if not args.zenoh_config:
            conf.insert_json5("timestamping/enabled", "true")
            # Room for Zenoh's most batches (its default is 2) before a put drops: its sending thread shares the
            # cores with a lockstep pair that polls, and may wait a few ms for one.
            conf.insert_json5("transport/link/tx/queue/size/data", "16")
        return zenoh.open(conf), zenoh_shm.pool() if shared else None

    def flush(self) -> None:
        """Publish the batched records (every stream gets the same ticks)."""
        rows = int(self.io[kernel.ROWS])
        if rows:
            for stream, pub in self.pubs.items():
                payload = self.batch.payload(stream, rows)
                zenoh_shm.put(pub, payload, self.pool)
                self.last_records[stream] = payload[-self.batch.regions[stream][1] :]
            for reader in self.readers:
                reader(self.batch, rows)
            self.io[kernel.ROWS] = 0
        self.last_flush = time.monotonic()
        if rows and self.slow is not None:
            self.slow.offer(self.last_records.get, self.last_flush)

    def period(self) -> float:
        """The batch's wall period [s]: BATCH_WALL, FAST_BATCH_WALL once it holds more than FAST_ROWS rows."""
        return FAST_BATCH_WALL if self.io[kernel.ROWS] > FAST_ROWS else BATCH_WALL

    def due(self, wall: float, early: float = 0.0) -> bool:
        """Rows are batched and their period has passed since the last flush, or will have in ``early`` [s]."""
        return bool(self.io[kernel.ROWS]) and wall + early - self.last_flush >= self.period()

    def idle(self) -> bool:
        """Rows are batched and no tick came since the last time this was asked (the chores ask it every
        HOUSEKEEPING): the run paused or ended, and its last ticks go out now, not a fast run's period later."""
        tick, seen = int(self.io[kernel.TICK]), self.tick_seen
        self.tick_seen = tick
        return bool(self.io[kernel.ROWS]) and tick == seen

    def deadline(self, otherwise: float) -> float:
        """When the batched rows are due [s wall]: ``otherwise`` when there are none."""
        return min(otherwise, self.last_flush + self.period() if self.io[kernel.ROWS] else otherwise)

    def catch_up(self, wall: float) -> None:
        """The overview's records owed since its period turned them away."""
        if self.slow is not None:
            self.slow.catch_up(self.last_records.get, wall)

    def again(self) -> None:
        """The last tick's records again (no new ticks: a subscriber that joined since sees the vehicle; the same
        tick again, which a join by tick keeps once)."""
        for stream, record in self.last_records.items():
            self.pubs[stream].put(record)
        if self.slow is not None:
            self.slow.offer(self.last_records.get, time.monotonic())

    def publish_plan(self, missions: Missions, commander: Commander, again: bool = False) -> None:
        """The mission document: when the plan, its current item, its state or home changed, or ``again`` (once a
        second, for subscribers that join late)."""
        if self.plan_pub is None:
            return
        p = missions.protocol
        now = (p.version, p.current, p.mission_state, commander.home, len(missions.reached), p.fence_version,
               p.rally_version)  # fmt: skip
        if now == self.plan_published and not again:
            return
        self.plan_published = now
        self.plan_pub.put(telemetry.encode_mission(p.version, p.current, p.mission_state, missions.plan(commander),
                                                   missions.reached, missions.fence_doc(),
                                                   missions.rally_doc()))  # fmt: skip

    def close(self) -> None:
        if self.pubs or self.readers:
            self.flush()
        if self.slow is not None and self.slow.owed:  # the overview ends on the last record
            self.slow.offer(self.last_records.get, time.monotonic(), force=True)
        slow = [self.slow.pub] if self.slow else []
        for pub in (*self.pubs.values(), *slow, *([self.plan_pub] if self.plan_pub else [])):
            pub.undeclare()
        if self.session is not None:
            self.session.close()
