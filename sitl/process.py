"""The plant process (``quadsitl plant``, ``python -m sitl``): owns the truth state and integrates it.

One MAVLink 2 UDP link to the autopilot (see :mod:`quadsitl.wire`). Each tick's datagram is the state as
ODOMETRY (``--state truth``), or in sensor mode (``--state sensors``, the default when the preset has a [sensors]
section) what the vehicle's sensors measure of it: HIL_SENSOR, HIL_GPS when a fix is delivered, and the ground
truth as HIL_STATE_QUATERNION (:mod:`quadsitl.hil`), the GPS's latitude and longitude from ``--home``.

- ``lockstep`` (default): the plant is the clock. For tick k it sends the state stamped with the
  simulated time, waits for the HIL_ACTUATOR_CONTROLS answering tick k, then integrates one period.
  Until an answer comes (at start, or if the autopilot goes away) it free-wheels: it re-sends the
  state every 50 ms without advancing time. ``--speed F`` caps the pace at F × real time (0 = as fast
  as possible).
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
from pathlib import Path

import numpy as np

from quadsitl import hil, wire
from quadsitl.cli_util import (
    UsageError,
    add_preset_arguments,
    add_state_arguments,
    add_wind_arguments,
    check_range,
    parse_home,
    with_state,
    with_wind,
)
from quadsitl.config import ConfigError, WindParams, load_preset
from quadsitl.earth import PX4_HOME
from quadsitl.process_util import (
    PLANT_DIVERGED,
    SpinThenBlock,
    bind_udp,
    parse_address,
    set_receive_timeout,
    start_process,
    wait_readable,
)
from quadsitl.telemetry import add_zenoh_arguments, config_from_args
from quadsitl.timing import period_stats
from sitl import tick
from sitl.impair import Impairment, add_impair_argument, impairment_from
from sitl.plant import Plant, outside_what, state_inside
from sitl.wind_link import WindLink

HIL_ACTUATOR_CONTROLS = wire.mavlink.MAVLINK_MSG_ID_HIL_ACTUATOR_CONTROLS
FREEWHEEL_PERIOD = 0.05  # [s] state re-send pace while no answer comes
AUTOPILOT_LOST_AFTER = 0.5  # [s] wall without an actuator message: the autopilot is lost


class PlantLink:
    """The plant's end of the UDP link: send states, receive actuator commands. The two per-tick messages
    are encoded and decoded in place by the compiled codec (:mod:`quadsitl.wire`, :mod:`sitl.tick`)."""

    def __init__(
        self,
        sock: socket.socket,
        autopilot: tuple[str, int],
        max_thrust: float,
        period: float,
        impairment: Impairment | None = None,
        sensing: bool = False,
    ):
        self.sock = sock  # bound (process_util.bind_udp)
        self.rx = bytearray(65535)
        self.rx_array = np.frombuffer(self.rx, dtype=np.uint8)
        self.tx = np.zeros(max(wire.FRAME_MAX, hil.DATAGRAM_MAX), dtype=np.uint8)
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
        self.last_heard: float | None = None  # wall time the autopilot was last heard (None: not yet)
        self.first_heard: float | None = None  # ... and first: the run's pace counts from its first answer
        self.lost = False
        self.impairment = impairment  # real-time runs only: both directions go through its queues
        self.outbox: list[tuple[float, int, bytes]] = []  # (release time, order, datagram), a heap
        self.inbox: list[tuple[float, int, bytes]] = []
        self.order = 0

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

    def send(self) -> None:
        """Send the state frame in tx."""
        frame = self.tx_view[: self.io[tick.TX_LEN]]
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
        """An actuator message was used: the autopilot is there."""
        self.last_heard = time.monotonic()
        if self.first_heard is None:
            self.first_heard = self.last_heard
        if self.lost:
            self.lost = False
            print("plant: autopilot back; following its commands", file=sys.stderr, flush=True)

    def check_lost(self, action: str) -> bool:
        """True while the autopilot has been silent for AUTOPILOT_LOST_AFTER (said once per loss)."""
        if self.last_heard is None or time.monotonic() - self.last_heard <= AUTOPILOT_LOST_AFTER:
            return False
        if not self.lost:
            self.lost = True
            print(f"plant: autopilot lost (no answer for {AUTOPILOT_LOST_AFTER:g} s); {action}", file=sys.stderr,
                  flush=True)  # fmt: skip
        return True

    def receive(self, timeout: float | None) -> int:
        """One datagram into rx: its length, or −1 when none came within ``timeout`` seconds."""
        if timeout != self.timeout:
            set_receive_timeout(self.sock, timeout)
            self.timeout = timeout
        try:
            return self.wait()
        except (BlockingIOError, InterruptedError, ConnectionRefusedError):
            return -1

    def decode(self, nbytes: int) -> int:
        """The stamp of the actuator message in rx[:nbytes] (its forces in ``self.received``); −1 when there
        is none (corrupt and non-finite ones counted)."""
        t = wire.decode_actuators(self.rx_array, nbytes, self.received, self.max_thrust)
        if t == wire.NOT_THIS_FRAME:
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
                self.io[tick.ANSWER_ARMED] = 1 if m.mode & wire.SAFETY_ARMED else 0
        return best

    def apply(self, plant: Plant, t: int) -> bool:
        """Real time: make the actuator message stamped ``t`` (forces in ``self.received``) the command,
        unless it is older than the last used."""
        if t < 0:
            return False
        if t <= self.io[tick.LAST_USEC]:
            self.io[tick.DISCARDED] += 1
            return False
        self.io[tick.LAST_USEC] = t
        plant.commanded[:] = self.received
        self.heard()
        return True

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
        frames = b"".join(wire.pack(m, self.mav) for m in wire.statustext(severity, text, 1))
        with contextlib.suppress(OSError):
            self.sock.send(frames)

    def close(self) -> None:
        self.sock.close()


def warm_up(plant: Plant) -> None:
    """Compile (or load from numba's cache) everything a tick calls, before the first tick, on a copy."""
    twin = copy.deepcopy(plant)
    link = np.zeros(max(wire.FRAME_MAX, hil.DATAGRAM_MAX), dtype=np.uint8)
    io = np.zeros(tick.IO_SIZE, dtype=np.int64)
    args = (twin.x, twin.motors, twin.out, twin.v, twin.a, twin.air, twin.air_rng, twin.period, twin.substeps,
            twin.method, link, io, twin.sensors.arrays)  # fmt: skip
    for sensing in (0, 1):
        io[tick.SENSING] = sensing
        n = wire.encode_actuators(link, 0, 1, 1, 0, (0.0, 0.0, 0.0, 0.0), 1.0, False)
        tick.lockstep_tick(link, n, 0, 1.0, twin.commanded.copy(), twin.commanded, *args, 0)
        tick.take_and_step(0, 0, twin.commanded, twin.commanded.copy(), *args, 0)
    wire.decode_actuators(link, n, twin.commanded, 1.0)
    twin.step()
    state_inside(twin.x)


class DivergedError(Exception):
    """The plant's state at the start of tick ``tick`` left its bounds (:func:`sitl.plant.inside`): the run ends,
    that state not sent. ``t`` is the plant's simulated time then [s], since the plant started."""

    def __init__(self, tick: int, period: float, x: np.ndarray) -> None:
        self.tick, self.t, self.what = tick, tick * period, outside_what(x)
        super().__init__(f"diverged at t = {self.t:.3f} s (tick {tick} of the plant's clock): {self.what}")


def check_state(plant: Plant, k: int) -> None:
    """The start of tick ``k``: raise :class:`DivergedError` when the state is not :func:`sitl.plant.inside` its
    default bounds (one compiled call; lockstep checks the states after the first in its compiled tick)."""
    if not state_inside(plant.x):
        raise DivergedError(k, plant.period, plant.x)


def run_lockstep(plant: Plant, link: PlantLink, speed: float, max_ticks: int | None, wind: WindLink | None = None
                 ) -> int:  # fmt: skip
    """The plant as the clock: send tick k's state, wait for the answer to it, integrate, until ``max_ticks``.
    The state frame goes out first; each answer to it is decoded, taken and integrated and the next state
    encoded by one compiled call (:func:`sitl.tick.lockstep_tick`). Wind changes from ``wind`` are taken
    between two ticks."""
    period = plant.period
    k = 0
    start = time.monotonic()
    link.encode(0, plant)
    rx, received, commanded, io, tx = link.rx_array, link.received, plant.commanded, link.io, link.tx
    args = (plant.x, plant.motors, plant.out, plant.v, plant.a, plant.air, plant.air_rng, period, plant.substeps,
            plant.method, tx, io, plant.sensors.arrays)  # fmt: skip
    max_thrust, monotonic, receive = link.max_thrust, time.monotonic, link.receive
    check_state(plant, 0)  # the initial state; the others are checked as they are made (tick.DIVERGED)
    while max_ticks is None or k < max_ticks:
        want = wire.usec_of(k, period)
        link.send()
        held = link.first_heard is None
        while True:
            nbytes = receive(FREEWHEEL_PERIOD)
            if nbytes < 0:
                held = True
                link.check_lost("holding: simulated time stops until it answers")
                link.send()  # free-wheel: no answer yet
                continue
            r = tick.lockstep_tick(rx, nbytes, want, max_thrust, received, commanded, *args, k)
            if r == tick.ANOTHER_FRAME:  # for pymavlink (several messages, signed)
                r = tick.take_and_step(link.decode(nbytes), want, commanded, received, *args, k)
            if r == tick.STEPPED:
                break
            if r == tick.HELD:  # the hold tick, the autopilot not yet armed: it is there, time waits
                held = True
                link.last_heard = monotonic()
            if r == tick.DIVERGED:  # x(k + 1), encoded but not sent
                raise DivergedError(k + 1, period, plant.x)
        if held:
            link.heard()
            if speed > 0:  # the pace resumes from here: no burst to catch up with time spent holding
                start = monotonic() - k * period / speed
        else:
            link.last_heard = monotonic()
        plant.time += period
        k += 1
        if wind is not None and wind.inbox:
            wind.take(plant)
        if speed > 0:
            delay = start + k * period / speed - monotonic()
            if delay > 0:
                time.sleep(delay)
    return k


def run_realtime(
    plant: Plant,
    link: PlantLink,
    max_ticks: int | None,
    starts: list[float] | None = None,
    on_loss: str = "zero",
    wind: WindLink | None = None,
) -> int:
    """Integrate on the wall clock, tick k due at t0 + k·T. ``starts`` (if given) receives each tick's
    actual start time [s, monotonic]."""
    period = plant.period
    k = 0
    next_time = time.monotonic()
    while max_ticks is None or k < max_ticks:
        if starts is not None:
            starts.append(time.monotonic())
        check_state(plant, k)
        link.send_state(k, plant)
        next_time += period
        while True:
            remaining = next_time - time.monotonic()
            if remaining <= 0:
                break
            link.receive_within(remaining, plant)
        if link.check_lost(f"applying {'zero thrust' if on_loss == 'zero' else 'the last command'}") and (
            on_loss == "zero"
        ):
            plant.commanded[:] = 0.0
        if wind is not None and wind.inbox:
            wind.take(plant)
        plant.step()
        k += 1
    return k


def open_wind_link(args: argparse.Namespace, wind: WindParams) -> WindLink | None:
    """The Zenoh session that takes wind changes, when the command line gives an endpoint or a configuration."""
    if not (args.zenoh_listen or args.zenoh_connect or args.zenoh_config):
        return None
    try:
        return WindLink(config_from_args(args), args.vehicle, wind)
    except Exception as exc:  # zenoh.ZError and the like: a bad endpoint or configuration
        raise UsageError(f"Zenoh session (for wind changes on quadsitl/{args.vehicle}/wind): {exc}") from None


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
        default="127.0.0.1:14560",
        metavar="HOST:PORT",
        help="where the autopilot listens for the plant (default: 127.0.0.1:14560)",
    )
    p.add_argument(
        "--bind",
        default="127.0.0.1:0",
        metavar="HOST:PORT",
        help="local address of the plant's socket (default: 127.0.0.1, any port)",
    )
    p.add_argument("--mode", choices=("lockstep", "realtime"), default="lockstep", help="default: lockstep")
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
    p.add_argument("--home", metavar="LAT,LON,ALT", help="where the local origin is on the globe, for the GPS: "
                   "degrees, degrees, metres AMSL (default: PX4 SITL's, 47.397742,8.545594,488)")  # fmt: skip
    add_wind_arguments(p)
    add_zenoh_arguments(p)  # a session only when an endpoint or a configuration is given: for wind changes
    return p


def main(argv: Sequence[str] | None = None) -> int:
    start_process()
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        preset = with_state(with_wind(load_preset(args.preset), args), args)
        home = parse_home(args.home) or PX4_HOME
        check_range("--speed", args.speed if args.speed != 0 else None, 0.0, 1000.0)
        autopilot = parse_address("--autopilot", args.autopilot)
        plant = Plant(preset, integrator=args.integrator, substeps=args.substeps, home=home)
        warm_up(plant)
        impairment = impairment_from(args.impair, args.mode)
        link = PlantLink(bind_udp("--bind", args.bind), autopilot, preset.actuators.max_thrust, preset.sim.period,
                         impairment, sensing=preset.sensors is not None)  # fmt: skip
        if args.hold_until_armed is not None:
            if args.mode != "lockstep" or not 0.0 <= args.hold_until_armed <= 3600.0:
                raise UsageError(f"--hold-until-armed {args.hold_until_armed!r}: expected a number of seconds in "
                                 "[0, 3600], in lockstep")  # fmt: skip
            link.io[tick.HOLD_TICK] = round(args.hold_until_armed / preset.sim.period)
        wind = open_wind_link(args, preset.wind)
    except (UsageError, ConfigError) as exc:
        print(f"{parser.prog}: error: {exc}", file=sys.stderr)
        return 2
    start = time.monotonic()
    starts: list[float] = []
    try:
        if args.mode == "lockstep":
            run_lockstep(plant, link, args.speed, args.ticks, wind)
        else:
            run_realtime(plant, link, args.ticks, starts if args.stats else None, args.on_autopilot_loss, wind)
    except KeyboardInterrupt:  # SIGINT or SIGTERM (process_util.StopRequested): a requested stop; say what the run did
        pass
    except DivergedError as exc:  # one line, always: the run ends with a status of its own
        print(f"plant: {exc}; the run ends (exit status {PLANT_DIVERGED})", file=sys.stderr, flush=True)
        link.announce(wire.mavlink.MAV_SEVERITY_CRITICAL, f"Simulation diverged at t = {exc.t:.3f} s: {exc.what}; "
                      "the plant stopped")  # fmt: skip
        return PLANT_DIVERGED
    finally:
        link.close()
        if wind is not None:
            wind.close()
    elapsed = time.monotonic() - start
    if args.stats:
        ticks = round(plant.time / preset.sim.period)
        # The pace from the autopilot's first answer on (tick 0 waits for the autopilot to start or to
        # take this plant over, which is not the loop's speed); the whole run's wall time next to it.
        flying = time.monotonic() - (link.first_heard or start)
        stats = {"mode": args.mode, "ticks": ticks, "wall_s": elapsed, "answered_wall_s": flying,
                 "ticks_per_s": max(ticks - 1, 0) / max(flying, 1e-9),
                 "receives_polled": link.wait.polled, "receives_blocked": link.wait.blocked}  # fmt: skip
        if args.mode == "realtime":
            stats.update(period_stats(starts, preset.sim.period))
        Path(args.stats).write_text(json.dumps(stats, indent=2) + "\n")
    if args.quiet:
        return 0
    print(
        f"plant: {plant.time:.3f} s simulated in {elapsed:.3f} s; {link.discarded} stale actuator messages discarded",
        file=sys.stderr,
    )
    if link.impairment is not None:
        im = link.impairment
        print(f"plant: link impairment dropped {im.dropped}, duplicated {im.duplicated}, reordered {im.reordered} "
              "datagrams", file=sys.stderr)  # fmt: skip
    return 0
