"""The plant process (``quadsitl plant``, ``python -m sitl``): owns the truth state and integrates it.

One MAVLink 2 UDP link to the autopilot (see :mod:`quadsitl.wire`).

- ``lockstep`` (default): the plant is the clock. For tick k it sends the state stamped with the
  simulated time, waits for the HIL_ACTUATOR_CONTROLS answering tick k, then integrates one period.
  Until an answer comes (at start, or if the autopilot goes away) it free-wheels: it re-sends the
  state every 50 ms without advancing time. ``--speed F`` caps the pace at F × real time (0 = as fast
  as possible).
- ``realtime``: integrates on the wall clock at period T and applies the latest actuator command it has.

In both, actuator messages older than the last one used (by ``time_usec``) are discarded.
"""

from __future__ import annotations

import argparse
import contextlib
import heapq
import json
import math
import socket
import sys
import time
from collections.abc import Sequence
from pathlib import Path

from quadsitl import wire
from quadsitl.cli_util import UsageError, add_preset_arguments, check_range
from quadsitl.config import ConfigError, load_preset
from quadsitl.process_util import (
    SpinThenBlock,
    bind_udp,
    parse_address,
    set_receive_timeout,
    start_process,
    wait_readable,
)
from quadsitl.timing import period_stats
from sitl.impair import Impairment, add_impair_argument, impairment_from
from sitl.plant import Plant

HIL_ACTUATOR_CONTROLS = wire.mavlink.MAVLINK_MSG_ID_HIL_ACTUATOR_CONTROLS
FREEWHEEL_PERIOD = 0.05  # [s] state re-send pace while no answer comes
AUTOPILOT_LOST_AFTER = 0.5  # [s] wall without an actuator message: the autopilot is lost


class PlantLink:
    """The plant's end of the UDP link: send states, receive actuator commands."""

    def __init__(
        self,
        sock: socket.socket,
        autopilot: tuple[str, int],
        max_thrust: float,
        period: float,
        impairment: Impairment | None = None,
    ):
        self.sock = sock  # bound (process_util.bind_udp)
        self.wait = SpinThenBlock(sock.recv)  # lockstep's receive: polls while the autopilot answers fast
        self.sock.connect(autopilot)  # the kernel drops datagrams from anyone but the autopilot
        self.mav = wire.link(wire.PLANT_SYSTEM_ID, wire.PLANT_COMPONENT_ID)
        self.fast = wire.FastLink(wire.PLANT_SYSTEM_ID, wire.PLANT_COMPONENT_ID)
        self.max_thrust = max_thrust
        self.period = period
        self.last_usec = -1  # newest actuator stamp used
        self.discarded = 0
        self.corrupt = 0
        self.timeout = -1.0
        self.last_heard: float | None = None  # wall time the autopilot was last heard (None: not yet)
        self.first_heard: float | None = None  # ... and first: the run's pace counts from its first answer
        self.lost = False
        self.impairment = impairment  # real-time runs only: both directions go through its queues
        self.outbox: list[tuple[float, int, bytes]] = []  # (release time, order, datagram), a heap
        self.inbox: list[tuple[float, int, bytes]] = []
        self.order = 0

    def send_state(self, tick: int, plant: Plant) -> None:
        frame = self.fast.pack_state(wire.usec_of(tick, self.period), plant.state)
        if self.impairment is not None:
            self._queue(self.outbox, frame)
            return
        with contextlib.suppress(ConnectionRefusedError):  # no autopilot yet (an ICMP error): free-wheel
            self.sock.send(frame)

    def _queue(self, queue: list, datagram: bytes) -> None:
        for t in self.impairment.schedule(time.monotonic()):
            self.order += 1
            heapq.heappush(queue, (t, self.order, datagram))

    def next_event(self) -> float:
        """When the next impaired datagram is due [s, monotonic] (inf when none waits)."""
        return min(self.outbox[0][0] if self.outbox else math.inf, self.inbox[0][0] if self.inbox else math.inf)

    def _release(self) -> list:
        """Send the due outgoing datagrams; parse the due incoming ones."""
        now, out = time.monotonic(), []
        while self.outbox and self.outbox[0][0] <= now:
            with contextlib.suppress(ConnectionRefusedError):
                self.sock.send(heapq.heappop(self.outbox)[2])
        while self.inbox and self.inbox[0][0] <= now:
            out += self._accept(heapq.heappop(self.inbox)[2])
        return out

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

    def receive_within(self, seconds: float) -> list:
        """Like :meth:`receive`, waiting at most ``seconds`` with microsecond precision (select), for the
        real-time loop; SO_RCVTIMEO counts in kernel ticks (4–10 ms) and Python's socket timeout in
        whole milliseconds, both too coarse for a 1 kHz schedule."""
        if self.impairment is None:
            return self.receive(None) if wait_readable(self.sock, seconds) else []
        out = self._release()
        wait = min(seconds, max(0.0, self.next_event() - time.monotonic()))
        if wait_readable(self.sock, wait):
            with contextlib.suppress(BlockingIOError, InterruptedError, ConnectionRefusedError):
                self._queue(self.inbox, self.sock.recv(65535))
        return out + self._release()

    def receive(self, timeout: float | None) -> list:
        """Actuator messages newer than the last used, from one datagram (empty on timeout)."""
        if timeout != self.timeout:
            set_receive_timeout(self.sock, timeout)
            self.timeout = timeout
        try:
            data = self.wait()
        except (BlockingIOError, InterruptedError, ConnectionRefusedError):
            return []
        return self._accept(data)

    def _accept(self, data: bytes) -> list:
        """Actuator messages in one datagram, newer than the last used (older and duplicates discarded)."""
        try:
            fast = wire.parse_actuators(data)  # the per-tick fast path
        except wire.FrameError:
            self.corrupt += 1
            return []
        if fast is not None:
            msgs = [fast]
        else:
            try:
                msgs = [m for m in self.mav.parse_buffer(data) or [] if m.get_msgId() == HIL_ACTUATOR_CONTROLS]
            except wire.mavlink.MAVError:
                self.corrupt += 1
                return []
        out = []
        for m in msgs:
            if not all(map(math.isfinite, m.controls[:4])):
                self.corrupt += 1  # never integrate a non-finite force
                continue
            if m.time_usec <= self.last_usec:
                self.discarded += 1
                continue
            out.append(m)
        return out

    def close(self) -> None:
        self.sock.close()


def run_lockstep(plant: Plant, link: PlantLink, speed: float, max_ticks: int | None) -> int:
    period = plant.period
    tick = 0
    start = time.monotonic()
    while max_ticks is None or tick < max_ticks:
        want = wire.usec_of(tick, period)
        link.send_state(tick, plant)
        forces, held = None, False
        while forces is None:
            for m in link.receive(FREEWHEEL_PERIOD):
                if m.time_usec == want:
                    forces = wire.forces_from_message(m, link.max_thrust)
                    link.last_usec = m.time_usec
                    link.heard()
                elif m.time_usec > want:  # from the future: not ours
                    link.discarded += 1
            if forces is None:
                held = True
                link.check_lost("holding: simulated time stops until it answers")
                link.send_state(tick, plant)  # free-wheel: no answer yet
        if held and speed > 0:  # the pace resumes from here: no burst to catch up with time spent holding
            start = time.monotonic() - tick * period / speed
        plant.step(forces)
        tick += 1
        if speed > 0:
            delay = start + tick * period / speed - time.monotonic()
            if delay > 0:
                time.sleep(delay)
    return tick


def run_realtime(
    plant: Plant, link: PlantLink, max_ticks: int | None, starts: list[float] | None = None, on_loss: str = "zero"
) -> int:
    """Integrate on the wall clock, tick k due at t0 + k·T. ``starts`` (if given) receives each tick's
    actual start time [s, monotonic]."""
    period = plant.period
    forces: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0)
    tick = 0
    next_time = time.monotonic()
    while max_ticks is None or tick < max_ticks:
        if starts is not None:
            starts.append(time.monotonic())
        link.send_state(tick, plant)
        next_time += period
        while True:
            remaining = next_time - time.monotonic()
            if remaining <= 0:
                break
            for m in link.receive_within(remaining):
                forces = wire.forces_from_message(m, link.max_thrust)
                link.last_usec = m.time_usec
                link.heard()
        if link.check_lost(f"applying {'zero thrust' if on_loss == 'zero' else 'the last command'}") and (
            on_loss == "zero"
        ):
            forces = (0.0, 0.0, 0.0, 0.0)
        plant.step(forces)
        tick += 1
    return tick


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
    return p


def main(argv: Sequence[str] | None = None) -> int:
    start_process()
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        preset = load_preset(args.preset)
        check_range("--speed", args.speed if args.speed != 0 else None, 0.0, 1000.0)
        autopilot = parse_address("--autopilot", args.autopilot)
        plant = Plant(preset, integrator=args.integrator, substeps=args.substeps)
        impairment = impairment_from(args.impair, args.mode)
        link = PlantLink(bind_udp("--bind", args.bind), autopilot, preset.actuators.max_thrust, preset.sim.period,
                         impairment)  # fmt: skip
    except (UsageError, ConfigError) as exc:
        print(f"{parser.prog}: error: {exc}", file=sys.stderr)
        return 2
    start = time.monotonic()
    status = 0
    starts: list[float] = []
    try:
        if args.mode == "lockstep":
            run_lockstep(plant, link, args.speed, args.ticks)
        else:
            run_realtime(plant, link, args.ticks, starts if args.stats else None, args.on_autopilot_loss)
    except KeyboardInterrupt:
        pass
    except SystemExit as exc:  # SIGTERM (exit_on_signals): still say what the run did
        status = exc.code if isinstance(exc.code, int) else 1
    finally:
        link.close()
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
        return status
    print(
        f"plant: {plant.time:.3f} s simulated in {elapsed:.3f} s; {link.discarded} stale actuator messages discarded",
        file=sys.stderr,
    )
    if link.impairment is not None:
        im = link.impairment
        print(f"plant: link impairment dropped {im.dropped}, duplicated {im.duplicated}, reordered {im.reordered} "
              "datagrams", file=sys.stderr)  # fmt: skip
    return status
