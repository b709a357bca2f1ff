"""``quadsitl replay FILE``: play a recorded flight back onto Zenoh, as the autopilot would publish it.

FILE is a ``telemetry.csv`` (from ``quadsitl sim`` or ``quadsitl fly``) or a ``.tlog`` (a MAVLink telemetry
log, as ``quadsitl gcs``, MAVProxy and QGroundControl write it). The records go out on
``quadsitl/<vehicle>/{state,setpoint,actuators,status}`` in the schema of :mod:`quadsitl.telemetry` (v2), so
``quadsitl dashboard`` or any subscriber sees a replay as it would see a live vehicle.

This is the shell: the pure :mod:`groundstation.recording` turns the file into a
:class:`~groundstation.recording.Recording`, one record per stream and tick (the record formats, units and
frames, and what a tlog does and does not give, are described there); :func:`publish` paces and publishes
it, :func:`main` is the command.

**Pacing.** A record is due (t − t₀)/speed wall seconds after the start (speed 0: at once). As the
autopilot does, due records of consecutive ticks are concatenated into one sample per stream, a sample at
most every millisecond of wall time unless it holds 256 records; a gap in the ticks (a tlog's ATTITUDE at
50 Hz) ends a sample. Publication uses congestion control BLOCK: every record reaches every subscriber,
and a slow subscriber slows the replay. Before playing, the replay waits up to ``--wait`` seconds for a
subscriber. With ``--loop``, each pass starts again at the first tick (and time).

**Zenoh.** The usual options (:func:`quadsitl.telemetry.add_zenoh_arguments`; ``--vehicle`` defaults to
``v1`` as everywhere). With no endpoint and no configuration file, the replay listens on
``tcp/127.0.0.1:7447``, where ``quadsitl up`` has the autopilot listen, so subscribers find it there.

Exit status: 0 done (with ``--loop``, which runs until stopped: stopped by SIGINT or SIGTERM), 2 bad input (one
line on stderr); a single pass cut short by SIGINT exits 130, by SIGTERM 143.
"""

from __future__ import annotations

import argparse
import bisect
import math
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import zenoh

from groundstation.recording import DEFAULT_PERIOD, Recording, ReplayError, load
from quadsitl import telemetry
from quadsitl.cli_util import UsageError, check_range, check_speed
from quadsitl.process_util import run_stoppable, start_process, stop_status

DEFAULT_LISTEN = "tcp/127.0.0.1:7447"  # where `quadsitl up` has the autopilot listen; subscribers connect
BATCH_WALL = 0.001  # [s] wall: at most one sample per stream this often (as the autopilot)...
BATCH_MAX = 256  # ...unless this many records are due
MAX_SLEEP = 0.05  # [s] wall: longest single sleep while waiting for a record to be due


# ---- publishing: the shell -----------------------------------------------------------------------------


@dataclass
class Stats:
    records: dict[str, int] = field(default_factory=lambda: dict.fromkeys(telemetry.STREAMS, 0))
    samples: dict[str, int] = field(default_factory=lambda: dict.fromkeys(telemetry.STREAMS, 0))
    simulated: float = 0.0  # [s] simulated time played (all passes)
    passes: int = 0  # passes completed
    started: float | None = None  # time.monotonic() when playing began
    finished: float | None = None

    @property
    def wall(self) -> float:
        if self.started is None:
            return 0.0
        return (self.finished if self.finished is not None else time.monotonic()) - self.started


def wait_for_subscribers(publishers: Sequence[zenoh.Publisher], seconds: float) -> bool:
    """Wait up to ``seconds`` (wall) until every publisher has a matching subscriber; True if they do."""
    deadline = time.monotonic() + seconds
    while True:
        if all(p.matching_status.matching for p in publishers):
            return True
        if time.monotonic() >= deadline:
            return False
        time.sleep(0.005)


def publish(
    session: zenoh.Session,
    vehicle: str,
    recording: Recording,
    speed: float,
    *,
    loop: bool = False,
    wait: float = 2.0,
    stats: Stats | None = None,
    clock: Callable[[], float] = time.monotonic,
    sleep: Callable[[float], None] = time.sleep,
) -> Stats:
    """Publish ``recording`` on quadsitl/<vehicle>/..., paced at ``speed`` × real time by simulated
    time (0: as fast as possible), once or, with ``loop``, until interrupted, after waiting up to ``wait``
    wall seconds for a subscriber. ``stats`` (updated as it goes, so an interrupted caller still has the
    figures) is returned. ``clock`` and ``sleep`` are the wall clock [s] and how to wait on it."""
    stats = stats if stats is not None else Stats()
    pubs = {
        s: session.declare_publisher(
            telemetry.key(vehicle, s), encoding=telemetry.encoding(s), congestion_control=zenoh.CongestionControl.BLOCK
        )
        for s in telemetry.STREAMS
    }
    slow = telemetry.Overview(session, vehicle)  # the overview, as an autopilot puts it
    try:
        wait_for_subscribers(list(pubs.values()), wait)
        n, ticks, times = len(recording), recording.ticks, recording.times
        # Sample boundaries: a record whose tick does not follow the previous one starts a new sample.
        breaks = [k for k in range(1, n) if ticks[k] != ticks[k - 1] + 1] + [n]
        payload = recording.payload
        sizes = {s: telemetry.STREAMS[s].size for s in pubs}
        stats.started = clock()
        while n:
            t0, start, last_flush = times[0], clock(), -math.inf
            i, b = 0, 0
            while i < n:
                while breaks[b] <= i:
                    b += 1
                now = clock()
                if speed > 0:
                    played = (now - start) * speed  # simulated seconds since the first record
                    due = bisect.bisect_right(times, t0 + played, i, n)
                    if due == i:  # the next record is not due yet
                        sleep(min((times[i] - t0) / speed - (now - start), MAX_SLEEP))
                        continue
                else:
                    due = n
                j = min(due, i + BATCH_MAX, breaks[b])
                if j - i < BATCH_MAX and j < breaks[b] and now - last_flush < BATCH_WALL:
                    sleep(last_flush + BATCH_WALL - now)  # more records may join this sample
                    continue
                for s, pub in pubs.items():
                    pub.put(bytes(payload[s][i * sizes[s] : j * sizes[s]]))
                    stats.records[s] += j - i
                    stats.samples[s] += 1
                slow.offer(lambda s, j=j: bytes(payload[s][(j - 1) * sizes[s] : j * sizes[s]]), now)
                # simulated time covered: from the previous record (the first one covers one period)
                stats.simulated += times[j - 1] - (times[i - 1] if i else times[0] - recording.period)
                last_flush, i = now, j
            stats.passes += 1
            if not loop:
                break
        if n and slow.owed:  # the overview ends on the recording's last record
            slow.offer(lambda s: bytes(payload[s][(n - 1) * sizes[s] : n * sizes[s]]), clock(), force=True)
    finally:
        stats.finished = clock()
        for pub in (*pubs.values(), slow.pub):
            pub.undeclare()
    return stats


def summary(prog: str, recording: Recording, vehicle: str, stats: Stats, interrupted: bool = False) -> str:
    per_stream = ", ".join(f"{stats.records[s]} {s}" for s in telemetry.STREAMS)
    samples = sum(stats.samples.values())
    wall = stats.wall
    rate = f"{stats.simulated / wall:.1f}× real time" if wall > 0 else "no wall time"
    if interrupted and stats.passes:
        passes = f" in {stats.passes} complete pass{'es' if stats.passes != 1 else ''} and part of the next"
    elif interrupted:
        passes = " in part of one pass"
    else:
        passes = f" in {stats.passes} passes" if stats.passes > 1 else ""
    return (
        f"{prog}: {'interrupted; ' if interrupted else ''}{recording.source}: published {per_stream} records "
        f"({samples} samples) on "
        f"{telemetry.key(vehicle, '*')}{passes}: {stats.simulated:.3f} s simulated in {wall:.3f} s wall ({rate})"
    )


# ---- the command ----------------------------------------------------------------------------------------

EXAMPLES = """examples:
  quadsitl replay runs/fly/telemetry.csv --speed 2
  quadsitl replay runs/fly/flight.tlog --loop
  quadsitl replay flight.tlog --zenoh-connect tcp/127.0.0.1:7447 --vehicle replay
  quadsitl replay runs/paper/telemetry.csv --speed 0 --quiet

  then, in another terminal, watch it:
  quadsitl dashboard

Without --zenoh-listen, --zenoh-connect or --zenoh-config, the replay listens on tcp/127.0.0.1:7447, where
`quadsitl up` has the autopilot listen, so subscribers that connect there see the replay instead (stop
`quadsitl up` first, or give the replay another endpoint). --vehicle defaults to v1, as for the other
commands; use --vehicle replay to keep a replay apart from a live vehicle on the same Zenoh network.

From a .tlog: u1..u4 are NaN (not in MAVLink), f1..f4 assume this autopilot's output encoding with F_max
from --preset, and x..vz are NaN in logs of `quadsitl fly`/`gcs` (they turn LOCAL_POSITION_NED off).
"""


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="quadsitl replay",
        description="Play a recorded telemetry.csv (quadsitl sim/fly) or .tlog (quadsitl gcs, MAVProxy, "
        "QGroundControl) back onto Zenoh, in the schema the autopilot publishes, paced by simulated time.",
        epilog=EXAMPLES,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("file", metavar="FILE", help="a telemetry .csv or a MAVLink .tlog")
    p.add_argument(
        "--speed",
        type=float,
        default=1.0,
        metavar="F",
        help="pace: F × real time, by simulated time (default 1; 0 = as fast as possible; at most 1000)",
    )
    p.add_argument("--loop", action="store_true", help="play again from the start until Ctrl-C")
    p.add_argument(
        "--period",
        type=float,
        default=DEFAULT_PERIOD,
        metavar="S",
        help=f"tlog: the vehicle's control period T for tick = round(t/T) (default {DEFAULT_PERIOD:g}); "
        "CSV: only when it has a single row (T is the median step of t)",
    )
    p.add_argument("--preset", default="paper", help="tlog: the vehicle's preset, for F_max in f1..f4 (default: paper)")
    p.add_argument(
        "--wait",
        type=float,
        default=2.0,
        metavar="S",
        help="wait up to S wall seconds for a subscriber before playing (default 2; 0 = start at once)",
    )
    p.add_argument("--quiet", "-q", action="store_true", help="print only errors")
    telemetry.add_zenoh_arguments(p)
    return p


def check_args(args: argparse.Namespace) -> None:
    """Refuse out-of-range options (UsageError naming the option, the value and what is allowed)."""
    check_speed(args.speed)
    check_range("--period", args.period, 0.0, 1.0)
    if not 0.0 <= args.wait <= 3600.0:
        raise UsageError(f"--wait {args.wait!r}: expected a number of seconds in [0, 3600]")


def main(argv: Sequence[str] | None = None) -> int:
    start_process(quiet_gc=False)
    parser = build_parser()
    args = parser.parse_args(argv)
    prog = parser.prog
    stats: Stats | None = None
    recording: Recording | None = None
    try:
        try:
            check_args(args)
            recording = load(Path(args.file), args.period, args.preset)
        except (UsageError, ReplayError) as exc:
            print(f"{prog}: error: {exc}", file=sys.stderr)
            return 2
        if not args.quiet:
            for note in recording.notes:
                print(f"{prog}: note: {note}", file=sys.stderr)
        default_listen = not (args.zenoh_listen or args.zenoh_connect or args.zenoh_config)
        if default_listen:
            args.zenoh_listen = [DEFAULT_LISTEN]
        try:
            session = zenoh.open(telemetry.config_from_args(args))
        except zenoh.ZError as exc:
            hint = (
                f" (the default endpoint {DEFAULT_LISTEN} is busy? give --zenoh-listen another)"
                if default_listen
                else ""
            )
            print(f"{prog}: error: cannot open the Zenoh session (--zenoh-listen / --zenoh-connect / "
                  f"--zenoh-config){hint}: {exc}", file=sys.stderr)  # fmt: skip
            return 2
        stats = Stats()
        try:
            publish(session, args.vehicle, recording, args.speed, loop=args.loop, wait=args.wait, stats=stats)
        finally:
            session.close()
        if not args.quiet:
            print(summary(prog, recording, args.vehicle, stats), file=sys.stderr)
        return 0
    except KeyboardInterrupt as exc:  # SIGINT or SIGTERM (StopRequested)
        code = 0 if args.loop else stop_status(exc)  # --loop runs until stopped; one pass was cut short
        if stats is not None and recording is not None and not args.quiet:
            print(summary(prog, recording, args.vehicle, stats, interrupted=True), file=sys.stderr)
        return code


if __name__ == "__main__":
    sys.exit(run_stoppable(main, name="quadsitl replay"))
