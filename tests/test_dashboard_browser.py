"""The dashboard in a real browser: Debian's headless Chromium driven by Playwright, against
``quadsitl up --dashboard`` flown by a raw pymavlink client. The page must show live data within seconds,
redraw its plots as the flight goes on, and show the response change when a gain is changed over MAVLink.
Screenshots go to ``$QUADSITL_ARTIFACTS`` (default: the test's temporary folder)."""

from __future__ import annotations

import json
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
            assert set(veh["setpoint"]) == {"t", "altitude_ref", "roll_ref", "pitch_ref", "yaw_ref"}
            # every tab follows the same vehicle independently
            last = [p.evaluate("() => quadsitl.lastT") for p in pages]
            assert max(last) - min(last) < 1.0
        finally:
            for p in pages:
                p.close()
