"""4. real-time mode at 1 kHz: period jitter and deadline misses of the plant's loop against a bare loop that keeps
time the same way and does nothing else (:func:`benchmarks.floor.bare_loop`)."""

from __future__ import annotations

from pathlib import Path

from benchmarks.autopilots import autopilot_process, run_plant
from benchmarks.floor import bare_loop
from benchmarks.report import Report
from benchmarks.sections.base import Context, Section


def bench_realtime(r: Report, workdir: Path, seconds: float) -> None:
    """The plant's real-time loop against the bare loop, each ``seconds`` long: jitter, lateness, deadline misses."""
    r.section(f"4. real-time mode at 1 kHz over {seconds:g} s: the plant's loop against a bare loop")
    ticks = round(seconds * 1000)
    bare = bare_loop(ticks, 0.001)
    with autopilot_process(workdir) as (plant_port, api, _ep, _pid):
        real = run_plant(plant_port, workdir, ticks, "--mode", "realtime", arm=api)
    for key, unit in (("jitter_p50_us", "us"), ("jitter_p99_us", "us"), ("jitter_max_us", "us"),
                      ("lateness_p50_us", "us"), ("lateness_p99_us", "us"), ("deadline_miss_ratio", "ratio"),
                      ("mean_period_us", "us")):  # fmt: skip
        ratio = real[key] / bare[key] if bare[key] else None
        r.add(f"real time: {key}", real[key], unit, bare[key], "bare loop", ratio=ratio)


def run(ctx: Context) -> dict[str, object]:
    """Runs of ``--realtime-seconds`` (3 s in the quick form, 10 with ``--full``); no keys of its own."""
    bench_realtime(ctx.report, ctx.work, ctx.args.realtime_seconds)
    return {}


SECTION = Section("realtime", run)
