"""The dashboard in a real browser: Debian's headless Chromium driven by Playwright, against
``quadsitl up --dashboard`` flown by a raw pymavlink client. The page must show live data within seconds,
redraw its plots as the flight goes on, and show the response change when a gain is changed over MAVLink.
Screenshots go to ``$QUADSITL_ARTIFACTS`` (default: the test's temporary folder)."""

from __future__ import annotations

import json
import math
import os
import socket
import time
import urllib.request
from pathlib import Path

import pytest

from benchmarks.browser import chromium
from groundstation.launcher import free_port
from tests.mavclient import Client, M, quadsitl_up


@pytest.fixture(scope="module")
def browser():
    try:
        with chromium() as b:  # not a skip when Chromium is missing: ./scripts/test installs it
            yield b
    except RuntimeError as exc:
        pytest.fail(str(exc))


@pytest.fixture
def artifacts(tmp_path) -> Path:
    out = Path(os.environ.get("QUADSITL_ARTIFACTS", tmp_path))
    out.mkdir(parents=True, exist_ok=True)
    return out


def wait_http(url: str, timeout: float = 20.0) -> None:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        try:
            with urllib.request.urlopen(url, timeout=1) as r:
                if r.status == 200:
                    return
        except OSError:
            time.sleep(0.1)
    raise AssertionError(f"nothing answered at {url} within {timeout} s")


def fly(c: Client, seconds: float, altitude: float) -> None:
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        c.setpoint(altitude)
        c.pump(0.05)


def page_state(page) -> dict:
    return page.evaluate(
        "() => ({updates: quadsitl.updates, redraws: quadsitl.redraws, lastT: quadsitl.lastT, "
        "points: Number(document.getElementById('plot-altitude').dataset.points || 0), "
        "armed: document.querySelector('#status [data-field=armed]').textContent, "
        "mode: document.querySelector('#status [data-field=mode]').textContent, "
        "link: document.querySelector('#status [data-field=link]').textContent, "
        "rate: document.querySelector('#status [data-field=tick_rate]').textContent})"
    )


def settle_time(page, t_from: float, target: float, start: float) -> float:
    """Simulated seconds from the reference step at or after ``t_from`` until the altitude the page holds
    first covers 90 % of the way from ``start`` to ``target``."""
    d = page.evaluate("() => ({t: quadsitl.data.t, alt: quadsitl.data.altitude, ref: quadsitl.data.altitude_ref})")
    t_step = next(t for t, r in zip(d["t"], d["ref"]) if t >= t_from and abs(r - target) < 1e-6)
    goal = start + 0.9 * (target - start)
    t90 = next(t for t, a in zip(d["t"], d["alt"]) if t >= t_step and (a - goal) * (target - start) >= 0)
    return t90 - t_step


@pytest.mark.timeout(120)
def test_the_page_shows_live_data_and_a_gain_change_over_mavlink(browser, artifacts):
    port = free_port(socket.SOCK_STREAM)
    url = f"http://127.0.0.1:{port}/"
    with quadsitl_up("--dashboard", "--dashboard-port", str(port)) as v:
        wait_http(url)
        c = Client(v.gcs_port)
        page = browser.new_page(viewport={"width": 1400, "height": 1100})
        errors: list[str] = []
        page.on("pageerror", lambda e: errors.append(str(e)))
        try:
            c.heartbeat()
            page.goto(url)
            # Live data within a few seconds, before anything flies: the vehicle idles in hold.
            page.wait_for_function("() => quadsitl.updates > 0 && quadsitl.lastT !== null", timeout=5000)
            first = page_state(page)
            assert first["armed"] == "disarmed" and first["mode"] == "hold"
            assert first["link"].startswith("live")

            fly(c, 0.3, 1.0)
            assert c.command(M.MAV_CMD_DO_SET_MODE, M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 6, 0).result == 0
            assert c.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == 0
            fly(c, 2.0, 1.0)
            armed = page_state(page)
            assert armed["armed"] == "armed" and armed["mode"] == "offboard"
            assert armed["redraws"] > first["redraws"] and armed["lastT"] > first["lastT"] + 1.5
            assert armed["points"] > 50
            rate = float(armed["rate"].split()[0])
            assert 500 < rate < 2000, armed  # lockstep at 1× real time: about 1000 ticks/s
            page.screenshot(path=str(artifacts / "dashboard-hover.png"), full_page=True)

            # A step up with the preset's gains, then a step down with slower altitude gains (set over
            # MAVLink): the page shows the slower response.
            t0 = armed["lastT"]
            fly(c, 2.0, 2.0)
            fast = settle_time(page, t0, 2.0, 1.0)
            for name in ("BS_K1", "BS_K2"):
                assert c.param_set(name, 3.0).param_value == pytest.approx(3.0)
            t1 = page_state(page)["lastT"]
            fly(c, 3.0, 1.0)
            slow = settle_time(page, t1, 1.0, 2.0)
            page.screenshot(path=str(artifacts / "dashboard-gain-change.png"), full_page=True)
            # k = 10 1/s: a double pole, 90 % in about 0.39 s; k = 3 1/s: about 1.3 s.
            assert 0.2 < fast < 0.6, fast
            assert slow > 2.0 * fast, (fast, slow)
            assert not errors, errors
            assert (artifacts / "dashboard-gain-change.png").stat().st_size > 20_000
        finally:
            page.close()
            c.close()


@pytest.mark.timeout(60)
def test_api_vehicles_and_any_number_of_tabs(browser):
    port = free_port(socket.SOCK_STREAM)
    url = f"http://127.0.0.1:{port}/"
    with quadsitl_up("--dashboard", "--dashboard-port", str(port)) as _v:
        wait_http(url)
        pages = [browser.new_page() for _ in range(3)]
        try:
            for p in pages:
                p.goto(url)
            for p in pages:
                p.wait_for_function("() => quadsitl.redraws > 1 && quadsitl.data.t.length > 10", timeout=10000)
            with urllib.request.urlopen(url + "api/vehicles", timeout=5) as r:
                body = json.loads(r.read())
            (veh,) = body["vehicles"]
            assert veh["name"] == "v1" and veh["status"]["mode"] == "hold" and veh["status"]["armed"] is False
            assert veh["link"]["telemetry"] == "live" and veh["link"]["malformed"] == 0
            assert veh["period"] == pytest.approx(0.001)
            assert 0.5 < veh["real_time_factor"] < 2.0
            assert set(veh["state"]) >= {"t", "x", "y", "z", "roll", "pitch", "yaw", "p", "q", "r"}
            assert set(veh["setpoint"]) == {"t", "altitude_ref", "roll_ref", "pitch_ref", "yaw_ref", "x_ref", "y_ref"}
            assert veh["setpoint"]["x_ref"] is None  # NaN: in hold, nothing controls x and y yet
            # every tab follows the same vehicle independently
            last = [p.evaluate("() => quadsitl.lastT") for p in pages]
            assert max(last) - min(last) < 1.0
        finally:
            for p in pages:
                p.close()


class Publisher:
    """A Zenoh session that publishes made-up telemetry of one vehicle, as the autopilot does (schema v3)."""

    def __init__(self, endpoint: str, vehicle: str = "map") -> None:
        import zenoh

        from quadsitl import telemetry

        self.session = zenoh.open(telemetry.zenoh_config(connect=[endpoint]))
        self.pubs = {s: self.session.declare_publisher(telemetry.key(vehicle, s)) for s in telemetry.STREAMS}
        end = time.monotonic() + 10  # peers connect directly: wait until the dashboard's session is found
        while not all(p.matching_status.matching for p in self.pubs.values()):
            assert time.monotonic() < end, "the dashboard's Zenoh session was not found"
            time.sleep(0.02)

    def put(self, ticks: range, point, mode: int = 1) -> None:
        """One sample per stream of ``ticks`` (T = 1 ms); ``point(t)`` → (x, y, x_ref, y_ref) [m, NED]."""
        from quadsitl import telemetry

        out: dict[str, bytes] = {s: b"" for s in telemetry.STREAMS}
        for k in ticks:
            t = k * 0.001
            x, y, x_ref, y_ref = point(t)
            st = telemetry.STREAMS
            out["state"] += st["state"].pack(k, t, x, y, -2.0, *[0.0] * 9)
            out["setpoint"] += st["setpoint"].pack(k, t, 2.0, 0.0, 0.0, 0.0, x_ref, y_ref)
            out["actuators"] += st["actuators"].pack(k, t, *[0.0] * 8)
            out["status"] += st["status"].pack(k, t, 1, mode, 0, 0)
        for s, pub in self.pubs.items():
            pub.put(out[s])

    def close(self) -> None:
        for p in self.pubs.values():
            p.undeclare()
        self.session.close()


def circle_point(t: float) -> tuple[float, float, float, float]:
    """A 4 m circle through home (centre 4 m east), 0.3 rad a second; measured 0.1 rad behind its reference."""
    th, lag = 0.3 * t, 0.3 * t - 0.1
    return 4 * math.sin(lag), 4 * (1 - math.cos(lag)), 4 * math.sin(th), 4 * (1 - math.cos(th))


def map_state(page) -> dict:
    """What the map shows (its data attributes) and the colours of its canvas at home, at the setpoint and in all."""
    return page.evaluate("""() => {
        const box = document.getElementById('plot-map'), c = box.querySelector('canvas');
        const r = window.devicePixelRatio || 1, ctx = c.getContext('2d');
        const at = s => { if (!s) return null; const [x, y] = s.split(',').map(Number);
                          return Array.from(ctx.getImageData(Math.round(x * r), Math.round(y * r), 1, 1).data); };
        const all = ctx.getImageData(0, 0, c.width, c.height).data;
        let measured = 0;
        const near = (i, v) => Math.abs(all[i] - v) < 20;
        for (let i = 0; i < all.length; i += 4) if (near(i, 31) && near(i + 1, 119) && near(i + 2, 180)) measured++;
        return {points: Number(box.dataset.points), t: Number(box.dataset.tLast), setpoint: box.dataset.setpoint,
                home: at(box.dataset.homePx),
                setpointColour: at(box.dataset.setpointPx), measured, scale: Number(box.dataset.scale),
                mode: document.querySelector('#status [data-field=mode]').textContent};
    }""")


@pytest.mark.timeout(90)
def test_the_map_shows_the_path_the_setpoint_and_home(browser, artifacts):
    """The x–y map, against made-up telemetry of a circle: the path of the window drawn, home marked at the
    origin, the setpoint where x_ref, y_ref say, and no setpoint once they are NaN; the new mode names."""
    import subprocess
    import sys

    zenoh_port, port = free_port(socket.SOCK_STREAM), free_port(socket.SOCK_STREAM)
    endpoint, url = f"tcp/127.0.0.1:{zenoh_port}", f"http://127.0.0.1:{port}/"
    server = subprocess.Popen([sys.executable, "-m", "groundstation.dashboard.server", "--port", str(port),
                               "--zenoh-listen", endpoint, "--quiet"])  # fmt: skip
    pub = page = None
    try:
        wait_http(url)
        pub = Publisher(endpoint)
        page = browser.new_page(viewport={"width": 1400, "height": 1100})
        errors: list[str] = []
        page.on("pageerror", lambda e: errors.append(str(e)))
        page.goto(url)
        for first in range(1, 8001, 200):  # 8 s of flight, 200 ticks a sample
            pub.put(range(first, first + 200), circle_point)
            time.sleep(0.01)
        # 400 rows at 50 per simulated second; an update carries at most 250 (thinned when more are new)
        # (the map shows the rows of its last redraw: wait until that one has the newest row)
        page.wait_for_function("() => { const m = document.getElementById('plot-map').dataset; "
                               "return Number(m.points) >= 100 && Number(m.tLast) >= 7.9 "
                               "&& Number(m.tLast) === quadsitl.lastT; }", timeout=10000)  # fmt: skip
        m = map_state(page)
        x_ref, y_ref = circle_point(m["t"])[2:]
        assert m["setpoint"] == f"{x_ref:.3f},{y_ref:.3f}"  # the newest row's reference
        assert m["home"][:3] == pytest.approx([44, 160, 44], abs=3)  # the green square at the origin
        assert m["setpointColour"][:3] == pytest.approx([214, 39, 40], abs=3)  # the red cross (anti-aliased)
        assert m["measured"] > 300  # the blue path
        # 8 s at 0.3 rad/s: 2.4 rad of a 4 m circle, plus home: the map spans about 7 m, at equal scales
        assert 20 < m["scale"] < 100
        assert m["mode"] == "offboard"
        page.screenshot(path=str(artifacts / "dashboard-map.png"), full_page=True)

        # x_ref, y_ref NaN (attitude setpoints now): no setpoint; return to launch shows its name.
        nan = math.nan
        for first in range(8001, 9001, 200):
            pub.put(range(first, first + 200), lambda t: (*circle_point(t)[:2], nan, nan), mode=4)
            time.sleep(0.01)
        no_setpoint = "document.getElementById('plot-map').dataset.setpoint === ''"
        page.wait_for_function(f"() => quadsitl.lastT >= 8.9 && {no_setpoint}", timeout=10000)
        m = map_state(page)
        assert m["setpointColour"] is None and m["home"][:3] == pytest.approx([44, 160, 44], abs=3)
        assert m["mode"] == "rtl"
        assert not errors, errors
    finally:
        if page is not None:
            page.close()
        if pub is not None:
            pub.close()
        server.terminate()
        server.wait(10)


@pytest.mark.timeout(120)
def test_the_map_shows_the_mission_and_its_current_item_as_it_flies(browser, artifacts):
    """``quadsitl up --dashboard``; a raw pymavlink ground station uploads three waypoints by the mission protocol
    and starts the mission: the page's map shows the plan where the items are, rings the current item, and
    follows it to the next one when the first is reached; the status panel says which item of how many."""
    from quadsitl.earth import PX4_HOME
    from quadsitl.frames import ned_to_geodetic

    port = free_port(socket.SOCK_STREAM)
    url = f"http://127.0.0.1:{port}/"
    points = ((6.0, 0.0), (6.0, 6.0), (0.0, 6.0))  # north, east [m]: short legs, so the test is short
    with quadsitl_up("--dashboard", "--dashboard-port", str(port)) as v:
        c = Client(v.gcs_port)
        page = None
        try:
            c.connect()
            items = [(M.MAV_CMD_NAV_WAYPOINT, *ned_to_geodetic(n, e, *PX4_HOME[:2]), 4.0) for n, e in points]
            assert c.upload_mission(items).type == M.MAV_MISSION_ACCEPTED
            wait_http(url)
            page = browser.new_page(viewport={"width": 1400, "height": 1100})
            page.goto(url)
            plan = "document.getElementById('plot-map').dataset"
            page.wait_for_function(f"() => Number({plan}.planItems) === 3 && {plan}.current === '0'", timeout=15000)
            mission = page.evaluate("() => quadsitl.mission")
            assert [(i["x"], i["y"]) for i in mission["items"]] == [pytest.approx(p, abs=0.02) for p in points]
            assert [i["altitude"] for i in mission["items"]] == [pytest.approx(4.0)] * 3
            text = "document.querySelector('#status [data-field=mission]').textContent"
            assert page.evaluate(f"() => {text}") == "item 0 of 3, not started"

            assert c.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == M.MAV_RESULT_ACCEPTED
            assert c.command(M.MAV_CMD_MISSION_START, 0, 0).result == M.MAV_RESULT_ACCEPTED
            page.wait_for_function(f"() => {text}.endsWith('active')", timeout=10000)
            # the first waypoint reached (takeoff to 4 m, then 6 m north): the ring moves on to item 1
            page.wait_for_function(f"() => {plan}.current === '1' && {text} === 'item 1 of 3, active'", timeout=40000)
            ring = page.evaluate("""() => {
                const box = document.getElementById('plot-map'), c = box.querySelector('canvas');
                const r = window.devicePixelRatio || 1, [x, y] = box.dataset.currentPx.split(',').map(Number);
                const px = c.getContext('2d').getImageData(Math.round(x * r), Math.round(y * r), 1, 1);
                return Array.from(px.data); }""")
            assert ring[:3] == pytest.approx([255, 127, 14], abs=40)  # the orange ring's top, over the item
            page.screenshot(path=str(artifacts / "dashboard-mission.png"), full_page=True)
        finally:
            if page is not None:
                page.close()
            c.close()
