"""``quadsitl fly --dashboard`` and the dashboard's command line: URL printed, the run visible on
/api/vehicles, the page kept up after the flight until Ctrl-C, no orphans, and one-line errors."""

import json
import os
import signal
import socket
import subprocess
import time
import urllib.error
import urllib.request
from pathlib import Path

import pytest

from groundstation.launcher import free_port
from quadsitl.process_util import free_ports_apart
from tests.test_fly import alive, children_of, procs, quadsitl  # noqa: F401 (procs is a fixture)


def vehicles(url: str, timeout: float = 30.0) -> list[dict]:
    """The dashboard's ``api/vehicles``, asked again after a time-out for up to ``timeout`` s: ``quadsitl up`` runs
    its dashboard at idle priority, and a loaded machine can leave it without CPU for seconds."""
    end = time.monotonic() + timeout
    while True:
        try:
            with urllib.request.urlopen(url + "api/vehicles", timeout=5) as r:
                return json.loads(r.read())["vehicles"]
        except OSError:
            if time.monotonic() > end:
                raise
            time.sleep(0.2)


def wait_listed(url: str, count: int, timeout: float = 30.0) -> list[str]:
    """The names of the vehicles the dashboard at ``url`` lists, once it lists ``count`` (or at ``timeout`` s)."""
    end = time.monotonic() + timeout
    while True:
        listed = sorted(v["name"] for v in vehicles(url, max(0.0, end - time.monotonic())))
        if len(listed) >= count or time.monotonic() > end:
            return listed
        time.sleep(0.2)


@pytest.mark.timeout(90)
def test_fly_dashboard_prints_its_url_shows_the_run_and_stays_until_ctrl_c(tmp_path, procs):  # noqa: F811
    port = free_port(socket.SOCK_STREAM)
    err = open(tmp_path / "stderr.txt", "w+")  # noqa: SIM115 - closed below
    # 12 s at twice real time: 6 s of wall time in offboard, for samples of an idle-priority server on a loaded
    # machine (CI runs' samples missed a 1.5 s, then a 3 s, offboard phase and saw only the landing)
    fly = subprocess.Popen(quadsitl("fly", "--dashboard", "--dashboard-port", str(port), "--speed", "2", "--duration",
                                    "12", "--no-figures", "--out", str(tmp_path / "run")),
                           stdout=subprocess.PIPE, stderr=err, text=True)  # fmt: skip
    procs.append(fly)
    line = fly.stdout.readline()
    url = f"http://127.0.0.1:{port}/"
    assert line.strip() == f"quadsitl fly: dashboard at {url}"
    modes, rates, telemetry = set(), [], []
    deadline = time.monotonic() + 40
    while time.monotonic() < deadline and "flight done" not in (tmp_path / "stderr.txt").read_text():
        try:
            vs = vehicles(url)
        except (TimeoutError, urllib.error.URLError):  # an idle-priority server on a loaded machine: the next sample
            continue
        if vs and vs[0]["status"] and vs[0]["status"]["armed"]:
            modes.add(vs[0]["status"]["mode"])
            telemetry.append(vs[0]["link"]["telemetry"])
            if vs[0]["real_time_factor"] is not None:  # None until it has 0.2 s of wall time to go by
                rates.append(vs[0]["real_time_factor"])
        time.sleep(0.2)
    assert "offboard" in modes and rates
    # The telemetry is live while the vehicle flies. The dashboard runs at idle priority (it never slows a flight),
    # so on a machine whose cores are both taken (the suite's other worker flying an unpaced lockstep run, which
    # polls both) it may fall a second behind now and then: most of the samples, not every one.
    assert set(telemetry) <= {"live", "stale"} and telemetry.count("live") >= max(3, len(telemetry) / 2), telemetry
    assert 1.0 < max(rates) < 3.0  # --speed 2
    assert "flight done" in (tmp_path / "stderr.txt").read_text()
    assert (tmp_path / "run" / "metrics.json").exists()
    kids = children_of(fly.pid)
    assert len(kids) == 1  # plant, autopilot and ground station are gone; the dashboard stays
    time.sleep(1.2)  # longer than the dashboard waits before it calls the telemetry stale
    (v,) = vehicles(url)
    assert v["status"]["armed"] is False and v["status"]["mode"] == "land"
    assert v["link"]["telemetry"] == "stale" and v["tick_rate"] == 0.0  # the autopilot has stopped
    fly.send_signal(signal.SIGINT)
    assert fly.wait(15) == 0
    time.sleep(0.2)
    assert not [pid for pid in kids if alive(pid)]
    err.close()


def test_a_busy_dashboard_port_is_refused_before_anything_starts(cli):
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        port = s.getsockname()[1]
        for argv, option in ((["dashboard", "--port", str(port)], "--port"),
                             (["up", "--dashboard", "--dashboard-port", str(port)], "--dashboard-port"),
                             (["fly", "--dashboard", "--dashboard-port", str(port)], "--dashboard-port")):  # fmt: skip
            r = cli(*argv, timeout=60)
            assert r.returncode == 2, (argv, r.stderr)
            assert f"{option} {port}" in r.stderr and f"choose another with {option}" in r.stderr
            assert "Traceback" not in r.stderr and len(r.stderr.strip().splitlines()) == 1


@pytest.mark.parametrize(
    ("argv", "needle"),
    [
        (["dashboard", "--plot-rate", "0"], "--plot-rate 0"),
        (["dashboard", "--window", "nan"], "--window nan"),
        (["dashboard", "--port", "70000"], "--port 70000"),
        (["dashboard", "--host", "not a host"], "--host"),
        (["up", "--dashboard", "--no-zenoh"], "--dashboard needs the Zenoh telemetry"),
    ],
)
def test_dashboard_options_are_checked(cli, argv, needle):
    r = cli(*argv, timeout=60)
    assert r.returncode == 2 and needle in r.stderr and "Traceback" not in r.stderr, r.stderr


@pytest.mark.timeout(90)
def test_hostile_zenoh_publishers_do_not_hurt_the_dashboard():
    """Garbage on the telemetry keys, strangers' keys and hundreds of made-up vehicles, from a real Zenoh
    session, while the vehicle runs: the dashboard stays up, counts what it refuses, keeps showing the
    vehicle, and never holds more than MAX_VEHICLES."""
    import random

    import zenoh

    from groundstation.dashboard.model import MAX_VEHICLES
    from quadsitl import telemetry
    from tests.mavclient import quadsitl_up
    from tests.test_dashboard_browser import Publisher, wait_http

    port = free_port(socket.SOCK_STREAM)
    url = f"http://127.0.0.1:{port}/"
    with quadsitl_up("--dashboard", "--dashboard-port", str(port)) as v:
        wait_http(url)
        session = zenoh.open(telemetry.zenoh_config(connect=[v.zenoh]))
        try:
            # Peers reach each other directly (the autopilot's session does not forward between them): wait
            # until this one has found the dashboard's subscriber (the only one on the overview keys), or its
            # samples go nowhere. Counting peers is not enough: the launcher's info session is one too.
            probe = session.declare_publisher(telemetry.overview_key("v1"))
            Publisher.wait_matching([probe], "the dashboard's Zenoh subscriber was never found")
            probe.undeclare()
            rng = random.Random(5)
            for i in range(3000):
                stream = rng.choice([*telemetry.STREAMS, "junk"])
                vehicle = "v1" if i % 3 else f"x{rng.randrange(500)}"
                payload = rng.randbytes(rng.choice([0, 1, 7, 13, 50, 112, 113, 400, telemetry.OVERVIEW_SIZE]))
                # the overview every vehicle is followed by, and the full rate a page would take
                key = telemetry.overview_key(vehicle) if i % 2 else f"quadsitl/{vehicle}/{stream}"
                session.put(key, payload)
                if i % 500 == 0:
                    session.put("quadsitl/a/b/c/d", b"deep")
                    session.put("elsewhere/v1/state", b"x")
            time.sleep(1.0)
        finally:
            session.close()
        # The idle-priority server may be a while behind on a loaded machine: its view once it has caught up.
        end = time.monotonic() + 30
        while True:
            vs = {x["name"]: x for x in vehicles(url)}
            v1 = vs.get("v1")
            caught_up = v1 is not None and v1["link"]["telemetry"] == "live" and v1["link"]["malformed"] > 100
            if caught_up or time.monotonic() > end:
                break
            time.sleep(0.2)
        assert len(vs) <= MAX_VEHICLES and caught_up, vs.get("v1")
        assert v1["status"]["mode"] == "hold" and v1["tick_rate"] and 500 < v1["tick_rate"] < 2000
        with urllib.request.urlopen(url, timeout=5) as r:
            assert r.status == 200 and b"quadsitl" in r.read()


@pytest.mark.timeout(120)
def test_a_dashboard_that_dies_is_reported_and_the_vehicle_flies_on(tmp_path, procs):  # noqa: F811
    from tests.mavclient import Client

    port, (gcs, gcs_listen, api_listen) = free_port(socket.SOCK_STREAM), free_ports_apart(3)
    zenoh_ep = f"tcp/127.0.0.1:{free_port(socket.SOCK_STREAM)}"
    err = tmp_path / "stderr.txt"
    with open(err, "w") as f:
        up = subprocess.Popen(quadsitl("up", "-q", "--dashboard", "--dashboard-port", str(port), "--gcs-listen",
                                       f"127.0.0.1:{gcs_listen}", "--gcs-remote", f"127.0.0.1:{gcs}", "--api-listen",
                                       f"127.0.0.1:{api_listen}", "--api-remote", "none", "--zenoh-listen", zenoh_ep),
                              stderr=f)  # fmt: skip
    procs.append(up)
    url = f"http://127.0.0.1:{port}/"
    from tests.test_dashboard_browser import wait_http

    wait_http(url)
    (dash,) = [pid for pid in children_of(up.pid) if b"dashboard" in Path(f"/proc/{pid}/cmdline").read_bytes()]
    os.kill(dash, signal.SIGKILL)
    said = "quadsitl up: warning: the dashboard process was killed by signal 9 (SIGKILL); the others go on"
    end = time.monotonic() + 10  # `up` looks at its children every few tenths of a second
    while said not in err.read_text() and time.monotonic() < end:
        time.sleep(0.1)
    assert said in err.read_text()
    assert up.poll() is None  # plant and autopilot go on
    c = Client(gcs)
    try:
        c.heartbeat()  # the vehicle still answers
    finally:
        c.close()
    up.send_signal(signal.SIGTERM)
    assert up.wait(15) == 0
