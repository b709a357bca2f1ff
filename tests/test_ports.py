"""quadsitl.process_util.free_port: the ports handed to child processes come from outside the OS's ephemeral range
(no other socket is given them by the OS before the child binds), are free when picked, never one a plan has named
but not bound yet, and the pick falls back to the OS's own choice where the ephemeral range leaves nothing outside
it."""

from __future__ import annotations

import os
import random
import socket
import subprocess
import sys
from types import SimpleNamespace
from typing import ClassVar

import pytest

from groundstation import cli, launcher
from groundstation.fleet import plan_fleet
from groundstation.launcher import planned_ports
from quadsitl import process_util
from quadsitl.process_util import PICK_PORTS, ephemeral_range, free_port, free_ports_apart
from tests.mavclient import free_ports


@pytest.mark.parametrize("kind", [socket.SOCK_DGRAM, socket.SOCK_STREAM])
def test_free_ports_are_outside_the_ephemeral_range_and_bindable(kind):
    first, last = ephemeral_range()
    for _ in range(100):
        port = free_port(kind)
        assert PICK_PORTS[0] <= port < PICK_PORTS[1] and not first <= port <= last, port
        with socket.socket(socket.AF_INET, kind) as s:
            s.bind(("127.0.0.1", port))


def test_a_port_in_use_is_passed_over(monkeypatch):
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as busy:
        busy.bind(("127.0.0.1", PICK_PORTS[0]))
        picks = iter([PICK_PORTS[0], PICK_PORTS[0], PICK_PORTS[0] + 7])
        monkeypatch.setattr(process_util._pick, "choice", lambda seq: next(picks))
        assert free_port() == PICK_PORTS[0] + 7


def test_an_ephemeral_range_over_every_pickable_port_falls_back_to_the_os(monkeypatch):
    first, last = ephemeral_range()
    monkeypatch.setattr(process_util, "ephemeral_range", lambda: (1024, 65535))
    monkeypatch.setattr(process_util._pick, "choice", lambda seq: pytest.fail("picked from an empty range"))
    port = free_port()
    assert first <= port <= last  # the OS's choice for port 0, from its (real) ephemeral range
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", port))


def test_ports_to_avoid_are_never_picked(monkeypatch):
    """Ports a plan has named but its processes have not bound yet are free now; ``avoid`` keeps them out."""
    monkeypatch.setattr(process_util, "ephemeral_range", lambda: (60000, 60999))
    base = free_ports(4)
    monkeypatch.setattr(process_util, "PICK_PORTS", (base, base + 4))
    avoid = {base, base + 1, base + 3}
    assert {free_port(avoid=avoid) for _ in range(50)} == {base + 2}


def test_ports_picked_together_are_never_the_same(monkeypatch):
    """A test's or a launcher's ports picked one after the other, none bound yet: each avoids those before it (two
    picks of one test came out the same once in some thousands, and its autopilot could not bind)."""
    monkeypatch.setattr(process_util, "ephemeral_range", lambda: (60000, 60999))
    base = free_ports(3)
    monkeypatch.setattr(process_util, "PICK_PORTS", (base, base + 3))
    for _ in range(20):
        assert sorted(free_ports_apart(3)) == [base, base + 1, base + 2]


class _Recorder:
    """Children that start nothing: records each command line; the plant "fails" at once, so ``up`` returns."""

    started: ClassVar[list[list[str]]] = []

    def __init__(self, env=None):
        self.env, self.procs = env, {}

    def start(self, name, args, ready=False):
        _Recorder.started.append(args)

    def wait_ready(self, timeout):
        return False  # nothing was started: nothing is ready

    def first_failure(self, done, prog="quadsitl"):
        return ("plant", 1)

    def stop(self, grace=3.0):
        pass


def test_up_never_hands_a_vehicle_a_port_of_a_later_vehicles_plan(monkeypatch):
    """``up --vehicles`` picks each autopilot's plant port before the later autopilots bind their listen ports:
    every port the plan names, and every plant port picked before, is kept out of those picks (a plant port once
    landed on a later vehicle's ``--api-listen``, which then failed with "Address already in use"). The pickable
    range here is the plan's ports and exactly three more."""
    taken: set[int] = set()
    gcs_listen, api_listen = free_ports(3, taken=taken), free_ports(3, taken=taken)
    spare = [free_ports(1, taken=taken) for _ in range(3)]
    monkeypatch.setattr(process_util, "ephemeral_range", lambda: (60000, 60999))
    monkeypatch.setattr(process_util, "PICK_PORTS", (min(taken), max(taken) + 1))
    monkeypatch.setattr(process_util, "_pick", random.Random(1))
    real_choice = process_util._pick.choice
    monkeypatch.setattr(process_util._pick, "choice", lambda seq: real_choice([p for p in seq if p in taken]))
    monkeypatch.setattr(launcher, "Children", _Recorder)
    monkeypatch.setattr(launcher, "compile_once", lambda *args: None)
    _Recorder.started = []
    status = cli.main(
        [
            "up",
            "--quiet",
            "--no-zenoh",
            "--vehicles",
            "3",
            "--gcs-remote",
            "none",
            "--api-remote",
            "none",
            "--gcs-listen",
            f"127.0.0.1:{gcs_listen}",
            "--api-listen",
            f"127.0.0.1:{api_listen}",
        ]
    )
    assert status == 1  # the recorder's plant "failed"
    autopilots = [a for a in _Recorder.started if a[0] == "autopilot"]
    plant_ports = [int(a[a.index("--plant-listen") + 1].rpartition(":")[2]) for a in autopilots]
    assert sorted(plant_ports) == sorted(spare)


def test_the_ports_of_a_plan():
    fleet = plan_fleet(4, preset="paper", gcs_listen="127.0.0.1:21000", gcs_remote="127.0.0.1:22000",
                       api_listen="127.0.0.1:23000", api_remote="10.0.0.2:24000")  # fmt: skip
    ports = planned_ports(fleet)
    assert ports == {21000, 21001, 21002, 21003, 22000, 23000, 23001, 23002, 23003, 24000, 24001, 24002, 24003}
    default = planned_ports(plan_fleet(2, preset="paper", gcs_remote="none", api_listen="127.0.0.1:0"))
    assert default == {18570, 18571, 14540, 14541}  # the gcs link's PX4 default, the api link's remotes; 0 is any


def test_a_benchs_fleet_gives_every_autopilot_ports_of_its_own(monkeypatch, tmp_path):
    """``quadsitl bench --only fleet`` starts N autopilots before any binds its ports: each one's picks keep out of
    the others' (a fleet of 12 once got a Zenoh port another autopilot was about to bind, "Address already in
    use"). The pickable range here is exactly the six ports two autopilots need, so any repeat would show."""
    from benchmarks import autopilots as bench

    base = free_ports(6)
    monkeypatch.setattr(process_util, "ephemeral_range", lambda: (60000, 60999))
    monkeypatch.setattr(process_util, "PICK_PORTS", (base, base + 6))
    started = []
    monkeypatch.setattr(bench, "_python", lambda *args, **kw: started.append(args) or SimpleNamespace(pid=0))
    monkeypatch.setattr(bench, "_stop", lambda proc: None)
    taken: set[int] = set()
    with (bench.autopilot_process(tmp_path, system_id=1, taken=taken, ready=False) as first,
          bench.autopilot_process(tmp_path, system_id=2, taken=taken, ready=False) as second):  # fmt: skip
        ports = [p for plant, api, zenoh, _ in (first, second) for p in (plant, api, int(zenoh.rsplit(":", 1)[1]))]
    assert sorted(ports) == list(range(base, base + 6)) and taken == set(ports)
    assert len(started) == 2


def test_a_benchs_autopilot_whose_port_was_bound_meanwhile_starts_again_on_others(monkeypatch, tmp_path):
    """Another process (a test beside the bench) may bind a port between the bench's pick and the autopilot's bind:
    the autopilot exits ("Address already in use"), and the bench starts it again on other ports."""
    from benchmarks import autopilots as bench

    with socket.socket() as other:
        other.bind(("127.0.0.1", 0))
        other.listen()
        busy = other.getsockname()[1]
        picks = []

        def pick(kind: int = socket.SOCK_DGRAM, avoid=()) -> int:
            picks.append(kind)
            return busy if len(picks) == 3 else free_port(kind, avoid=avoid)  # the first start's Zenoh port

        monkeypatch.setattr(bench, "free_port", pick)
        with bench.autopilot_process(tmp_path) as ap:
            assert ap.attempts == 2 and len(picks) == 6 and ap.proc.poll() is None
            assert ap.endpoint != f"tcp/127.0.0.1:{busy}" and busy in ap.taken


def test_quadsitl_ports_narrows_the_picks_and_a_bad_value_is_refused_naming_it():
    code = "from quadsitl.process_util import PICK_PORTS, free_port; print(PICK_PORTS, free_port())"
    env = {**os.environ, "QUADSITL_PORTS": "25000-25009"}
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=60)
    assert out.stdout.startswith("(25000, 25010) ")
    assert 25000 <= int(out.stdout.split()[-1]) <= 25009
    for bad in ("25000", "30000-20000"):
        env["QUADSITL_PORTS"] = bad
        out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=60)
        assert out.returncode != 0 and f"QUADSITL_PORTS={bad!r}" in out.stderr
