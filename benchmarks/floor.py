"""The machine's floor for a loop keeping time: what a loop that does nothing else misses, and when.

A virtual machine's host takes a virtual CPU away for milliseconds at a time (its steal time), and a loop keeping
time at 1 kHz misses the periods that fall in those stalls, with nothing else running at all. The host stalls each
virtual CPU on its own: bare loops pinned one to each core miss different periods, and few at once on both
(docs/fleets.md). A vehicle of a fleet spans the cores (its plant ticks on one, its autopilot answers on either),
so it misses a period when either of them stalls:

- its floor is the periods missed on *any* core, about the sum of the cores' and twice one loop's
  (:func:`floor_on_every_core`, before a fleet runs);
- and while a fleet runs, the same loops beside it, above it in SCHED_FIFO priority (:data:`WATCH_PRIORITY`), say
  which of its periods the host stalled a core in (:func:`watching_every_core`, :meth:`Stalls.of`): nothing on the
  machine delays them but the host (and the kernel), so a fleet's miss in any other period is its own.

``python -m benchmarks.floor --cpu C [--ticks N] [--priority P]`` is one core's loop (the processes both start):
pinned to CPU ``C`` (under SCHED_FIFO at ``P``), it prints ``ready``, reads the first period's time from stdin
(``time.monotonic()``, the same clock in every process of the machine), keeps time in periods of 1 ms from it for
``N`` periods, or until a line or the end of stdin comes, and prints ``{"ticks": n, "late": [k, ...]}``: how many
periods it kept and which it missed.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import IO

from quadsitl.children import stop_all
from quadsitl.process_util import timers_on_time, wait_readable
from quadsitl.timing import late_periods, period_stats

FIFO_PRIORITY = 10  # SCHED_FIFO's priority for a fleet's processes, as `chrt -f 10 quadsitl up ...` gives them
WATCH_PRIORITY = 20  # the loops that watch a fleet: above its processes (the plant's clock takes FIFO_PRIORITY + 1)


def keep_time(ticks: int | None, period: float, start: float, until: IO | None = None) -> list[float]:
    """Start times [s, ``time.monotonic()``] of the periods scheduled at ``start`` + k·``period``, keeping time as the
    plant's real-time loop does (absolute schedule, waiting for a datagram with
    :func:`quadsitl.process_util.wait_readable`) and doing nothing else: ``ticks`` of them, or (``ticks`` None) as
    many as come before ``until`` (a file, stdin) has something to read. Its timers fire on time as the plant's do
    (:func:`quadsitl.process_util.timers_on_time`)."""
    timers_on_time()
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", 0))
    waited = until if until is not None else sock
    starts: list[float] = []
    try:
        while ticks is None or len(starts) < ticks:
            while (remaining := start + len(starts) * period - time.monotonic()) > 0:
                if wait_readable(waited, remaining) and until is not None:
                    return starts
            starts.append(time.monotonic())
    finally:
        sock.close()
    return starts


def bare_loop(ticks: int, period: float) -> dict:
    """One loop keeping time in this process (:func:`keep_time`) → :func:`quadsitl.timing.period_stats`."""
    return period_stats(keep_time(ticks, period, time.monotonic()), period)


@dataclass
class Stalls:
    """What the loops on every core missed: their periods ran at ``start`` + j·``period`` [s, ``time.monotonic()``],
    ``ticks`` of them; ``late`` {cpu: the j each missed}."""

    start: float
    period: float
    ticks: int
    late: dict[int, set[int]] = field(default_factory=dict)

    def ratios(self) -> dict:
        """``per_core`` {cpu: miss ratio}, ``any`` (the ratio of periods missed on at least one core: the floor of a
        fleet whose vehicles span the cores) and ``all`` (missed on every core at once: stalls of the whole
        machine)."""
        n = max(self.ticks, 1)
        return {
            "per_core": {cpu: len(j) / n for cpu, j in self.late.items()},
            "any": len(set().union(*self.late.values())) / n,
            "all": len(set.intersection(*self.late.values())) / n if self.late else 0.0,
        }

    def of(self, t0: float, period: float) -> set[int]:
        """The periods k of another loop (due at ``t0`` + k·``period``) that a stall of any core overlapped. A loop
        that missed its period j did not wake at its due time, nor before its end: its core was taken over all of
        it, so the periods of the other loop that overlap it are the host's."""
        stalled: set[int] = set()
        for j in set().union(*self.late.values()):  # its span, in the other loop's periods from t0
            begin, end = ((self.start + i * self.period - t0) / period for i in (j, j + 1))
            stalled.update(range(math.floor(begin + 1e-9), math.ceil(end - 1e-9)))
        return {k for k in stalled if k >= 0}


def _start_loops(ticks: int | None, priority: int | None, period: float) -> dict[int, subprocess.Popen]:
    """One loop per CPU this process may use (``python -m benchmarks.floor``), each pinned to its CPU and ready."""
    argv = ["--period", repr(period)]
    argv += ["--ticks", str(ticks)] if ticks is not None else []
    argv += ["--priority", str(priority)] if priority is not None else []
    procs = {cpu: subprocess.Popen([sys.executable, "-m", "benchmarks.floor", "--cpu", str(cpu), *argv],
                                   stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
             for cpu in sorted(os.sched_getaffinity(0))}  # fmt: skip
    try:
        for proc in procs.values():  # each pinned (and under FIFO) and waiting, before the schedule is set
            proc.stdout.readline()
    except BaseException:  # interrupted: no loop left behind
        stop_all(procs.values(), grace=0)
        raise
    return procs


def _write(proc: subprocess.Popen, line: str) -> None:
    with contextlib.suppress(OSError):  # a loop that failed to start: its status and stderr say why
        proc.stdin.write(line)
        proc.stdin.flush()


def _collect(procs: dict[int, subprocess.Popen], stalls: Stalls, timeout: float) -> None:
    """Each loop's result into ``stalls`` (its ``ticks``: the fewest any loop kept); RuntimeError naming the core
    whose loop failed."""
    results = {}
    for cpu, proc in procs.items():
        out, err = proc.communicate(timeout=timeout)
        if proc.returncode != 0:
            why = (err.strip().splitlines() or [f"exit status {proc.returncode}"])[-1]
            raise RuntimeError(f"the bare loop on CPU {cpu} failed: {why}")
        results[cpu] = json.loads(out)
    stalls.ticks = min(r["ticks"] for r in results.values())  # the periods every loop kept
    stalls.late = {cpu: {j for j in r["late"] if j < stalls.ticks} for cpu, r in results.items()}


def floor_on_every_core(ticks: int, fifo: bool = False, period: float = 0.001) -> dict:
    """One bare loop per CPU this process may use, each pinned to its CPU, all on one schedule, at once (a process
    each, under SCHED_FIFO at :data:`FIFO_PRIORITY` when ``fifo``), nothing else running → :meth:`Stalls.ratios`.
    Raises RuntimeError naming the core whose loop failed (PermissionError's text for SCHED_FIFO without root or
    CAP_SYS_NICE)."""
    procs = _start_loops(ticks, FIFO_PRIORITY if fifo else None, period)
    try:
        stalls = Stalls(time.monotonic() + 0.05, period, ticks)
        for proc in procs.values():
            _write(proc, f"{stalls.start!r}\n")
        _collect(procs, stalls, timeout=60 + 3 * ticks * period)
    finally:
        stop_all(procs.values(), grace=0)
    return stalls.ratios()


@contextlib.contextmanager
def watching_every_core(period: float = 0.001) -> Iterator[Stalls]:
    """While entered, one loop per core keeps time under SCHED_FIFO at :data:`WATCH_PRIORITY`, above any fleet's
    processes; on leaving, the :class:`Stalls` yielded holds what they missed (RuntimeError naming the core whose
    loop failed: SCHED_FIFO needs root or CAP_SYS_NICE). Each costs its core a wake-up per period."""
    procs = _start_loops(None, WATCH_PRIORITY, period)
    try:
        stalls = Stalls(time.monotonic() + 0.05, period, 0)
        for proc in procs.values():
            _write(proc, f"{stalls.start!r}\n")
        yield stalls
        for proc in procs.values():
            _write(proc, "stop\n")
        _collect(procs, stalls, timeout=30)
    finally:
        stop_all(procs.values(), grace=0)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks.floor", description=__doc__.split("\n\n")[0])
    p.add_argument("--cpu", type=int, required=True)
    p.add_argument("--ticks", type=int, help="periods to keep (default: until a line or the end of stdin)")
    p.add_argument("--period", type=float, default=0.001)
    p.add_argument("--priority", type=int, help="SCHED_FIFO at this priority (default: the default scheduler)")
    a = p.parse_args(argv)
    os.sched_setaffinity(0, {a.cpu})
    if a.priority is not None:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(a.priority))
    print("ready", flush=True)
    start = float(sys.stdin.readline())  # the first period's time [s, time.monotonic()], common to every loop
    starts = keep_time(a.ticks, a.period, start, sys.stdin if a.ticks is None else None)
    print(json.dumps({"ticks": len(starts), "late": late_periods(starts, a.period, start)}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
