"""``quadsitl sweep``, the command: its options (:func:`add_sweep_parser`), their checks and the run
(:func:`cmd_sweep`), and the summary it prints on the terminal (:func:`format_summary`). The sweep itself:
:mod:`groundstation.sweep.spec`, :mod:`groundstation.sweep.run`.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
from pathlib import Path

from quadsitl.cli_util import CONTROLLER_HELP, UsageError, controller_name
from quadsitl.config import ConfigError

EXAMPLES_SWEEP = """examples:
  quadsitl sweep paper-mass-mismatch --out runs/mass          # a shipped spec, by name
  quadsitl sweep paper-mass-mismatch --trials 100000 --workers 2 --out runs/mass-100k
  quadsitl sweep my-sweep.toml --keep 5 --json --out runs/mine  # trajectories of trials 0..4; summary on stdout
  quadsitl sweep paper-mass-mismatch --trials 100000 --cluster tcp://10.0.0.5:8786  # on a Dask scheduler's workers
"""


def cmd_sweep(args: argparse.Namespace) -> int:
    """``quadsitl sweep`` with ``args``: the options checked (a UsageError naming the first bad one), the trials
    flown, the table, summary and figures written into ``--out`` → the exit status."""
    from groundstation.sweep.spec import check_engine, load_spec
    from quadsitl.controller_names import absolute

    try:
        spec = load_spec(args.spec, None if args.controller is None else absolute(args.controller))
        if args.trials is not None:
            spec = spec.with_trials(args.trials)
    except ConfigError as exc:
        raise UsageError(str(exc)) from None
    if args.engine is not None:
        try:
            spec = check_engine(dataclasses.replace(spec, engine=args.engine))
        except ConfigError as exc:
            raise UsageError(f"--engine {args.engine}: {exc}") from None
    if args.cluster is not None and args.workers is not None:
        raise UsageError(f"--workers {args.workers} with --cluster {args.cluster}: expected one of them (--cluster: "
                         "the cluster's workers fly the trials)")  # fmt: skip
    if args.cluster is not None:
        from groundstation.sweep.cluster import parse_address

        address = parse_address("--cluster", args.cluster)
    cores = os.cpu_count() or 1  # a `fly` keeps two cores busy (plant and autopilot in lockstep)
    default_workers = max(1, cores // 2) if spec.engine == "sitl" else cores
    workers = default_workers if args.workers is None else args.workers
    if not 1 <= workers <= 256:
        raise UsageError(f"--workers {workers}: expected an integer in [1, 256]")
    if args.chunk is not None and not 1 <= args.chunk <= 1_000_000:
        raise UsageError(f"--chunk {args.chunk}: expected an integer in [1, 1000000]")
    keep = set(spec.keep) | set(args.keep_trial or ())
    if args.keep is not None:
        if not 0 <= args.keep <= 1000:
            raise UsageError(f"--keep {args.keep}: expected an integer in [0, 1000] (the first N trials)")
        keep |= set(range(min(args.keep, spec.trials)))
    bad = [k for k in keep if not 0 <= k < spec.trials]
    if bad:
        raise UsageError(f"--keep-trial {bad[0]}: expected a trial number in [0, {spec.trials - 1}]")
    spec = dataclasses.replace(spec, keep=tuple(sorted(keep)))
    quiet = args.quiet or args.json
    total_s = spec.trials * spec.duration
    chunk = args.chunk or (1 if spec.engine == "sitl" else None)  # a SITL trial takes seconds: progress per trial
    # after the checks: a refusal is answered without loading the compiler
    from groundstation.progress import FlightProgress, announce_if_slow
    from groundstation.sweep.run import SweepError, run_sweep, summarize, warm_up, write_outputs

    if args.cluster is None:  # compiled (first use) or loaded from numba's cache before the progress clock starts
        with announce_if_slow("quadsitl sweep: compiling the engine for this configuration (first use only: numba's "
                              "cache keeps it)", enabled=not args.quiet):  # fmt: skip
            warm_up(spec)
    try:
        with FlightProgress(total_s, enabled=not args.quiet, label="sweep (vehicle-seconds):") as bar:
            if args.cluster is None:
                result = run_sweep(spec, workers, chunk, progress=bar.update)
            else:
                from groundstation.sweep.cluster import run_on_cluster

                def warn(line: str) -> None:
                    if not args.quiet:
                        print(f"quadsitl sweep: warning: {line}", file=sys.stderr)

                result = run_on_cluster(spec, address, chunk, progress=bar.update, warn=warn)
    except SweepError as exc:  # a trial lost or twice; with --cluster, also the cluster's failures (ClusterError)
        print(f"quadsitl sweep: error: {exc}", file=sys.stderr)
        return 1
    summary = summarize(result)
    files = write_outputs(Path(args.out), result, summary)
    figures = []
    if not args.no_figures:
        from groundstation.sweep.figures import write_sweep_figures  # matplotlib: only when drawing

        figures = write_sweep_figures(Path(args.out), result)
    if args.json:
        print(json.dumps(summary, indent=2))
    if not quiet:
        print(format_summary(summary))
        kept = sum(f.parent.name == "trajectories" for f in files)
        names = [f.name for f in files if f.parent.name != "trajectories"] + [f.name for f in figures]
        print(f"wrote {args.out}/" + ", ".join(names)
              + (f" and {kept} trajector{'y' if kept == 1 else 'ies'}" if kept else ""))  # fmt: skip
    return 0


def format_summary(s: dict) -> str:
    """A few lines for the terminal: the sweep, its speed, settling times and overshoot per channel, the worst."""
    flown = (f"mission {s['mission']}" if s.get("mission") else f"trajectory {s['trajectory']}"
             if s.get("trajectory") else f"task {s['task']}")  # fmt: skip
    flown += ", on sensors" if s.get("state") == "sensors" else ""
    tracked = s["metrics"]["horizontal_rms"].get("p50") is not None  # a position trajectory or a mission
    lines = [
        f"sweep {s['spec']}: {s['trials']} trials of {s['duration']:g} s ({s['controller']}, preset {s['preset']}, "
        f"{flown}) in {s['wall_s']:.1f} s, {s['vehicle_steps_per_s'] or 0:.3g} vehicle-steps/s"
        + (f" on {s['workers']} Dask worker{'s' * (s['workers'] != 1)} at {s['cluster']}" if s.get("cluster") else ""),
        f"diverged {s['diverged']} of {s['flown']} flown (failure rate {s['failure_rate'] or 0:.3g}); "
        f"inadmissible {s['inadmissible']}",
    ]

    def f(m: dict, key: str, fmt: str = ".3f") -> str:
        return "—" if m.get(key) is None else format(m[key], fmt)

    if tracked:
        lines.append(f"{'tracking [m]':<16}{'p50':>10}{'p95':>10}{'max':>10}")
        for name in ("horizontal_rms", "horizontal_max", "altitude_rms"):
            m = s["metrics"][name]
            lines.append(f"{name:<16}{f(m, 'p50'):>10}{f(m, 'p95'):>10}{f(m, 'max'):>10}")
    else:
        lines.append(
            f"{'channel':<10}{'settling p50':>14}{'p95':>10}{'max':>10}{'overshoot p95':>16}{'not settled':>13}"
        )
        for ch in ("altitude", "roll", "pitch", "yaw"):
            st, ov = s["metrics"][f"{ch}_settling_time"], s["metrics"][f"{ch}_overshoot_pct"]
            lines.append(f"{ch:<10}{f(st, 'p50'):>14}{f(st, 'p95'):>10}{f(st, 'max'):>10}"
                         f"{f(ov, 'p95', '.2f') + ' %':>16}{st['undefined']:>13}")  # fmt: skip
    if s["worst"]:
        w = s["worst"][0]
        params = ", ".join(f"{k} = {v:.4g}" for k, v in w["parameters"].items())
        what = (f"diverged at {w['diverged_at']:.3f} s" if w["diverged"] else "largest horizontal error" if tracked
                else "longest settling")  # fmt: skip
        lines.append(f"worst: trial {w['trial']} ({what}): {params}")
    return "\n".join(lines)


def add_sweep_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """The ``sweep`` command's parser, added to ``quadsitl``'s subcommands ``sub``."""
    sw = sub.add_parser(
        "sweep",
        help="Monte-Carlo sweep: many trials of the closed loop, batched on the compiled equations",
        epilog=EXAMPLES_SWEEP,
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description="Fly every trial of a sweep spec (what varies: plant, model mismatch, gains, initial state, "
        "references) on the batch engine and write trials.csv, trials.parquet, summary.json and figures (see "
        "docs/sweeps.md).",
    )
    sw.add_argument("spec", metavar="SPEC", help="a shipped spec's name (paper-mass-mismatch, ...) or a TOML file")
    sw.add_argument("--out", default="runs/sweep", metavar="DIR", help="output folder (default: runs/sweep)")
    sw.add_argument("--trials", type=int, metavar="N", help="number of trials (default: the spec's)")
    sw.add_argument("--controller", type=controller_name, metavar="NAME",
                    help=f"fly this controller instead of the spec's: {CONTROLLER_HELP}")  # fmt: skip
    sw.add_argument(
        "--workers", type=int, metavar="W",
        help="worker processes (default: one per core, or one per two cores with --engine sitl; 1: in this process)",
    )  # fmt: skip
    sw.add_argument(
        "--engine",
        choices=("batch", "sitl"),
        help="batch: the compiled batch engine (default: the "
        "spec's, else batch); sitl: every trial a whole `quadsitl fly` (plant, autopilot, ground station)",
    )
    sw.add_argument("--cluster", metavar="tcp://HOST:PORT", help="fly the chunks on the workers of a running Dask "
                    "scheduler instead (dask scheduler, dask worker: see docs/sweeps.md)")  # fmt: skip
    sw.add_argument("--chunk", type=int, metavar="N", help="trials per chunk (default: about four chunks per worker)")
    sw.add_argument("--keep", type=int, metavar="N", help="write the trajectories of the first N trials")
    sw.add_argument("--keep-trial", type=int, action="append", metavar="K", help="write trial K's trajectory "
                    "(repeatable)")  # fmt: skip
    sw.add_argument("--json", action="store_true", help="print summary.json on stdout (and nothing else)")
    sw.add_argument("--no-figures", action="store_true", help="skip the PNG figures")
    sw.add_argument("--quiet", "-q", action="store_true", help="print only errors")
    sw.set_defaults(func=cmd_sweep)
    return sw
