"""The dashboard's fleet view against a fleet of N vehicles publishing on Zenoh: the dashboard process's CPU, the
size of its updates, and the page's redraw time, measured.

    python -m benchmarks.fleet_dashboard --vehicles 20 --seconds 20

A publisher process (``--publish``) stands in for N autopilots: every vehicle flies a 2 m circle around its own
home at 1 kHz of simulated time in real time, and its four streams go out as the autopilot sends them, a sample of
the records of the last 5 ms (``--batch-ms``) per stream, in the schema's record layouts
(:data:`quadsitl.telemetry.STREAMS`, packed with numpy as the compiled tick writes them); the homes are those of
``quadsitl up --vehicles N`` (:func:`groundstation.fleet.plan_fleet`), on ``quadsitl/<vehicle>/info``
(:class:`groundstation.vehicle_info.InfoPublisher`). The dashboard runs as ``quadsitl dashboard`` does (idle
priority); its page opens in Debian's headless Chromium (benchmarks/browser.py).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import socket
import statistics
import subprocess
import sys
import time
import urllib.request

import numpy as np

from benchmarks.machine import process_cpu_seconds
from quadsitl import telemetry
from quadsitl.children import stop

T = 0.001  # [s] the control period


def dtype(stream: str) -> np.dtype:
    """The numpy layout of a stream's record (the same bytes as telemetry.STREAMS[stream])."""
    return telemetry.record_dtype(stream)


def publish(endpoint: str, n: int, seconds: float, batch_ms: float) -> None:
    """N vehicles' telemetry on ``endpoint`` for ``seconds`` of wall time (see the module's docstring)."""
    import zenoh

    from groundstation.fleet import plan_fleet
    from groundstation.vehicle_info import InfoPublisher, encode_info

    fleet = plan_fleet(n, preset="paper")
    session = zenoh.open(telemetry.zenoh_config(connect=[endpoint]))
    info = InfoPublisher(zenoh.open(telemetry.zenoh_config(connect=[endpoint])),
                         {v.name: encode_info(v.system_id, v.home, "paper", n) for v in fleet})  # fmt: skip
    pubs = [{s: session.declare_publisher(telemetry.key(v.name, s), encoding=telemetry.encoding(s),
                                          congestion_control=zenoh.CongestionControl.DROP)
             for s in telemetry.STREAMS} for v in fleet]  # fmt: skip
    overviews = [telemetry.Overview(session, v.name) for v in fleet]  # as an autopilot puts them
    types = {s: dtype(s) for s in telemetry.STREAMS}
    start, tick = time.monotonic(), 1
    end = start + seconds
    while (now := time.monotonic()) < end:
        info.tick(now)
        upto = int((now - start) / T) + 1
        if upto <= tick:
            time.sleep(0.0005)
            continue
        k = np.arange(tick, upto, dtype=np.uint64)
        t = k * T
        for i, p in enumerate(pubs):
            th = 2 * math.pi * t / 20.0 + i  # a 2 m circle every 20 s, each vehicle at its own phase
            rec = {s: np.zeros(len(k), dtype=types[s]) for s in telemetry.STREAMS}
            for s in rec:
                rec[s]["tick"], rec[s]["t"] = k, t
            st = rec["state"]
            st["x"], st["y"], st["z"] = 2 * np.cos(th), 2 * np.sin(th), -2.0
            st["yaw"] = np.arctan2(np.cos(th), -np.sin(th))  # along the circle
            rec["setpoint"]["altitude_ref"] = 2.0
            rec["setpoint"]["x_ref"], rec["setpoint"]["y_ref"] = np.nan, np.nan
            rec["actuators"]["u1"] = 4.9
            rec["status"]["armed"], rec["status"]["mode"] = 1, 1
            for s, pub in p.items():
                pub.put(rec[s].tobytes())
            overviews[i].offer(lambda s, rec=rec: rec[s][-1:].tobytes(), now)
        tick = upto
        time.sleep(max(0.0, batch_ms / 1000 - (time.monotonic() - now)))
    info.close()
    session.close()


def samples(url: str) -> int:
    """Zenoh samples the dashboard has taken in, every vehicle's together."""
    with urllib.request.urlopen(url + "api/vehicles", timeout=5) as r:
        return sum(v["link"]["samples"] for v in json.loads(r.read())["vehicles"])


def measure(n: int, seconds: float, batch_ms: float) -> dict:
    from benchmarks.browser import chromium
    from groundstation.launcher import free_port

    zport, port = free_port(socket.SOCK_STREAM), free_port(socket.SOCK_STREAM)
    endpoint, url = f"tcp/127.0.0.1:{zport}", f"http://127.0.0.1:{port}/"
    dash = subprocess.Popen([sys.executable, "-m", "groundstation.dashboard.server", "--port", str(port),
                             "--zenoh-listen", endpoint, "--quiet"])  # fmt: skip
    pub = subprocess.Popen([sys.executable, "-m", "benchmarks.fleet_dashboard", "--publish", endpoint, "--vehicles",
                            str(n), "--seconds", str(seconds + 30), "--batch-ms", str(batch_ms)])  # fmt: skip
    try:
        for _ in range(200):
            try:
                urllib.request.urlopen(url, timeout=1).close()
                break
            except OSError:
                time.sleep(0.1)
        with chromium() as browser:
            page = browser.new_page(viewport={"width": 1600, "height": 1000})
            page.goto(url)
            page.wait_for_function(f"() => quadsitl.fleetMarkers.length === {n}", timeout=30000)
            time.sleep(2.0)
            page.evaluate(
                "() => { quadsitl.fleetDrawMs = []; quadsitl.bytesIn = 0; quadsitl.updatesAt = quadsitl.updates; }"
            )
            c0, p0, w0, s0 = process_cpu_seconds(dash.pid), process_cpu_seconds(pub.pid), time.monotonic(), samples(url)
            time.sleep(seconds)
            c1, p1, w1, s1 = process_cpu_seconds(dash.pid), process_cpu_seconds(pub.pid), time.monotonic(), samples(url)
            got = page.evaluate(
                "() => ({ms: quadsitl.fleetDrawMs, bytes: quadsitl.bytesIn, markers: "
                "quadsitl.fleetMarkers.length, updates: quadsitl.updates - quadsitl.updatesAt})"
            )
            page.screenshot(path=os.environ.get("QUADSITL_FLEET_SHOT", "/tmp/fleet-dashboard.png"))
            # one vehicle's plots, as today, with the fleet still publishing
            page.evaluate(f"() => quadsitl.choose('v{n}')")
            page.wait_for_function("() => quadsitl.redraws > 2 && quadsitl.data.t.length > 50", timeout=20000)
            page.evaluate("() => { quadsitl.bytesIn = 0; quadsitl.updatesAt = quadsitl.updates; }")
            time.sleep(5.0)
            single = page.evaluate("() => ({bytes: quadsitl.bytesIn, updates: quadsitl.updates - quadsitl.updatesAt})")
            with urllib.request.urlopen(url + "api/vehicles", timeout=5) as r:
                rates = [v["tick_rate"] for v in json.loads(r.read())["vehicles"]]
            page.close()
        ms = sorted(got["ms"])
        return {
            "vehicles": n,
            "seconds": round(w1 - w0, 1),
            "dashboard_cpu_percent": round(100 * (c1 - c0) / (w1 - w0), 1),
            "publisher_cpu_percent": round(100 * (p1 - p0) / (w1 - w0), 1),
            "samples_per_s": round((s1 - s0) / (w1 - w0)),
            "fleet_redraws": len(ms),
            "fleet_redraw_ms_median": round(statistics.median(ms), 2) if ms else None,
            "fleet_redraw_ms_p95": round(ms[int(0.95 * (len(ms) - 1))], 2) if ms else None,
            "fleet_update_bytes_mean": round(got["bytes"] / max(got["updates"], 1)),
            "fleet_updates_per_s": round(got["updates"] / (w1 - w0), 2),
            "single_update_bytes_mean": round(single["bytes"] / max(single["updates"], 1)),
            "tick_rates_min_max": [min(rates), max(rates)],
            "markers": got["markers"],
        }
    finally:
        for p in (pub, dash):
            stop(p, grace=10.0)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks.fleet_dashboard", description=__doc__.split("\n\n")[0])
    p.add_argument("--vehicles", type=int, default=20)
    p.add_argument("--seconds", type=float, default=20.0, help="wall seconds measured (default 20)")
    p.add_argument("--batch-ms", type=float, default=5.0, help="wall ms between a vehicle's samples (default 5)")
    p.add_argument("--publish", metavar="ENDPOINT", help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.publish:
        publish(args.publish, args.vehicles, args.seconds, args.batch_ms)
        return 0
    print(json.dumps(measure(args.vehicles, args.seconds, args.batch_ms), indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
