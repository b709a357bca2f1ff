"""Host B of the two-host test (tests/test_fleet_netns.py), run inside B's network namespace: what a ground station
there sees and does. It waits for the dashboard (fed by the router) to show v1 and v2 live, measures how late
Zenoh samples arrive through the router, hears both system ids on the ground-station port, then MAVSDK on
vehicle 2's offboard port arms it and takes it off, and the dashboard shows v2 up and v1 on the ground. One JSON
object on stdout; wall times are time.time(), the host's clock, shared by both namespaces.

    python -m tests.netns_client --dashboard http://127.0.0.1:8050 --router tcp/127.0.0.1:7447 --gcs 14550 \\
        --api 14541
"""

from __future__ import annotations

import argparse
import asyncio
import json
import statistics
import sys
import time
import urllib.request


def vehicles(url: str) -> dict[str, dict]:
    try:
        with urllib.request.urlopen(f"{url}/api/vehicles", timeout=2.0) as r:
            return {v["name"]: v for v in json.load(r)["vehicles"]}
    except OSError:
        return {}


def wait_live(url: str, names: set[str], timeout: float) -> dict[str, dict]:
    end = time.monotonic() + timeout
    seen: dict[str, dict] = {}
    while time.monotonic() < end:
        seen = vehicles(url)
        if all(n in seen and seen[n]["state"] and seen[n]["link"]["telemetry"] == "live" for n in names):
            return seen
        time.sleep(0.1)
    raise SystemExit(f"netns_client: the dashboard did not show {sorted(names)} live within {timeout} s: {seen}")


def latencies(router: str, seconds: float, out: dict, enough: int) -> list[float]:
    """Publication → arrival [s] of state samples through the router (Zenoh timestamps, the publisher's clock), until
    ``enough`` have come or ``seconds`` have passed (about 100 a second: two vehicles, 20 ms batches; a loaded machine
    may hold them back); ``out`` gets how many routers and peers this session had (the vehicles, the router's
    clients, are neither)."""
    import zenoh

    from quadsitl.telemetry import zenoh_config

    lat: list[float] = []

    def note(sample) -> None:
        if sample.timestamp is not None:
            lat.append(time.time() - sample.timestamp.get_time().timestamp())

    with zenoh.open(zenoh_config(connect=[router])) as session:
        sub = session.declare_subscriber("quadsitl/*/state", note)
        end = time.monotonic() + seconds
        while len(lat) < enough and time.monotonic() < end:
            time.sleep(0.05)
        sub.undeclare()
        out["zenoh_routers"] = len(list(session.info.routers_zid()))
        out["zenoh_peers"] = len(list(session.info.peers_zid()))
    return lat


def heartbeats(port: int, seconds: float) -> list[int]:
    from pymavlink import mavutil

    conn = mavutil.mavlink_connection(f"udpin:0.0.0.0:{port}", source_system=255)
    ids: set[int] = set()
    end = time.monotonic() + seconds
    try:
        while time.monotonic() < end and ids != {1, 2}:
            m = conn.recv_match(type="HEARTBEAT", blocking=True, timeout=0.2)
            if m is not None and m.get_srcComponent() == 1:
                ids.add(m.get_srcSystem())
    finally:
        conn.close()
    return sorted(ids)


async def take_off(port: int) -> dict:
    from mavsdk.asyncio import ComponentType, Configuration, Mavsdk
    from mavsdk.asyncio.plugins.action import ActionAsync
    from mavsdk.asyncio.plugins.telemetry import TelemetryAsync

    from tests.mavsdk_client import healthy, until

    async with Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION)) as m:
        await m.add_any_connection(f"udpin://0.0.0.0:{port}")
        system = await m.first_autopilot(timeout_s=30.0)
        assert system is not None, "MAVSDK saw no autopilot"
        tel, action = TelemetryAsync(system), ActionAsync(system)
        await healthy(tel)
        await action.set_takeoff_altitude(3.0)
        await action.arm()
        started = time.time()
        await action.takeoff()
        p = await until(tel.subscribe_position(), lambda p: p.relative_altitude_m > 2.5, 20.0)
        return {"mavsdk_system_ids": sorted([await s.get_system_id() for s in await m.get_systems()]),
                "takeoff_at": started, "mavsdk_altitude": p.relative_altitude_m}  # fmt: skip


def main() -> int:
    p = argparse.ArgumentParser()
    p.add_argument("--dashboard", required=True)
    p.add_argument("--router", required=True)
    p.add_argument("--gcs", type=int, required=True)
    p.add_argument("--api", type=int, required=True)
    p.add_argument("--timeout", type=float, default=60.0)
    args = p.parse_args()
    out: dict = {}
    wait_live(args.dashboard, {"v1", "v2"}, args.timeout)
    out["live_at"] = time.time()
    lat = latencies(args.router, 20.0, out, enough=101)
    out["latency_samples"] = len(lat)
    if lat:
        lat.sort()
        out["latency_median_ms"] = 1e3 * statistics.median(lat)
        out["latency_p95_ms"] = 1e3 * lat[int(0.95 * (len(lat) - 1))]
    out["heartbeat_system_ids"] = heartbeats(args.gcs, 10.0)
    out.update(asyncio.run(asyncio.wait_for(take_off(args.api), 60.0)))
    end = time.monotonic() + 10.0
    while time.monotonic() < end:  # the dashboard, through the router, shows the climb
        seen = vehicles(args.dashboard)
        out["dashboard_z"] = {n: v["state"]["z"] for n, v in seen.items() if v["state"]}
        if out["dashboard_z"].get("v2", 0.0) < -2.5:
            break
        time.sleep(0.1)
    print(json.dumps(out), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
