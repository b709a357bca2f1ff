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


def received(conf_path: Path, cwd: Path, seconds: float) -> int:
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
    time.sleep(seconds)
    sub.undeclare()
    session.close()
    return count[0]


def test_telemetry_flows_over_tls_with_access_control_and_not_to_an_untrusting_subscriber(tls_autopilot):
    tmp, port = tls_autopilot
    trusted = config(DOCS / "subscriber-tls.json5", tmp / "sub.json5", port)
    assert received(trusted, tmp, 3.0) > 50  # samples (each with one or more records) at 1 kHz
    untrusted = tmp / "untrusted.json5"
    untrusted.write_text(trusted.read_text().replace('root_ca_certificate: "certs/ca.pem"', ""))
    assert received(untrusted, tmp, 2.0) == 0
