"""The machine's floor for a fleet (benchmarks.floor): one bare loop per core on one schedule, and the periods missed
on any of them."""

import json
import os
import shutil
import signal
import subprocess
import sys
import time

import pytest

from benchmarks.floor import WATCH_PRIORITY, Stalls, floor_on_every_core, watching_every_core
from quadsitl.timing import late_periods


def test_a_period_is_missed_when_it_starts_a_whole_period_late():
    start, period = 100.0, 0.001
    starts = [100.0, 100.0019, 100.0031, 100.0045, 100.0040]  # late by 0, 0.9, 1.1, 1.5 and 0 ms
    assert late_periods(starts, period, start) == [2, 3]


def test_the_floor_of_a_fleet_is_the_periods_missed_on_any_core():
    got = Stalls(0.0, 0.001, 100, {0: {3, 7, 9}, 1: {7, 20}}).ratios()
    assert got == {"per_core": {0: 0.03, 1: 0.02}, "any": 0.04, "all": 0.01}
    assert Stalls(0.0, 0.001, 10, {0: set()}).ratios() == {"per_core": {0: 0.0}, "any": 0.0, "all": 0.0}


def test_a_stall_is_set_beside_the_periods_of_another_loop_that_it_touched():
    # the watching loops' period j spans [100 + j ms, 100 + (j + 1) ms]; the fleet's k [100.0004 + k ms, ...]
    stalls = Stalls(100.0, 0.001, 50, {0: {10}, 1: {11, 30}})
    assert stalls.of(100.0004, 0.001) == {9, 10, 11, 29, 30}  # j = 10 touches k = 9 and 10, j = 11 k = 10 and 11, ...
    assert stalls.of(100.0, 0.002) == {5, 15}  # a loop of 2 ms periods: j = 10 and 11 both inside its k = 5
    assert stalls.of(100.0, 0.001) == {10, 11, 30}  # periods that line up: one each
    assert Stalls(100.0, 0.001, 50, {0: {0}}).of(100.0015, 0.001) == set()  # before the other loop began: none
    assert Stalls(100.0, 0.001, 50, {0: set(), 1: set()}).of(100.0, 0.001) == set()


def test_one_loop_per_core_reports_each_core_and_their_union():
    got = floor_on_every_core(300)
    assert sorted(got["per_core"]) == sorted(os.sched_getaffinity(0))
    per_core = got["per_core"].values()
    assert 0.0 <= got["all"] <= min(per_core) <= max(per_core) <= got["any"] <= min(1.0, sum(per_core)) + 1e-12


def test_a_stalled_loop_misses_the_periods_of_its_stall_and_only_those():
    """One core's loop stopped (SIGSTOP) for 40 ms, as a host stalling its virtual CPU would: it misses those
    periods, on its own schedule."""
    ticks = 1000  # 1 s: the stall falls inside it even when this test wakes a few hundred ms late (a loaded machine)
    cpu = str(min(os.sched_getaffinity(0)))
    loop = subprocess.Popen([sys.executable, "-m", "benchmarks.floor", "--cpu", cpu, "--ticks", str(ticks)],
                            stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)  # fmt: skip
    try:
        assert loop.stdout.readline() == "ready\n"
        start = time.monotonic() + 0.05
        loop.stdin.write(f"{start!r}\n")
        loop.stdin.flush()
        time.sleep(max(0.0, start + 0.150 - time.monotonic()))
        loop.send_signal(signal.SIGSTOP)
        stopped = time.monotonic()
        time.sleep(0.040)
        resumed = time.monotonic()
        loop.send_signal(signal.SIGCONT)
        out, _ = loop.communicate(timeout=30)
    finally:
        loop.kill()
        loop.wait()
    assert loop.returncode == 0
    late = json.loads(out)["late"]
    # the periods due while it was stopped, but for one at each end (when exactly the signals took effect)
    due = [k for k in range(ticks) if stopped + 0.001 < start + k * 0.001 < resumed - 0.001]
    assert len(due) >= 37 and due[-1] < ticks - 1, (stopped - start, resumed - start)
    assert len(set(due) & set(late)) >= len(due) - 1, late  # it missed them (a scheduler's slack for one)
    assert all(late.count(k) == 1 for k in late) and late == sorted(late) and max(late) < ticks


@pytest.mark.skipif(os.geteuid() != 0 or shutil.which("setpriv") is None, reason="needs root and setpriv")
def test_under_fifo_without_the_right_to_it_the_floor_says_which_core_and_why():
    code = ("from benchmarks.floor import floor_on_every_core\n"
            "try:\n    floor_on_every_core(100, fifo=True)\nexcept RuntimeError as e:\n    print(e)\n")  # fmt: skip
    r = subprocess.run(["setpriv", "--inh-caps=-sys_nice", "--bounding-set=-sys_nice", sys.executable, "-c", code],
                       capture_output=True, text=True, timeout=60)  # fmt: skip
    cpu = min(os.sched_getaffinity(0))
    assert r.stdout.strip() == f"the bare loop on CPU {cpu} failed: PermissionError: [Errno 1] Operation not permitted"


@pytest.mark.skipif(os.geteuid() != 0, reason="SCHED_FIFO needs root (or CAP_SYS_NICE)")
def test_the_loops_watching_every_core_run_above_a_fleet_for_as_long_as_it_does():
    before = time.monotonic()
    with watching_every_core() as stalls:
        policies = {}
        for pid in _children_running("benchmarks.floor"):
            policy = os.sched_getscheduler(pid), os.sched_getparam(pid).sched_priority
            policies[pid] = (*policy, os.sched_getaffinity(pid))
        time.sleep(0.4)
    after = time.monotonic()
    assert sorted(stalls.late) == sorted(os.sched_getaffinity(0))
    assert before < stalls.start < before + 5
    assert 300 <= stalls.ticks <= (after - stalls.start) / 0.001 + 1  # kept time until told to stop
    assert all(j < stalls.ticks for late in stalls.late.values() for j in late)
    # one per core, each pinned to its own, under SCHED_FIFO above the fleet's processes
    assert sorted(policies.values(), key=lambda p: sorted(p[2])) == [
        (os.SCHED_FIFO, WATCH_PRIORITY, {cpu}) for cpu in sorted(os.sched_getaffinity(0))
    ]


def _children_running(module: str) -> list[int]:
    """The pids of this process's children whose command line runs ``module``."""
    found = []
    for pid in os.listdir("/proc"):
        if not pid.isdigit():
            continue
        try:
            with open(f"/proc/{pid}/stat") as f:
                ppid = int(f.read().rsplit(")", 1)[1].split()[1])
            with open(f"/proc/{pid}/cmdline", "rb") as f:
                cmdline = f.read().split(b"\0")
        except OSError:
            continue
        if ppid == os.getpid() and module.encode() in cmdline:
            found.append(int(pid))
    return found


def test_a_fleets_own_misses_are_those_outside_the_periods_the_host_stalled():
    from benchmarks.sections.fleet import own_misses

    # the fleet's clock 0.4 ms after the watching loops' schedule; a core stalled over their period 10: the fleet's
    # periods 9 and 10 are the host's
    res = {"ticks": 100, "clock_t0_s": 100.0004, "period_s": 0.001, "clock_late_ticks": [9, 50],
           "answer_late_ticks": [[9, 10, 11, 60], [50]]}  # fmt: skip
    got = own_misses(res, Stalls(100.0, 0.001, 100, {0: {10}, 1: set()}))
    # vehicle 1: its late 11 and 60 and the clock's 50; vehicle 2: the clock's 50 (a late tick is late for every one)
    assert got == {"stalled_ratio": 0.02, "worst_own_miss_ratio": 0.03}
