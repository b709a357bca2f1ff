"""Lockstep that cannot be starved: `quadsitl fly` whose ground station is stopped (SIGSTOP) for seconds at random
moments flies the same flight, to the byte, as one left alone: a mission on sensors (selected and armed while the
plant holds its clock, landed by its own last item) and an offboard trajectory (the clock waits for the ground station
as long as it is heard within the datalink timeout)."""

import contextlib
import json
import os
import random
import signal
import subprocess
import threading
import time
from pathlib import Path

import pytest

from tests.test_fly import children_of, quadsitl

SQUARE = Path(__file__).parent / "data" / "square.plan"
CIRCLE = "circle:radius=3,period=10,hold=2"


def fly_stopped(argv: list[str], stops: list[tuple[float, float]], timeout: float = 240) -> tuple[int, str, int]:
    """Run ``argv`` (a `quadsitl fly`), stopping its ground station at each (wall seconds after it first appears,
    for how long) of ``stops``; always continued. → (exit status, stderr, how many stops were made)."""
    proc = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)  # fmt: skip
    made = 0

    def stopper() -> None:
        nonlocal made
        gcs, deadline = None, time.monotonic() + timeout
        while gcs is None and proc.poll() is None and time.monotonic() < deadline:
            for pid in children_of(proc.pid):
                with contextlib.suppress(OSError):
                    if b"groundstation\0--preset" in Path(f"/proc/{pid}/cmdline").read_bytes():
                        gcs = pid
            time.sleep(0.01)
        start = time.monotonic()
        for at, length in stops:
            time.sleep(max(0.0, start + at - time.monotonic()))
            if proc.poll() is not None:
                return
            try:
                os.kill(gcs, signal.SIGSTOP)
            except OSError:
                return
            made += 1
            time.sleep(length)
            with contextlib.suppress(OSError):
                os.kill(gcs, signal.SIGCONT)

    thread = threading.Thread(target=stopper, daemon=True)
    thread.start()
    try:
        _, err = proc.communicate(timeout=timeout)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
        thread.join(timeout=10)
    return proc.returncode, err, made


def random_stops(seed: int, within: float, n: int) -> list[tuple[float, float]]:
    """``n`` stops of 1 to 2.5 s at random moments within ``within`` wall seconds, in order, none overlapping."""
    rng = random.Random(seed)
    stops, at = [], 0.0
    for _ in range(n):
        at += rng.uniform(0.3, within / n)
        length = rng.uniform(1.0, 2.5)
        stops.append((round(at, 3), round(length, 3)))
        at += length
    return stops


@pytest.mark.timeout(600)
def test_a_mission_on_sensors_is_the_same_to_the_byte_however_long_the_ground_station_stops(tmp_path):
    """`fly --mission --state sensors` twice with the same seed, the first with its ground station stopped three
    times for seconds (at 10x real time: tens of seconds of flight each): the same telemetry.csv and mission.json.
    The mission is selected and the vehicle armed while the plant holds its clock at SENSOR_GROUND_S, and a mission
    that does not land is given its own landing, so nothing the ground station does later changes the flight."""
    seed = int(time.time())
    stops = random_stops(seed, within=6.0, n=3)
    runs = {}
    for name, plan in (("stopped", stops), ("alone", [])):
        out = tmp_path / name
        argv = quadsitl("fly", "--preset", "x500", "--state", "sensors", "--mission", str(SQUARE), "--speed", "10",
                        "--no-figures", "-q", "--out", str(out))  # fmt: skip
        status, err, made = fly_stopped(argv, plan)
        assert status == 0, (name, stops, err)
        runs[name] = (out, made)
    assert runs["stopped"][1] >= 2, f"the ground station was stopped {runs['stopped'][1]} times ({stops})"
    a, b = runs["stopped"][0], runs["alone"][0]
    assert (a / "telemetry.csv").read_bytes() == (b / "telemetry.csv").read_bytes(), (seed, stops)
    doc = json.loads((a / "mission.json").read_text())
    assert doc == json.loads((b / "mission.json").read_text()), (seed, stops)
    assert doc["all_reached_in_order"] and doc["disarmed_t"] is not None


@pytest.mark.timeout(600)
def test_an_offboard_flight_is_the_same_to_the_byte_however_long_the_ground_station_stops(tmp_path):
    """`fly --trajectory circle...` with its ground station stopped twice for seconds, flown again alone: the same
    telemetry.csv. The autopilot's clock waits for the setpoints (--offboard-lockstep) while the ground station is
    heard within COM_DL_LOSS_T (10 s), so no stop trips the offboard-loss failsafe."""
    seed = int(time.time())
    stops = random_stops(seed, within=3.0, n=2)
    outs = []
    for name, plan in (("stopped", stops), ("alone", [])):
        out = tmp_path / name
        argv = quadsitl("fly", "--preset", "x500", "--trajectory", CIRCLE, "--speed", "5", "--no-figures", "-q",
                        "--out", str(out))  # fmt: skip
        status, err, made = fly_stopped(argv, plan)
        assert status == 0, (name, stops, err)
        assert "ran out" not in err and "Failsafe" not in err, err
        if plan:
            assert made >= 1, f"the ground station was never stopped ({stops})"
        outs.append(out)
    assert (outs[0] / "telemetry.csv").read_bytes() == (outs[1] / "telemetry.csv").read_bytes(), (seed, stops)
