"""Zenoh with TLS and access control, through Zenoh's own configuration files (docs/zenoh/): telemetry
still flows to a subscriber that trusts the CA, and not to one that does not."""

import shutil
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
import zenoh

from groundstation.launcher import free_port
from tests.mavclient import free_ports
from tests.test_dashboard_cli import wait_listed

DOCS = Path(__file__).resolve().parent.parent / "docs" / "zenoh"


def config(src: Path, dst: Path, port: int) -> Path:
    dst.write_text(src.read_text().replace("localhost:7447", f"localhost:{port}"))
    return dst


@pytest.fixture
def tls_autopilot(tmp_path):
    if shutil.which("openssl") is None:
        pytest.fail("openssl is needed to make the test certificates (./scripts/test installs it)")
    subprocess.run(["sh", str(DOCS / "make-certs.sh"), str(tmp_path / "certs")], check=True, capture_output=True)
    port = free_port(socket.SOCK_STREAM)
    ap_conf = config(DOCS / "autopilot-tls-acl.json5", tmp_path / "autopilot.json5", port)
    plant_port = free_port()
    ap = subprocess.Popen([sys.executable, "-m", "autopilot", "--plant-listen", f"127.0.0.1:{plant_port}",
                           "--gcs-listen", "127.0.0.1:0", "--gcs-remote", "none", "--api-listen", "127.0.0.1:0",
                           "--api-remote", "none", "--zenoh-config", str(ap_conf)], cwd=tmp_path)  # fmt: skip
    plant = subprocess.Popen([sys.executable, "-m", "sitl", "--autopilot", f"127.0.0.1:{plant_port}", "--speed", "1"])
    end = time.monotonic() + 20
    while time.monotonic() < end:  # until the autopilot's TLS listener is up
        with socket.socket() as s:
            if s.connect_ex(("127.0.0.1", port)) == 0:
                break
        time.sleep(0.1)
    try:
        yield tmp_path, port
    finally:
        for p in (plant, ap):
            p.terminate()
        for p in (plant, ap):
            p.wait(10)


def received(conf_path: Path, cwd: Path, seconds: float, enough: int | None = None) -> int:
    """How many quadsitl/v1/state samples a session opened with ``conf_path`` receives in ``seconds`` of wall time
    (or until ``enough`` have come)."""
    import os

    old = os.getcwd()
    os.chdir(cwd)  # the configuration's certificate paths are relative
    try:
        session = zenoh.open(zenoh.Config.from_file(str(conf_path)))
    finally:
        os.chdir(old)
    count = [0]
    lock = threading.Lock()

    def cb(sample: zenoh.Sample) -> None:
        with lock:
            count[0] += 1

    sub = session.declare_subscriber("quadsitl/v1/state", cb)
    end = time.monotonic() + seconds
    while time.monotonic() < end and (enough is None or count[0] < enough):
        time.sleep(0.05)
    sub.undeclare()
    session.close()
    return count[0]


def test_telemetry_flows_over_tls_with_access_control_and_not_to_an_untrusting_subscriber(tls_autopilot):
    tmp, port = tls_autopilot
    trusted = config(DOCS / "subscriber-tls.json5", tmp / "sub.json5", port)
    # samples (each with one or more records) at 1 kHz: 50 a second; a loaded machine may start the flight late
    assert received(trusted, tmp, 30.0, enough=51) > 50
    untrusted = tmp / "untrusted.json5"
    untrusted.write_text(trusted.read_text().replace('root_ca_certificate: "certs/ca.pem"', ""))
    assert received(untrusted, tmp, 2.0) == 0


@pytest.mark.timeout(180)
def test_up_flies_a_fleet_through_a_tls_router_with_its_configuration(tmp_path):
    """``up --zenoh-config``: every session up opens takes the file (here: trust the CA of a router that speaks only
    TLS), the vehicles', the plant's, the vehicle info's and the dashboard's alike."""
    from tests.test_router import read_banner, start_router, stop

    if shutil.which("openssl") is None:
        pytest.fail("openssl is needed to make the test certificates (./scripts/test installs it)")
    subprocess.run(["sh", str(DOCS / "make-certs.sh"), str(tmp_path / "certs")], check=True, capture_output=True)
    port = free_port(socket.SOCK_STREAM)
    router_conf = config(DOCS / "router-tls.json5", tmp_path / "router.json5", port)
    client_conf = config(DOCS / "subscriber-tls.json5", tmp_path / "client.json5", port)
    for conf in (router_conf, client_conf):  # absolute certificate paths: the processes start elsewhere
        conf.write_text(conf.read_text().replace('"certs/', f'"{tmp_path}/certs/'))
    endpoint = f"tls/localhost:{port}"
    router, banner = start_router("--zenoh-config", str(router_conf))
    assert f"listening on {endpoint}" in banner, banner
    taken: set[int] = set()
    gcs, api = free_ports(1, taken=taken), free_ports(2, taken=taken)
    gcs_listen, api_listen = free_ports(2, taken=taken), free_ports(2, taken=taken)
    up = subprocess.Popen([sys.executable, "-m", "groundstation.cli", "up", "--vehicles", "2", "--zenoh-connect",
                           endpoint, "--zenoh-config", str(client_conf), "--gcs-listen", f"127.0.0.1:{gcs_listen}",
                           "--gcs-remote", f"127.0.0.1:{gcs}", "--api-listen", f"127.0.0.1:{api_listen}",
                           "--api-remote", f"127.0.0.1:{api}", "--dashboard", "--dashboard-port", "0"],
                          stdout=subprocess.PIPE, text=True)  # fmt: skip
    try:
        text = read_banner(up)
        assert f"through the router at {endpoint} (configuration {client_conf})" in text, text
        url = text.split("  dashboard:       ")[1].split()[0]
        names: set[str] = set()
        session = zenoh.open(zenoh.Config.from_file(str(client_conf)))  # a subscriber that trusts the CA, via TLS
        try:
            sub = session.declare_subscriber("quadsitl/*/state", lambda s: names.add(str(s.key_expr)))
            end = time.monotonic() + 60
            while len(names) < 2 and time.monotonic() < end and up.poll() is None:
                time.sleep(0.1)
            sub.undeclare()
        finally:
            session.close()
        assert names == {"quadsitl/v1/state", "quadsitl/v2/state"}
        assert wait_listed(url, 2) == ["v1", "v2"]  # the dashboard, through the router over TLS as well
    finally:
        assert stop(up) == 0
        stop(router)


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (
            ["--zenoh-config", "missing.json5"],
            "--zenoh-config missing.json5: no such file (a Zenoh JSON5 configuration: see docs/security.md)",
        ),
        (["--zenoh-config", "bad.json5"], "--zenoh-config bad.json5: Zenoh cannot read it: "),
        (
            ["--zenoh-config", "good.json5", "--no-zenoh"],
            "--zenoh-config good.json5 with --no-zenoh: expected one or the other",
        ),
    ],
)
def test_up_refuses_a_zenoh_configuration_it_cannot_use_before_anything_starts(tmp_path, argv, message):
    (tmp_path / "bad.json5").write_text("{ mode: [unclosed")
    (tmp_path / "good.json5").write_text('{ mode: "peer" }')
    r = subprocess.run([sys.executable, "-m", "groundstation.cli", "up", *argv], capture_output=True, text=True,
                       timeout=60, cwd=tmp_path)  # fmt: skip
    assert r.returncode == 2 and r.stdout == ""
    (line,) = r.stderr.strip().splitlines()
    assert line.startswith(f"quadsitl up: error: {message}"), line
