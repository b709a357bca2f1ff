"""``quadsitl bench [--json]``: the speed of the SITL against this machine's own limits.

Every figure is printed next to a baseline measured in the same run, because absolute times on shared
machines drift:

1. lockstep: control ticks per second of the full ``quadsitl fly`` pipeline (plant and autopilot as
   processes, MAVLink over UDP, Zenoh telemetry every tick, the ground station streaming setpoints and
   logging all telemetry) against a bare UDP ping-pong between two Python processes with datagrams of the
   same sizes. ``lockstep_ratio`` = fly rate / ping-pong rate.
2. per-tick costs [µs]: controller steps, plant steps, encode and decode of the two per-tick messages
   (ours and pymavlink's), Zenoh publish; against the ping-pong round trip.
3. telemetry fan-out: 1, 3 and 10 subscriber processes on the autopilot's Zenoh session; delivered
   samples per second, loss and latency at 1 kHz, and the lockstep tick rate with each, against none.
4. real-time mode at 1 kHz: period jitter and deadline misses of the plant's loop against a bare loop
   that keeps time the same way and does nothing else.
5. the dashboard: lockstep tick rate with its page open in headless Chromium against without
   (``dashboard_ratio``, ``dashboard_ratio_10x``). It needs Playwright (the test extra) and Debian's Chromium;
   without them it is skipped with one line saying what is missing, and the JSON has no dashboard figures
   and says why under ``skipped`` (:data:`OPTIONAL`).
6. the sweeps' batch engine: vehicle-steps per second of ``quadsitl sweep``'s engine (the paper's controller and
   plant, 5 s trials), in one process and over one worker process per core, against ``quadsitl sim``'s compiled
   loop of the whole vehicle on the same step; and that loop on the x500's circle (``sim_circle_steps_per_s``).
7. fleets: N vehicles at once (N autopilot processes and one plant process on one clock, as ``up --vehicles N``),
   growing N. In real time at 1 kHz, with the dashboard's page open when the machine has a browser: the worst
   vehicle's deadline-miss ratio (its tick started late, or its autopilot's answer missed the period) against one
   vehicle's, with CPU (% of a core: per vehicle, each autopilot's, the plant's), memory per vehicle and the
   hypervisor's steal time during the run;
   ``fleet_max_realtime`` is the largest N whose every vehicle misses under 1 % of its periods. The machine's own
   floor comes first: a bare loop keeping time at 1 kHz and doing nothing else on each core at once, and the
   hypervisor's steal time meanwhile (a virtual machine whose host takes a core for milliseconds at a time misses
   periods with nothing running at all). The host stalls each core on its own and a vehicle spans the cores, so the
   floor is the periods missed on any core (:mod:`benchmarks.floor`); ``fleet_max_realtime_over_floor`` is the
   largest N that misses under 1 % more than that. Under SCHED_FIFO (``fleet_max_realtime_fifo``) the floor is the
   same loops under SCHED_FIFO: there nothing on the machine delays a loop but the host itself, and the
   default-scheduled floor would excuse misses a FIFO fleet makes. Where the cores can be kept out of slow idle states
   (``--cores-awake``: root), the FIFO series and its floor run so (``fleet_fifo_cores_awake``): the set-up for real
   time on a virtual machine. Where SCHED_FIFO is permitted, the same loops
   also run beside each fleet, above it in priority, and name the periods in which the host stalled a core; the
   worst vehicle's misses outside them are its own (``fleet_max_realtime_own``, ``fleet_max_realtime_fifo_own``:
   the largest N that missed under 1 % of its periods outside the host's stalls), and the sizes grow until that
   reaches 1 % (without those loops, until the misses beyond the floor do). In lockstep, the fleet's ticks per
   second (all vehicles) against one vehicle's.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import time
import timeit
from collections.abc import Callable, Iterator, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

from benchmarks import machine, pingpong
from benchmarks.browser import missing as browser_missing
from benchmarks.floor import FIFO_PRIORITY, Stalls, bare_loop, floor_on_every_core, watching_every_core
from quadsitl.cli_util import UsageError
from quadsitl.process_util import SPIN_ENV, free_port, hold_cores_awake, stop_status
from quadsitl.timing import percentile


@dataclass
class Figure:
    name: str
    value: float
    unit: str
    baseline: float | None = None
    baseline_name: str = ""
    ratio: float | None = None


class Report:
    def __init__(self, quiet: bool) -> None:
        self.figures: list[Figure] = []
        self.quiet = quiet

    def add(self, name: str, value: float, unit: str, baseline: float | None = None, baseline_name: str = "",
            ratio: float | None = None) -> Figure:  # fmt: skip
        if ratio is None and baseline:
            ratio = value / baseline
        f = Figure(name, value, unit, baseline, baseline_name, ratio)
        self.figures.append(f)
        if not self.quiet:
            base = f"   baseline {baseline:,.6g} ({baseline_name})" if baseline is not None else ""
            rat = f"   ratio {ratio:.3g}" if ratio is not None else ""
            print(f"  {name:46s} {value:>12,.6g} {unit:10s}{base}{rat}", file=sys.stderr, flush=True)
        return f

    def section(self, title: str) -> None:
        if not self.quiet:
            print(f"\n{title}", file=sys.stderr, flush=True)


def _python(*args: str, **kw) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", *args], **kw)


def _stop(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(5)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


# ---- 1. the lockstep pipeline ------------------------------------------------------------------------


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


def bench_lockstep(r: Report, workdir: Path, rounds: int) -> tuple[float, float]:
    r.section("1. lockstep loop (quadsitl fly, paper preset) against a bare UDP ping-pong")
    runs: dict[str, list[float]] = {}
    for _ in range(rounds):  # interleaved, so that all see the same machine
        for name, measure in (
            ("ping", pingpong.measure),
            ("ping polling", lambda: pingpong.measure(spin=True)),
            ("ping one core", lambda: pingpong.measure(cpu=0)),
            ("fly", lambda: fly_rate(10.0, workdir)),
            ("fly blocking", lambda: fly_rate(10.0, workdir, BLOCKING)),
            ("fly one core", lambda: fly_rate(10.0, workdir, cpu=0)),
        ):
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
    r.add("fly ticks, polling off ($QUADSITL_SPIN_US=0)", best["fly blocking"], "1/s", floor, "fastest ping-pong")
    # Where waking a process on the other core is slow (a Firecracker guest: 130-210 us), the whole run on one core
    # can beat the default; not where it is fast (docs/performance.md). Shown, so a user can tell which machine this is.
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
        hog.kill()
        hog.wait()
    r.add("plant + autopilot ticks, one CPU hog, blocking", rates["blocking"], "1/s")
    r.add("plant + autopilot ticks, one CPU hog, polling", rates["polling"], "1/s", rates["blocking"], "blocking")


def bench_cold_start(r: Report, workdir: Path) -> None:
    """The compiler's cost, paid once: a short ``quadsitl fly`` with numba's cache empty (as right after
    installing, or after any change to the equations), then the same again with the cache it left."""
    r.section("0. cold start: quadsitl fly --duration 1, end to end, with numba's cache empty and then filled")
    env = {**os.environ, "NUMBA_CACHE_DIR": str(workdir / "numba-cache")}
    walls = []
    for _ in range(2):
        start = time.monotonic()
        subprocess.run([sys.executable, "-m", "groundstation.cli", "fly", "--preset", "paper", "--duration", "1",
                        "--out", str(workdir / "cold"), "--no-figures", "--quiet"], check=True, timeout=600,
                       env=env)  # fmt: skip
        walls.append(time.monotonic() - start)
    r.add("first run after install (compiles)", walls[0], "s")
    r.add("second run (from numba's cache)", walls[1], "s", walls[0], "first run")


def compile_first() -> None:
    """The equations into numba's cache before the first timed section, as ``quadsitl up`` does before a fleet: on
    an empty cache (right after installing, or after any change to the equations) the first autopilot would
    otherwise spend its start compiling (a minute or more on a 2-core guest) and miss the bench's wait for its
    heartbeat. A second or so from the cache."""
    from groundstation.launcher import compile_once
    from groundstation.progress import announce_if_slow

    with announce_if_slow("quadsitl bench: compiling the equations first (numba's cache keeps them)", after=3.0):
        compile_once(None)


# ---- 2. per-tick costs ---------------------------------------------------------------------------------


def per_tick(fn: Callable[[], object], number: int = 20000) -> float:
    return min(timeit.repeat(fn, number=number, repeat=3)) / number * 1e6


def call_costs(compiled: bool) -> dict[str, float]:
    """benchmarks.costs in a process of its own: the compiled functions, or (``compiled`` False) the same
    source as ordinary Python (NUMBA_DISABLE_JIT=1)."""
    env = {**os.environ, "NUMBA_DISABLE_JIT": "0" if compiled else "1"}
    out = subprocess.run([sys.executable, "-m", "benchmarks.costs"], check=True, timeout=300, env=env,
                         capture_output=True, text=True).stdout  # fmt: skip
    return json.loads(out.strip().splitlines()[-1])


def bench_costs(r: Report, ping: float) -> None:
    import zenoh

    from quadsitl import telemetry

    r.section("2. per-call costs from Python: compiled (quadsitl.jit) against the same source as plain Python")
    compiled, python = call_costs(True), call_costs(False)
    for name, us in compiled.items():
        r.add(name, us, "us", python[name], "plain Python")
    rtt = 1e6 / ping
    session = zenoh.open(telemetry.zenoh_config("peer", listen=[f"tcp/127.0.0.1:{free_port(socket.SOCK_STREAM)}"]))
    try:
        pubs = [session.declare_publisher(telemetry.key("bench", s), congestion_control=zenoh.CongestionControl.DROP)
                for s in telemetry.STREAMS]  # fmt: skip
        payloads = [bytes(f.size) for f in telemetry.STREAMS.values()]

        def publish() -> None:
            for pub, payload in zip(pubs, payloads):
                pub.put(payload)

        r.add("Zenoh publish, 4 streams, no subscriber", per_tick(publish), "us", rtt, "round trip")
        for pub in pubs:
            pub.undeclare()
    finally:
        session.close()


# ---- 3. telemetry fan-out ---------------------------------------------------------------------------


class StartedAutopilot:
    """An autopilot process on free ports (:func:`autopilot_process`); unpacks as (plant port, api port, Zenoh
    endpoint, process id)."""

    def __init__(self, env: dict[str, str] | None, system_id: int, taken: set[int],
                 extra: tuple[str, ...] = ()) -> None:  # fmt: skip
        self.env, self.system_id, self.taken, self.extra = env, system_id, taken, extra
        self.attempts = 0
        self.start()

    def start(self) -> None:
        picks = []
        for kind in (socket.SOCK_DGRAM, socket.SOCK_DGRAM, socket.SOCK_STREAM):
            picks.append(free_port(kind, avoid=self.taken))
            self.taken.add(picks[-1])
        self.plant_port, self.api_port, zenoh_port = picks
        self.endpoint = f"tcp/127.0.0.1:{zenoh_port}"
        self.proc = _python("autopilot", "--preset", "paper", "--plant-listen", f"127.0.0.1:{self.plant_port}",
                            "--api-listen", f"127.0.0.1:{self.api_port}", "--api-remote", "none", "--gcs-listen",
                            "127.0.0.1:0", "--gcs-remote", "none", "--zenoh-listen", self.endpoint, "--system-id",
                            str(self.system_id), *self.extra, env=self.env)  # fmt: skip
        self.attempts += 1

    def __iter__(self) -> Iterator:
        return iter((self.plant_port, self.api_port, self.endpoint, self.proc.pid))

    def wait_ready(self, timeout: float = 60.0) -> None:
        """Until it answers a ground station's heartbeat (started and warmed up). One that exits first is started
        again on other ports, up to START_ATTEMPTS times in all: another process (a test beside the bench) may
        bind a picked port before the autopilot does ("Address already in use")."""
        while True:
            try:
                _wait_heartbeat(self.api_port, timeout, alive=lambda: self.proc.poll() is None)
                return
            except AutopilotExitedError:
                if self.attempts >= START_ATTEMPTS:
                    raise RuntimeError(f"the autopilot exited with status {self.proc.returncode} while starting, "
                                       f"{self.attempts} times, each on other ports") from None  # fmt: skip
                self.start()


START_ATTEMPTS = 3


class AutopilotExitedError(RuntimeError):
    """The autopilot's process ended before it answered a heartbeat."""


@contextlib.contextmanager
def autopilot_process(workdir: Path, env: dict[str, str] | None = None, system_id: int = 1,
                      taken: set[int] | None = None, ready: bool = True,
                      extra: tuple[str, ...] = ()) -> Iterator[StartedAutopilot]:  # fmt: skip
    """An autopilot on free ports, unpacking as (plant port, api port, Zenoh endpoint, its process id), and with
    ``ready`` started and warmed up (:meth:`StartedAutopilot.wait_ready`; else call it before its ports are used: a
    fleet's start together). :func:`run_plant` with the api port arms it in hold at the start of each run, as a
    ground station would. (On the ground an autopilot armed in hold idles, as PX4's does, so the control law
    itself, about 1 µs of a ~100 µs tick, does not run.) ``taken``: ports picked for processes that may not have
    bound them yet (a fleet's other autopilots), never picked here; this one's are added to it. ``extra``: more of
    the autopilot's options."""
    ap = StartedAutopilot(env, system_id, set() if taken is None else taken, extra)
    try:
        if ready:
            ap.wait_ready()
        yield ap
    finally:
        _stop(ap.proc)


class RunEndedUnarmedError(RuntimeError):
    """A plant run ended before its autopilot accepted the arm command (a short lockstep run is a fraction of a
    second)."""


def _arm_in_hold(api_port: int, plant: subprocess.Popen) -> None:
    """Arm the autopilot in hold while ``plant`` runs (arming needs a vehicle state; a run that ended left the
    plant-link failsafe in land, so hold first). Each run starts disarmed-then-armed within its first ms."""
    from pymavlink import mavutil

    os.environ.setdefault("MAVLINK20", "1")
    gcs = mavutil.mavlink_connection(f"udpout:127.0.0.1:{api_port}", source_system=255, dialect="common")
    try:
        end = time.monotonic() + 30
        while time.monotonic() < end and plant.poll() is None:
            gcs.mav.command_long_send(1, 1, 176, 0, 1, 4, 3, 0, 0, 0, 0)  # DO_SET_MODE auto/loiter
            gcs.mav.command_long_send(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0)
            deadline = time.monotonic() + 0.02  # again soon: refused until the first state (a run is 10k ticks/s+)
            while time.monotonic() < deadline:
                ack = gcs.recv_match(type="COMMAND_ACK", blocking=True, timeout=0.005)
                if ack is not None and ack.command == 400 and ack.result == 0:
                    return
        if plant.poll() is not None:
            raise RunEndedUnarmedError(f"the plant's run ended (status {plant.returncode}) before the autopilot armed")
        raise RuntimeError("the autopilot did not arm within 30 s")
    finally:
        gcs.close()


def run_plant(plant_port: int, workdir: Path, ticks: int, *extra: str, env: dict[str, str] | None = None,
              arm: int | None = None) -> dict:  # fmt: skip
    """A plant run of ``ticks`` against the autopilot at ``plant_port``; with ``arm`` (its api port), armed in hold
    as the run starts (a run that ended before the autopilot armed, seen once in a fan-out warm-up of 5000 ticks,
    is run again, once). Returns the plant's statistics."""
    try:
        return _run_plant(plant_port, workdir, ticks, *extra, env=env, arm=arm)
    except RunEndedUnarmedError:
        return _run_plant(plant_port, workdir, ticks, *extra, env=env, arm=arm)


def _run_plant(plant_port: int, workdir: Path, ticks: int, *extra: str, env: dict[str, str] | None,
               arm: int | None) -> dict:  # fmt: skip
    stats = workdir / f"plant-{time.monotonic_ns()}.json"
    plant = subprocess.Popen([sys.executable, "-m", "sitl", "--preset", "paper", "--autopilot",
                              f"127.0.0.1:{plant_port}", "--ticks", str(ticks), "--stats", str(stats), *extra],
                             stderr=subprocess.DEVNULL, env=env)  # fmt: skip
    try:
        if arm is not None:
            _arm_in_hold(arm, plant)
        if plant.wait(120) != 0:
            raise RuntimeError(f"the plant exited with status {plant.returncode}")
    finally:
        if plant.poll() is None:
            plant.kill()
            plant.wait()
    return json.loads(stats.read_text())


@contextlib.contextmanager
def subscribers(endpoint: str, count: int, nice: int, workdir: Path) -> Iterator[list[dict]]:
    """``count`` subscriber processes (:mod:`benchmarks.subscriber`) on ``endpoint``; yields the list their results
    fill once they are stopped. Each one's stderr goes to a file in ``workdir``, quoted when it gives no result."""
    logs = [workdir / f"subscriber-{time.monotonic_ns()}-{i}.log" for i in range(count)]
    procs = []
    for log in logs:
        with log.open("w") as err:
            procs.append(_python("benchmarks.subscriber", endpoint, "v1", str(nice), stdout=subprocess.PIPE,
                                 stderr=err, text=True))  # fmt: skip
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
                p.kill()
                p.wait()
                why = "no result within 20 s of SIGTERM" if isinstance(exc, subprocess.TimeoutExpired) else \
                    f"exit status {p.returncode} and no result"  # fmt: skip
                tail = log.read_text(errors="replace").strip().splitlines()[-3:]
                failures.append(why + (f" ({' / '.join(tail)})" if tail else ""))
    if failures:  # never report loss and latency over the subscribers that happened to answer
        raise RuntimeError(f"{len(failures)} of {count} fan-out subscriber processes gave no result: {failures[0]}")


def bench_fanout(r: Report, workdir: Path, nice: int) -> None:
    r.section(f"3. telemetry fan-out: subscriber processes (nice {nice}) on the autopilot's Zenoh session")
    ticks_fast, ticks_paced = 10000, 3000
    with autopilot_process(workdir) as (plant_port, api, endpoint, _pid):
        run_plant(plant_port, workdir, 5000, arm=api)  # warm-up
        alone = run_plant(plant_port, workdir, ticks_fast, arm=api)["ticks_per_s"]
        r.add("lockstep ticks, no subscriber", alone, "1/s")
        for n in (1, 3, 10):
            with subscribers(endpoint, n, nice, workdir):
                rate = run_plant(plant_port, workdir, ticks_fast, arm=api)["ticks_per_s"]
            r.add(f"lockstep ticks, {n} subscriber(s)", rate, "1/s", alone, "no subscriber")
            with subscribers(endpoint, n, nice, workdir) as res:
                paced = run_plant(plant_port, workdir, ticks_paced, "--speed", "1", arm=api)
                time.sleep(0.5)
            expected = 4 * ticks_paced
            got = [sum(x["counts"].values()) for x in res]
            lat = sorted(v * 1e3 for x in res for v in x["latencies"])
            delivered = sum(got) / paced["answered_wall_s"]  # from the first answer: before it, nothing flows
            r.add(f"  {n} sub: delivered samples at 1 kHz, all subs", delivered, "1/s", n * 4000.0, "4 streams x 1 kHz")
            r.add(f"  {n} sub: loss", 100.0 * (1 - min(got, default=0) / expected), "% (worst)")
            r.add(f"  {n} sub: latency p50", percentile(lat, 50), "ms")
            r.add(f"  {n} sub: latency p99", percentile(lat, 99), "ms")


# ---- 5. the dashboard ------------------------------------------------------------------------------------


@contextlib.contextmanager
def dashboard_page(browser, endpoint: str | Sequence[str]) -> Iterator[object]:
    """``quadsitl dashboard`` on the autopilots' Zenoh sessions (an endpoint, or several), its page open in
    ``browser``."""
    port = free_port(socket.SOCK_STREAM)
    connect = [a for e in ([endpoint] if isinstance(endpoint, str) else endpoint) for a in ("--zenoh-connect", e)]
    dash = _python("groundstation.dashboard.server", "--port", str(port), *connect, "--quiet")
    page = browser.new_page(viewport={"width": 1400, "height": 1100})
    try:
        end = time.monotonic() + 20
        while True:
            try:
                page.goto(f"http://127.0.0.1:{port}/")
                break
            except Exception:  # Playwright's error while the server is still starting
                if time.monotonic() > end or dash.poll() is not None:
                    raise RuntimeError("the dashboard did not start") from None
                time.sleep(0.2)
        page.wait_for_function("() => quadsitl.updates > 0", timeout=20000)  # connected to the stream
        time.sleep(0.5)  # a page that is open, not one that is loading
        yield page
    finally:
        page.close()
        _stop(dash)


def bench_dashboard(r: Report, workdir: Path, rounds: int) -> dict:
    """Lockstep tick rate with the dashboard serving an open page against the same run without it, in
    pairs run back to back (the dashboard and its page start afresh each time; the browser, with no page
    open, stays: an idle Chromium costs a lockstep nothing, measured): as fast as possible, and paced at 10×
    real time (a run one watches). The figures are medians of the pairs' ratios: a lockstep that polls on
    both cores varies by ±15 % from run to run on a shared VM, and pairing and the median keep that drift
    out of the comparison."""
    from benchmarks.browser import chromium
    from groundstation.launcher import LOGGED

    r.section("5. dashboard: lockstep ticks with the page open in headless Chromium, against without")
    out = {}
    # The autopilot as `fly` starts it: its telemetry blocks on a full link (a page that can hold it back)
    with autopilot_process(workdir, extra=LOGGED) as (plant_port, api, endpoint, _pid), chromium() as browser:
        run_plant(plant_port, workdir, 5000, arm=api)  # warm-up
        for label, key, pairs, ticks, extra in (
            # Runs of a few seconds: a page updates once a second while a run goes faster than 2x real time
            ("as fast as possible", "dashboard_ratio", 2 * rounds + 1, 60000, ()),
            ("paced at 10x real time", "dashboard_ratio_10x", rounds + 1, 20000, ("--speed", "10")),
        ):
            alone, watched, redraws = [], [], 0
            for _ in range(pairs):
                alone.append(run_plant(plant_port, workdir, ticks, *extra, arm=api)["ticks_per_s"])
                with dashboard_page(browser, endpoint) as page:
                    watched.append(run_plant(plant_port, workdir, ticks, *extra, arm=api)["ticks_per_s"])
                    seen = page.evaluate("() => ({redraws: quadsitl.redraws, lastT: quadsitl.lastT})")
                # A paced page that saw nothing would measure nothing. As fast as possible, the lockstep pair
                # polls on both cores and the dashboard (SCHED_IDLE by design) may draw only once it is over.
                if extra and (not seen["redraws"] or not seen["lastT"]):
                    raise RuntimeError(f"the dashboard page drew no telemetry during the run: {seen}")
                redraws += seen["redraws"]
            out[key] = statistics.median(w / a for w, a in zip(watched, alone))
            r.add(f"lockstep ticks, {label}, no dashboard (median)", statistics.median(alone), "1/s")
            r.add(f"  with the page open (median of {pairs} pairs' ratios)", statistics.median(watched), "1/s",
                  statistics.median(alone), "no dashboard", ratio=out[key])  # fmt: skip
            r.add("  page redraws during those runs", redraws, "")
    return out


# ---- 4. real time ---------------------------------------------------------------------------------------


def bench_realtime(r: Report, workdir: Path, seconds: float) -> None:
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


# ---- 6. the sweeps' batch engine ------------------------------------------------------------------------


def bench_batch(r: Report, trials: int) -> dict:
    """Vehicle-steps per second of the sweeps' batch engine on the paper's controller and plant (the
    paper-mass-mismatch spec: the paper's step, ±20 % mass and inertia mismatch, 5 s per trial), in this process
    and over one worker process per core, against ``quadsitl sim``'s loop of the whole vehicle
    (:mod:`groundstation.vehicle`: the autopilot's tick and the plant's, compiled) on the same step, measured in
    the same run; that loop on the x500's circle (position loop and limits, truth, calm air), and on its sensors
    (the x500-wind-hold spec's hold, through the estimator), beside that spec's sweep."""
    from groundstation.offline import run_offline
    from groundstation.sweep.run import fly, run_sweep, warm_up
    from groundstation.sweep.spec import load_spec, trial_preset
    from quadsitl.config import load_preset

    r.section("6. sweeps: the batch engine (paper's controller and plant) against quadsitl sim's vehicle loop")
    spec = load_spec("paper-mass-mismatch")
    warm_up()
    x500 = load_preset("x500")
    run_offline(spec.preset, ["backstepping"], 0.01)  # compiled, or loaded from the cache, before timing
    run_offline(x500, ["backstepping"], 0.01, trajectory="circle")

    def sim_rate(preset, seconds: float, trajectory: str) -> tuple[float, float]:
        """(the flight's steps/s in the compiled loop alone, end to end: the vehicle built, the setpoints made)"""
        flight = []
        start = time.perf_counter()
        run_offline(preset, ["backstepping"], seconds, progress=lambda s: flight.append(time.perf_counter()),
                    trajectory=trajectory)  # fmt: skip
        ticks = round(seconds / preset.sim.period)
        return ticks / (flight[-1] - flight[0]), ticks / (time.perf_counter() - start)

    scalar = max(sim_rate(spec.preset, 5.0, "step") for _ in range(3))
    circle = max(sim_rate(x500, 27.5, "circle") for _ in range(3))
    wind = load_spec("x500-wind-hold")  # on sensors, through the estimator, in wind: each trial a sim flight
    hold = max(sim_rate(trial_preset(wind, 0), wind.duration, wind.trajectory) for _ in range(2))
    one = []
    n = max(trials // 8, 50)
    for _ in range(3):
        start = time.perf_counter()
        fly(spec, range(n))
        one.append(n * spec.ticks / (time.perf_counter() - start))
    workers = os.cpu_count() or 1
    big = spec.with_trials(trials)
    start = time.perf_counter()
    result = run_sweep(big, workers=workers)
    wall = time.perf_counter() - start
    many = result.ticks_flown / result.wall_s  # the flights, workers started and warm: what `quadsitl sweep` reports
    sensed = run_sweep(wind, workers=workers)
    r.add("quadsitl sim's vehicle loop, paper step", scalar[0], "steps/s", scalar[1], "end to end")
    r.add("quadsitl sim's vehicle loop, x500 circle (truth, calm)", circle[0], "steps/s", circle[1], "end to end")
    r.add("batch engine, this process", max(one), "steps/s", scalar[0], "sim's vehicle loop")
    r.add(f"batch engine, {workers} worker processes ({trials} trials)", many, "steps/s", max(one), "one process")
    r.add(f"  {trials} trials of 5 s: the flights / end to end with the workers' start", result.wall_s, "s", wall,
          "end to end")  # fmt: skip
    r.add("quadsitl sim's vehicle loop, x500-wind-hold's trial 0 (sensors, wind)", hold[0], "steps/s", hold[1],
          "end to end")  # fmt: skip
    r.add(f"sweep on sensors, {workers} workers (x500-wind-hold, {wind.trials} trials)",
          sensed.ticks_flown / sensed.wall_s, "steps/s", hold[0], "sim's loop")  # fmt: skip
    return {"batch_steps_per_s": many, "batch_steps_per_s_one_process": max(one), "scalar_steps_per_s": scalar[0],
            "sim_circle_steps_per_s": circle[0], "sim_circle_steps_per_s_end_to_end": circle[1],
            "sim_sensors_steps_per_s": hold[0],
            "sensor_sweep_steps_per_s": sensed.ticks_flown / sensed.wall_s}  # fmt: skip


# ---- the command ----------------------------------------------------------------------------------------


# Sections that need something a user's install may lack (``pip install -e .`` has no test extra, and
# Chromium is a Debian package): section -> (the function that says what is missing, or None, and the JSON
# keys it would have written). Such a section is skipped with one line saying what is missing and how to get
# it; its figures are absent from the report (not zero), which says why under "skipped"; the rest runs.
OPTIONAL: dict[str, tuple[Callable[[], str | None], tuple[str, ...]]] = {
    "dashboard": (browser_missing, ("dashboard_ratio", "dashboard_ratio_10x")),
}

# ---- 7. fleets ---------------------------------------------------------------------------------------------


def _rss_mb(pid: int) -> float:
    """Resident memory [MB] of a live process (``/proc/PID/status``)."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024.0
    return 0.0


def _wait_heartbeat(api_port: int, timeout: float = 60.0, alive: Callable[[], bool] | None = None) -> None:
    """Until the autopilot on ``api_port`` answers a ground station's heartbeat with its own (it is started and
    warmed up), so that a real-time plant's ticks are not spent waiting for an autopilot still starting;
    :class:`AutopilotExitedError` as soon as ``alive()`` says its process has gone."""
    from pymavlink import mavutil

    os.environ.setdefault("MAVLINK20", "1")
    gcs = mavutil.mavlink_connection(f"udpout:127.0.0.1:{api_port}", source_system=255, dialect="common")
    try:
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if alive is not None and not alive():
                raise AutopilotExitedError(f"the autopilot on port {api_port} exited while starting")
            gcs.mav.heartbeat_send(6, 8, 0, 0, 0)  # MAV_TYPE_GCS, MAV_AUTOPILOT_INVALID
            if gcs.recv_match(type="HEARTBEAT", blocking=True, timeout=0.2) is not None:
                return
        raise RuntimeError(f"no heartbeat from the autopilot on port {api_port} in {timeout:g} s")
    finally:
        gcs.close()


@contextlib.contextmanager
def fifo_scheduling(enabled: bool) -> Iterator[None]:
    """While entered (and ``enabled``), this process runs under SCHED_FIFO at FIFO_PRIORITY, so the processes it
    starts inherit it, as under ``chrt -f``; PermissionError without root or CAP_SYS_NICE."""
    if not enabled:
        yield
        return
    policy, param = os.sched_getscheduler(0), os.sched_getparam(0)
    os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(FIFO_PRIORITY))
    try:
        yield
    finally:
        os.sched_setscheduler(0, policy, param)


def raise_to_fifo(pid: int) -> None:
    """Every thread of process ``pid`` to SCHED_FIFO at FIFO_PRIORITY (threads it starts later inherit it)."""
    for tid in os.listdir(f"/proc/{pid}/task"):
        with contextlib.suppress(ProcessLookupError):  # a thread that has just ended
            os.sched_setscheduler(int(tid), os.SCHED_FIFO, os.sched_param(FIFO_PRIORITY))


def fifo_missing() -> str | None:
    """Why this machine cannot run a fleet under SCHED_FIFO (one line), or None when it can."""
    try:
        with fifo_scheduling(True):
            return None
    except (PermissionError, AttributeError, OSError) as exc:
        return f"SCHED_FIFO is not permitted here ({exc}): it needs root or CAP_SYS_NICE"


@contextlib.contextmanager
def cores_awake(enabled: bool) -> Iterator[None]:
    """While entered (and ``enabled``), every core is kept out of slow idle states, as ``quadsitl up --cores-awake``
    keeps them (:func:`quadsitl.process_util.hold_cores_awake`); UsageError where that is refused."""
    if not enabled:
        yield
        return
    fd = hold_cores_awake()
    try:
        yield
    finally:
        os.close(fd)


def awake_missing() -> str | None:
    """Why this machine cannot keep its cores awake for a fleet (one line), or None when it can."""
    try:
        with cores_awake(True):
            return None
    except UsageError as exc:
        return str(exc)


def fleet_run(n: int, workdir: Path, ticks: int, mode: str, browser: object | None = None, fifo: bool = False,
              awake: bool = False) -> dict:  # fmt: skip
    """``n`` vehicles (an autopilot each and one plant process simulating all of them on one clock, as ``quadsitl up
    --vehicles N`` runs them, the paper preset) flying ``ticks`` ticks in ``mode`` (``realtime`` or ``lockstep``).
    The vehicles are not armed: an autopilot armed in hold on the ground idles (no control law) as a disarmed one
    does, and the law is about 1 µs of a tick's ~100 µs, so every tick costs what a flying one does, without a race
    to arm a short lockstep run before it ends. Returns the deadline-miss ratio of the fleet's clock (real time),
    the fleet's ticks per second (all vehicles' ticks over the wall time from the autopilots' first answers), and
    CPU [% of a core] and memory [MB] per vehicle (its autopilot and its share of the plant process), and the
    hypervisor's steal time over the run (:func:`benchmarks.machine.steal_ratio`). With a
    ``browser``, the dashboard watches every vehicle, its page open there (the fleet view, for several), as a user
    watching the fleet would have it; its CPU is not counted in the vehicles'. ``fifo``: the autopilots (raised to it
    once started: :func:`raise_to_fifo`) and the plant run under SCHED_FIFO (:func:`fifo_scheduling`); the
    dashboard does not (it runs at idle priority). ``awake``: every core is kept out of slow idle states while the
    fleet runs (:func:`cores_awake`, as ``--cores-awake``)."""
    with contextlib.ExitStack() as stack:
        stack.enter_context(cores_awake(awake))
        # system ids 1..n, as `quadsitl up --vehicles N` gives them (each streams on ticks of its own), all started at
        # once and then waited for; under the default scheduler, and raised to SCHED_FIFO once started: N start-ups
        # (imports, compiled code loading) at FIFO priority would take both cores from everything else for seconds
        taken: set[int] = set()  # every autopilot's ports distinct, picked before any of them binds
        aps = [stack.enter_context(autopilot_process(workdir, system_id=i + 1, taken=taken, ready=False))
               for i in range(n)]  # fmt: skip
        for ap in aps:
            ap.wait_ready()
            if fifo:
                raise_to_fifo(ap.proc.pid)
        ap_pids = [ap.proc.pid for ap in aps]
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
            rss = [_rss_mb(pid) for pid in ap_pids]
            _, status, usage = os.wait4(plant.pid, 0)  # reaped here, with its peak memory
            steal = machine.steal_ratio(before, machine.cpu_times())
            plant.returncode = os.waitstatus_to_exitcode(status)
            if plant.returncode != 0:
                raise RuntimeError(f"the fleet's plant exited with status {plant.returncode}")
            rss.append(usage.ru_maxrss / 1024.0)
            ap_cpu = sum(machine.process_cpu_seconds(pid) - c0 for pid, c0 in zip(ap_pids, ap_cpu0, strict=True))
        finally:
            if plant.poll() is None:
                plant.kill()
                plant.wait()
    res = json.loads(stats.read_text())
    host = own_misses(res, watch) if watch is not None else None
    # CPU over the run itself: the plant's own count from its first tick to its last (its imports and compiled code
    # load, about a second of CPU, are not a running fleet's cost); the autopilots idle until the plant starts.
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


def bench_fleet(r: Report, workdir: Path, sizes: Sequence[int], seconds: float) -> dict:
    """See the module's docstring (7.); the real-time runs with the dashboard's page open when this machine has
    Playwright and Chromium (said in the section's title)."""
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
    watched = "the dashboard open in headless Chromium"
    if browser is None:
        watched = f"no dashboard: {browser_missing()}"
    r.section(f"7. fleets: N vehicles at once, {seconds:g} s at 1 kHz in real time ({watched}), then in lockstep")
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
        one = fleet_run(1, workdir, ticks, "realtime", browser, fifo, fifo and awake)
        largest = largest_over_floor = largest_own = 0
        kept = kept_over_floor = kept_own = True
        for n in sizes:
            rt = one if n == 1 else fleet_run(n, workdir, ticks, "realtime", browser, fifo, fifo and awake)
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
    lockstep_ticks = 4 * ticks  # a few seconds at several times real time
    one_ls = fleet_run(1, workdir, lockstep_ticks, "lockstep")
    for n in sizes:
        ls = one_ls if n == 1 else fleet_run(n, workdir, lockstep_ticks, "lockstep")
        r.add(f"fleet of {n}, lockstep: ticks of all vehicles (plant + autopilot, no ground station)",
              ls["ticks_per_s"], "1/s", one_ls["ticks_per_s"], "one vehicle")  # fmt: skip
    return out


def optional_parts_missing(parts: Sequence[str]) -> dict[str, str]:
    """{section: what it lacks and how to get it} for each of ``parts`` that cannot run on this machine."""
    return {part: why for part in parts if part in OPTIONAL and (why := OPTIONAL[part][0]())}


PARTS = ("coldstart", "lockstep", "costs", "fanout", "realtime", "dashboard", "batch", "fleet")


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="quadsitl bench",
        description="Measure the SITL's speed against baselines taken in the same run on this machine.",
        epilog="examples:\n  quadsitl bench\n  quadsitl bench --json > bench.json\n  quadsitl bench --only lockstep",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--json", action="store_true", help="print every figure as JSON on stdout")
    p.add_argument("--only", choices=PARTS, action="append", help="run only these parts (repeatable; default: all)")
    p.add_argument("--rounds", type=int, default=2, help="interleaved ping-pong/fly rounds, best of (default 2)")
    p.add_argument("--realtime-seconds", type=float, default=10.0, help="real-time run length (default 10)")
    p.add_argument("--subscriber-nice", type=int, default=10, help="niceness of fan-out subscribers (default 10)")
    p.add_argument("--batch-trials", type=int, default=20000,
                   help="trials of the batch section's sweep (default 20000: 10⁸ vehicle-steps)")  # fmt: skip
    p.add_argument("--fleet-sizes", default="1,2,4,8,12,16", metavar="N,N,...",
                   help="fleet sizes, ascending; the section stops after the first that misses 1 %% of its deadlines "
                   "outside the host's stalls (default 1,2,4,8,12,16)")  # fmt: skip
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


def steal_since(r: Report, before: tuple[int, int]) -> float:
    """The hypervisor's share of CPU time since ``before`` (:func:`benchmarks.machine.cpu_times`), as the section's
    last figure: on a virtual machine the same section can read 0.38 and 0.66 in two runs back to back, and a host
    busy elsewhere is one reason to tell."""
    steal = machine.steal_ratio(before, machine.cpu_times())
    r.add("  the hypervisor's steal time during the section", steal, "ratio")
    return steal


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
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
    parts = args.only or list(PARTS)
    skipped = optional_parts_missing(parts)
    for part, why in skipped.items():
        print(f"quadsitl bench: skipping the {part} section: {why}", file=sys.stderr, flush=True)
    r = Report(quiet=False)
    host = machine.describe()
    print(f"quadsitl bench on {machine.one_line(host)}", file=sys.stderr)
    started = time.monotonic()
    ratio, ping = None, None
    extra: dict[str, float] = {}
    try:
        with tempfile.TemporaryDirectory(prefix="quadsitl-bench-") as tmp:
            work = Path(tmp)
            if "coldstart" in parts:
                bench_cold_start(r, work)
            if set(parts) & {"lockstep", "costs", "fanout", "realtime", "dashboard", "fleet"}:
                compile_first()
            if "lockstep" in parts:
                before = machine.cpu_times()
                fly, ping, floor = bench_lockstep(r, work, args.rounds)
                ratio = fly / floor
                extra["lockstep_ratio_blocking"] = fly / ping
                extra["steal_lockstep"] = steal_since(r, before)
                bench_contention(r, work)
            if "costs" in parts:
                bench_costs(r, ping or pingpong.measure())
            if "fanout" in parts:
                bench_fanout(r, work, args.subscriber_nice)
            if "realtime" in parts:
                bench_realtime(r, work, args.realtime_seconds)
            if "dashboard" in parts and "dashboard" not in skipped:
                before = machine.cpu_times()
                extra.update(bench_dashboard(r, work, args.rounds))
                extra["steal_dashboard"] = steal_since(r, before)
            if "batch" in parts:
                extra.update(bench_batch(r, args.batch_trials))
            if "fleet" in parts:
                extra.update(bench_fleet(r, work, sizes, args.fleet_seconds))
    except (subprocess.CalledProcessError, subprocess.TimeoutExpired, RuntimeError, OSError) as exc:
        print(f"quadsitl bench: error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt as exc:  # SIGINT or SIGTERM (quadsitl.process_util.StopRequested)
        print("quadsitl bench: interrupted", file=sys.stderr)
        return stop_status(exc)
    elapsed = time.monotonic() - started
    if ratio is not None:
        print(f"\nlockstep_ratio = {ratio:.3f} against the fastest ping-pong (goal >= 0.5); {elapsed:.0f} s on "
              f"{machine.one_line(host)}", file=sys.stderr)  # fmt: skip
    if args.json:
        report = {"lockstep_ratio": ratio, **extra, "elapsed_s": elapsed, "machine": host,
                  "figures": [asdict(f) for f in r.figures]}  # fmt: skip
        if skipped:  # their figures are absent, not zero: say why
            report["skipped"] = {part: {"reason": why, "absent": list(OPTIONAL[part][1])}
                                 for part, why in skipped.items()}  # fmt: skip
        print(json.dumps(report, indent=2))
    return 0
