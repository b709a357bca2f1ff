"""3. telemetry fan-out: 10 subscriber processes (:mod:`benchmarks.subscriber`; with ``--full`` also 1 and 3) on the
autopilot's Zenoh session: the lockstep tick rate with each, against none before and after them (``fanout_ratio_10``);
with ``--full`` the samples delivered per second, loss and latency at 1 kHz."""

from __future__ import annotations

import contextlib
import json
import signal
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path

from benchmarks.autopilots import autopilot_process, run_plant
from benchmarks.report import Report
from benchmarks.sections.base import Context, Section
from benchmarks.subscriber import loss_percent
from quadsitl.children import start_module, stop
from quadsitl.timing import percentile


@contextlib.contextmanager
def subscribers(endpoint: str, count: int, nice: int, workdir: Path, below: int = 0) -> Iterator[list[dict]]:
    """``count`` subscriber processes (:mod:`benchmarks.subscriber`) on ``endpoint``, counting the distinct ticks
    below ``below``; yields the list their results fill once they are stopped. Each one's stderr goes to a file in
    ``workdir``, quoted when it gives no result."""
    logs = [workdir / f"subscriber-{time.monotonic_ns()}-{i}.log" for i in range(count)]
    procs = []
    for log in logs:
        with log.open("w") as err:
            procs.append(start_module("benchmarks.subscriber", endpoint, "v1", str(nice), str(below),
                                      stdout=subprocess.PIPE, stderr=err, text=True))  # fmt: skip
    results: list[dict] = []
    failures: list[str] = []
    try:
        for p in procs:
            if p.stdout.readline().strip() != "ready":
                raise RuntimeError("a fan-out subscriber process did not start")
        time.sleep(0.5)  # let the sessions finish declaring
        yield results
    finally:
        for p in procs:
            if p.poll() is None:
                p.send_signal(signal.SIGTERM)
        for p, log in zip(procs, logs, strict=True):
            try:
                out, _ = p.communicate(timeout=20)
                results.append(json.loads(out.strip().splitlines()[-1]))
            except (subprocess.TimeoutExpired, ValueError, IndexError) as exc:
                stop(p, grace=0)
                why = "no result within 20 s of SIGTERM" if isinstance(exc, subprocess.TimeoutExpired) else \
                    f"exit status {p.returncode} and no result"  # fmt: skip
                tail = log.read_text(errors="replace").strip().splitlines()[-3:]
                failures.append(why + (f" ({' / '.join(tail)})" if tail else ""))
    if failures:  # never report loss and latency over the subscribers that happened to answer
        raise RuntimeError(f"{len(failures)} of {count} fan-out subscriber processes gave no result: {failures[0]}")


def bench_fanout(r: Report, workdir: Path, nice: int, counts: tuple[int, ...], paced: bool) -> float:
    """The lockstep's tick rate with ``counts`` subscriber processes at niceness ``nice``, as fast as possible and
    (``paced``) at 1 kHz (delivered samples, loss, latency) → the last count's tick rate over none's."""
    r.section(f"3. telemetry fan-out: subscriber processes (nice {nice}) on the autopilot's Zenoh session")
    # a few seconds each, many of a fast run's 100 ms batches: runs of 10,000 ticks read 0.5-0.9 by turns, of 50,000
    # 0.74-0.93 (docs/performance.md#fan-out)
    ticks_fast, ticks_paced = 200_000, 3000
    with autopilot_process(workdir) as (plant_port, api, endpoint, _pid):
        run_plant(plant_port, workdir, 5000, arm=api)  # warm-up
        first = run_plant(plant_port, workdir, ticks_fast, arm=api)["ticks_per_s"]
        rates, paced_runs = {}, {}
        for n in counts:
            with subscribers(endpoint, n, nice, workdir):
                rates[n] = run_plant(plant_port, workdir, ticks_fast, arm=api)["ticks_per_s"]
            if not paced:
                continue
            with subscribers(endpoint, n, nice, workdir, below=ticks_paced) as res:
                at_1khz = run_plant(plant_port, workdir, ticks_paced, "--speed", "1", arm=api)
                time.sleep(0.5)
            paced_runs[n] = (res, at_1khz)
        # the host's pace drifts by a fifth from one run to the next: the baseline is the mean of a run before the
        # subscribers' and one after
        last = run_plant(plant_port, workdir, ticks_fast, arm=api)["ticks_per_s"]
    alone = (first + last) / 2
    r.add("lockstep ticks, no subscriber", alone, "1/s (mean)")
    r.add("  no subscriber, before", first, "1/s")
    r.add("  no subscriber, after", last, "1/s")
    for n, rate in rates.items():
        r.add(f"lockstep ticks, {n} subscriber(s)", rate, "1/s", alone, "no subscriber")
        if n not in paced_runs:
            continue
        res, at_1khz = paced_runs[n]
        got = [sum(x["counts"].values()) for x in res]
        lat = sorted(v * 1e3 for x in res for v in x["latencies"])
        delivered = sum(got) / at_1khz["answered_wall_s"]  # from the first answer: before it, nothing flows
        r.add(f"  {n} sub: delivered samples at 1 kHz, all subs", delivered, "1/s", n * 4000.0, "4 streams x 1 kHz")
        r.add(f"  {n} sub: loss", loss_percent(res, ticks_paced), "% (worst; distinct ticks of the run)")
        r.add(f"  {n} sub: latency p50", percentile(lat, 50), "ms")
        r.add(f"  {n} sub: latency p99", percentile(lat, 99), "ms")
    return rates[counts[-1]] / alone


def run(ctx: Context) -> dict[str, object]:
    """The fan-out with subscribers at ``--subscriber-nice`` → ``fanout_ratio_10``: the lockstep's tick rate with ten
    of them over none's."""
    counts = (1, 3, 10) if ctx.full else (10,)  # the quick form: the goal's figure, not the delivery at 1 kHz
    return {"fanout_ratio_10": bench_fanout(ctx.report, ctx.work, ctx.args.subscriber_nice, counts, ctx.full)}


SECTION = Section("fanout", run)
