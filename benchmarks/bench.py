"""``quadsitl bench [--json]``: the speed of the SITL against this machine's own limits.

Every figure is printed next to a baseline measured in the same run, because absolute times on shared machines
drift. The sections, one module each under :mod:`benchmarks.sections` (registered in :mod:`benchmarks.registry`),
run in this order (``--only NAME``, the default all of them), each in a quick form by default (the run about two
minutes on 2 cores) or whole with ``--full``:

0. ``coldstart``: ``quadsitl fly`` with numba's cache empty, then filled (with ``--full`` or ``--only`` only);
1. ``lockstep``: ``fly``'s tick rate against a bare UDP ping-pong of the same datagrams (``lockstep_ratio``);
2. ``costs``: per-call costs [µs], compiled against plain Python, and a Zenoh publish against the round trip;
3. ``fanout``: telemetry subscribers on the autopilot's Zenoh session: delivery, loss, latency, tick rate;
4. ``realtime``: the plant's real-time loop at 1 kHz against a bare loop that keeps time the same way;
5. ``dashboard``: the tick rate with the dashboard's page open in headless Chromium (optional: it needs Playwright
   and Chromium, and says so when skipped);
6. ``batch``: the sweeps' batch engine against ``quadsitl sim``'s vehicle loop;
7. ``fleet``: N vehicles at once, in real time against the machine's own floor, and in lockstep.

The figures go to :class:`benchmarks.report.Report`, printed as they come and with ``--json`` written as one document;
then the goals they meet or miss (:mod:`benchmarks.goals`).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path

from benchmarks import machine
from benchmarks.autopilots import compile_first
from benchmarks.goals import check, print_goals
from benchmarks.registry import PARTS, left_out, selected, unavailable
from benchmarks.report import Report, summary
from benchmarks.sections.base import Context
from quadsitl.process_util import stop_status


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="quadsitl bench",
        description="Measure the SITL's speed against baselines taken in the same run on this machine.",
        epilog="examples:\n  quadsitl bench\n  quadsitl bench --full --json > bench.json\n"
        "  quadsitl bench --only lockstep",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--json", action="store_true", help="print every figure as JSON on stdout")
    p.add_argument("--full", action="store_true",
                   help="every section whole: the cold start, the fleet series in real time under both schedulers, "
                   "the lockstep's, fan-out's, dashboard's and sweeps' other runs (about 9 minutes on 2 cores; "
                   "default: each section's quick form, about 2 minutes)")  # fmt: skip
    p.add_argument("--only", choices=PARTS, action="append", help="run only these parts (repeatable; default: all)")
    p.add_argument("--rounds", type=int, default=2, help="interleaved ping-pong/fly rounds, best of (default 2)")
    p.add_argument("--realtime-seconds", type=float, help="real-time run length (default 3, 10 with --full)")
    p.add_argument("--subscriber-nice", type=int, default=10, help="niceness of fan-out subscribers (default 10)")
    p.add_argument("--batch-trials", type=int,
                   help="trials of the batch section's sweep (default 4000: 2 x 10⁷ vehicle-steps; 20000 with "
                   "--full)")  # fmt: skip
    p.add_argument("--fleet-sizes", default="1,2,4,8,12,16,24,32", metavar="N,N,...",
                   help="fleet sizes, ascending (the quick form: the largest, hosted in one process, in lockstep); "
                   "with --full the real-time series stops after the first that misses "
                   "1 %% of its deadlines outside the host's stalls (default 1,2,4,8,12,16,24,32)")  # fmt: skip
    p.add_argument("--fleet-seconds", type=float, default=5.0, help="each fleet run's length (default 5)")
    return p


def parse_sizes(text: str) -> list[int]:
    """``--fleet-sizes`` as ascending vehicle counts in 1..64, or a ValueError naming what is wrong."""
    try:
        sizes = [int(part) for part in text.split(",")]
    except ValueError:
        sizes = []
    if not sizes or sizes != sorted(set(sizes)) or not all(1 <= n <= 64 for n in sizes):
        raise ValueError(f"--fleet-sizes {text!r}: expected ascending vehicle counts in 1..64, e.g. 1,2,4,8")
    return sizes


def main(argv: Sequence[str] | None = None) -> int:
    """``quadsitl bench``: the exit status (2 for a bad option, 1 when a section failed)."""
    args = build_parser().parse_args(argv)
    if args.realtime_seconds is None:
        args.realtime_seconds = 10.0 if args.full else 3.0
    if args.batch_trials is None:
        args.batch_trials = 20000 if args.full else 4000
    if not 1 <= args.rounds <= 10:
        print(f"quadsitl bench: error: --rounds {args.rounds}: expected 1..10", file=sys.stderr)
        return 2
    if not 16 <= args.batch_trials <= 10_000_000:
        print(f"quadsitl bench: error: --batch-trials {args.batch_trials}: expected 16..10000000", file=sys.stderr)
        return 2
    if not 1.0 <= args.realtime_seconds <= 600.0:
        print(f"quadsitl bench: error: --realtime-seconds {args.realtime_seconds:g}: expected 1..600", file=sys.stderr)
        return 2
    if not 2.0 <= args.fleet_seconds <= 600.0:
        print(f"quadsitl bench: error: --fleet-seconds {args.fleet_seconds:g}: expected 2..600", file=sys.stderr)
        return 2
    try:
        sizes = parse_sizes(args.fleet_sizes)
    except ValueError as exc:
        print(f"quadsitl bench: error: {exc}", file=sys.stderr)
        return 2
    sections = selected(args.only or PARTS)
    skipped = unavailable(sections)
    for part, (why, _absent) in skipped.items():
        print(f"quadsitl bench: skipping the {part} section: {why}", file=sys.stderr, flush=True)
    for part, (why, absent) in left_out(sections, args.full, bool(args.only)).items():
        skipped.setdefault(part, (why, absent))
        print(f"quadsitl bench: leaving out the {part} section: {why}", file=sys.stderr, flush=True)
    r = Report(quiet=False)
    host = machine.describe()
    print(f"quadsitl bench on {machine.one_line(host)}", file=sys.stderr)
    started = time.monotonic()
    extra: dict[str, object] = {}
    took: dict[str, float] = {}  # each section's wall time [s]
    compiling = any(s.compiled for s in sections)  # still to do, once
    try:
        with tempfile.TemporaryDirectory(prefix="quadsitl-bench-") as tmp:
            ctx = Context(r, Path(tmp), args, sizes)
            for section in sections:
                if compiling and not section.cold:
                    compile_first()
                    compiling = False
                if section.name not in skipped:
                    begun = time.monotonic()
                    extra.update(section.run(ctx))
                    took[section.name] = time.monotonic() - begun
    except (subprocess.CalledProcessError, subprocess.TimeoutExpired, RuntimeError, OSError) as exc:
        print(f"quadsitl bench: error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt as exc:  # SIGINT or SIGTERM (quadsitl.process_util.StopRequested)
        print("quadsitl bench: interrupted", file=sys.stderr)
        return stop_status(exc)
    elapsed = time.monotonic() - started
    scope = "full" if args.full else "quick"
    report = r.document(ctx.lockstep_ratio, {"scope": scope, **extra, "section_s": took}, elapsed, host, skipped)
    report["goals"] = check(report, whole=not args.only)
    print_goals(report["goals"])
    summary(ctx.lockstep_ratio, elapsed, host, took)
    if args.json:
        print(json.dumps(report, indent=2))
    return 0
