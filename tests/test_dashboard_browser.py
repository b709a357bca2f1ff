"""The dashboard in a real browser: Debian's headless Chromium driven by Playwright, against
``quadsitl up --dashboard`` flown by a raw pymavlink client. The page must show live data within seconds,
redraw its plots as the flight goes on, and show the response change when a gain is changed over MAVLink.
Screenshots go to ``$QUADSITL_ARTIFACTS`` (default: the test's temporary folder)."""

from __future__ import annotations

import contextlib
import json
import math
import os
import socket
import threading
import time
import urllib.request
from pathlib import Path

import pytest

from benchmarks.browser import chromium
from groundstation.launcher import free_port
from tests.mavclient import Client, M, quadsitl_up

# How long a wait on the page allows for the page to catch up [ms]. The dashboard server runs at idle priority
# (SCHED_IDLE): while the suite's other workers keep both cores busy it gets almost no CPU. The map test's burst
# of 8 s of telemetry costs it 0.07 s of CPU, and once in CI that took more than 10 s to get.
BEHIND_MS = 30_000


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


def wait_http(url: str, timeout: float = 60.0) -> None:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        try:
            with urllib.request.urlopen(url, timeout=1) as r:
                if r.status == 200:
                    return
        except OSError:
            time.sleep(0.1)
    raise AssertionError(f"nothing answered at {url} within {timeout} s")


def vehicle_clock(c: Client) -> tuple[float, float]:
    """(wall [s], the vehicle's clock [s]) from the latest ATTITUDE the client has received."""
    return time.monotonic(), c.latest["ATTITUDE"].time_boot_ms / 1000.0


def page_state(page) -> dict:
    return page.evaluate(
        "() => ({updates: quadsitl.updates, redraws: quadsitl.redraws, lastT: quadsitl.lastT, "
        "points: Number(document.getElementById('plot-altitude').dataset.points || 0), "
        "armed: document.querySelector('#status [data-field=armed]').textContent, "
        "mode: document.querySelector('#status [data-field=mode]').textContent, "
        "link: document.querySelector('#status [data-field=link]').textContent, "
        "battery: document.querySelector('#status [data-field=battery]').textContent, "
        "rate: document.querySelector('#status [data-field=tick_rate]').textContent})"
    )


class SetpointStream:
    """Altitude setpoints sent from a thread every 50 ms, as an offboard client streams them (MAVSDK does) whatever
    else it is doing: a page screenshot or a wait on a page behind the flight on a loaded machine can outlast the
    setpoint-loss failsafe's second. ``altitude`` [m] is the one sent; the client's receiving stays with the test."""

    def __init__(self, c: Client, altitude: float) -> None:
        self.altitude = altitude
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, args=(c,), daemon=True)

    def _run(self, c: Client) -> None:
        while not self._stop.is_set():
            c.setpoint(self.altitude)
            self._stop.wait(0.05)

    def __enter__(self) -> SetpointStream:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join()


def settle_time(page, t_from: float, target: float, start: float, timeout: float = 15.0) -> float:
    """Simulated seconds from the reference step at or after ``t_from`` until the altitude the page holds
    first covers 90 % of the way from ``start`` to ``target``. The page may run behind the flight on a loaded
    machine (the dashboard runs at idle priority): this waits up to ``timeout`` s of wall time for it to hold both."""
    goal = start + 0.9 * (target - start)
    end = time.monotonic() + timeout
    while True:
        d = page.evaluate("() => ({t: quadsitl.data.t, alt: quadsitl.data.altitude, ref: quadsitl.data.altitude_ref})")
        t_step = next((t for t, r in zip(d["t"], d["ref"]) if t >= t_from and abs(r - target) < 1e-6), None)
        if t_step is not None:
            t90 = next(
                (t for t, a in zip(d["t"], d["alt"]) if t >= t_step and (a - goal) * (target - start) >= 0), None
            )
            if t90 is not None:
                return t90 - t_step
        if time.monotonic() > end:
            last = d["t"][-1] if d["t"] else None
            raise AssertionError(f"the page holds no step to {target} m after t = {t_from} s and its 90 % point "
                                 f"(step at {t_step}, the page's last t = {last})")  # fmt: skip
        time.sleep(0.2)


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
        stack = contextlib.ExitStack()
        try:
            c.heartbeat()
            page.goto(url)
            # Live data within a few seconds, before anything flies: the vehicle idles in hold.
            page.wait_for_function("() => quadsitl.updates > 0 && quadsitl.lastT !== null", timeout=BEHIND_MS)
            first = page_state(page)
            assert first["armed"] == "disarmed" and first["mode"] == "hold"
            assert first["battery"] == "none"  # the paper's ideal supply
            assert first["link"].startswith("live")

            sp = stack.enter_context(SetpointStream(c, 1.0))
            c.pump(0.3)
            began = vehicle_clock(c)
            assert c.command(M.MAV_CMD_DO_SET_MODE, M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 6, 0).result == 0
            assert c.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == 0
            c.pump(2.0)
            ended = vehicle_clock(c)
            # the page as of the vehicle's time now (an idle-priority server on a loaded machine may be behind it)
            page.wait_for_function(f"() => quadsitl.lastT >= {ended[1] - 0.1}", timeout=BEHIND_MS)
            armed = page_state(page)
            # (what the vehicle said, should it have left offboard: a failsafe names itself in a STATUSTEXT)
            assert armed["armed"] == "armed" and armed["mode"] == "offboard", (armed, c.texts)
            assert armed["redraws"] > first["redraws"] and armed["lastT"] > first["lastT"] + 1.5
            assert armed["points"] > 50
            # The rate the page shows is the rate the vehicle runs at (1 kHz ticks; about 1000 /s at 1× real
            # time, less when the machine is loaded), as its own clock in the MAVLink stream tells it.
            ran = (ended[1] - began[1]) / (ended[0] - began[0]) / 1e-3
            rate = float(armed["rate"].split()[0])
            assert ran > 100 and 0.5 * ran < rate < 2.0 * ran, (armed, ran)
            page.screenshot(path=str(artifacts / "dashboard-hover.png"), full_page=True)

            # A step up with the preset's gains, then a step down with slower altitude gains (set over
            # MAVLink): the page shows the slower response.
            t0 = armed["lastT"]
            sp.altitude = 2.0
            c.pump(2.0)
            fast = settle_time(page, t0, 2.0, 1.0)
            for name in ("BS_K1", "BS_K2"):
                assert c.param_set(name, 3.0).param_value == pytest.approx(3.0)
            t1 = page_state(page)["lastT"]
            sp.altitude = 1.0
            c.pump(3.0)
            slow = settle_time(page, t1, 1.0, 2.0)
            page.screenshot(path=str(artifacts / "dashboard-gain-change.png"), full_page=True)
            # k = 10 1/s: a double pole, 90 % in about 0.39 s; k = 3 1/s: about 1.3 s.
            assert 0.2 < fast < 0.6, fast
            assert slow > 2.0 * fast, (fast, slow)
            assert not errors, errors
            assert (artifacts / "dashboard-gain-change.png").stat().st_size > 20_000
        finally:
            stack.close()
            page.close()
            c.close()


@pytest.mark.timeout(120)
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
                p.wait_for_function("() => quadsitl.redraws > 1 && quadsitl.data.t.length > 10", timeout=BEHIND_MS)
            # The real-time factor is averaged over 2 s of wall time: at first that holds the start (the plant's
            # clock waits for the autopilot), and on a loaded machine a slow second; `up` paces at 1× real time.
            end = time.monotonic() + 20
            while True:
                with urllib.request.urlopen(url + "api/vehicles", timeout=5) as r:
                    body = json.loads(r.read())
                (veh,) = body["vehicles"]
                if 0.5 < (veh["real_time_factor"] or 0.0) < 2.0 or time.monotonic() > end:
                    break
                time.sleep(0.5)
            assert veh["name"] == "v1" and veh["status"]["mode"] == "hold" and veh["status"]["armed"] is False
            assert veh["link"]["telemetry"] == "live" and veh["link"]["malformed"] == 0
            assert veh["period"] == pytest.approx(0.001)
            assert 0.5 < veh["real_time_factor"] < 2.0
            assert set(veh["state"]) >= {"t", "x", "y", "z", "roll", "pitch", "yaw", "p", "q", "r"}
            assert set(veh["setpoint"]) == {"t", "altitude_ref", "roll_ref", "pitch_ref", "yaw_ref", "x_ref", "y_ref"}
            assert veh["setpoint"]["x_ref"] is None  # NaN: in hold, nothing controls x and y yet
            # every tab follows the same vehicle independently: each reaches the time the furthest one shows (a tab
            # may be a redraw behind on a loaded machine; one that stopped following never gets there)
            last = [p.evaluate("() => quadsitl.lastT") for p in pages]
            assert all(t is not None and t > 0 for t in last)
            for p in pages:
                p.wait_for_function(f"() => quadsitl.lastT >= {max(last)}", timeout=BEHIND_MS)
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
        self.slow = telemetry.Overview(self.session, vehicle)  # the overview, as the autopilot puts it
        self.wait_matching([self.slow.pub], "the dashboard's Zenoh session was not found")

    @staticmethod
    def wait_matching(pubs, why: str) -> None:
        end = time.monotonic() + 10  # peers connect directly: wait until the dashboard's subscribers are found
        while not all(p.matching_status.matching for p in pubs):
            assert time.monotonic() < end, why
            time.sleep(0.02)

    def wait_shown(self) -> None:
        """Until a page shows this vehicle: the dashboard then takes its full rate."""
        self.wait_matching(self.pubs.values(), "no page showed the vehicle: its full rate was not subscribed")

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
            out["status"] += st["status"].pack(k, t, 1, mode, 0, 0, 15.2, 17.9, 830.0, 4.5e4, 0.12)  # a low battery
        for s, pub in self.pubs.items():
            pub.put(out[s])
        self.slow.offer(lambda s: out[s][-telemetry.STREAMS[s].size :], time.monotonic())

    def close(self) -> None:
        for p in (*self.pubs.values(), self.slow.pub):
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
                mode: document.querySelector('#status [data-field=mode]').textContent,
                battery: document.querySelector('#status [data-field=battery]').textContent,
                batteryClass: document.querySelector('#status [data-field=battery]').className};
    }""")


@pytest.mark.timeout(120)
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
        pub.put(range(1, 2), circle_point)  # its overview puts the vehicle on the page, which shows it (one alone)
        pub.wait_shown()
        for first in range(1, 8001, 200):  # 8 s of flight, 200 ticks a sample
            pub.put(range(first, first + 200), circle_point)
            time.sleep(0.01)
        # 400 rows at 50 per simulated second; an update carries at most 250 (thinned when more are new)
        # (the map shows the rows of its last redraw: wait until that one has the newest row)
        page.wait_for_function("() => { const m = document.getElementById('plot-map').dataset; "
                               "return Number(m.points) >= 100 && Number(m.tLast) >= 7.9 "
                               "&& Number(m.tLast) === quadsitl.lastT; }", timeout=BEHIND_MS)  # fmt: skip
        m = map_state(page)
        x_ref, y_ref = circle_point(m["t"])[2:]
        assert m["setpoint"] == f"{x_ref:.3f},{y_ref:.3f}"  # the newest row's reference
        assert m["home"][:3] == pytest.approx([44, 160, 44], abs=3)  # the green square at the origin
        assert m["setpointColour"][:3] == pytest.approx([214, 39, 40], abs=3)  # the red cross (anti-aliased)
        assert m["measured"] > 300  # the blue path
        # 8 s at 0.3 rad/s: 2.4 rad of a 4 m circle, plus home: the map spans about 7 m, at equal scales
        assert 20 < m["scale"] < 100
        assert m["mode"] == "offboard"
        assert m["battery"] == "12 %, 15.20 V, 17.9 A" and m["batteryClass"] == "v bad"  # the panel's: below 15 %
        page.screenshot(path=str(artifacts / "dashboard-map.png"), full_page=True)

        # x_ref, y_ref NaN (attitude setpoints now): no setpoint; return to launch shows its name.
        nan = math.nan
        for first in range(8001, 9001, 200):
            pub.put(range(first, first + 200), lambda t: (*circle_point(t)[:2], nan, nan), mode=4)
            time.sleep(0.01)
        no_setpoint = "document.getElementById('plot-map').dataset.setpoint === ''"
        page.wait_for_function(f"() => quadsitl.lastT >= 8.9 && {no_setpoint}", timeout=BEHIND_MS)
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
    """``quadsitl up --dashboard``; a raw pymavlink ground station uploads three waypoints by the mission protocol,
    a geofence and a rally point, and starts the mission: the page's map shows the plan where the items are, the
    fence and the rally point where they are, rings the current item, and
    follows it to the next one when the first is reached; the status panel says which item of how many."""
    from quadsitl.frames import PX4_HOME, ned_to_geodetic

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
            square = [(M.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION, *ned_to_geodetic(n, e, *PX4_HOME[:2]), 0.0)
                      for n, e in ((-12, -12), (12, -12), (12, 12), (-12, 12))]  # fmt: skip
            assert c.upload_mission(square, mission_type=1, param1=4).type == M.MAV_MISSION_ACCEPTED
            rally = [(M.MAV_CMD_NAV_RALLY_POINT, *ned_to_geodetic(9.0, -6.0, *PX4_HOME[:2]), 5.0)]
            assert c.upload_mission(rally, mission_type=2).type == M.MAV_MISSION_ACCEPTED
            wait_http(url)
            page = browser.new_page(viewport={"width": 1400, "height": 1100})
            page.goto(url)
            plan = "document.getElementById('plot-map').dataset"
            page.wait_for_function(f"() => Number({plan}.planItems) === 3 && {plan}.current === '0'", timeout=BEHIND_MS)
            page.wait_for_function(f"() => {plan}.fenceItems === '4' && {plan}.rallyPx !== ''", timeout=BEHIND_MS)
            triangle = page.evaluate("""() => {
                const box = document.getElementById('plot-map'), c = box.querySelector('canvas');
                const r = window.devicePixelRatio || 1, [x, y] = box.dataset.rallyPx.split(',').map(Number);
                const px = c.getContext('2d').getImageData(Math.round(x * r), Math.round(y * r), 1, 1);
                return Array.from(px.data); }""")
            assert triangle[:3] == pytest.approx([140, 86, 75], abs=40)  # the rally point's brown triangle, there
            mission = page.evaluate("() => quadsitl.mission")
            assert [(f["x"], f["y"]) for f in mission["fence"]] == [
                pytest.approx(p, abs=0.02) for p in ((-12, -12), (12, -12), (12, 12), (-12, 12))]  # fmt: skip
            assert [(r["x"], r["y"]) for r in mission["rally"]] == [pytest.approx((9.0, -6.0), abs=0.02)]
            assert [(i["x"], i["y"]) for i in mission["items"]] == [pytest.approx(p, abs=0.02) for p in points]
            assert [i["altitude"] for i in mission["items"]] == [pytest.approx(4.0)] * 3
            text = "document.querySelector('#status [data-field=mission]').textContent"
            assert page.evaluate(f"() => {text}") == "item 0 of 3, not started"

            assert c.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == M.MAV_RESULT_ACCEPTED
            assert c.command(M.MAV_CMD_MISSION_START, 0, 0).result == M.MAV_RESULT_ACCEPTED
            page.wait_for_function(f"() => {text}.endsWith('active')", timeout=BEHIND_MS)
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


FLEET_COLOURS = {"v1": [31, 119, 180], "v2": [255, 127, 14], "v3": [44, 160, 44]}  # the page's first three


def fleet_rows(page) -> dict[str, dict]:
    """The fleet table as the page shows it: {name: {column: text}}."""
    return page.evaluate("""() => {
        const heads = [...document.querySelectorAll('#fleet-table thead th')].map(th => th.textContent);
        const out = {};
        for (const tr of document.querySelectorAll('#fleet-table tbody tr[data-name]'))
            out[tr.dataset.name] = Object.fromEntries([...tr.children].map((td, i) => [heads[i], td.textContent]));
        return out; }""")


def markers(page) -> dict[str, dict]:
    """The fleet map's markers (metres in the common frame, pixels) and the canvas's colour under each."""
    return page.evaluate("""() => {
        const box = document.getElementById('fleet-map'), c = box.querySelector('canvas');
        const r = window.devicePixelRatio || 1, ctx = c.getContext('2d');
        const out = {};
        for (const m of JSON.parse(box.dataset.markers || '[]')) {
            const px = ctx.getImageData(Math.round(m.px * r), Math.round(m.py * r), 1, 1).data;
            out[m.name] = {...m, colour: Array.from(px), scale: Number(box.dataset.scale)};
        }
        return out; }""")


def until(page, c: Client, js: str, timeout: float) -> None:
    """Wait for ``js`` to hold on the page, heartbeating as a ground station meanwhile."""
    end = time.monotonic() + timeout
    while not page.evaluate(js):
        assert time.monotonic() < end, f"not within {timeout} s: {js}; table: {fleet_rows(page)}"
        c.conn.mav.heartbeat_send(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, 0)
        c.pump(0.25)


@pytest.mark.timeout(300)
def test_the_fleet_view_of_three_vehicles_one_flown_then_opened(browser, artifacts):
    """``quadsitl up --vehicles 3 --spacing 5 --dashboard``: the page opens on the fleet view, three rows with system
    ids 1, 2, 3 and three markers at their grid places in one frame (v1's home, v2 5 m east, v3 5 m north), drawn in
    their colours; system id 2 armed, taken off and sent 4 m north over MAVLink: its row says so and its marker
    moves there, the others stay; a click on its row opens its plots, as the single-vehicle view."""
    from quadsitl.frames import ned_to_geodetic
    from tests.mavclient import fleet_up

    port = free_port(socket.SOCK_STREAM)
    url = f"http://127.0.0.1:{port}/"
    with fleet_up(3, "--spacing", "5", "--dashboard", "--dashboard-port", str(port)) as fleet:
        c = Client(fleet.gcs_port)
        page = None
        try:
            wait_http(url, timeout=150)  # the fleet compiles the equations once before it starts
            page = browser.new_page(viewport={"width": 1500, "height": 1000})
            errors: list[str] = []
            page.on("pageerror", lambda e: errors.append(str(e)))
            page.goto(url)
            placed = "() => quadsitl.selected === '' && quadsitl.fleetMarkers.length === 3 " \
                     "&& quadsitl.fleetMarkers.every(m => m.known)"  # fmt: skip
            until(page, c, placed, 90)
            rows = fleet_rows(page)
            assert sorted(rows) == ["v1", "v2", "v3"]
            assert [rows[n]["system id"] for n in ("v1", "v2", "v3")] == ["1", "2", "3"]
            assert all(
                r["armed"] == "disarmed" and r["mode"] == "hold" and r["failsafe"] == "none" for r in rows.values()
            )
            # Live: each vehicle's telemetry less than a second old (on a loaded machine it may lag for a moment).
            live = "() => { const heads = [...document.querySelectorAll('#fleet-table thead th')]" \
                   ".map(th => th.textContent); const i = heads.indexOf('telemetry'); " \
                   "const rows = [...document.querySelectorAll('#fleet-table tbody tr[data-name]')]; " \
                   "return rows.length === 3 " \
                   "&& rows.every(tr => tr.children[i].textContent.startsWith('live')); }"  # fmt: skip
            until(page, c, live, 30)
            assert rows["v2"]["home N, E"] == "0.0, 5.0 m" and rows["v3"]["home N, E"] == "5.0, 0.0 m"
            m = markers(page)
            grid = {"v1": (0.0, 0.0), "v2": (0.0, 5.0), "v3": (5.0, 0.0)}  # 2 columns: rows northward
            for name, (north, east) in grid.items():
                assert (m[name]["north"], m[name]["east"]) == (
                    pytest.approx(north, abs=0.05),
                    pytest.approx(east, abs=0.05),
                )
                assert m[name]["colour"][:3] == pytest.approx(FLEET_COLOURS[name], abs=3), (name, m[name])
                assert m[name]["system_id"] == int(name[1])
            s = m["v1"]["scale"]  # north up, east right, equal scales
            assert m["v2"]["px"] - m["v1"]["px"] == pytest.approx(5 * s, abs=1.5)
            assert m["v1"]["py"] - m["v3"]["py"] == pytest.approx(5 * s, abs=1.5)

            # system id 2: arm, take off, then 4 m north of its home
            c.wait("SYS_STATUS", lambda msg: msg.get_srcSystem() == 2 and msg.onboard_control_sensors_health
                   & M.MAV_SYS_STATUS_PREARM_CHECK, 30)  # fmt: skip
            # (commands resent every second without an ACK, by the MAVLink command protocol, as ground stations do)
            assert c.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1, system=2).result == 0
            nan = math.nan
            assert c.command(M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, nan, nan, nan, nan, system=2).result == 0
            row = "document.querySelector('#fleet-table tr[data-name=v2]').children"
            until(page, c, f"() => {row}[3].textContent === 'armed' && {row}[2].textContent === 'takeoff'", 10)
            until(page, c, f"() => {row}[2].textContent === 'hold' && parseFloat({row}[8].textContent) > 2.0", 20)
            page.screenshot(path=str(artifacts / "dashboard-fleet-takeoff.png"), full_page=True)
            with urllib.request.urlopen(url + "api/vehicles", timeout=5) as r:
                v2 = next(v for v in json.loads(r.read())["vehicles"] if v["name"] == "v2")
            assert v2["system_id"] == 2 and v2["offset"][:2] == [
                pytest.approx(0.0, abs=1e-3),
                pytest.approx(5.0, abs=1e-3),
            ]
            home2 = (v2["home"]["latitude"], v2["home"]["longitude"])
            lat, lon = ned_to_geodetic(4.0, 0.0, *home2)
            ack = c.command_int(2, M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, M.MAV_CMD_DO_REPOSITION, -1, 1, 0, nan,
                                round(lat * 1e7), round(lon * 1e7), 2.5)  # fmt: skip
            assert ack.result == 0
            there = "() => { const m = quadsitl.fleetMarkers.find(m => m.name === 'v2'); " \
                    "return Math.hypot(m.north - 4, m.east - 5) < 0.3; }"  # fmt: skip
            until(page, c, there, 30)
            m = markers(page)
            assert m["v2"]["py"] < m["v1"]["py"] - 3 * s  # drawn north (up) of where it started
            assert (m["v1"]["north"], m["v1"]["east"]) == (pytest.approx(0.0, abs=0.05), pytest.approx(0.0, abs=0.05))
            assert (m["v3"]["north"], m["v3"]["east"]) == (pytest.approx(5.0, abs=0.05), pytest.approx(0.0, abs=0.05))
            trail = page.evaluate("() => quadsitl.trails.v2.x.length")
            assert trail > 10  # its trail, 5 points a simulated second
            page.screenshot(path=str(artifacts / "dashboard-fleet.png"), full_page=True)

            # a click on its row: v2's plots, as the single-vehicle view shows them
            page.click("#fleet-table tr[data-name=v2]")
            until(
                page, c, "() => quadsitl.selected === 'v2' && quadsitl.data.t.length > 50 && quadsitl.redraws > 1", 15
            )
            assert page.is_hidden("#fleet-view") and page.is_visible("#plot-altitude")
            shown = page_state(page)
            assert shown["armed"] == "armed" and shown["mode"] == "hold"
            assert page.evaluate("() => document.querySelector('#status [data-field=system_id]').textContent") == "2"
            x, alt = page.evaluate("() => [quadsitl.data.x.at(-1), quadsitl.data.altitude.at(-1)]")
            assert x == pytest.approx(4.0, abs=0.3) and alt == pytest.approx(2.5, abs=0.3)  # local: from its own home
            page.screenshot(path=str(artifacts / "dashboard-fleet-v2.png"), full_page=True)
            page.click("#fleet-tab")  # and back
            until(page, c, "() => !document.getElementById('fleet-view').hidden && quadsitl.fleetRedraws > 0", 5)
            assert not errors, errors
        finally:
            if page is not None:
                page.close()
            c.close()
