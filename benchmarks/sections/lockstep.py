"""1. lockstep: control ticks per second of the full ``quadsitl fly`` pipeline (plant and autopilot as processes,
MAVLink over UDP, Zenoh telemetry every tick, the ground station streaming setpoints and logging all telemetry)
against a bare UDP ping-pong between two Python processes with datagrams of the same sizes
(:mod:`benchmarks.pingpong`). ``lockstep_ratio`` = fly rate / the fastest ping-pong's rate. With ``--full``, also
``fly`` with polling off and on one core, and (1b.) the lockstep with a busy-looping process on the machine, polling
against blocking."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

from benchmarks import machine, pingpong
from benchmarks.autopilots import autopilot_process, run_plant
from benchmarks.report import Report, steal_since
from benchmarks.sections.base import Context, Section
from quadsitl.children import stop
from quadsitl.process_util import SPIN_ENV

BLOCKING = {**os.environ, SPIN_ENV: "0"}  # the environment that turns polling off (SpinThenBlock)


def fly_rate(seconds: float, workdir: Path, env: dict[str, str] | None = None, cpu: int | None = None) -> float:
    """Ticks per second of ``quadsitl fly`` (the flight itself, measured by its ground station); with ``cpu``, every
    process of the run on that one core (as ``taskset -c CPU quadsitl fly`` does)."""
    out = workdir / "fly"
    affinity = os.sched_getaffinity(0)
    try:
        if cpu is not None:  # the children inherit it
            os.sched_setaffinity(0, {cpu})
        subprocess.run([sys.executable, "-m", "groundstation.cli", "fly", "--preset", "paper", "--duration",
                        str(seconds), "--out", str(out), "--no-figures", "--quiet"],
                       check=True, timeout=120, env=env)  # fmt: skip
    finally:
        os.sched_setaffinity(0, affinity)
    return json.loads((out / "rate.json").read_text())["ticks_per_s"]


def bench_lockstep(r: Report, workdir: Path, rounds: int, full: bool) -> tuple[float, float, float]:
    """Interleaved rounds of the ping-pongs and of ``fly`` (``full``: also with polling off and on one core), the best
    of each → (fly's ticks per second, the blocking ping-pong's round trips per second, the fastest ping-pong's)."""
    r.section("1. lockstep loop (quadsitl fly, paper preset) against a bare UDP ping-pong")
    runs: dict[str, list[float]] = {}
    measures = [
        ("ping", pingpong.measure),
        ("ping polling", lambda: pingpong.measure(spin=True)),
        ("ping one core", lambda: pingpong.measure(cpu=0)),
        ("fly", lambda: fly_rate(10.0, workdir)),
    ]
    if full:
        measures += [
            ("fly blocking", lambda: fly_rate(10.0, workdir, BLOCKING)),
            ("fly one core", lambda: fly_rate(10.0, workdir, cpu=0)),
        ]
    for _ in range(rounds):  # interleaved, so that all see the same machine
        for name, measure in measures:
            runs.setdefault(name, []).append(measure())
    best = {name: max(values) for name, values in runs.items()}
    ping, fly = best["ping"], best["fly"]
    pings = {"blocking": ping, "polling": best["ping polling"], "one core": best["ping one core"]}
    floor_name, floor = max(pings.items(), key=lambda item: item[1])
    r.add("ping-pong round trips (blocking receive)", ping, "1/s")
    r.add("ping-pong, both sides polling (SpinThenBlock)", best["ping polling"], "1/s")
    r.add("ping-pong, both processes on one core", best["ping one core"], "1/s")
    r.add("fly ticks", fly, "1/s", floor, f"fastest ping-pong: {floor_name}")
    r.add("fly real-time factor at 1 kHz", fly / 1000.0, "x")
    r.add("fly ticks against the blocking ping-pong", fly, "1/s", ping, "blocking ping-pong")
    if full:
        r.add("fly ticks, polling off ($QUADSITL_SPIN_US=0)", best["fly blocking"], "1/s", floor, "fastest ping-pong")
        # Where waking a process on the other core is slow (a Firecracker guest), the whole run on one core can beat
        # the default; not where it is fast (docs/performance.md). Shown, so a user can tell which machine this is.
        r.add("fly ticks, every process on one core (taskset -c 0)", best["fly one core"], "1/s", fly, "fly")
    return fly, ping, floor


def bench_contention(r: Report, workdir: Path) -> None:
    """Polling only pays while plant and autopilot have a core each: with a CPU hog on the machine it must
    back off to blocking (SpinThenBlock's verdicts), not collapse."""
    r.section("1b. lockstep with a busy-looping process on the machine: polling (default) against blocking")
    hog = subprocess.Popen([sys.executable, "-c", "while True: pass"])
    try:
        rates = {}
        for name, env in (("polling", None), ("blocking", BLOCKING)):
            with autopilot_process(workdir, env) as (plant_port, api, _ep, _pid):
                run_plant(plant_port, workdir, 5000, env=env, arm=api)  # warm-up
                rates[name] = max(run_plant(plant_port, workdir, 10000, env=env, arm=api)["ticks_per_s"]
                                  for _ in range(2))  # fmt: skip
    finally:
        stop(hog, grace=0)
    r.add("plant + autopilot ticks, one CPU hog, blocking", rates["blocking"], "1/s")
    r.add("plant + autopilot ticks, one CPU hog, polling", rates["polling"], "1/s", rates["blocking"], "blocking")


def run(ctx: Context) -> dict[str, object]:
    """The lockstep against the ping-pongs (``ctx.ping`` and ``ctx.lockstep_ratio`` set for the sections after it),
    the hypervisor's steal time meanwhile, then the lockstep beside a CPU hog: ``lockstep_ratio_blocking`` (against
    the blocking ping-pong) and ``steal_lockstep``; the CPU hog with ``--full``."""
    before = machine.cpu_times()
    fly, ctx.ping, floor = bench_lockstep(ctx.report, ctx.work, ctx.args.rounds, ctx.full)
    ctx.lockstep_ratio = fly / floor
    out = {"lockstep_ratio_blocking": fly / ctx.ping, "steal_lockstep": steal_since(ctx.report, before)}
    if ctx.full:
        bench_contention(ctx.report, ctx.work)
    return out


SECTION = Section("lockstep", run)
