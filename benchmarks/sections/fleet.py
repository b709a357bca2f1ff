"""7. fleets: N vehicles at once (their autopilots hosted in one process and one plant process on one clock, as ``up
--vehicles N --hosted``), growing N. In real time at 1 kHz, with the dashboard's page open when the machine has a
browser: the worst vehicle's
deadline-miss ratio (its tick started late, or its autopilot's answer missed the period) against one vehicle's, with
CPU (% of a core: per vehicle, each autopilot's, the plant's), memory per vehicle and the hypervisor's steal time
during the run; ``fleet_max_realtime`` is the largest N whose every vehicle misses under 1 % of its periods.

The machine's own floor comes first: a bare loop keeping time at 1 kHz and doing nothing else on each core at once,
and the hypervisor's steal time meanwhile (a virtual machine whose host takes a core for milliseconds at a time misses
periods with nothing running at all). The host stalls each core on its own and a vehicle spans the cores, so the floor
is the periods missed on any core (:mod:`benchmarks.floor`); ``fleet_max_realtime_over_floor`` is the largest N that
misses under 1 % more than that. Under SCHED_FIFO (``fleet_max_realtime_fifo``) the floor is the same loops under
SCHED_FIFO: there nothing on the machine delays a loop but the host itself, and the default-scheduled floor would
excuse misses a FIFO fleet makes. Where the cores can be kept out of slow idle states (``--cores-awake``: root), the
FIFO series and its floor run so (``fleet_fifo_cores_awake``): the set-up for real time on a virtual machine
(:mod:`benchmarks.scheduling`). Where SCHED_FIFO is permitted, the same loops also run beside each fleet, above it in
priority, and name the periods in which the host stalled a core; the worst vehicle's misses outside them are its own
(``fleet_max_realtime_own``, ``fleet_max_realtime_fifo_own``: the largest N that missed under 1 % of its periods
outside the host's stalls), and the sizes grow until that reaches 1 % (without those loops, until the misses beyond
the floor do). In lockstep, the fleet's ticks per second (all vehicles) against one vehicle's, hosted at each size
and with an autopilot process each at one (:func:`_fleet_lockstep`), and memory per vehicle.

The real-time series and its floors, every size and the fleet of processes run with ``--full``; the quick form is the
lockstep of one vehicle and of the largest fleet, hosted.
"""

from __future__ import annotations

import contextlib
import json
import subprocess
import sys
import time
from collections.abc import Sequence
from pathlib import Path

from benchmarks import machine
from benchmarks.autopilots import GRACE, HostedAutopilots, autopilot_process
from benchmarks.browser import missing as browser_missing
from benchmarks.floor import FIFO_PRIORITY, Stalls, floor_on_every_core, watching_every_core
from benchmarks.report import Report
from benchmarks.scheduling import awake_missing, cores_awake, fifo_missing, fifo_scheduling, raise_to_fifo
from benchmarks.sections.base import Context, Section
from benchmarks.sections.dashboard import dashboard_page
from quadsitl.children import stop
from quadsitl.process_util import rss_mb

PROCESSES_FLEET = 16  # --full's fleet of processes, beside the hosted ones (docs/fleets.md#hosted-autopilots: memory)


def fleet_run(n: int, workdir: Path, ticks: int, mode: str, browser: object | None = None, fifo: bool = False,
              awake: bool = False, hosted: bool = False) -> dict:  # fmt: skip
    """``n`` vehicles (an autopilot each and one plant process simulating all of them on one clock, as ``quadsitl up
    --vehicles N`` runs them, the paper preset) flying ``ticks`` ticks in ``mode`` (``realtime`` or ``lockstep``).
    The vehicles are not armed: an autopilot armed in hold on the ground idles (no control law) as a disarmed one
    does, and the law is a small part of a tick, so every tick costs what a flying one does, without a race
    to arm a short lockstep run before it ends. Returns the deadline-miss ratio of the fleet's clock (real time),
    the fleet's ticks per second (all vehicles' ticks over the wall time from the autopilots' first answers), and
    CPU [% of a core] and memory [MB] per vehicle (its autopilot and its share of the plant process), and the
    hypervisor's steal time over the run (:func:`benchmarks.machine.steal_ratio`). With a
    ``browser``, the dashboard watches every vehicle, its page open there (the fleet view, for several), as a user
    watching the fleet would have it; its CPU is not counted in the vehicles'. ``fifo``: the autopilots (raised to it
    once started: :func:`raise_to_fifo`) and the plant run under SCHED_FIFO (:func:`fifo_scheduling`); the
    dashboard does not (it runs at idle priority). ``awake``: every core is kept out of slow idle states while the
    fleet runs (:func:`cores_awake`, as ``--cores-awake``). ``hosted``: the autopilots in one process
    (:class:`benchmarks.autopilots.HostedAutopilots`, as ``up --hosted``); its CPU and memory are the vehicles'."""
    with contextlib.ExitStack() as stack:
        stack.enter_context(cores_awake(awake))
        # system ids 1..n, as `quadsitl up --vehicles N` gives them (each streams on ticks of its own), all started at
        # once and then waited for; under the default scheduler, and raised to SCHED_FIFO once started: N start-ups
        # (imports, compiled code loading) at FIFO priority would take both cores from everything else for seconds
        taken: set[int] = set()  # every autopilot's ports distinct, picked before any of them binds
        if hosted:
            host = HostedAutopilots(n, taken)
            stack.callback(stop, host.proc, GRACE)
            host.wait_ready()
            aps: list = host.vehicles
            ap_pids = [host.proc.pid]
        else:
            aps = [stack.enter_context(autopilot_process(workdir, system_id=i + 1, taken=taken, ready=False))
                   for i in range(n)]  # fmt: skip
            for ap in aps:
                ap.wait_ready()
            ap_pids = [ap.proc.pid for ap in aps]
        if fifo:
            for pid in ap_pids:
                raise_to_fifo(pid)
        if browser is not None:
            stack.enter_context(dashboard_page(browser, [endpoint for _, _, endpoint, _ in aps]))
        stats = workdir / f"fleet-{n}-{mode}-{time.monotonic_ns()}.json"
        ap_cpu0 = [machine.process_cpu_seconds(pid) for pid in ap_pids]
        argv = [sys.executable, "-m", "sitl", "--preset", "paper", "--ticks", str(ticks), "--stats", str(stats),
                "--mode", mode]  # fmt: skip
        for plant_port, _, _, _ in aps:
            argv += ["--autopilot", f"127.0.0.1:{plant_port}"]
        before = machine.cpu_times()
        # the host's stalls of each core while the fleet runs (real time, where SCHED_FIFO is permitted)
        watch = stack.enter_context(watching_every_core()) if mode == "realtime" and not fifo_missing() else None
        with fifo_scheduling(fifo):
            plant = subprocess.Popen(argv, stderr=subprocess.DEVNULL)
        try:
            rss = [rss_mb(pid) for pid in ap_pids]
            plant.wait()
            steal = machine.steal_ratio(before, machine.cpu_times())
            if plant.returncode != 0:
                raise RuntimeError(f"the fleet's plant exited with status {plant.returncode}")
            ap_cpu = sum(machine.process_cpu_seconds(pid) - c0 for pid, c0 in zip(ap_pids, ap_cpu0, strict=True))
        finally:
            stop(plant, grace=0)
    res = json.loads(stats.read_text())
    rss.append(res["peak_memory_mb"])  # the plant's own peak
    host = own_misses(res, watch) if watch is not None else None
    # CPU over the run itself: the plant's own count from its first tick to its last (its imports and compiled code
    # load are not a running fleet's cost); the autopilots idle until the plant starts.
    run_wall = max(res["wall_s"], 1e-9)
    return {
        "clock_miss_ratio": res.get("deadline_miss_ratio", 0.0),
        # a vehicle misses a period when its plant tick starts late (the fleet's clock) or when its autopilot's
        # answer does not come within it (the vehicle flies the previous command)
        "worst_miss_ratio": max([res.get("deadline_miss_ratio", 0.0), *res.get("answer_miss_ratios", [0.0])]),
        "answer_miss_ratios": res.get("answer_miss_ratios", []),
        "ticks_per_s": n * res["ticks_per_s"],  # the fleet's clock's ticks per second, once per vehicle
        "cpu_per_vehicle_pct": 100.0 * (ap_cpu + res["cpu_s"]) / run_wall / n,
        "cpu_per_autopilot_pct": 100.0 * ap_cpu / run_wall / n,  # the two parts of it: each autopilot's, ...
        "cpu_plant_pct": 100.0 * res["cpu_s"] / run_wall,  # ... and the one plant process's, for all n
        "memory_per_vehicle_mb": sum(rss) / n,
        # the host's share of the CPU over the run (its start and compiled code load too): a run that missed more
        # than the floor while the host took more than during the floor says more about the host than the fleet
        "steal_ratio": steal,
        # the periods a stall of any core touched (the loops watching each core above the fleet missed one), and the
        # worst vehicle's misses outside them: its own (None where SCHED_FIFO is not permitted)
        "host_stalled_ratio": host and host["stalled_ratio"],
        "worst_own_miss_ratio": host and host["worst_own_miss_ratio"],
    }


def own_misses(res: dict, watch: Stalls) -> dict:
    """A real-time fleet's plant statistics (``--stats``: each tick's due time and which missed) beside what the loops
    watching every core missed meanwhile → ``stalled_ratio``, the share of the fleet's periods a stall of a core
    touched (:meth:`benchmarks.floor.Stalls.of`), and ``worst_own_miss_ratio``, the worst vehicle's periods missed
    outside them (its tick late, or its answer) over all the fleet's periods."""
    ticks = max(res["ticks"], 1)
    stalled = {k for k in watch.of(res["clock_t0_s"], res["period_s"]) if k < ticks}
    clock = set(res["clock_late_ticks"])
    own = [len((clock | set(late)) - stalled) / ticks for late in res["answer_late_ticks"]]
    return {"stalled_ratio": len(stalled) / ticks, "worst_own_miss_ratio": max(own, default=0.0)}


def bench_fleet(r: Report, workdir: Path, sizes: Sequence[int], seconds: float, full: bool) -> dict:
    """The section (the module's docstring) over fleets of ``sizes`` vehicles, each run ``seconds`` long, the real-time
    runs with the dashboard's page open when this machine has Playwright and Chromium (said in the section's title);
    returns its keys of the JSON report. Without ``full``, the quick form: the lockstep of one vehicle and of the
    largest fleet of ``sizes``, hosted."""
    if not full:
        r.section(f"7. fleets in lockstep: one vehicle, and {sizes[-1]} hosted in one process (every size, a process "
                  "each, and the real-time series: --full)")  # fmt: skip
        return _fleet_lockstep(r, workdir, [sizes[-1]], round(4 * seconds * 1000), None)
    with contextlib.ExitStack() as stack:
        browser = None
        if browser_missing() is None:
            from benchmarks.browser import chromium

            browser = stack.enter_context(chromium())
        return _bench_fleet(r, workdir, sizes, seconds, browser)


def _floor(r: Report, ticks: int, fifo: bool, awake: bool = False) -> dict:
    """:func:`benchmarks.floor.floor_on_every_core` over ``ticks`` periods (``awake``: every core kept out of slow idle
    states meanwhile), with the steal time meanwhile, reported."""
    how = (f" under SCHED_FIFO {FIFO_PRIORITY}" if fifo else "") + (", cores awake" if awake else "")
    before = machine.cpu_times()
    with cores_awake(awake):
        floor = floor_on_every_core(ticks, fifo)
    steal = machine.steal_ratio(before, machine.cpu_times())
    for cpu, ratio in floor["per_core"].items():
        r.add(f"a bare loop keeping time at 1 kHz{how} on CPU {cpu}, one on each core, nothing else running: "
              "deadline-miss ratio", ratio, "ratio")  # fmt: skip
    r.add(f"the bare loops{how}: periods missed on any core (the floor{' under FIFO' if fifo else ''})", floor["any"],
          "ratio")  # fmt: skip
    r.add(f"the bare loops{how}: periods missed on every core at once", floor["all"], "ratio")
    r.add(f"the hypervisor's steal time meanwhile{how} (CPU time the host took)", steal, "ratio")
    return floor


def _bench_fleet(r: Report, workdir: Path, sizes: Sequence[int], seconds: float, browser: object | None) -> dict:
    """:func:`bench_fleet` with ``browser`` (None: no dashboard watches)."""
    watched = "the dashboard open in headless Chromium"
    if browser is None:
        watched = f"no dashboard: {browser_missing()}"
    r.section(f"7. fleets: N vehicles at once, hosted in one process (up --hosted), {seconds:g} s at 1 kHz in real "
              f"time ({watched}), then in lockstep")  # fmt: skip
    ticks = round(seconds * 1000)
    out: dict[str, object] = {"fleet_dashboard_open": browser is not None}
    # The machine's floor, in this run: what keeping time costs with nothing else running. On a virtual machine the
    # host takes each core away for milliseconds at a time, on its own: a vehicle spans the cores (its plant on one,
    # its autopilot on either), so its floor is the periods missed on any core (benchmarks.floor), about the sum of
    # the cores'. No fleet can miss fewer periods than that.
    floors = {False: _floor(r, ticks, fifo=False)}
    out["fleet_floor_miss_ratio"] = floors[False]["any"]
    out["fleet_floor_miss_ratios_per_core"] = list(floors[False]["per_core"].values())
    why_not_fifo = fifo_missing()
    # the real-time set-up for a virtual machine: SCHED_FIFO, and the cores kept out of slow idle states (a halted
    # virtual CPU is a thread its host must wake and schedule again), as `chrt -f 10 quadsitl up --cores-awake ...`
    why_not_awake = awake_missing() if why_not_fifo is None else None
    awake = why_not_fifo is None and why_not_awake is None
    out["fleet_fifo_cores_awake"] = awake
    for fifo, key, how in ((False, "fleet_max_realtime", "default scheduling"),
                           (True, "fleet_max_realtime_fifo",
                            f"SCHED_FIFO {FIFO_PRIORITY}{', cores awake' if awake else ''}")):  # fmt: skip
        if fifo and why_not_fifo:
            r.add(f"real time under SCHED_FIFO: not measured: {why_not_fifo}", 0, "")
            out[key] = out[f"{key}_over_floor"] = out[f"{key}_own"] = None
            continue
        if fifo and why_not_awake:  # FIFO without the cores kept awake (CAP_SYS_NICE, but not root): say why
            r.add(f"real time under SCHED_FIFO: the cores not kept awake: {why_not_awake}", 0, "")
        if fifo:  # the floor of loops that nothing on the machine preempts: only the host delays them
            floors[True] = _floor(r, ticks, fifo=True, awake=awake)
            out["fleet_floor_miss_ratio_fifo"] = floors[True]["any"]
            out["fleet_floor_miss_ratios_per_core_fifo"] = list(floors[True]["per_core"].values())
        floor = floors[fifo]["any"]
        one = fleet_run(1, workdir, ticks, "realtime", browser, fifo, fifo and awake, hosted=True)
        largest = largest_over_floor = largest_own = 0
        kept = kept_over_floor = kept_own = True
        for n in sizes:
            rt = one if n == 1 else fleet_run(n, workdir, ticks, "realtime", browser, fifo, fifo and awake, hosted=True)
            r.add(f"fleet of {n}, real time, {how}: worst vehicle's deadline-miss ratio", rt["worst_miss_ratio"],
                  "ratio", one["worst_miss_ratio"], "one vehicle", ratio=None)  # fmt: skip
            r.add(f"fleet of {n}, real time, {how}: the clock's deadline-miss ratio (ticks started a period late)",
                  rt["clock_miss_ratio"], "ratio", one["clock_miss_ratio"], "one vehicle", ratio=None)  # fmt: skip
            r.add(f"fleet of {n}, real time, {how}: CPU per vehicle", rt["cpu_per_vehicle_pct"], "% of a core")
            r.add(f"fleet of {n}, real time, {how}: CPU of each autopilot (mean)", rt["cpu_per_autopilot_pct"],
                  "% of a core")  # fmt: skip
            r.add(f"fleet of {n}, real time, {how}: CPU of the plant process (all vehicles)", rt["cpu_plant_pct"],
                  "% of a core")  # fmt: skip
            r.add(f"fleet of {n}, real time, {how}: best vehicle's deadline-miss ratio",
                  min(rt["answer_miss_ratios"], default=0.0), "ratio")  # fmt: skip
            r.add(f"fleet of {n}, real time, {how}: memory per vehicle", rt["memory_per_vehicle_mb"], "MB")
            r.add(f"fleet of {n}, real time, {how}: the hypervisor's steal time meanwhile", rt["steal_ratio"], "ratio")
            beyond, own = rt["worst_miss_ratio"] - floor, rt["worst_own_miss_ratio"]
            r.add(f"fleet of {n}, real time, {how}: worst vehicle's deadline-miss ratio beyond the floor", beyond,
                  "ratio")  # fmt: skip
            if own is not None:  # the loops watching each core, above the fleet: which periods the host took
                r.add(f"fleet of {n}, real time, {how}: periods in which the host stalled a core (loops watching "
                      "each core above the fleet missed them)", rt["host_stalled_ratio"], "ratio")  # fmt: skip
                r.add(f"fleet of {n}, real time, {how}: worst vehicle's deadline-miss ratio outside the host's "
                      "stalls (its own)", own, "ratio")  # fmt: skip
            # the largest size that kept under 1 %, this size and every smaller one: the criterion, beyond
            # the floor measured before, and outside the host's stalls measured during
            kept = kept and rt["worst_miss_ratio"] < 0.01
            kept_over_floor = kept_over_floor and beyond < 0.01
            kept_own = kept_own and own is not None and own < 0.01
            largest = n if kept else largest
            largest_over_floor = n if kept_over_floor else largest_over_floor
            largest_own = n if kept_own else largest_own
            if (own if own is not None else beyond) >= 0.01:
                break  # the next sizes would miss more
        out[key], out[f"{key}_over_floor"] = largest, largest_over_floor
        out[f"{key}_own"] = largest_own if one["worst_own_miss_ratio"] is not None else None
    each = max([n for n in sizes if n <= PROCESSES_FLEET] or [1])  # a few seconds at several times real time:
    return out | _fleet_lockstep(r, workdir, sizes, 4 * ticks, each)


def _fleet_lockstep(r: Report, workdir: Path, sizes: Sequence[int], ticks: int, each: int | None) -> dict[str, object]:
    """One vehicle (its own autopilot process), then fleets of ``sizes`` vehicles in lockstep for ``ticks`` ticks,
    their autopilots hosted in one process (``up --hosted``), and (``each``) a fleet of that many with an autopilot
    process each: each fleet's ticks per second (all vehicles) against one vehicle's, and memory per vehicle → for the
    largest hosted fleet ``fleet_lockstep_size``, ``fleet_lockstep_ratio``, ``fleet_memory_per_vehicle_mb``, and for
    the processes ``fleet_processes_size``, ``fleet_processes_lockstep_ratio``,
    ``fleet_processes_memory_per_vehicle_mb``."""
    one = fleet_run(1, workdir, ticks, "lockstep")
    r.add("one vehicle, lockstep: ticks (plant + autopilot, no ground station)", one["ticks_per_s"], "1/s")
    hosted = one
    for n in sizes:
        hosted = fleet_run(n, workdir, ticks, "lockstep", hosted=True)
        r.add(f"fleet of {n}, lockstep, hosted (up --hosted): ticks of all vehicles", hosted["ticks_per_s"], "1/s",
              one["ticks_per_s"], "one vehicle")  # fmt: skip
    n = sizes[-1]
    r.add(f"fleet of {n}, lockstep, hosted: memory per vehicle", hosted["memory_per_vehicle_mb"], "MB")
    out: dict[str, object] = {"fleet_lockstep_size": n, "fleet_lockstep_ratio": hosted["ticks_per_s"] / one[
        "ticks_per_s"], "fleet_memory_per_vehicle_mb": hosted["memory_per_vehicle_mb"]}  # fmt: skip
    if each is None:
        return out
    processes = fleet_run(each, workdir, ticks, "lockstep")
    r.add(f"fleet of {each}, lockstep, an autopilot process each: ticks of all vehicles", processes["ticks_per_s"],
          "1/s", one["ticks_per_s"], "one vehicle")  # fmt: skip
    r.add(f"fleet of {each}, lockstep, an autopilot process each: memory per vehicle",
          processes["memory_per_vehicle_mb"], "MB", hosted["memory_per_vehicle_mb"], f"{n} hosted")  # fmt: skip
    return out | {"fleet_processes_size": each,
                  "fleet_processes_lockstep_ratio": processes["ticks_per_s"] / one["ticks_per_s"],
                  "fleet_processes_memory_per_vehicle_mb": processes["memory_per_vehicle_mb"]}  # fmt: skip


def run(ctx: Context) -> dict[str, object]:
    """Fleets of ``--fleet-sizes`` vehicles, each run ``--fleet-seconds`` long (:func:`bench_fleet`; the real-time
    series with ``--full``)."""
    return bench_fleet(ctx.report, ctx.work, ctx.sizes, ctx.args.fleet_seconds, ctx.full)


SECTION = Section("fleet", run)
