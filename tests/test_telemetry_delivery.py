"""``--telemetry-congestion block`` (what ``quadsitl fly`` runs): a subscriber that stops reading holds a lockstep
vehicle instead of losing ticks. The subscriber is a real process on a real Zenoh session (tests/tick_counter.py),
stopped with SIGSTOP for longer than its links' buffers last while the plant runs as fast as it can."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time

from groundstation.launcher import free_port
from quadsitl import telemetry
from tests.test_fly import procs  # noqa: F401 (a fixture)

TICKS = 30000  # lockstep ticks of the plant's run: about 8 MB of telemetry, more than Zenoh's and TCP's buffers hold
STOP = 3.0  # [s] wall: how long the subscriber is stopped, from 0.3 s into the run


def test_a_stopped_subscriber_holds_a_blocking_vehicle_and_gets_every_tick(tmp_path, procs):  # noqa: F811
    plant_port = free_port()
    endpoint = f"tcp/127.0.0.1:{free_port(socket.SOCK_STREAM)}"
    procs.append(ap := subprocess.Popen(
        [sys.executable, "-m", "autopilot", "--preset", "x500", "--plant-listen", f"127.0.0.1:{plant_port}",
         "--gcs-listen", "127.0.0.1:0", "--gcs-remote", "none", "--api-listen", "127.0.0.1:0", "--api-remote", "none",
         "--zenoh-listen", endpoint, "--telemetry-congestion", "block"], stderr=subprocess.DEVNULL))  # fmt: skip
    procs.append(sub := subprocess.Popen([sys.executable, "-m", "tests.tick_counter", endpoint], stdin=subprocess.PIPE,
                                         stdout=subprocess.PIPE, text=True))  # fmt: skip
    assert sub.stdout.readline() == "ready\n"  # its subscription has reached the autopilot
    stats = tmp_path / "stats.json"
    procs.append(plant := subprocess.Popen(
        [sys.executable, "-m", "sitl", "--preset", "x500", "--autopilot", f"127.0.0.1:{plant_port}", "--ticks",
         str(TICKS), "--stats", str(stats)], stderr=subprocess.DEVNULL))  # fmt: skip
    time.sleep(0.3)
    os.kill(sub.pid, signal.SIGSTOP)
    try:
        time.sleep(STOP)
        assert plant.poll() is None  # held: a run this long takes under 3 s on an idle machine
    finally:
        os.kill(sub.pid, signal.SIGCONT)
    assert plant.wait(120) == 0
    out, _ = sub.communicate("", timeout=60)
    got = json.loads(out)
    assert ap.poll() is None  # the vehicle waited; nothing failed
    for stream in telemetry.STREAMS:
        ticks = got[stream]
        assert ticks == list(range(ticks[0], ticks[-1] + 1)), f"{stream}: ticks lost"
        assert ticks[-1] - ticks[0] + 1 >= TICKS - 1, f"{stream}: {ticks[0]}..{ticks[-1]}"
