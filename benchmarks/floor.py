"""The machine's floor for a loop keeping time: what a loop that does nothing else misses.

A virtual machine's host takes a virtual CPU away for milliseconds at a time (its steal time), and a loop keeping
time at 1 kHz misses the periods that fall in those stalls, with nothing else running at all. The host stalls each
virtual CPU on its own: on a 2-core Firecracker guest, two bare loops pinned one to each core missed 0.27 % and
0.49 % of their periods, and 0.70 % missed on either (0.06 % on both). A vehicle of a fleet spans the cores (its
plant ticks on one, its autopilot answers on either), so it misses a period when either of them stalls: its floor
is the periods missed on *any* core, about the sum of the cores' and twice one loop's
(:func:`floor_on_every_core`).

``python -m benchmarks.floor --cpu C --ticks N [--fifo]`` is one core's loop (the processes
:func:`floor_on_every_core` starts): pinned to CPU ``C``, it prints ``ready``, reads the first period's time from
stdin (``time.monotonic()``, the same clock in every process of the machine), keeps time in periods of 1 ms from it,
and prints the indices of the periods it missed as one JSON list.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import socket
import subprocess
import sys
import time

from quadsitl.process_util import wait_readable
from quadsitl.timing import period_stats

FIFO_PRIORITY = 10  # SCHED_FIFO's priority for a fleet's processes, as `chrt -f 10 quadsitl up ...` gives them


def keep_time(ticks: int, period: float, start: float) -> list[float]:
    """Start times [s, ``time.monotonic()``] of ``ticks`` periods scheduled at ``start`` + k·``period``, keeping time
    as the plant's real-time loop does (absolute schedule, waiting for a datagram with
    :func:`quadsitl.process_util.wait_readable`) and doing nothing else."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", 0))
    starts: list[float] = []
    try:
        for k in range(ticks):
            while (remaining := start + k * period - time.monotonic()) > 0:
                wait_readable(sock, remaining)
            starts.append(time.monotonic())
    finally:
        sock.close()
    return starts


def bare_loop(ticks: int, period: float) -> dict:
    """One loop keeping time in this process (:func:`keep_time`) → :func:`quadsitl.timing.period_stats`."""
    return period_stats(keep_time(ticks, period, time.monotonic()), period)


def missed(starts: list[float], period: float, start: float) -> list[int]:
    """Indices of the periods that started a whole period or more after their scheduled time (start + k·period),
    as :func:`quadsitl.timing.period_stats` counts a deadline miss."""
    return [k for k, s in enumerate(starts) if s - (start + k * period) >= period]


def floor_on_every_core(ticks: int, fifo: bool = False, period: float = 0.001) -> dict:
    """One bare loop per CPU this process may use, each pinned to its CPU, all on one schedule, at once (a process
    each, under SCHED_FIFO at :data:`FIFO_PRIORITY` when ``fifo``). Returns ``per_core`` {cpu: miss ratio},
    ``any`` (the ratio of periods missed on at least one core: the floor of a fleet whose vehicles span the cores)
    and ``all`` (missed on every core at once: stalls of the whole machine). Raises RuntimeError naming the core
    whose loop failed (PermissionError's text for SCHED_FIFO without root or CAP_SYS_NICE) (:func:`combine`)."""
    cpus = sorted(os.sched_getaffinity(0))
    argv = ["--ticks", str(ticks), "--period", repr(period), *(["--fifo"] if fifo else [])]
    procs = {cpu: subprocess.Popen([sys.executable, "-m", "benchmarks.floor", "--cpu", str(cpu), *argv],
                                   stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
             for cpu in cpus}  # fmt: skip
    late: dict[int, set[int]] = {}
    try:
        for proc in procs.values():  # each pinned (and under FIFO) and waiting, before the schedule is set
            proc.stdout.readline()
        start = time.monotonic() + 0.05
        for proc in procs.values():
            with contextlib.suppress(OSError):  # a loop that failed to start: its status and stderr below say why
                proc.stdin.write(f"{start!r}\n")
                proc.stdin.flush()
        for cpu, proc in procs.items():
            out, err = proc.communicate(timeout=60 + 3 * ticks * period)
            if proc.returncode != 0:
                why = (err.strip().splitlines() or [f"exit status {proc.returncode}"])[-1]
                raise RuntimeError(f"the bare loop on CPU {cpu} failed: {why}")
            late[cpu] = set(json.loads(out))
    finally:
        for proc in procs.values():
            if proc.poll() is None:
                proc.kill()
                proc.wait()
    return combine(late, ticks)


def combine(late: dict[int, set[int]], ticks: int) -> dict:
    """The indices of the periods each core's loop missed ({cpu: indices}) over ``ticks`` periods → ``per_core``
    {cpu: miss ratio}, ``any`` (missed on at least one core) and ``all`` (missed on every core)."""
    return {
        "per_core": {cpu: len(k) / ticks for cpu, k in late.items()},
        "any": len(set.union(*late.values())) / ticks,
        "all": len(set.intersection(*late.values())) / ticks,
    }


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks.floor", description=__doc__.split("\n\n")[0])
    p.add_argument("--cpu", type=int, required=True)
    p.add_argument("--ticks", type=int, required=True)
    p.add_argument("--period", type=float, default=0.001)
    p.add_argument("--fifo", action="store_true")
    a = p.parse_args(argv)
    os.sched_setaffinity(0, {a.cpu})
    if a.fifo:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(FIFO_PRIORITY))
    print("ready", flush=True)
    start = float(sys.stdin.readline())  # the first period's time [s, time.monotonic()], common to every loop
    print(json.dumps(missed(keep_time(a.ticks, a.period, start), a.period, start)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
