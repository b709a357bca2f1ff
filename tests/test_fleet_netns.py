"""A fleet across two hosts, made real: two Linux network namespaces joined by a veth pair. Host A runs
``quadsitl up --vehicles 2`` with its Zenoh sessions connecting to the router on B and its MAVLink links
streaming to B; host B runs ``quadsitl router``, ``quadsitl dashboard`` (through the router) and a MAVSDK client
on vehicle 2's offboard port (tests/netns_client.py). Telemetry of v1 and v2 arrives across, both system ids are
heard on B's ground-station port, and MAVSDK arms and takes off vehicle 2: it climbs, vehicle 1 stays down.

Needs root and iproute2's ``ip``: skipped without them, except where $CI is set (CI runs as root, and
./scripts/test installs iproute2), where it fails instead. Each namespace has its own network stack, so the
PX4 ports (14550, 14540 + i, 18570 + i, 14580 + i) and Zenoh's 7447 are used as on two real machines, whatever
else runs on this one; the names carry the test's pid, and the /24 lives only inside the two namespaces.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
SUBNET = "10.213.47"  # A is .1, B is .2: a /24 that exists only inside the two namespaces
A_ADDR, B_ADDR = f"{SUBNET}.1", f"{SUBNET}.2"
IP = shutil.which("ip") or next((p for p in ("/usr/sbin/ip", "/sbin/ip") if os.access(p, os.X_OK)), None)


def unavailable() -> str | None:
    if not sys.platform.startswith("linux"):
        return "needs Linux network namespaces"
    if os.geteuid() != 0:
        return "needs root to make network namespaces (ip netns add); CI runs it as root"
    if IP is None:
        return "needs iproute2's ip (./scripts/test installs it: apt-get install iproute2)"
    return None


def not_here(why: str) -> None:
    """Skip, but fail where $CI is set: CI must run this test."""
    if os.environ.get("CI"):
        pytest.fail(f"the two-host test cannot run: {why} (CI is set, so this is a failure, not a skip)")
    pytest.skip(why)


def ip(*args: str) -> None:
    r = subprocess.run([IP, *args], capture_output=True, text=True, timeout=10)
    if r.returncode != 0:
        raise RuntimeError(f"ip {' '.join(args)}: {r.stderr.strip()}")


class Hosts:
    """Two namespaces ``a`` and ``b`` joined by a veth pair, and the processes started in them."""

    def __init__(self, tmp: Path) -> None:
        pid = os.getpid()
        self.a, self.b = f"quadsitl-a-{pid}", f"quadsitl-b-{pid}"
        self.tmp = tmp
        self.procs: list[subprocess.Popen] = []

    def make(self) -> None:
        pid = os.getpid()
        veth_a, veth_b = f"qsa{pid}"[:15], f"qsb{pid}"[:15]  # interface names: at most 15 characters
        ip("netns", "add", self.a)
        ip("netns", "add", self.b)
        ip("link", "add", veth_a, "netns", self.a, "type", "veth", "peer", "name", veth_b, "netns", self.b)
        for ns, dev, addr in ((self.a, veth_a, A_ADDR), (self.b, veth_b, B_ADDR)):
            ip("-n", ns, "addr", "add", f"{addr}/24", "dev", dev)
            ip("-n", ns, "link", "set", dev, "up")
            ip("-n", ns, "link", "set", "lo", "up")

    def start(self, ns: str, name: str, *args: str) -> subprocess.Popen:
        """``quadsitl ARGS`` in namespace ``ns``; its stdout and stderr in tmp/NAME.out and .err."""
        argv = [IP, "netns", "exec", ns, sys.executable, "-m", "groundstation.cli", *args]
        with open(self.tmp / f"{name}.out", "w") as out, open(self.tmp / f"{name}.err", "w") as err:
            proc = subprocess.Popen(argv, cwd=ROOT, stdout=out, stderr=err, start_new_session=True)
        self.procs.append(proc)
        return proc

    def output(self, name: str) -> str:
        return (self.tmp / f"{name}.out").read_text() + (self.tmp / f"{name}.err").read_text()

    def clean_up(self) -> None:
        for p in self.procs:  # `ip netns exec` execs the command: the pid is quadsitl's, its group its children
            if p.poll() is None:
                os.killpg(p.pid, signal.SIGTERM)
        end = time.monotonic() + 8.0
        for p in self.procs:
            try:
                p.wait(max(0.1, end - time.monotonic()))
            except subprocess.TimeoutExpired:
                os.killpg(p.pid, signal.SIGKILL)
                p.wait()
        for ns in (self.a, self.b):  # deleting a namespace deletes its end of the veth pair, and so the pair
            subprocess.run([IP, "netns", "del", ns], capture_output=True, timeout=10)


@pytest.fixture
def hosts(tmp_path):
    why = unavailable()
    if why:
        not_here(why)
    h = Hosts(tmp_path)
    try:
        try:
            h.make()
        except RuntimeError as exc:  # e.g. a container without CAP_SYS_ADMIN
            not_here(f"cannot make the network namespaces: {exc}")
        yield h
    finally:
        h.clean_up()


def wait_for_line(h: Hosts, name: str, text: str, proc: subprocess.Popen, timeout: float) -> str:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        out = h.output(name)
        if text in out:
            return out
        if proc.poll() is not None:
            break
        time.sleep(0.05)
    raise AssertionError(f"{name}: no {text!r} within {timeout} s (status {proc.poll()}):\n{h.output(name)}")


@pytest.mark.timeout(150)
def test_two_hosts_telemetry_through_a_router_and_mavsdk_flies_vehicle_2_across(hosts):
    h = hosts
    started = time.time()
    router = h.start(h.b, "router", "router", "--listen", "tcp/0.0.0.0:7447")
    banner = wait_for_line(h, "router", "Ctrl-C stops", router, 20)
    assert "Zenoh router " in banner and "listening on tcp/0.0.0.0:7447" in banner, banner
    h.start(h.b, "dashboard", "dashboard", "--zenoh-connect", "tcp/127.0.0.1:7447", "--port", "8050")
    up = h.start(h.a, "up", "up", "--vehicles", "2", "--zenoh-connect", f"tcp/{B_ADDR}:7447",
                 "--gcs-remote", f"{B_ADDR}:14550", "--api-remote", f"{B_ADDR}:14540")  # fmt: skip
    up_started = time.time()
    client = subprocess.run(
        [IP, "netns", "exec", h.b, sys.executable, "-m", "tests.netns_client", "--dashboard",
         "http://127.0.0.1:8050", "--router", "tcp/127.0.0.1:7447", "--gcs", "14550", "--api", "14541"],
        cwd=ROOT, capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert client.returncode == 0, f"{client.stdout}\n{client.stderr}\n--- up:\n{h.output('up')}"
    seen = json.loads(client.stdout.strip().splitlines()[-1])
    assert up.poll() is None, h.output("up")

    # up's banner: the links bound to A's address (the interface facing B), the clients' one-line connections
    text = h.output("up")
    for line in (f"{B_ADDR}:14550    on {B_ADDR}: mavproxy.py --master=udpin:0.0.0.0:14550",
                 f"{A_ADDR}:18571 {A_ADDR}:14581 → udpin://0.0.0.0:14541 on {B_ADDR}",
                 f"Zenoh through the router at tcp/{B_ADDR}:7447"):  # fmt: skip
        assert line in text, text
    # telemetry crossed: the dashboard on B, fed by the router, showed v1 and v2 live; samples came through it
    assert seen["latency_samples"] > 100
    assert seen["zenoh_routers"] == 1 and seen["zenoh_peers"] <= 1  # the router, and at most the dashboard (on B)
    # the ground-station port on B hears both vehicles; MAVSDK on 14541 finds vehicle 2 only, and flies it
    assert seen["heartbeat_system_ids"] == [1, 2]
    assert seen["mavsdk_system_ids"] == [2] and seen["mavsdk_altitude"] > 2.5
    z = seen["dashboard_z"]
    assert z["v2"] < -2.5  # vehicle 2 climbed (NED: z down)
    assert abs(z["v1"]) < 0.01  # vehicle 1 did not
    print(f"\ntwo hosts: up → both vehicles live on B's dashboard in {seen['live_at'] - up_started:.1f} s "
          f"(router up {up_started - started:.1f} s before); Zenoh state samples through the router: median "
          f"{seen['latency_median_ms']:.2f} ms, p95 {seen['latency_p95_ms']:.2f} ms after publication "
          f"({seen['latency_samples']} samples in 2 s); wall {time.time() - started:.1f} s")  # fmt: skip
