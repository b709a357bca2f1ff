"""``quadsitl router`` and ``up --zenoh-connect`` on this host: bad endpoints and busy ports refused in one line
before anything starts; the router's banner, Zenoh clients (which reach each other only through a router)
talking through it, a clean stop on SIGTERM; a vehicle of ``up`` whose telemetry goes through it. The two-host
version is tests/test_fleet_netns.py."""

from __future__ import annotations

import argparse
import signal
import socket
import subprocess
import sys
import threading
import time

import pytest

from groundstation.fleet import plan_fleet, zenoh_argv
from groundstation.launcher import fleet_banner, free_port
from tests.mavclient import free_ports
from tests.test_dashboard_cli import wait_listed


def start_router(*args: str) -> tuple[subprocess.Popen, str]:
    """``quadsitl router ARGS`` and its banner line."""
    proc = subprocess.Popen([sys.executable, "-m", "groundstation.cli", "router", *args], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)  # fmt: skip
    line = proc.stdout.readline()
    assert line, proc.stderr.read()
    return proc, line


def stop(proc: subprocess.Popen) -> int:
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
    return proc.returncode


def read_banner(up: subprocess.Popen) -> str:
    """``quadsitl up``'s banner from its stdout, up to its last line."""
    banner = ""
    while not banner.endswith("  Ctrl-C stops.\n"):
        line = up.stdout.readline()
        assert line, f"up ended before its banner (status {up.wait()}): {banner}"
        banner += line
    return banner


def client_session(endpoint: str):
    import zenoh

    from quadsitl.telemetry import zenoh_config

    return zenoh.open(zenoh_config("client", connect=[endpoint]))


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["router", "--listen", "garbage"], "--listen garbage: expected PROTOCOL/HOST:PORT, PROTOCOL one of tcp, "
         "tls, udp, quic, ws and PORT in 0..65535, e.g. tcp/127.0.0.1:7447"),
        (["router", "--listen", "tcp/127.0.0.1:70000"], "--listen tcp/127.0.0.1:70000: expected PROTOCOL/HOST:PORT"),
        (["router", "--listen", "serial/dev/ttyUSB0:115200"], "--listen serial/dev/ttyUSB0:115200: expected"),
        (["router", "--listen", "tcp/192.0.2.99:7447"], "--listen tcp/192.0.2.99:7447: cannot listen on "
         "192.0.2.99:7447: Cannot assign requested address (not an address of this machine; 0.0.0.0 is all of them)"),
        (["router", "--connect", "tcp/nohost"], "--connect tcp/nohost: expected PROTOCOL/HOST:PORT"),
        (["up", "--zenoh-connect", "tcp:10.0.0.2:7447"], "--zenoh-connect tcp:10.0.0.2:7447: expected "
         "PROTOCOL/HOST:PORT, PROTOCOL one of tcp, tls, udp, quic, ws and PORT in 0..65535, e.g. tcp/10.0.0.2:7447"),
        (["up", "--zenoh-connect", "tcp/127.0.0.1:7447", "--no-zenoh"], "--zenoh-connect tcp/127.0.0.1:7447 with "
         "--no-zenoh: expected one or the other"),
        (["up", "--zenoh-connect", "tcp/127.0.0.1:7447", "--zenoh-listen", "tcp/127.0.0.1:7448"],
         "--zenoh-connect tcp/127.0.0.1:7447 with --zenoh-listen tcp/127.0.0.1:7448: expected one or the other"),
    ],
)  # fmt: skip
def test_bad_router_and_connect_endpoints_are_refused_in_one_line(cli, argv, message):
    r = cli(*argv, timeout=60)
    assert r.returncode == 2 and r.stdout == "", (r.stdout, r.stderr)
    assert r.stderr.count("\n") == 1 and r.stderr.startswith(f"quadsitl {argv[0]}: error: {message}"), r.stderr


def test_a_busy_router_port_and_a_router_that_is_not_there_are_refused(cli):
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        r = cli("router", "--listen", f"tcp/127.0.0.1:{port}", timeout=60)
    assert r.returncode == 2 and r.stderr == (
        f"quadsitl router: error: --listen tcp/127.0.0.1:{port}: cannot listen on 127.0.0.1:{port}: Address already "
        "in use; choose another with --listen tcp/HOST:PORT\n"
    )
    nobody = free_port(socket.SOCK_STREAM)
    r = cli("up", "--vehicles", "2", "--zenoh-connect", f"tcp/127.0.0.1:{nobody}", timeout=60)
    assert r.returncode == 2 and r.stderr == (
        f"quadsitl up: error: --zenoh-connect tcp/127.0.0.1:{nobody}: no router answers there (Connection refused); "
        f"start it first there: quadsitl router --listen tcp/0.0.0.0:{nobody}\n"
    )


@pytest.mark.timeout(60)
def test_the_router_carries_samples_between_its_clients_and_stops_on_sigterm():
    port = free_port(socket.SOCK_STREAM)
    endpoint = f"tcp/127.0.0.1:{port}"
    proc, banner = start_router("--listen", endpoint)
    try:
        assert banner.startswith("quadsitl router: Zenoh router ") and banner.endswith(
            f" listening on {endpoint}; Ctrl-C stops\n"
        ), banner
        zid = banner.split()[4]
        got: list[bytes] = []
        arrived = threading.Event()
        with client_session(endpoint) as sub_session, client_session(endpoint) as pub_session:
            assert [str(z) for z in sub_session.info.routers_zid()] == [zid]  # the one the banner named
            sub = sub_session.declare_subscriber("quadsitl/v9/**", lambda s: (got.append(s.payload.to_bytes()),
                                                                               arrived.set()))  # fmt: skip
            end = time.monotonic() + 10
            while not arrived.is_set() and time.monotonic() < end:  # until the subscription has reached the router
                pub_session.put("quadsitl/v9/state", b"across")
                arrived.wait(0.1)
            sub.undeclare()
        assert got and got[0] == b"across"
    finally:
        status = stop(proc)
    assert status == 0, proc.stderr.read()


@pytest.mark.timeout(120)
def test_a_vehicle_of_up_sends_its_telemetry_through_a_router():
    port = free_port(socket.SOCK_STREAM)
    endpoint = f"tcp/127.0.0.1:{port}"
    router, _ = start_router("--listen", endpoint)
    taken: set[int] = set()
    gcs_listen, gcs, api_listen, api = (free_ports(1, taken=taken) for _ in range(4))
    up = subprocess.Popen([sys.executable, "-m", "groundstation.cli", "up", "--zenoh-connect", endpoint,
                           "--gcs-listen", f"127.0.0.1:{gcs_listen}", "--gcs-remote", f"127.0.0.1:{gcs}",
                           "--api-listen", f"127.0.0.1:{api_listen}", "--api-remote", f"127.0.0.1:{api}",
                           "--dashboard", "--dashboard-port", "0"], stdout=subprocess.PIPE, text=True)  # fmt: skip
    names: set[str] = set()
    try:
        banner = read_banner(up)
        assert f"  telemetry:       Zenoh through the router at {endpoint}, keys quadsitl/v1/" in banner, banner
        url = banner.split("  dashboard:       ")[1].split()[0]
        with client_session(endpoint) as session:
            sub = session.declare_subscriber("quadsitl/*/state", lambda s: names.add(str(s.key_expr)))
            end = time.monotonic() + 60
            while not names and time.monotonic() < end and up.poll() is None:
                time.sleep(0.1)
            sub.undeclare()
        assert names == {"quadsitl/v1/state"}
        # up's dashboard, through the router too: it runs at idle priority, and on a loaded machine it may hear the
        # vehicle a moment after this subscriber did.
        assert wait_listed(url, 1) == ["v1"]
    finally:
        assert stop(up) == 0
        stop(router)


def test_with_a_router_every_session_is_its_client():
    assert zenoh_argv(0, "tcp/127.0.0.1:7447", [], True) == ["--zenoh-listen", "tcp/127.0.0.1:7447"]
    assert zenoh_argv(0, "tcp/127.0.0.1:7447", [], False) == ["--zenoh-connect", "tcp/127.0.0.1:7447"]
    assert zenoh_argv(1, "tcp/127.0.0.1:7447", [], True) == ["--zenoh-connect", "tcp/127.0.0.1:7447"]
    for index, autopilot in ((0, True), (0, False), (3, True)):
        assert zenoh_argv(index, None, ["tcp/10.0.0.2:7447", "tcp/10.0.0.3:7447"], autopilot) == [
            "--zenoh-mode", "client", "--zenoh-connect", "tcp/10.0.0.2:7447", "--zenoh-connect", "tcp/10.0.0.3:7447"
        ]  # fmt: skip
    # up --zenoh-config: every session takes the file as well, its endpoints replaced by these
    assert zenoh_argv(1, None, ["tls/10.0.0.2:7447"], True, "/etc/tls.json5") == [
        "--zenoh-mode", "client", "--zenoh-connect", "tls/10.0.0.2:7447", "--zenoh-config", "/etc/tls.json5"
    ]  # fmt: skip
    assert zenoh_argv(0, "tcp/127.0.0.1:7447", [], True, "/etc/tls.json5") == [
        "--zenoh-listen", "tcp/127.0.0.1:7447", "--zenoh-config", "/etc/tls.json5"
    ]  # fmt: skip


def test_the_fleet_banner_says_where_each_client_runs_when_it_is_another_host():
    fleet = plan_fleet(2, preset="paper", gcs_listen="10.0.0.1:18570", gcs_remote="10.0.0.2:14550",
                       api_listen="10.0.0.1:14580", api_remote="10.0.0.2:14540")  # fmt: skip
    args = argparse.Namespace(mode="lockstep", speed=1.0, controller=None, no_zenoh=False, zenoh_listen=None,
                              zenoh_connect=["tcp/10.0.0.2:7447"])  # fmt: skip
    text = fleet_banner(fleet, args)
    assert (
        "every vehicle streams MAVLink to udp 10.0.0.2:14550    on 10.0.0.2: mavproxy.py --master=udpin:0.0.0.0:14550"
        in text
    )
    assert "10.0.0.1:18571  10.0.0.1:14581 → udpin://0.0.0.0:14541 on 10.0.0.2" in text
    assert "Zenoh through the router at tcp/10.0.0.2:7447, keys" in text
    here = argparse.Namespace(**{**vars(args), "zenoh_connect": [], "zenoh_listen": "tcp/127.0.0.1:7447"})
    local = fleet_banner(plan_fleet(2, preset="paper"), here)
    assert "mavproxy.py --master=udpin:127.0.0.1:14550" in local and " on 127.0.0.1" not in local
    assert "127.0.0.1:14581 → udpin://0.0.0.0:14541\n" in local and "Zenoh tcp/127.0.0.1:7447, keys" in local
    assert "quadsitl up: 2 vehicles, each preset's controller, lockstep at 1× real time\n" in local
    awake = argparse.Namespace(**{**vars(here), "mode": "realtime", "cores_awake": True})
    assert ", real time (free-running plant), cores kept awake (PM QoS)\n" in fleet_banner(
        plan_fleet(2, preset="paper"), awake
    )
