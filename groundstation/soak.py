"""``quadsitl soak``: a fleet flown through missions for a long time, to see that nothing grows and nothing is lost.

Two segments of half the time each, one with the fleet in lockstep (``quadsitl up``, paced at real time) and one in
real time (``--mode realtime``). In each, every vehicle flies a short mission (take off to 3 m, a waypoint 5 m north
of home, land there) over and over, each flight by a new ground station (``quadsitl gcs --mission``: the ground
station restarted with every mission); the dashboard and a Zenoh router (joined to the vehicles' sessions; the
dashboard reads the telemetry through it) are restarted in turn every ``--restart-every`` seconds. A monitor of its
own, a peer of the vehicles' sessions, follows every vehicle's status stream.

Every ``--sample`` seconds of wall time it records each long-lived process's resident memory (``/proc/PID/status``
VmRSS: the launcher, each autopilot, the fleet's plant, the router, the dashboard), each vehicle's ticks per second, the
telemetry ticks lost (gaps in a vehicle's tick sequence at the monitor), the failsafes that began (a status record's
``failsafe`` turning non-zero), the missions flown and the ground stations that failed. ``soak.json`` holds every
sample and the summary; the summary is printed: per process, its memory a quarter into the segment (after the
warm-up) and at the end, and the growth; per vehicle, the tick rate in the first and last sample; the totals.

Exit status 0 when the soak ran to its end (its figures are for the reader: docs/performance.md#the-soak), 1 when a
process of the fleet died or a segment could not start.
"""

from __future__ import annotations

import argparse
import json
import shutil
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from quadsitl import telemetry
from quadsitl.children import start_module, stop
from quadsitl.cli_util import UsageError, serve_until_stopped
from quadsitl.frames import PX4_HOME, ned_to_geodetic
from quadsitl.process_util import children_of, free_port, free_ports, rss_mb

MISSION_NORTH, MISSION_ALT = 5.0, 3.0  # [m] the mission's waypoint north of home, and its altitude
WARM_UP = 0.25  # the share of a segment after which memory is the baseline the end is compared with
STATUS_DTYPE = telemetry.record_dtype("status")


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="quadsitl soak",
        description="Fly a fleet through missions for a long time, in lockstep then in real time, restarting the "
        "ground stations, the dashboard and a Zenoh router along the way; report memory, tick rate, lost telemetry "
        "and failsafes over time.",
        epilog="examples:\n  quadsitl soak --minutes 60 --out runs/soak      # the figures of docs/performance.md\n"
        "  quadsitl soak --minutes 2 --vehicles 2",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--minutes", type=float, default=10.0, metavar="N", help="how long, both segments (default 10)")
    p.add_argument("--vehicles", type=int, default=2, metavar="N", help="vehicles in the fleet (1..8, default 2)")
    p.add_argument("--preset", default="x500", help="the vehicles' preset (default: x500)")
    p.add_argument("--sample", type=float, default=10.0, metavar="S", help="wall seconds between samples (default 10)")
    p.add_argument(
        "--restart-every",
        type=float,
        default=120.0,
        metavar="S",
        help="wall seconds between restarts of the dashboard and the router, in turn (default 120)",
    )
    p.add_argument("--out", default="runs/soak", metavar="DIR", help="where soak.json goes (default runs/soak)")
    p.add_argument("--quiet", "-q", action="store_true", help="no progress lines")  # fmt: skip
    return p


def check(args: argparse.Namespace) -> None:
    """Every option in its range, or a UsageError naming it."""
    if not 0.0 < args.minutes <= 24 * 60:
        raise UsageError(f"--minutes {args.minutes!r}: expected a number of minutes in (0, 1440]")
    if not 1 <= args.vehicles <= 8:
        raise UsageError(f"--vehicles {args.vehicles!r}: expected 1..8")
    if not 1.0 <= args.sample <= 600.0:
        raise UsageError(f"--sample {args.sample!r}: expected seconds in [1, 600]")
    if not 5.0 <= args.restart_every <= 3600.0:
        raise UsageError(f"--restart-every {args.restart_every!r}: expected seconds in [5, 3600]")


def mission_file(folder: Path) -> Path:
    """The soak's mission (QGC WPL 110, from PX4's home): take off to MISSION_ALT, a waypoint MISSION_NORTH north of
    home, land there."""
    lat, lon = ned_to_geodetic(MISSION_NORTH, 0.0, PX4_HOME[0], PX4_HOME[1])
    path = folder / "soak.waypoints"
    path.write_text("QGC WPL 110\n"
                    f"0\t1\t0\t16\t0\t0\t0\t0\t{PX4_HOME[0]}\t{PX4_HOME[1]}\t{PX4_HOME[2]}\t1\n"
                    f"1\t0\t3\t22\t0\t0\t0\t0\t0\t0\t{MISSION_ALT}\t1\n"
                    f"2\t0\t3\t16\t0\t1\t0\t0\t{lat:.9f}\t{lon:.9f}\t{MISSION_ALT}\t1\n"
                    "3\t0\t3\t21\t0\t0\t0\t0\t0\t0\t0\t1\n")  # fmt: skip
    return path


@dataclass
class Follow:
    """One vehicle's status stream, as the monitor sees it (filled on Zenoh's thread, read under ``lock``)."""

    ticks: int = 0  # records seen
    last_tick: int = -1
    lost: int = 0  # ticks missing between consecutive records
    failsafes: int = 0  # failsafes that began
    failsafe: int = 0
    missions: int = 0  # landings: armed → disarmed
    armed: int = 0


@dataclass
class Segment:
    """One segment's processes and what was seen of them."""

    mode: str
    vehicles: int
    up: subprocess.Popen | None = None
    router: subprocess.Popen | None = None
    dashboard: subprocess.Popen | None = None
    pilots: dict[int, subprocess.Popen] = field(default_factory=dict)
    flights: dict[int, int] = field(default_factory=dict)
    failed_flights: int = 0
    why_failed: list[str] = field(default_factory=list)  # each failed mission's ground station: its last words
    restarts: dict[str, int] = field(default_factory=lambda: {"dashboard": 0, "router": 0, "gcs": 0})
    follows: dict[str, Follow] = field(default_factory=dict)
    lock: threading.Lock = field(default_factory=threading.Lock)
    samples: list[dict] = field(default_factory=list)


def on_status(seg: Segment, vehicle: str, payload: bytes) -> None:
    """A status sample of ``vehicle``: its ticks, gaps, failsafes that began, landings."""
    recs = np.frombuffer(payload[: len(payload) // STATUS_DTYPE.itemsize * STATUS_DTYPE.itemsize], dtype=STATUS_DTYPE)
    if not len(recs):
        return
    ticks, armed, failsafe = recs["tick"].astype(np.int64), recs["armed"], recs["failsafe"]
    with seg.lock:
        f = seg.follows.setdefault(vehicle, Follow())
        if f.last_tick >= 0 and ticks[0] > f.last_tick + 1:
            f.lost += int(ticks[0] - f.last_tick - 1)
        steps = np.diff(ticks)
        f.lost += int(np.maximum(steps - 1, 0).sum())
        f.ticks += len(recs)
        f.last_tick = int(ticks[-1])
        before = np.concatenate(([f.failsafe], failsafe[:-1]))
        f.failsafes += int(((failsafe != 0) & (before == 0)).sum())
        f.failsafe = int(failsafe[-1])
        prior = np.concatenate(([f.armed], armed[:-1]))
        f.missions += int(((prior != 0) & (armed == 0)).sum())
        f.armed = int(armed[-1])


def processes(seg: Segment) -> dict[str, int]:
    """The long-lived processes' pids by name: the launcher (up), each autopilot and the plant (which simulates the
    whole fleet: its children), the router and the dashboard."""
    out: dict[str, int] = {}
    if seg.up is not None and seg.up.poll() is None:
        out["up"] = seg.up.pid
        for pid in children_of(seg.up.pid):
            try:
                argv = Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0")
            except OSError:
                continue
            words = [a.decode(errors="replace") for a in argv]
            kind = "autopilot" if "autopilot" in words else "plant" if "sitl" in words or "plant" in words else None
            if kind is None:
                continue
            name = next((words[i + 1] for i, a in enumerate(words[:-1]) if a == "--vehicle"), None)
            out[f"{kind} {name}" if name and kind == "autopilot" else kind] = pid  # one plant for the fleet
    for name in ("router", "dashboard"):
        proc = getattr(seg, name)
        if proc is not None and proc.poll() is None:
            out[name] = proc.pid
    return out


class Soak:
    """The soak of ``args``: :meth:`run` → the exit status."""

    def __init__(self, args: argparse.Namespace) -> None:
        self.args = args
        self.out = Path(args.out)
        self.work = Path(tempfile.mkdtemp(prefix="quadsitl-soak-"))
        self.mission = mission_file(self.work)
        self.py = [sys.executable, "-m", "groundstation.cli"]

    def say(self, text: str) -> None:
        if not self.args.quiet:
            print(f"quadsitl soak: {text}", flush=True)

    def run(self) -> int:
        import zenoh  # noqa: F401 (the monitor's; imported here so that --help needs no Zenoh)

        self.out.mkdir(parents=True, exist_ok=True)
        segments, status = [], 0
        try:
            for mode in ("lockstep", "realtime"):
                seg = Segment(mode, self.args.vehicles)
                segments.append(seg)
                if not self.fly(seg, self.args.minutes * 30.0):
                    status = 1
                    break
        finally:
            shutil.rmtree(self.work, ignore_errors=True)
        from benchmarks.machine import describe

        report = {"machine": describe(), "minutes": self.args.minutes, "vehicles": self.args.vehicles,
                  "preset": self.args.preset, "segments": [summary(s) for s in segments]}  # fmt: skip
        (self.out / "soak.json").write_text(json.dumps(report, indent=1) + "\n")
        m = report["machine"]
        print(f"machine: {m['cpu']}, {m['cores']} cores, {m['hypervisor']}, Linux {m['kernel']}, Python {m['python']}")
        for s in report["segments"]:
            print(table(s), flush=True)
        print(f"quadsitl soak: wrote {self.out / 'soak.json'}", flush=True)
        return status

    def fly(self, seg: Segment, seconds: float) -> bool:
        """One segment of ``seconds`` of wall time; False when the fleet died or did not start."""
        import zenoh

        n = self.args.vehicles
        taken: set[int] = set()
        gcs, api = free_ports(1, taken=taken), free_ports(n, taken=taken)
        gcs_listen, api_listen = free_ports(n, taken=taken), free_ports(n, taken=taken)
        zport = free_port(socket.SOCK_STREAM)
        rport = free_port(socket.SOCK_STREAM, avoid={zport})
        endpoint, router = f"tcp/127.0.0.1:{zport}", f"tcp/127.0.0.1:{rport}"
        mode = ["--mode", "realtime"] if seg.mode == "realtime" else []
        seg.up = subprocess.Popen([*self.py, "up", "--quiet", "--preset", self.args.preset, "--vehicles", str(n),
                                   "--gcs-listen", f"127.0.0.1:{gcs_listen}", "--gcs-remote", f"127.0.0.1:{gcs}",
                                   "--api-listen", f"127.0.0.1:{api_listen}", "--api-remote", f"127.0.0.1:{api}",
                                   "--zenoh-listen", endpoint, "--logs", str(self.out / "logs"), *mode],
                                  start_new_session=True)  # fmt: skip
        session = zenoh.open(telemetry.zenoh_config("peer", connect=[endpoint], shared_memory=True))
        sub = session.declare_subscriber(f"{telemetry.PREFIX}/*/status",
                                         lambda s: on_status(seg, str(s.key_expr).split("/")[1],
                                                             s.payload.to_bytes()))  # fmt: skip
        start = time.monotonic()
        try:
            self.say(f"{seg.mode}: {n} vehicles, {seconds / 60:g} min")
            seg.router = self.router(router, endpoint)
            seg.dashboard = self.dashboard(router)
            if not self.wait_for_telemetry(seg, 120.0):
                print(f"quadsitl soak: {seg.mode}: no telemetry from the fleet within 120 s", file=sys.stderr)
                return False
            start = time.monotonic()
            next_sample, next_restart, turn = start, start + self.args.restart_every, 0
            while time.monotonic() - start < seconds:
                if seg.up.poll() is not None:
                    print(f"quadsitl soak: {seg.mode}: the fleet (quadsitl up) exited with status {seg.up.returncode}",
                          file=sys.stderr)  # fmt: skip
                    return False
                self.pilot(seg, gcs_listen, endpoint)
                now = time.monotonic()
                if now >= next_restart:
                    name = ("dashboard", "router")[turn % 2]
                    turn += 1
                    next_restart = now + self.args.restart_every
                    stop(getattr(seg, name))
                    setattr(seg, name, self.router(router, endpoint) if name == "router" else self.dashboard(router))
                    seg.restarts[name] += 1
                if now >= next_sample:
                    self.sample(seg, start)
                    next_sample += self.args.sample
                time.sleep(0.2)
            self.sample(seg, start)
            return True
        finally:
            for proc in (*seg.pilots.values(), seg.dashboard, seg.router):
                if proc is not None:
                    stop(proc)
            sub.undeclare()
            session.close()
            if seg.up.poll() is None:
                stop(seg.up, grace=15.0)

    def router(self, listen: str, endpoint: str) -> subprocess.Popen:
        return start_module("groundstation.cli", "router", "--quiet", "--listen", listen, "--connect", endpoint,
                            stdout=subprocess.DEVNULL)  # fmt: skip

    def dashboard(self, router: str) -> subprocess.Popen:
        return start_module("groundstation.cli", "dashboard", "--quiet", "--port", "0", "--zenoh-mode", "client",
                            "--zenoh-connect", router, stdout=subprocess.DEVNULL)  # fmt: skip

    def wait_for_telemetry(self, seg: Segment, timeout: float) -> bool:
        end = time.monotonic() + timeout
        while time.monotonic() < end and seg.up.poll() is None:
            with seg.lock:
                if len(seg.follows) == seg.vehicles and all(f.ticks for f in seg.follows.values()):
                    return True
            time.sleep(0.2)
        return False

    def pilot(self, seg: Segment, gcs_listen: int, endpoint: str) -> None:
        """Each vehicle's ground station: the next mission's, once the last has ended (a failed one counted)."""
        for i in range(seg.vehicles):
            proc = seg.pilots.get(i)
            if proc is not None and proc.poll() is None:
                continue
            if proc is not None:
                if proc.returncode == 0:
                    seg.flights[i] = seg.flights.get(i, 0) + 1
                else:
                    seg.failed_flights += 1
                    seg.why_failed.append(
                        f"v{i + 1}, status {proc.returncode}: {last_words(self.work / f'v{i + 1}.err')}"
                    )
                seg.restarts["gcs"] += 1
            folder = self.work / f"v{i + 1}"
            shutil.rmtree(folder, ignore_errors=True)
            with open(self.work / f"v{i + 1}.err", "w") as err:  # the child holds its own copy
                seg.pilots[i] = start_module("groundstation.cli", "gcs", "--quiet", "--preset", self.args.preset,
                                             "--connect", f"127.0.0.1:{gcs_listen + i}", "--target-system",
                                             str(i + 1), "--vehicle", f"v{i + 1}", "--zenoh-connect", endpoint,
                                             "--mission", str(self.mission), "--out", str(folder), "--timeout", "300",
                                             stdout=subprocess.DEVNULL, stderr=err)  # fmt: skip

    def sample(self, seg: Segment, start: float) -> None:
        """One sample, ``start`` the segment's first moment (time.monotonic [s]). Its time is read with the ticks: a
        restart just before it (which blocks) does not put ticks counted later in an earlier moment."""
        rss = {}
        for name, pid in processes(seg).items():
            try:
                rss[name] = round(rss_mb(pid), 1)
            except OSError:
                continue
        with seg.lock:
            follows = {v: (f.ticks, f.lost, f.failsafes, f.missions) for v, f in sorted(seg.follows.items())}
            t = time.monotonic() - start
        last = seg.samples[-1] if seg.samples else None
        rates = {}
        for v, (ticks, *_rest) in follows.items():
            if last is not None and last["t"] < t:
                rates[v] = round((ticks - last["ticks"].get(v, 0)) / (t - last["t"]), 1)
        seg.samples.append({"t": round(t, 3), "rss_mb": rss, "ticks": {v: f[0] for v, f in follows.items()},
                            "tick_rate": rates, "lost": {v: f[1] for v, f in follows.items()},
                            "failsafes": {v: f[2] for v, f in follows.items()},
                            "landings": {v: f[3] for v, f in follows.items()},
                            "missions": sum(seg.flights.values()), "failed_missions": seg.failed_flights,
                            "why_failed": list(seg.why_failed),
                            "restarts": dict(seg.restarts)})  # fmt: skip
        self.say(
            f"{seg.mode} {t:6.0f} s: rss {sum(rss.values()):.0f} MB in {len(rss)} processes, tick rate "
            f"{', '.join(f'{v} {r:g}/s' for v, r in rates.items()) or '-'}, missions {sum(seg.flights.values())}, "
            f"lost {sum(f[1] for f in follows.values())}, failsafes {sum(f[2] for f in follows.values())}"
        )


def last_words(path: Path, lines: int = 3) -> str:
    """The last ``lines`` non-empty lines of a ground station's stderr, joined: why its mission failed."""
    try:
        said = [line.strip() for line in path.read_text(errors="replace").splitlines() if line.strip()]
    except OSError:
        return "(no output)"
    return " / ".join(said[-lines:]) or "(no output)"


def summary(seg: Segment) -> dict:
    """A segment's samples and what they come to: memory after WARM_UP of it and at its end, per process (the
    growth, %); tick rate in the first and last sample with one, per vehicle; the totals."""
    samples = seg.samples
    out: dict = {"mode": seg.mode, "samples": samples}
    if not samples:
        return out
    end_t = samples[-1]["t"]
    base = next((s for s in samples if s["t"] >= WARM_UP * end_t), samples[0])
    memory = {}
    for name, mb in samples[-1]["rss_mb"].items():
        if name in ("dashboard", "router"):  # restarted along the way: their own lifetime is shorter than the segment
            continue
        first = base["rss_mb"].get(name)
        if first:
            memory[name] = {"base_mb": first, "end_mb": mb, "growth_pct": round(100.0 * (mb - first) / first, 2)}
    rated = [s for s in samples if s["tick_rate"]]
    out.update(memory=memory, base_t=base["t"], end_t=end_t,
               tick_rate={"first": rated[0]["tick_rate"] if rated else {}, "last": rated[-1]["tick_rate"] if rated
                          else {}},
               lost=sum(samples[-1]["lost"].values()), failsafes=sum(samples[-1]["failsafes"].values()),
               missions=samples[-1]["missions"], failed_missions=samples[-1]["failed_missions"],
               why_failed=samples[-1]["why_failed"],
               restarts=samples[-1]["restarts"])  # fmt: skip
    return out


def table(s: dict) -> str:
    """A segment's summary as lines to print."""
    base = f"MB at {s.get('base_t', 0):.1f} s"
    lines = [f"{s['mode']}: {s.get('end_t', 0):.0f} s sampled, missions {s.get('missions', 0)} (failed "
             f"{s.get('failed_missions', 0)}), telemetry ticks lost {s.get('lost', 0)}, failsafes "
             f"{s.get('failsafes', 0)}, restarts {s.get('restarts', {})}",
             f"  {'process':<16} {base:>14} {'MB at end':>10} "
             f"{'growth %':>9}"]  # fmt: skip
    for name, m in s.get("memory", {}).items():
        lines.append(f"  {name:<16} {m['base_mb']:>14.1f} {m['end_mb']:>10.1f} {m['growth_pct']:>9.2f}")
    rate = s.get("tick_rate", {})
    for v in rate.get("first", {}):
        lines.append(f"  tick rate {v}: {rate['first'][v]:g}/s first, {rate['last'].get(v, float('nan')):g}/s last")
    lines += [f"  failed mission: {why}" for why in s.get("why_failed", [])]
    return "\n".join(lines)


def serve(args: argparse.Namespace) -> int:
    check(args)
    return Soak(args).run()


def main(argv: Sequence[str] | None = None) -> int:
    return serve_until_stopped(build_parser(), serve, argv)


if __name__ == "__main__":
    sys.exit(main())
