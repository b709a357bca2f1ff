"""The plant process (``quadsitl plant``, ``python -m sitl``): owns the truth state and integrates it.

One MAVLink 2 UDP link to the autopilot (see :mod:`quadsitl.wire`). Each tick's datagram is the state as
ODOMETRY (``--state truth``), or in sensor mode (``--state sensors``, the default when the preset has a [sensors]
section) what the vehicle's sensors measure of it: HIL_SENSOR, HIL_GPS when a fix is delivered, and the ground
truth as HIL_STATE_QUATERNION (:mod:`quadsitl.hil`), the GPS's latitude and longitude from ``--home``.

- ``lockstep`` (default): the plant is the clock. For tick k it sends the state stamped with the
  simulated time, waits for the HIL_ACTUATOR_CONTROLS answering tick k, then integrates one period.
  Until an answer comes (at start, or if the autopilot goes away) it free-wheels: it re-sends the
  state every 50 ms without advancing time. ``--speed F`` caps the pace at F × real time (0 = as fast
  as possible): a late tick is made up, but time lost to a stall longer than PACE_SLACK (or to holding) is not
  caught up in a burst.
- ``realtime``: integrates on the wall clock at period T and applies the latest actuator command it has.

In both, actuator messages older than the last one used (by ``time_usec``) are discarded.

Divergence: the state x(k) is checked at the start of every tick k, before it goes out (the autopilot's
controller never sees it), with the check of the sweeps' batch engine and ``quadsitl sim``
(:func:`sitl.plant.inside`, its default bounds). A state that is not finite or out of its bounds ends the run:
it is not sent; the plant says one line on stderr naming the quantity, its value and the bound, tells the
autopilot in a STATUSTEXT (severity CRITICAL, which the autopilot relays to its ground stations), and exits with
status :data:`~quadsitl.process_util.PLANT_DIVERGED` (3).

Wind: the preset's [wind] and the wind options; given a Zenoh endpoint or configuration (``quadsitl up`` gives
its own), the plant also takes wind changes on ``quadsitl/<vehicle>/wind`` (:mod:`sitl.wind_link`).
"""

from __future__ import annotations

import argparse
import contextlib
import copy
import heapq
import json
import math
import socket
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from quadsitl import codec, fastio, hil, wire
from quadsitl.cli_util import (
    UsageError,
    add_preset_arguments,
    add_state_arguments,
    add_wind_arguments,
    check_speed,
    parse_home,
    parse_vehicle_presets,
    per_vehicle,
    with_state,
    with_wind,
)
from quadsitl.config import ConfigError, Preset, load_preset
from quadsitl.frames import PX4_HOME
from quadsitl.process_util import (
    CORES_AWAKE_HELP,
    HOT_AFTER,
    PATIENCE,
    PLANT_DIVERGED,
    SpinThenBlock,
    bind_udp,
    clock_above_its_peers,
    hold_cores_awake,
    parse_address,
    readable_of,
    set_receive_timeout,
    start_process,
    timers_on_time,
    wait_readable,
)
from quadsitl.telemetry import add_zenoh_arguments, config_from_args
from quadsitl.timing import late_periods, period_stats
from sitl import lockstep_loop, realtime_loop, tick
from sitl.fleet_arrays import FleetArrays
from sitl.impair import Impairment, add_impair_argument, impairment_from
from sitl.plant import Plant, outside_what, state_inside
from sitl.realtime_fleet import RealtimeFleet
from sitl.wind_link import WindLink

HIL_ACTUATOR_CONTROLS = wire.mavlink.MAVLINK_MSG_ID_HIL_ACTUATOR_CONTROLS
FREEWHEEL_PERIOD = 0.05  # [s] state re-send pace while no answer comes
# [s] wall: a paced lockstep plant this far behind its pace (a stall of the machine) resumes the pace from where it
# is instead of running the lost ticks back to back; a shorter lateness (a late wake-up) is made up, so the pace holds
PACE_SLACK = 0.02
LOOP_RETURN_NS = 1_000_000  # [ns] wall: the compiled clock comes back to Python at least this often (signals, wind)
AUTOPILOT_LOST_AFTER = 0.5  # [s] wall without an actuator message: the autopilot is lost
LOST_AFTER_NS = round(AUTOPILOT_LOST_AFTER * 1e9)


class PlantLink:
    """The plant's end of the UDP link: send states, receive actuator commands. The two per-tick messages
    are encoded and decoded in place by the compiled codec (:mod:`quadsitl.codec`, :mod:`sitl.tick`)."""

    def __init__(
        self,
        sock: socket.socket,
        autopilot: tuple[str, int],
        max_thrust: float,
        period: float,
        impairment: Impairment | None = None,
        sensing: bool = False,
        name: str = "",
    ):
        self.sock = sock  # bound (process_util.bind_udp)
        self.who = f"{name}'s autopilot" if name else "autopilot"  # in messages (a fleet's name the vehicle)
        self.rx = bytearray(65535)
        self.rx_array = np.frombuffer(self.rx, dtype=np.uint8)
        self.tx = np.zeros(max(codec.FRAME_MAX, hil.DATAGRAM_MAX), dtype=np.uint8)
        self.tx_view = memoryview(self.tx)  # type: ignore[arg-type]
        self.io = np.zeros(tick.IO_SIZE, dtype=np.int64)  # sequence, frame length, last stamp used, refusals
        self.io[tick.LAST_USEC] = -1
        self.io[tick.SYSTEM], self.io[tick.COMPONENT] = wire.PLANT_SYSTEM_ID, wire.PLANT_COMPONENT_ID
        self.io[tick.SENSING] = sensing
        self.io[tick.HOLD_TICK] = -1  # lockstep: the tick at which the clock holds until the autopilot arms
        self.received = np.zeros(4)  # the commanded forces [N] of the last actuator message decoded
        self.wait = SpinThenBlock(sock.recv_into, self.rx)  # lockstep's receive: polls while the autopilot answers fast
        self.sock.connect(autopilot)  # the kernel drops datagrams from anyone but the autopilot
        self.mav = wire.link(wire.PLANT_SYSTEM_ID, wire.PLANT_COMPONENT_ID)
        self.max_thrust = max_thrust
        self.period = period
        self.timeout = -1.0
        # answered and late periods, when the autopilot was first and last heard, whether it is lost: one account
        # for the Python loops and the compiled real-time one (sitl.realtime_loop)
        self.rt = np.zeros(realtime_loop.RT_SIZE, dtype=np.int64)
        self.impairment = impairment  # real-time runs only: both directions go through its queues
        self.outbox: list[tuple[float, int, bytes]] = []  # (release time, order, datagram), a heap
        self.inbox: list[tuple[float, int, bytes]] = []
        self.order = 0

    @property
    def last_heard(self) -> float | None:
        """When the autopilot was last heard [s, time.monotonic] (None: not yet)."""
        ns = self.rt[realtime_loop.LAST_NS]
        return None if ns == 0 else ns * 1e-9

    @last_heard.setter
    def last_heard(self, wall: float) -> None:
        self.rt[realtime_loop.LAST_NS] = round(wall * 1e9)

    @property
    def first_heard(self) -> float | None:
        """... and first: the run's pace counts from its first answer."""
        ns = self.rt[realtime_loop.FIRST_NS]
        return None if ns == 0 else ns * 1e-9

    @property
    def lost(self) -> bool:
        """Whether the autopilot is lost: silent for longer than AUTOPILOT_LOST_AFTER."""
        return bool(self.rt[realtime_loop.LOST])

    @property
    def discarded(self) -> int:
        """Actuator messages discarded: stale, duplicates, or (lockstep) from the future."""
        return int(self.io[tick.DISCARDED])

    @property
    def corrupt(self) -> int:
        """Datagrams refused: corrupt frames, non-finite forces."""
        return int(self.io[tick.CORRUPT])

    def encode(self, k: int, plant: Plant) -> None:
        """Tick ``k``'s datagram (the state, or its measurements), into tx."""
        tick.encode_tick(self.tx, self.io, plant.x, plant.out, plant.air, plant.sensors.arrays, k, self.period)

    def send(self, frame: bytes | None = None) -> None:
        """Send the state frame in tx (or ``frame``, one sent before)."""
        frame = self.tx_view[: self.io[tick.TX_LEN]] if frame is None else frame
        if self.impairment is not None:
            self._queue(self.outbox, bytes(frame))
            return
        with contextlib.suppress(ConnectionRefusedError):  # no autopilot yet (an ICMP error): free-wheel
            self.sock.send(frame)

    def send_state(self, k: int, plant: Plant) -> None:
        self.encode(k, plant)
        self.send()

    def _queue(self, queue: list, datagram: bytes) -> None:
        for t in self.impairment.schedule(time.monotonic()):
            self.order += 1
            heapq.heappush(queue, (t, self.order, datagram))

    def next_event(self) -> float:
        """When the next impaired datagram is due [s, monotonic] (inf when none waits)."""
        return min(self.outbox[0][0] if self.outbox else math.inf, self.inbox[0][0] if self.inbox else math.inf)

    def heard(self) -> None:
        """An actuator message was used: the autopilot is there (:func:`sitl.realtime_loop.heard`)."""
        if realtime_loop.heard(self.rt, time.monotonic_ns()) == realtime_loop.BACK_NOW:
            self.say_back()

    def say_back(self) -> None:
        print(f"plant: {self.who} back; following its commands", file=sys.stderr, flush=True)

    def say_lost(self, action: str) -> None:
        print(f"plant: {self.who} lost (no answer for {AUTOPILOT_LOST_AFTER:g} s); {action}", file=sys.stderr,
              flush=True)  # fmt: skip

    def check_lost(self, action: str) -> bool:
        """True while the autopilot has been silent for AUTOPILOT_LOST_AFTER (said once per loss:
        :func:`sitl.realtime_loop.lost_clock`)."""
        lost = realtime_loop.lost_clock(self.rt, time.monotonic_ns(), LOST_AFTER_NS)
        if lost == realtime_loop.LOST_NOW:
            self.say_lost(action)
        return lost != 0

    def receive(self, timeout: float | None) -> int:
        """One datagram into rx: its length, or −1 when none came within ``timeout`` seconds."""
        if timeout != self.timeout:
            set_receive_timeout(self.sock, timeout)
            self.timeout = timeout
        try:
            return self.wait()
        except ConnectionRefusedError:
            # The ICMP error of a send to a port nobody listens on (the autopilot gone, or not started yet) ends the
            # receive after it at once: wait on for an answer. Without this, a free-wheeling plant sent its tick again
            # (to every vehicle of a fleet) about 28,000 times a second on a core of its own, not every
            # FREEWHEEL_PERIOD.
            with contextlib.suppress(BlockingIOError, InterruptedError, ConnectionRefusedError):
                return self.wait()
            return -1
        except (BlockingIOError, InterruptedError):
            return -1

    def decode(self, nbytes: int) -> int:
        """The stamp of the actuator message in rx[:nbytes] (its forces in ``self.received``); −1 when there
        is none (corrupt and non-finite ones counted)."""
        t = codec.decode_actuators(self.rx_array, nbytes, self.received, self.max_thrust)
        if t == codec.NOT_THIS_FRAME:
            return self._decode_slowly(nbytes)
        if t < 0:
            self.io[tick.CORRUPT] += 1
        return t

    def _decode_slowly(self, nbytes: int) -> int:
        """What pymavlink finds in a datagram the compiled decoder does not take (several messages, signed):
        the newest finite HIL_ACTUATOR_CONTROLS, its forces in ``self.received``; −1 when there is none."""
        try:
            msgs = [m for m in self.mav.parse_buffer(bytes(self.rx[:nbytes])) or []
                    if m.get_msgId() == HIL_ACTUATOR_CONTROLS]  # fmt: skip
        except wire.mavlink.MAVError:
            self.io[tick.CORRUPT] += 1
            return -1
        best = -1
        for m in msgs:
            if not all(map(math.isfinite, m.controls[:4])):
                self.io[tick.CORRUPT] += 1  # never integrate a non-finite force
            elif m.time_usec > best:
                best = m.time_usec
                self.received[:] = wire.forces_from_message(m, self.max_thrust)
                self.io[tick.ANSWER_ARMED] = 1 if m.mode & codec.SAFETY_ARMED else 0
        return best

    def apply(self, plant: Plant, t: int) -> bool:
        """Real time: make the actuator message stamped ``t`` (forces in ``self.received``) the command,
        unless it is older than the last used (:func:`sitl.realtime_loop.apply`)."""
        if t < 0:
            return False
        r = realtime_loop.apply(t, self.received, self.io, self.rt, plant.commanded, time.monotonic_ns())
        if r == realtime_loop.BACK_NOW:
            self.say_back()
        return r >= 0

    def end_period(self, want: int, plant: Plant, zero_on_loss: bool, action: str) -> None:
        """Real time, the period's answers taken (:meth:`apply`): counted, the lost clock, one step
        (:func:`sitl.realtime_loop.end_period`)."""
        flags = realtime_loop.end_period(self.io, self.rt, plant.commanded, want, time.monotonic_ns(), LOST_AFTER_NS,
                                         zero_on_loss, *self.step_args(plant))  # fmt: skip
        if flags & realtime_loop.LOST_NOW:
            self.say_lost(action)
        plant.time += plant.period

    @staticmethod
    def step_args(plant: Plant) -> tuple:
        """The arguments of :func:`sitl.plant.step_work` for ``plant``."""
        return plant.work, plant.params, plant.air_rng, plant.period, plant.substeps, plant.method

    def receive_within(self, seconds: float, plant: Plant) -> None:
        """Real time: apply every actuator message that arrives within ``seconds`` (microsecond precision:
        select); SO_RCVTIMEO counts in kernel ticks (4–10 ms) and Python's socket timeout in whole
        milliseconds, both too coarse for a 1 kHz schedule."""
        if self.impairment is None:
            if wait_readable(self.sock, seconds):
                nbytes = self.receive(None)
                if nbytes >= 0:
                    self.apply(plant, self.decode(nbytes))
            return
        self._release(plant)
        wait = min(seconds, max(0.0, self.next_event() - time.monotonic()))
        if wait_readable(self.sock, wait):
            with contextlib.suppress(BlockingIOError, InterruptedError, ConnectionRefusedError):
                self._queue(self.inbox, self.sock.recv(65535))
        self._release(plant)

    def drain(self, plant: Plant) -> None:
        """Real time, unimpaired: apply every actuator message waiting in the socket, without waiting (the newest
        stamp wins; older ones are discarded as stale)."""
        while True:
            try:
                nbytes = self.sock.recv_into(self.rx, 0, socket.MSG_DONTWAIT)
            except (BlockingIOError, InterruptedError, ConnectionRefusedError):
                return
            self.apply(plant, self.decode(nbytes))

    def _release(self, plant: Plant) -> None:
        """Send the due outgoing datagrams; apply the due incoming ones."""
        now = time.monotonic()
        while self.outbox and self.outbox[0][0] <= now:
            with contextlib.suppress(ConnectionRefusedError):
                self.sock.send(heapq.heappop(self.outbox)[2])
        while self.inbox and self.inbox[0][0] <= now:
            datagram = heapq.heappop(self.inbox)[2]
            self.rx[: len(datagram)] = datagram
            self.apply(plant, self.decode(len(datagram)))

    def announce(self, severity: int, text: str) -> None:
        """``text`` as STATUSTEXT to the autopilot, all its chunks in one datagram, at once (no impairment: the
        plant is about to end); nobody listening is no error."""
        frames = b"".join(codec.pack(m, self.mav) for m in wire.statustext(severity, text, 1))
        with contextlib.suppress(OSError):
            self.sock.send(frames)

    def close(self) -> None:
        self.sock.close()


def warm_up(plant: Plant) -> None:
    """Compile (or load from numba's cache) everything a tick calls, before the first tick, on a copy."""
    twin = copy.deepcopy(plant)
    link = np.zeros(max(codec.FRAME_MAX, hil.DATAGRAM_MAX), dtype=np.uint8)
    io = np.zeros(tick.IO_SIZE, dtype=np.int64)
    args = (twin.x, twin.motors, twin.out, twin.v, twin.a, twin.air, twin.air_rng, twin.period, twin.substeps,
            twin.method, link, io, twin.sensors.arrays)  # fmt: skip
    for sensing in (0, 1):
        io[tick.SENSING] = sensing
        n = codec.encode_actuators(link, 0, 1, 1, 0, (0.0, 0.0, 0.0, 0.0), 1.0, False)
        tick.lockstep_tick(link, n, 0, 1.0, twin.commanded.copy(), twin.commanded, *args, 0)
        tick.take_and_step(0, 0, twin.commanded, twin.commanded.copy(), *args, 0)
    codec.decode_actuators(link, n, twin.commanded, 1.0)
    twin.step()
    state_inside(twin.x)
    if fastio.AVAILABLE:  # the compiled clock, on a loopback pair: each wait finds an answer to tick 0
        io[tick.SENSING], io[tick.LAST_USEC] = 0, -1
        udp = (socket.AF_INET, socket.SOCK_DGRAM)
        with socket.socket(*udp) as a, socket.socket(*udp) as b:
            a.bind(("127.0.0.1", 0))
            b.bind(("127.0.0.1", 0))
            a.connect(b.getsockname())
            b.connect(a.getsockname())
            set_receive_timeout(a, 0.1)
            # the real-time period (sitl.realtime_loop): a fleet of one, its state sent, its answer taken, a step
            one = [x[None].copy() for x in (link, io, twin.work, twin.params, twin.air_rng, twin.commanded)]
            tx, rt_io, work, params, air_rng, received = one
            sens = tuple(x[None].copy() for x in twin.sensors.arrays)
            fds, rt = np.array([a.fileno()], dtype=np.int64), np.zeros((1, realtime_loop.RT_SIZE), dtype=np.int64)
            realtime_loop.send_ticks(fds, tx, rt_io, work, sens, 0, twin.period)
            b.recv(65535)
            n = codec.encode_actuators(link, 0, 1, 1, 0, (0.0, 0.0, 0.0, 0.0), 1.0, False)
            b.send(link[:n].tobytes())
            realtime_loop.take_and_step_all(fds, np.zeros(65535, dtype=np.uint8), received, np.ones(1), rt_io, rt,
                                            work, params, air_rng, np.array([twin.substeps]), np.array([twin.method]),
                                            0, 0, True, twin.period, 0, np.zeros(1, dtype=np.int64))  # fmt: skip
            rt = rt[0]
            realtime_loop.heard(rt, 1)  # (a held lockstep clock's: PlantLink.heard and check_lost)
            realtime_loop.lost_clock(rt, 2, LOST_AFTER_NS)
            realtime_loop.send_order(0, 0, 1)  # (the Python period's order of sending, impaired links)
            # the lockstep clock (sitl.lockstep_loop): a fleet of one, its answer to tick 0 waiting
            rt_io[0, tick.LAST_USEC] = -1
            b.send(link[:n].tobytes())
            lockstep_loop.run(fds, np.zeros(65535, dtype=np.uint8), 0, 1, np.ones(1), received, work, params, air_rng,
                              sens, np.array([twin.substeps]), np.array([twin.method]), twin.period, tx, rt_io,
                              np.zeros_like(tx), np.zeros(1, dtype=np.int64), 0, np.ones(1, dtype=np.bool_),
                              np.full(1, 1000), np.full(1, 1000), HOT_AFTER,
                              np.zeros((1, lockstep_loop.STATS_SIZE), dtype=np.int64))  # fmt: skip


@dataclass
class Vehicle:
    """One vehicle the plant process simulates: its name (Zenoh's ``quadsitl/<name>/…``, and in messages when the
    process simulates several), its preset (the state and wind options applied), its plant, its link to its
    autopilot, and its wind changes (None: no Zenoh)."""

    name: str
    preset: Preset
    plant: Plant
    link: PlantLink
    wind: WindLink | None = None

    @property
    def answered(self) -> int:
        """Real time: periods whose own answer (stamped with the period's tick) came within it ..."""
        return int(self.link.rt[realtime_loop.ANSWERED])

    @property
    def late(self) -> int:
        """... and periods since the autopilot's first answer whose answer did not: it flew a stale command."""
        return int(self.link.rt[realtime_loop.LATE])


class DivergedError(Exception):
    """The state of ``vehicle`` at the start of tick ``tick`` left its bounds (:func:`sitl.plant.inside`): the run
    ends, that state not sent. ``t`` is the plant's simulated time then [s], since the plant started. ``named``:
    the message names the vehicle (a fleet)."""

    def __init__(self, vehicle: Vehicle, tick: int, named: bool = False) -> None:
        self.vehicle, self.tick, self.t = vehicle, tick, tick * vehicle.plant.period
        self.what = outside_what(vehicle.plant.x)
        who = f"vehicle {vehicle.name} " if named else ""
        super().__init__(f"{who}diverged at t = {self.t:.3f} s (tick {tick} of the plant's clock): {self.what}")


def check_state(v: Vehicle, k: int, named: bool = False) -> None:
    """The start of tick ``k``: raise :class:`DivergedError` when the state is not :func:`sitl.plant.inside` its
    default bounds (one compiled call; lockstep checks the states after the first in its compiled tick)."""
    if not state_inside(v.plant.x):
        raise DivergedError(v, k, named)


def run_lockstep(vehicles: Sequence[Vehicle], speed: float, max_ticks: int | None) -> int:
    """The plant as the clock, one clock for every vehicle: send tick k's datagram to each vehicle's autopilot,
    wait for every answer to it, integrate each vehicle, and only then go on to tick k + 1, until ``max_ticks``.
    A fleet therefore advances tick by tick together and is as deterministic as one vehicle.

    Each answer is decoded, taken and integrated and the vehicle's next datagram encoded by one compiled call
    (:func:`sitl.tick.lockstep_tick`). The answers are awaited in the vehicles' order: each vehicle's come on its
    own socket, so one that answered while another was awaited is waiting there, and the tick takes as long as the
    slowest answer, no longer. A vehicle that does not answer within FREEWHEEL_PERIOD is sent its datagram again
    (simulated time waits, for every vehicle), and so is every other vehicle its datagram of tick k (an answered one
    answers it again, and that answer is discarded as stale): an autopilot that heard nothing for a while would
    declare its plant lost and land. Wind changes are taken between two ticks."""
    period = vehicles[0].plant.period
    named = len(vehicles) > 1
    links = [v.link for v in vehicles]
    # Unpaced, once the autopilots have answered, the ticks run in compiled code (sitl.lockstep_loop) until Python has
    # something to do; the loop below then goes on from where it stopped. Its arrays are the fleet's (a row per
    # vehicle, the vehicles' own arrays views of them), stacked before anything below takes the vehicles' arrays.
    fast = speed <= 0 and fastio.compiled_loops() and all(link.impairment is None for link in links)
    fleet = FleetArrays(vehicles) if fast else None
    k = 0
    start = time.monotonic()
    waits = []
    for v in vehicles:
        check_state(v, 0, named)  # the initial state; the others are checked as they are made (tick.DIVERGED)
        v.link.encode(0, v.plant)
        # Unpaced, a late answer is polled for with patience (nothing else waits on this run's pace); paced, the
        # processes the pace serves get the core back after a budget (SpinThenBlock).
        v.link.wait.be_patient(PATIENCE if speed <= 0 else None)
        p, link = v.plant, v.link
        args = (p.x, p.motors, p.out, p.v, p.a, p.air, p.air_rng, period, p.substeps, p.method, link.tx, link.io,
                p.sensors.arrays)  # fmt: skip
        waits.append((v, link, link.receive, link.rx_array, link.max_thrust, link.received, p.commanded, args))
    winds = [v for v in vehicles if v.wind is not None]
    monotonic, lockstep_tick, usec_of = time.monotonic, tick.lockstep_tick, codec.usec_of
    count = len(vehicles)
    stats = np.zeros((count, lockstep_loop.STATS_SIZE), dtype=np.int64)
    polling = np.zeros(count, dtype=np.bool_)
    budget_ns, patience_ns = np.zeros(count, dtype=np.int64), np.zeros(count, dtype=np.int64)
    sent_rows = np.zeros_like(fleet.tx) if fleet is not None else None  # tick k's datagrams, kept by the loop
    sent_len = np.zeros(count, dtype=np.int64)
    end = np.iinfo(np.int64).max if max_ticks is None else max_ticks
    while max_ticks is None or k < max_ticks:
        taken = None  # (length, result) of a datagram the compiled loop took for tick k, its answer not yet found
        sent = False
        first = 0  # the first vehicle whose answer to tick k is awaited (those before it stepped in compiled code)
        if fleet is not None and links[0].first_heard is not None:
            stats[:] = 0
            for i, link in enumerate(links):
                wait = link.wait
                if link.timeout != FREEWHEEL_PERIOD:  # the receive's own timeout: the free-wheel's
                    set_receive_timeout(link.sock, FREEWHEEL_PERIOD)
                    link.timeout = FREEWHEEL_PERIOD
                stats[i, lockstep_loop.SHORT] = wait.short
                polling[i] = wait.polling()
                budget_ns[i], patience_ns[i] = int(wait.budget * 1e9), int(wait.patience * 1e9)
            k0 = k
            status, k, first, nbytes, r = lockstep_loop.run(
                fleet.fds, fleet.rx, k, end, fleet.max_thrust, fleet.received, fleet.work, fleet.params,
                fleet.air_rng, fleet.sens, fleet.substeps, fleet.method, period, fleet.tx, fleet.io, sent_rows,
                sent_len, time.monotonic_ns() + LOOP_RETURN_NS, polling, budget_ns, patience_ns, HOT_AFTER, stats
            )  # fmt: skip
            for i, link in enumerate(links):
                link.wait.tally(int(stats[i, lockstep_loop.POLLED]), int(stats[i, lockstep_loop.LATE]),
                                status == lockstep_loop.QUIET and i == first, int(stats[i, lockstep_loop.BLOCKED]),
                                int(stats[i, lockstep_loop.SHORT]))  # fmt: skip
            if k > k0:
                now = monotonic()
                for link in links:
                    link.last_heard = now
                for v in vehicles:
                    for _ in range(k - k0):
                        v.plant.time += period
            if status in (lockstep_loop.DUE, lockstep_loop.END):
                for w in winds:
                    if w.wind.inbox:
                        w.wind.take(w.plant)
                continue
            sent = True
            if status == lockstep_loop.TAKEN:
                links[first].rx_array[:nbytes] = fleet.rx[:nbytes]  # (for pymavlink, if it is its to decode)
                taken = (nbytes, r)
            elif status == lockstep_loop.TIMED_OUT:
                taken = (-1, None)
        want = usec_of(k, period)
        if not sent:
            for link in links:
                link.send()
        if named:  # tick k's datagrams, to send again while any vehicle keeps the fleet waiting
            if sent:  # by the compiled loop, which kept them: the vehicles before `first` hold their next already
                sent_frames = [bytes(row[:n]) for row, n in zip(sent_rows, sent_len.tolist(), strict=True)]
            else:
                sent_frames = [bytes(link.tx_view[: link.io[tick.TX_LEN]]) for link in links]
        held = links[0].first_heard is None
        for v, link, receive, rx, max_thrust, received, commanded, args in waits[first:]:
            while True:
                if taken is not None:
                    (nbytes, r), taken = taken, None
                else:
                    nbytes, r = receive(FREEWHEEL_PERIOD), None
                if nbytes < 0:
                    held = True
                    link.check_lost("holding: simulated time stops until it answers")
                    if named:  # free-wheel the whole fleet: an autopilot that hears nothing declares its plant lost
                        for other, frame in zip(links, sent_frames, strict=True):
                            other.send(frame)
                    else:
                        link.send()  # free-wheel: no answer yet
                    continue
                if r is None:
                    r = lockstep_tick(rx, nbytes, want, max_thrust, received, commanded, *args, k)
                if r == tick.ANOTHER_FRAME:  # for pymavlink (several messages, signed)
                    r = tick.take_and_step(link.decode(nbytes), want, commanded, received, *args, k)
                if r == tick.STEPPED:
                    break
                if r == tick.HELD:  # the hold tick, the autopilot not yet armed: it is there, time waits
                    held = True
                    link.last_heard = monotonic()
                if r == tick.DIVERGED:  # x(k + 1), encoded but not sent
                    raise DivergedError(v, k + 1, named)
        if held:
            for link in links:
                link.heard()
            if speed > 0:  # the pace resumes from here: no burst to catch up with time spent holding
                start = monotonic() - k * period / speed
        else:
            now = monotonic()
            for link in links:
                link.last_heard = now
        for v in vehicles:
            v.plant.time += period
        k += 1
        for v in winds:
            if v.wind.inbox:
                v.wind.take(v.plant)
        if speed > 0:
            delay = start + k * period / speed - monotonic()
            if delay > 0:
                time.sleep(delay)
            elif delay < -PACE_SLACK:  # stalled: no burst at the machine's full speed to catch up, as after a hold
                start -= delay
    return k


def receive_within(vehicles: Sequence[Vehicle], seconds: float, socks: dict[socket.socket, Vehicle]) -> None:
    """Real time with impaired links (``--impair``): apply every actuator message that arrives within ``seconds`` on
    any vehicle's link (``socks``: the vehicles by their sockets), and release the impaired datagrams that fall
    due; without impairment the plant sleeps through the period instead (:func:`run_realtime`)."""
    if len(vehicles) == 1:
        vehicles[0].link.receive_within(seconds, vehicles[0].plant)
        return
    impaired = [v for v in vehicles if v.link.impairment is not None]
    if impaired:
        seconds = min(seconds, max(0.0, min(v.link.next_event() for v in impaired) - time.monotonic()))
    arrived = {socks[s].name for s in readable_of(list(socks), seconds)}
    for v in vehicles:
        if v.name in arrived or v.link.impairment is not None:
            v.link.receive_within(0.0, v.plant)  # readable now (or its queues due): takes it without waiting


def sleep_until(deadline: float) -> None:
    """Sleep until ``deadline`` [s, time.monotonic's clock]; return at once when it has passed."""
    remaining = deadline - time.monotonic()
    if remaining > 0:
        time.sleep(remaining)


def run_realtime(
    vehicles: Sequence[Vehicle],
    max_ticks: int | None,
    starts: list[float] | None = None,
    on_loss: str = "zero",
    late: Sequence[list[int]] | None = None,
) -> int:
    """Integrate every vehicle on the wall clock, tick k due at t0 + k·T. ``starts`` (if given) receives each
    tick's actual start time [s, monotonic]; ``late`` (if given, a list per vehicle) the ticks whose answer did not
    come within their period, from the autopilot's first answer on (what ``rt[LATE]`` counts). Where the compiled
    loops run (:func:`quadsitl.fastio.compiled_loops`), but with impaired links, whose queues are Python's, the whole
    fleet's work of a period is two compiled calls (:class:`sitl.realtime_fleet.RealtimeFleet`); the Python loop does
    the same, vehicle by vehicle."""
    period = vehicles[0].plant.period
    named = len(vehicles) > 1
    socks = {v.link.sock: v for v in vehicles}
    impaired = any(v.link.impairment is not None for v in vehicles)  # their queues release datagrams on time
    fleet = RealtimeFleet(vehicles) if fastio.compiled_loops() and not impaired else None
    winds = [v for v in vehicles if v.wind is not None]
    zero = on_loss == "zero"
    action = f"applying {'zero thrust' if zero else 'the last command'}"
    k = 0
    next_time = time.monotonic()
    while max_ticks is None or k < max_ticks:
        if starts is not None:
            starts.append(time.monotonic())
        if fleet is not None:
            if (i := fleet.send(k)) >= 0:
                raise DivergedError(vehicles[i], k, named)
        else:
            for v in vehicles:
                check_state(v, k, named)
            for j in range(len(vehicles)):  # the vehicles take turns at going first, as the compiled period's do
                v = vehicles[realtime_loop.send_order(j, k, len(vehicles))]
                v.link.send_state(k, v.plant)
        if k == 0:  # the clock starts once the first states are out: a slow first send (page faults, a machine busy
            next_time = time.monotonic()  # starting a dashboard) would otherwise be caught up in a burst of late ticks
            if starts is not None:
                starts[0] = next_time
        next_time += period
        if impaired:
            while True:
                remaining = next_time - time.monotonic()
                if remaining <= 0:
                    break
                receive_within(vehicles, remaining, socks)
            receive_within(vehicles, 0.0, socks)
        else:
            # The answers are needed only when the period ends, so the plant sleeps until then and takes them all at
            # once: one wake-up per period, not one per answer, and an autopilot's answer wakes nobody (on a virtual
            # machine, waking a process on the other core cost the waker 100-200 us of CPU)
            sleep_until(next_time)
            # Everything that came before the period ended, and only then: a plant whose own wake-up came late (the
            # scheduler ran something else) takes the answers that came in time, not the last command
            for v in vehicles if fleet is None else ():
                v.link.drain(v.plant)
        want = codec.usec_of(k, period)
        for v in winds:
            if v.wind.inbox:
                v.wind.take(v.plant)
        if fleet is not None:  # the drain above and the end of the period, for every vehicle in one compiled call
            fleet.take_and_step(want, LOST_AFTER_NS, zero, action)
        else:
            for v in vehicles:
                v.link.end_period(want, v.plant, zero, action)
        if late is not None:  # a period counts late at most once: the count grew by one for each vehicle late now
            for v, ticks in zip(vehicles, late, strict=True):
                if v.late > len(ticks):
                    ticks.append(k)
        k += 1
    return k


def open_wind_links(args: argparse.Namespace, vehicles: Sequence[Vehicle]) -> Any:
    """One Zenoh session, when the command line gives an endpoint or a configuration, taking each vehicle's wind
    changes on ``quadsitl/<vehicle>/wind``; None otherwise."""
    if not (args.zenoh_listen or args.zenoh_connect or args.zenoh_config):
        return None
    import zenoh

    keys = ", ".join(f"quadsitl/{v.name}/wind" for v in vehicles)
    try:
        session = zenoh.open(config_from_args(args))
    except Exception as exc:  # zenoh.ZError and the like: a bad endpoint or configuration
        raise UsageError(f"Zenoh session (for wind changes on {keys}): {exc}") from None
    for v in vehicles:
        v.wind = WindLink(session, v.name, v.preset.wind)
    return session


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="quadsitl plant",
        description="The simulated quadrotor: integrates the truth state and talks MAVLink over UDP to the autopilot.",
        epilog="examples:\n  quadsitl plant --preset paper --autopilot 127.0.0.1:14560\n"
        "  quadsitl plant --preset x500 --mode realtime --autopilot 127.0.0.1:14560",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_preset_arguments(p, controller=False)
    p.add_argument(
        "--autopilot",
        action="append",
        metavar="HOST:PORT",
        help="where the autopilot listens for the plant (default: 127.0.0.1:14560); repeat it to simulate a fleet, "
        "one vehicle per autopilot, on one clock",
    )
    p.add_argument(
        "--bind",
        default="127.0.0.1:0",
        metavar="HOST:PORT",
        help="local address of the plant's socket (default: 127.0.0.1, any port; in a fleet vehicle i's is PORT + i)",
    )
    p.add_argument("--vehicle-preset", action="append", default=[], metavar="K=PRESET",
                   help="in a fleet, vehicle K (1-based) flies PRESET (a name or a TOML file) instead of --preset; "
                   "every preset must have the same control period (repeatable)")  # fmt: skip
    p.add_argument("--mode", choices=("lockstep", "realtime"), default="lockstep", help="default: lockstep")
    p.add_argument("--cores-awake", action="store_true", help=CORES_AWAKE_HELP)
    p.add_argument(
        "--speed",
        type=float,
        default=0.0,
        metavar="F",
        help="lockstep pace cap, × real time (0 = as fast as possible; default 0)",
    )
    p.add_argument(
        "--hold-until-armed",
        type=float,
        metavar="S",
        help="lockstep: at S simulated seconds, hold the clock until the autopilot's answer says armed (quadsitl fly "
        "uses it with sensors: its flight then starts after the same ticks on the ground in every run)",
    )
    p.add_argument("--hold-when-landed", action="store_true",
                   help="lockstep, one vehicle: once the vehicle has flown, hold the clock while the autopilot's "
                   "answer says disarmed and the vehicle rests on the ground; arming again resumes it (quadsitl fly: "
                   "the flight is over, and nothing ticks while the results are written)")  # fmt: skip
    p.add_argument("--integrator", choices=("euler", "rk4"), help="default: the preset's")
    p.add_argument("--substeps", type=int, metavar="N", help="default: the preset's")
    p.add_argument("--ticks", type=int, metavar="N", help="stop after N ticks (default: run until stopped)")
    add_impair_argument(p)
    p.add_argument(
        "--on-autopilot-loss",
        choices=("zero", "last"),
        default="zero",
        help="realtime mode, when the autopilot stops answering: zero thrust (default) or hold its last command",
    )
    p.add_argument("--stats", metavar="FILE", help="write the run's pace (and, in realtime, its timing) as JSON")
    p.add_argument("--quiet", "-q", action="store_true", help="no summary at the end (errors still print)")
    add_state_arguments(p)
    p.add_argument("--home", action="append", metavar="LAT,LON,ALT", help="where the local origin is on the globe, "
                   "for the GPS: degrees, degrees, metres AMSL (default: PX4 SITL's, 47.397742,8.545594,488); in a "
                   "fleet once for every vehicle or once per --autopilot, in order")  # fmt: skip
    add_wind_arguments(p)
    p.add_argument("--vehicle", action="append", metavar="NAME", help="the vehicle's name in the Zenoh keys "
                   "quadsitl/<vehicle>/wind (default: v1; in a fleet v1..vN, or one per --autopilot, in "
                   "order)")  # fmt: skip
    add_zenoh_arguments(p, vehicle=False)  # a session only when an endpoint or a configuration is given: for wind
    return p


def fleet_from_args(args: argparse.Namespace) -> list[Vehicle]:
    """The vehicles the command line asks for: one per ``--autopilot``, each with its preset (``--preset``, or
    ``--vehicle-preset``), state and wind options, home and name; a UsageError naming the option otherwise.
    Vehicle i (0-based) draws its sensor noise and turbulence from the seeds + i: every vehicle its own."""
    autopilots = [parse_address("--autopilot", a) for a in args.autopilot or ["127.0.0.1:14560"]]
    n = len(autopilots)
    fleet = f"--autopilot given {n} times"
    names = per_vehicle("--vehicle", args.vehicle, n, fleet) or [f"v{i + 1}" for i in range(n)]
    if len(set(names)) != n:
        raise UsageError(f"--vehicle {' '.join(names)}: two vehicles named alike; each needs a name of its own")
    homes = [parse_home(h) for h in per_vehicle("--home", args.home, n, fleet) or [None] * n]
    presets = parse_vehicle_presets(args.vehicle_preset, n, fleet)
    check_speed(args.speed)
    host, port = parse_address("--bind", args.bind)
    if port and port + n - 1 > 65535:
        raise UsageError(f"--bind {args.bind}: vehicle {n} would need port {port + n - 1}, beyond 65535")
    if args.hold_until_armed is not None and (args.mode != "lockstep" or not 0.0 <= args.hold_until_armed <= 3600.0):
        raise UsageError(f"--hold-until-armed {args.hold_until_armed!r}: expected a number of seconds in [0, 3600], "
                         "in lockstep")  # fmt: skip
    if args.hold_when_landed and (args.mode != "lockstep" or n > 1):
        vehicles = f"{n} vehicle{'s' if n > 1 else ''}"
        raise UsageError(f"--hold-when-landed: only in lockstep with one vehicle (here: {args.mode}, {vehicles}); "
                         "a fleet's one clock would stop for all when the first one lands")  # fmt: skip
    impairment_from(args.impair, args.mode)  # refused here, before any socket is bound
    base = with_state(with_wind(load_preset(args.preset), args), args)
    vehicles: list[Vehicle] = []
    for i, (autopilot, name, home) in enumerate(zip(autopilots, names, homes, strict=True)):
        preset = base
        if i + 1 in presets:
            try:
                preset = with_state(with_wind(load_preset(presets[i + 1]), args), args)
            except ConfigError as exc:
                raise UsageError(f"--vehicle-preset {i + 1}={presets[i + 1]}: {exc}") from None
            if preset.sim.period != base.sim.period:
                raise UsageError(f"--vehicle-preset {i + 1}={presets[i + 1]}: its control period is "
                                 f"{preset.sim.period:g} s, --preset {args.preset}'s {base.sim.period:g} s; one clock "
                                 "needs one period")  # fmt: skip
        if i > 0:  # every vehicle its own noise and turbulence
            preset = replace(preset, wind=replace(preset.wind, seed=(preset.wind.seed + i) % 2**63))
            if preset.sensors is not None:
                preset = replace(preset, sensors=replace(preset.sensors, seed=(preset.sensors.seed + i) % 2**63))
        plant = Plant(preset, integrator=args.integrator, substeps=args.substeps, home=home or PX4_HOME)
        bind = f"{host}:{port + i if port else 0}"
        link = PlantLink(bind_udp("--bind", bind), autopilot, preset.actuators.max_thrust, preset.sim.period,
                         impairment_from(args.impair, args.mode),
                         sensing=preset.sensors is not None, name=name if n > 1 else "")  # fmt: skip
        if args.hold_until_armed is not None:
            link.io[tick.HOLD_TICK] = round(args.hold_until_armed / preset.sim.period)
        link.io[tick.HOLD_LANDED] = int(args.hold_when_landed)
        vehicles.append(Vehicle(name, preset, plant, link))
    return vehicles


def main(argv: Sequence[str] | None = None) -> int:
    start_process()
    parser = build_parser()
    args = parser.parse_args(argv)
    vehicles: list[Vehicle] = []
    session = None
    try:
        fastio.compiled_loops()  # $QUADSITL_COMPILED_LOOPS checked before anything starts
        # held (open) until this process ends: the kernel drops the request then, however it ends
        awake = hold_cores_awake() if args.cores_awake else None  # noqa: F841
        vehicles = fleet_from_args(args)
        warm_up(vehicles[0].plant)
        session = open_wind_links(args, vehicles)
    except (UsageError, ConfigError) as exc:
        for v in vehicles:
            v.link.close()
        print(f"{parser.prog}: error: {exc}", file=sys.stderr)
        return 2
    period = vehicles[0].plant.period
    if args.mode == "realtime":
        clock_above_its_peers()  # under chrt -f: the clock one priority above the autopilots
        timers_on_time()  # each tick's timer fires within 1 µs of its due time, not 50
    start, cpu_start = time.monotonic(), time.process_time()
    starts: list[float] = []
    late: list[list[int]] = [[] for _ in vehicles]
    try:
        if args.mode == "lockstep":
            run_lockstep(vehicles, args.speed, args.ticks)
        else:
            run_realtime(vehicles, args.ticks, starts if args.stats else None, args.on_autopilot_loss,
                         late if args.stats else None)  # fmt: skip
    except KeyboardInterrupt:  # SIGINT or SIGTERM (process_util.StopRequested): a requested stop; say what the run did
        pass
    except DivergedError as exc:  # one line, always: the run ends with a status of its own
        print(f"plant: {exc}; the run ends (exit status {PLANT_DIVERGED})", file=sys.stderr, flush=True)
        exc.vehicle.link.announce(wire.mavlink.MAV_SEVERITY_CRITICAL, f"Simulation diverged at t = {exc.t:.3f} s: "
                                  f"{exc.what}; the plant stopped")  # fmt: skip
        return PLANT_DIVERGED
    finally:
        for v in vehicles:
            v.link.close()
            if v.wind is not None:
                v.wind.close()
        if session is not None:
            session.close()
    elapsed = time.monotonic() - start
    plant = vehicles[0].plant
    if args.stats:
        ticks = round(plant.time / period)
        # The pace from the autopilots' first answers on (tick 0 waits for the autopilots to start or to take this
        # plant over, which is not the loop's speed); the whole run's wall time next to it.
        first = min((v.link.first_heard for v in vehicles if v.link.first_heard is not None), default=start)
        flying = time.monotonic() - first
        stats = {"mode": args.mode, "vehicles": len(vehicles), "ticks": ticks, "wall_s": elapsed,
                 "answered_wall_s": flying, "ticks_per_s": max(ticks - 1, 0) / max(flying, 1e-9),
                 "cpu_s": time.process_time() - cpu_start,  # this process's CPU over wall_s (not its start-up)
                 "receives_polled": sum(v.link.wait.polled for v in vehicles),
                 "receives_blocked": sum(v.link.wait.blocked for v in vehicles),
                 "polling_budget_s": vehicles[0].link.wait.budget,  # SpinThenBlock: what makes a wait hot
                 "polling_patience_s": vehicles[0].link.wait.patience}  # fmt: skip
        if args.mode == "realtime":  # the clock's timing, and the autopilots' answers that missed their period
            stats.update(period_stats(starts, period))
            stats["answer_miss_ratios"] = [v.late / max(v.answered + v.late, 1) for v in vehicles]
            # which periods: tick k due at clock_t0_s + k·period [s, CLOCK_MONOTONIC], to set beside other clocks
            stats["period_s"] = period
            stats["clock_t0_s"] = starts[0] if starts else None
            stats["clock_late_ticks"] = late_periods(starts, period, starts[0]) if starts else []
            stats["answer_late_ticks"] = late
            stats["answered_ticks"] = [v.answered + v.late for v in vehicles]  # the answer ratios' denominators
        Path(args.stats).write_text(json.dumps(stats, indent=2) + "\n")
    if args.quiet:
        return 0
    fleet = f"{len(vehicles)} vehicles, " if len(vehicles) > 1 else ""
    print(f"plant: {fleet}{plant.time:.3f} s simulated in {elapsed:.3f} s; "
          f"{sum(v.link.discarded for v in vehicles)} stale actuator messages discarded", file=sys.stderr)  # fmt: skip
    for v in vehicles:
        im = v.link.impairment
        if im is not None:
            who = f" ({v.name})" if len(vehicles) > 1 else ""
            print(f"plant: link impairment{who} dropped {im.dropped}, duplicated {im.duplicated}, reordered "
                  f"{im.reordered} datagrams", file=sys.stderr)  # fmt: skip
    return 0
