"""Lockstep pacing: ``--speed F`` holds F × real time from the autopilot's first answer on. Time spent
holding (waiting for an autopilot that starts late) or lost to a stall of the machine is not caught up afterwards
in a burst; a late wake-up is."""

import json
import socket
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

from quadsitl import codec
from quadsitl.process_util import PATIENCE, SPIN_BUDGET, free_port
from sitl import lockstep, process


@pytest.mark.timeout(60)
def test_a_late_autopilot_does_not_make_the_plant_race_to_catch_up(tmp_path):
    port, stats = free_port(), tmp_path / "stats.json"
    plant = subprocess.Popen([sys.executable, "-m", "sitl", "--preset", "paper", "--autopilot", f"127.0.0.1:{port}",
                              "--speed", "1", "--ticks", "3000", "--stats", str(stats), "--quiet"])  # fmt: skip
    autopilot = None
    try:
        time.sleep(1.5)  # the plant holds tick 0 meanwhile
        autopilot = subprocess.Popen(autopilot_argv(port))
        assert plant.wait(30) == 0
    finally:
        for p in (plant, autopilot):
            if p is not None and p.poll() is None:
                p.kill()
                p.wait()
    s = json.loads(stats.read_text())
    assert s["ticks"] == 3000
    # Real time (1,000 ticks/s) from the first answer on. Racing to catch up with the hold (1.5 s plus the autopilot's
    # start, over 2,500 ticks of the 3,000) would run those ticks at the machine's full speed: 1,580 ticks/s over the
    # run even on the slowest loaded CI run on record (1,800 ticks/s at most), 5,000+ on an idle one. A pace this
    # slow is one every machine keeps, so the bound does not depend on the machine (at --speed 5 a loaded CI run read
    # 1,800, below the pace itself). The lower bound only says the run was paced, not stalled.
    assert 500 < s["ticks_per_s"] < 1150, s
    # Paced: a late answer is polled for one budget only, then the core goes to the processes the pace serves.
    assert s["polling_patience_s"] == s["polling_budget_s"] == SPIN_BUDGET


def autopilot_argv(port: int) -> list[str]:
    """The paper's autopilot, answering a plant on ``port``, with no ground link or Zenoh."""
    return [sys.executable, "-m", "autopilot", "--preset", "paper", "--plant-listen", f"127.0.0.1:{port}",
            "--api-listen", "127.0.0.1:0", "--api-remote", "none", "--gcs-listen", "127.0.0.1:0", "--gcs-remote",
            "none", "--no-zenoh"]  # fmt: skip


def unpaced_run(tmp_path, ticks: int) -> dict:
    """The plant's ``--stats`` after ``ticks`` unpaced lockstep ticks with the paper's autopilot."""
    port, stats = free_port(), tmp_path / "stats.json"
    autopilot = subprocess.Popen(autopilot_argv(port))
    try:
        r = subprocess.run([sys.executable, "-m", "sitl", "--preset", "paper", "--autopilot", f"127.0.0.1:{port}",
                            "--ticks", str(ticks), "--stats", str(stats), "--quiet"], timeout=50)  # fmt: skip
        assert r.returncode == 0
    finally:
        autopilot.kill()
        autopilot.wait()
    return json.loads(stats.read_text())


@pytest.mark.timeout(60)
def test_an_unpaced_plant_polls_for_a_late_answer_with_patience(tmp_path):
    s = unpaced_run(tmp_path, 3000)
    assert s["ticks"] == 3000 and s["polling_budget_s"] == SPIN_BUDGET and s["polling_patience_s"] == PATIENCE


class StallingClock:
    """``time`` as the plant's loop sees it: every pace sleep wakes OVERSLEEP late (a loaded machine's wake-up),
    and the STALL_AT-th sleeps STALL longer (the machine stalled); the deadline each sleep was for is recorded."""

    OVERSLEEP, STALL_AT, STALL = 0.0005, 150, 0.3  # [s], [sleeps], [s]

    def __init__(self) -> None:
        self.deadlines: list[float] = []
        self.stalled_at: float | None = None

    def __getattr__(self, name: str):
        return getattr(time, name)

    def sleep(self, seconds: float) -> None:
        self.deadlines.append(time.monotonic() + seconds)
        extra = self.STALL if len(self.deadlines) == self.STALL_AT else 0.0
        time.sleep(seconds + self.OVERSLEEP + extra)
        if extra:
            self.stalled_at = time.monotonic()


def test_a_paced_plant_makes_up_late_wake_ups_but_not_a_stall(monkeypatch):
    """--speed 1: a wake-up 0.5 ms late is made up (the next tick is due on the pace's grid, not 1 ms after the late
    one); a stall of 0.3 s is not (the ticks after it come at the pace, not back to back). Both are properties of
    the schedule: a loaded machine only makes the ticks later, so neither assertion depends on its speed."""
    ap = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    ap.bind(("127.0.0.1", 0))
    ap.settimeout(5.0)
    argv = ["--preset", "paper", "--autopilot", f"127.0.0.1:{ap.getsockname()[1]}"]
    fleet = process.fleet_from_args(process.build_parser().parse_args(argv))
    process.warm_up(fleet[0].plant)
    max_thrust = fleet[0].link.max_thrust
    arrived: list[float] = []  # when each state came [s, monotonic]

    def autopilot() -> None:
        rx, tx = np.zeros(65535, dtype=np.uint8), np.zeros(codec.FRAME_MAX, dtype=np.uint8)
        decoded = np.zeros(codec.DECODED_SIZE)
        while True:
            try:
                n, sender = ap.recvfrom_into(rx)
            except OSError:  # closed, or the plant is done
                return
            stamp = codec.decode_state(rx, n, decoded)
            arrived.append(time.monotonic())
            m = codec.encode_actuators(tx, 0, 1, 1, stamp, (0.25 * max_thrust,) * 4, max_thrust, True)
            ap.sendto(tx[:m].tobytes(), sender)

    clock = StallingClock()
    monkeypatch.setattr(lockstep, "time", clock)
    answering = threading.Thread(target=autopilot, daemon=True)
    answering.start()
    ticks = 600
    try:
        assert lockstep.run_lockstep(fleet, 1.0, ticks) == ticks
    finally:
        fleet[0].link.close()
        ap.close()
        answering.join(5)
    period = fleet[0].plant.period
    # Made up: before the stall, the sleeps' deadlines lie on the pace's grid (whole periods apart; a tick that woke
    # a period or more late sleeps not at all). A pace that restarted from each late wake-up would put them 1.5 ms
    # apart. A stall of the test's own process longer than PACE_SLACK moves the grid once: most, not every gap.
    gaps = np.diff(clock.deadlines[: clock.STALL_AT])
    on_grid = np.abs(gaps / period - np.round(gaps / period)) < 0.1
    assert on_grid.mean() > 0.9, gaps
    # Not caught up: the 200 ticks after the stall take at least 200 periods at 1 × real time; caught up, the 300
    # periods the stall lost would send them back to back (a few ms).
    after = [when for when in arrived if when > clock.stalled_at]
    assert len(after) > 200 + 1
    assert after[200] - after[0] > 0.9 * 200 * period, np.diff(after[:201])


@pytest.mark.timeout(60)
def test_the_plants_stats_give_its_own_peak_memory_not_its_parents(tmp_path):
    """``--stats``' peak_memory_mb is the plant's own (VmHWM), not getrusage's, which also counts what the parent held
    when it started the plant: a bench holding 2.4 GB once read as 2.4 GB for every plant it started."""
    ballast = np.ones(80 * 2**20)  # 640 MB, every page touched, held while the plant starts
    s = unpaced_run(tmp_path, 500)
    assert ballast[-1] == 1.0
    assert 20 < s["peak_memory_mb"] < 400
