"""End to end: the real processes on free loopback ports, always cleaned up."""

import contextlib
import json
import math
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from pymavlink import mavutil

from groundstation import pacing, trajectories
from groundstation.launcher import SETPOINTS_AHEAD
from groundstation.setpoint_grid import SETPOINT_MS
from groundstation.telemetry_csv import read_csv
from quadsitl.config import SENSOR_GROUND_S
from quadsitl.process_util import children_of, free_ports_apart
from quadsitl.state import Reference

BIN = Path(sys.executable).parent
PREARM_CHECK = mavutil.mavlink.MAV_SYS_STATUS_PREARM_CHECK  # SYS_STATUS: healthy = armable


def quadsitl(*args: str) -> list[str]:
    exe = BIN / "quadsitl"
    return [str(exe), *args] if exe.exists() else [sys.executable, "-m", "groundstation.cli", *args]


def alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


@pytest.fixture
def procs():
    """Processes a test starts; killed (with their children) whatever happens."""
    started: list[subprocess.Popen] = []
    yield started
    for p in started:
        for c in children_of(p.pid):
            os.kill(c, signal.SIGKILL)
        if p.poll() is None:
            p.kill()
            p.wait()


CIRCLE = "circle:radius=4,period=16,hold=4"  # x500: at 2 m, 1.57 m/s, after 4 s at home


STALL, STALL_EVERY = 0.15, 0.3  # [s] wall: the circle flight's ground station is stopped this long, this often


def stall_child(proc: subprocess.Popen, marker: bytes, stall: float, every: float, timeout: float) -> int:
    """Stop (SIGSTOP) ``proc``'s child whose command line holds ``marker`` for ``stall`` s of every ``every`` s,
    as a busy machine may deschedule it, until ``proc`` exits (or ``timeout`` s); always continued. Returns how
    many stalls."""
    stalls, deadline = 0, time.monotonic() + timeout
    while proc.poll() is None and time.monotonic() < deadline:
        for pid in children_of(proc.pid):
            try:
                if marker not in Path(f"/proc/{pid}/cmdline").read_bytes():
                    continue
                os.kill(pid, signal.SIGSTOP)
            except OSError:
                continue
            try:
                time.sleep(stall)
                stalls += 1
            finally:
                with contextlib.suppress(OSError):
                    os.kill(pid, signal.SIGCONT)
        time.sleep(every - stall)
    return stalls


@pytest.fixture(scope="module")
def circle_flight(tmp_path_factory) -> tuple[Path, subprocess.CompletedProcess]:
    """One `quadsitl fly --trajectory circle...` on the realistic preset, shared by the tests that read it. Its
    ground station is stopped for 0.15 s of every 0.3 s of wall time (seconds of flight, at lockstep's speed), as a
    busy machine may deschedule it: the vehicle's clock waits for it (the autopilot's --offboard-lockstep)."""
    out = tmp_path_factory.mktemp("circle")
    argv = quadsitl("fly", "--preset", "x500", "--trajectory", CIRCLE, "--out", str(out))
    with open(out / "stdout.txt", "w+") as stdout, open(out / "stderr.txt", "w+") as stderr:
        proc = subprocess.Popen(argv, stdout=stdout, stderr=stderr, text=True, start_new_session=True)
        try:
            stalls = stall_child(proc, b"groundstation\0--preset", STALL, STALL_EVERY, timeout=240)
            proc.wait(timeout=10)
        finally:
            if proc.poll() is None:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait()
        stdout.seek(0)
        stderr.seek(0)
        r = subprocess.CompletedProcess(argv, proc.returncode, stdout.read(), stderr.read())
    assert stalls > 0, "the ground station was never stopped"
    return out, r


def test_fly_sends_a_position_trajectory_as_offboard_position_setpoints(circle_flight):
    """The ground station's side of a position trajectory: only SET_POSITION_TARGET_LOCAL_NED, frame LOCAL_NED,
    type_mask 2496, every one a point of the circle with its velocity feed-forward and yaw along the path;
    the position table, metrics.json and the x–y figure."""
    out, r = circle_flight
    assert r.returncode == 0, r.stderr
    R, P, altitude = 4.0, 16.0, 2.0  # the x500 preset's reference altitude
    sent, attitude_targets = [], 0
    log = mavutil.mavlink_connection(str(out / "flight.tlog"))
    while (m := log.recv_match()) is not None:
        if m.get_srcSystem() != 255:  # the ground station's messages only
            continue
        if m.get_type() == "SET_ATTITUDE_TARGET":
            attitude_targets += 1
        elif m.get_type() == "SET_POSITION_TARGET_LOCAL_NED":
            sent.append(m)
    # Sent ahead (quadsitl fly's gcs --setpoints-ahead): every 20 ms of the flight while the circle moves, so over
    # 800 for its 16 s, and at least one per SETPOINTS_AHEAD while the reference holds (the vehicle's clock waits).
    assert attitude_targets == 0 and len(sent) > 16 / 0.02
    # a changing reference: one per SETPOINT_MS (50 Hz) of the vehicle's time, as a rule (the 10 Hz wall-time
    # keep-alive also goes while the clock waits for this stalled ground station)
    stamps = sorted({m.time_boot_ms for m in sent})
    assert np.median(np.diff(stamps)) >= SETPOINT_MS
    moving = 0
    for m in sent:
        assert (m.coordinate_frame, m.type_mask) == (mavutil.mavlink.MAV_FRAME_LOCAL_NED, 2496)
        assert math.hypot(m.x, m.y - R) == pytest.approx(R, abs=1e-5)  # on the circle (float32)
        assert m.z == pytest.approx(-altitude) and m.vz == 0.0
        speed = math.hypot(m.vx, m.vy)
        assert speed <= 2 * math.pi * R / P + 1e-5
        if speed > 0.1:  # tangent to the circle, the nose along it
            moving += 1
            assert m.vx * m.x + m.vy * (m.y - R) == pytest.approx(0.0, abs=1e-4)
            assert math.remainder(m.yaw - math.atan2(m.vy, m.vx), 2 * math.pi) == pytest.approx(0.0, abs=1e-5)
    assert moving > 100
    # The first setpoints, before offboard: the start point, at rest.
    assert (sent[0].x, sent[0].y, sent[0].vx, sent[0].vy) == (0.0, 0.0, 0.0, 0.0)
    lines = r.stdout.splitlines()
    assert "horizontal RMS [m]" in lines[0] and lines[2].split()[0] == "backstepping"
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["trajectory"] == CIRCLE and metrics["duration"] == pytest.approx(4 + 16 + 2)
    assert set(metrics["position"]["backstepping"]) == {"samples", "horizontal_rms", "horizontal_max", "altitude_rms"}
    assert (out / "fig_xy_path.png").stat().st_size > 10_000


def test_a_moving_reference_is_flown_to_the_byte_however_late_the_ground_station(circle_flight, tmp_path):
    """The circle flight whose ground station was stopped again and again, flown again with nothing stopped: the same
    telemetry.csv to the byte. The ground station sends each setpoint ahead, stamped with the tick it is for, and the
    autopilot flies it from that tick and holds its clock until the ground station is ahead, for as long as the
    ground station is heard within the datalink timeout, 10 s (docs/commands.md)."""
    out, r = circle_flight
    assert r.returncode == 0, r.stderr
    said = re.search(r"clock waited for a setpoint (\d+) times, .* \((\d+) ran out", r.stderr)
    assert said is None or int(said[2]) == 0, r.stderr
    argv = quadsitl("fly", "--preset", "x500", "--trajectory", CIRCLE, "--out", str(tmp_path), "--no-figures", "-q")
    again = subprocess.run(argv, capture_output=True, text=True, timeout=240)
    assert again.returncode == 0, again.stderr
    assert (tmp_path / "telemetry.csv").read_bytes() == (out / "telemetry.csv").read_bytes()


SPEED = 2 * math.pi * 4.0 / 16.0  # [m/s] along the circle
LAG_M = (SETPOINTS_AHEAD + 0.01) * SPEED  # the most the reference flown may lag the plan (see below)


def test_fly_circle_tracks_the_position_reference(circle_flight):
    """The autopilot's side (needs its position control, and x_ref, y_ref in the setpoint record): x_ref, y_ref
    are the circle, and the vehicle flies it. Thresholds: PX4-like position control at 1.57 m/s on a 4 m
    circle, without an acceleration feed-forward (it runs a little outside the circle)."""
    out, r = circle_flight
    assert r.returncode == 0, r.stderr
    data = read_csv(out / "telemetry.csv")
    t = data["t"]
    plan = trajectories.make(CIRCLE, Reference(2.0))
    want = np.array([plan(tk)[:2] for tk in t])
    # The reference the autopilot reports is the one sent: on the circle, behind the plan by the ground station's
    # lag (it follows the flight time from the telemetry it receives).
    finite = np.isfinite(data["x_ref"]) & np.isfinite(data["y_ref"])
    assert finite.mean() > 0.95, f"x_ref finite in {finite.mean():.1%} of the ticks"
    x_ref, y_ref = data["x_ref"][finite], data["y_ref"][finite]
    assert np.abs(np.hypot(x_ref, y_ref - 4.0) - 4.0).max() < 1e-4
    phase = np.unwrap(np.arctan2(x_ref, 4.0 - y_ref))
    assert np.diff(phase).min() > -1e-4, "the reference went back along the circle"
    # Lockstep runs at 20-40x real time, so each 0.15 s stop of the ground station is seconds of flight: the
    # vehicle's clock waits for it (quadsitl fly's --offboard-lockstep; 7 waits in one run), and the reference
    # flown never lags the plan by more than SETPOINTS_AHEAD of flight (0.1-0.3 s on a quiet machine, unstopped).
    # A machine so loaded that the flight runs under ~3x real time never needs to wait (a stop is then less than
    # SETPOINTS_AHEAD of flight), and says nothing: the bound is checked all the same.
    lag = np.hypot(x_ref - want[finite, 0], y_ref - want[finite, 1])
    assert np.median(lag) < LAG_M, (np.median(lag), r.stderr)
    # The lap ends at home at full speed: the last reference is behind home by at most that lag (0.2 rad of the
    # circle).
    assert lag.max() < LAG_M, (lag.max(), np.flatnonzero(lag >= LAG_M)[:5], r.stderr)
    assert phase[-1] == pytest.approx(2 * math.pi, abs=LAG_M / 4.0), r.stderr
    assert math.hypot(x_ref[-1], y_ref[-1]) < LAG_M, r.stderr
    # The vehicle goes round: as far as the circle's far side (2R east), and back home, off its last reference
    # by its tracking error (0.16 and 0.28 m in one run) and by as much as that reference trails the plan: the
    # vehicle flies on at the setpoint's velocity while the ground station is stopped (0.57 m in a CI run whose last
    # reference trailed by 0.46 s).
    assert data["y"].max() > 2 * 4.0 - 0.5 and data["x"].max() > 4.0 - 0.5 and data["x"].min() < -4.0 + 0.5
    assert math.hypot(data["x"][-1] - x_ref[-1], data["y"][-1] - y_ref[-1]) < 0.5 + lag[-1], (lag[-1], r.stderr)
    m = json.loads((out / "metrics.json").read_text())["position"]["backstepping"]
    assert m["samples"] == int(finite.sum())
    assert m["horizontal_rms"] < 0.4 and m["horizontal_max"] < 1.0, m  # 0.23 and 0.46 m when written
    assert abs(data["altitude"][-1] - 2.0) < 0.1


def test_fly_equals_sim_and_loses_nothing(tmp_path):
    out = tmp_path / "fly"
    r = subprocess.run(quadsitl("fly", "--preset", "paper", "--duration", "2", "--out", str(out)),
                       capture_output=True, text=True, timeout=180)  # fmt: skip
    assert r.returncode == 0, r.stderr
    s = subprocess.run(quadsitl("sim", "--duration", "2", "--no-figures", "--out", str(tmp_path / "sim")),
                       capture_output=True, text=True, timeout=60)  # fmt: skip
    assert s.returncode == 0, s.stderr
    fly, sim = read_csv(out / "telemetry.csv"), read_csv(tmp_path / "sim" / "telemetry.csv")
    # Exactly one row per tick, t = 0 at the first tick under the trajectory: nothing lost.
    assert len(fly["t"]) == len(sim["t"]) == 2000
    assert np.allclose(fly["t"], np.arange(2000) * 0.001)
    for column in ("altitude", "roll", "pitch", "yaw"):
        assert np.abs(fly[column] - sim[column]).max() < 1e-3, column
    # on the ground at t = 0 (armed in hold on the ground before, the vehicle may sit a few nm up: 1e-9 in one CI run)
    assert fly["altitude"][0] == pytest.approx(0.0, abs=1e-6) and fly["altitude"][-1] == pytest.approx(5.0, abs=1e-3)
    # Attitude setpoints, the paper's experiment: nothing controls x and y, and the telemetry says so.
    for data in (fly, sim):
        assert np.isnan(data["x_ref"]).all() and np.isnan(data["y_ref"]).all()
    # The .tlog is standard: pymavlink reads it, both directions are in it.
    tlog = mavutil.mavlink_connection(str(out / "flight.tlog"))
    seen, targets, vehicle_ms, texts = set(), [], 0, []
    attitude_ms: list[int] = []
    last_seen_ms: dict[str, int] = {}  # each message type: the vehicle's time (its newest ATTITUDE) when last logged
    while (m := tlog.recv_match()) is not None:
        seen.add(m.get_type())
        last_seen_ms[m.get_type()] = vehicle_ms
        if m.get_type() == "SET_ATTITUDE_TARGET":
            targets.append((m.time_boot_ms, m._timestamp, tuple(m.q), m.thrust))
        elif m.get_type() == "ATTITUDE":
            vehicle_ms = max(vehicle_ms, m.time_boot_ms)
            attitude_ms.append(m.time_boot_ms)
        elif m.get_type() == "STATUSTEXT":
            texts.append(m.text)
    assert {"HEARTBEAT", "ATTITUDE", "COMMAND_ACK", "COMMAND_LONG", "SET_ATTITUDE_TARGET", "SYS_STATUS"} <= seen
    # The streams the ground station does not read stop (each one the autopilot builds in Python is a trip out of its
    # compiled loop): those at once, before the flight; SYS_STATUS, read for its pre-arm check, once the flight starts
    # (the command goes before the setpoints that let the clock run on).
    for name in ("HOME_POSITION", "ESTIMATOR_STATUS", "EXTENDED_SYS_STATE", "LOCAL_POSITION_NED", "GPS_RAW_INT"):
        assert last_seen_ms.get(name, 0) <= 1000 * SENSOR_GROUND_S, (name, last_seen_ms)
    assert last_seen_ms["SYS_STATUS"] <= 1000 * (SENSOR_GROUND_S + 1.0), last_seen_ms
    # ATTITUDE, which tells the ground station the vehicle's clock, at 10 Hz of it (the least a ground station sending
    # ahead asks for).
    attitude_ms = np.array(attitude_ms)
    flying = attitude_ms[attitude_ms > 1000 * SENSOR_GROUND_S]
    assert len(flying) >= 20 and np.diff(flying).min() >= 100 - 1, attitude_ms
    # Landed and disarmed, the flight is over and the plant's clock holds (--hold-when-landed): it ends within the
    # ground station's last read of the vehicle's ATTITUDE (10 Hz here), not tens of simulated seconds later.
    assert texts[-1] == "Landed, disarmed", texts
    simulated = float(re.search(r"plant: ([0-9.]+) s simulated", r.stderr).group(1))
    assert 0.0 <= simulated - vehicle_ms / 1000.0 < 1.0, (simulated, vehicle_ms)
    # In flight (after the ground wait: the clock holds at SENSOR_GROUND_S until armed; before, the keep-alive is
    # stamped with the vehicle's clock, which may still be running on the ground when the ground station comes up), a
    # constant reference goes again once per AHEAD_KEEPALIVE of the vehicle's time, on a grid from the flight's first
    # tick (each is the furthest moment the ground station may send for as it goes out: --setpoints-ahead), the last
    # made for the tick after the flight's end: the same setpoint every time. Sent at each read instead, they were
    # 150 ms of vehicle time apart or less; topped up at each read, at uneven moments.
    assert len({(q, thrust) for _, _, q, thrust in targets}) == 1
    stamps = sorted({ms for ms, _, _, _ in targets})
    flight = [ms for ms in stamps if ms > 1000 * SENSOR_GROUND_S]
    keep_ms = round(1000 * pacing.AHEAD_KEEPALIVE)
    assert len(flight) >= 4 and set(np.diff(flight[:-1])) == {keep_ms}, stamps
    # From the hold on the ground at SENSOR_GROUND_S, the stream never lapses: the clock holds before it runs past the
    # newest setpoint, so they are never further apart than the grid's step (half the 1 s setpoint timeout). Before
    # the hold the clock runs on its own and the ground station stamps its keep-alive with the clock it last read,
    # once per pass of its loop: under load 680 ms of vehicle time apart (one CI run), harmless while the vehicle is
    # not yet in offboard.
    held = [ms for ms in stamps if ms >= 1000 * SENSOR_GROUND_S]
    assert held[0] == 1000 * SENSOR_GROUND_S, stamps
    assert np.diff(held).max() <= keep_ms, stamps
    assert len(stamps) <= 5000 / SETPOINT_MS  # 2 s flown, and the landing: each moment of the grid sent once
    assert (out / "metrics.json").exists() and (out / "fig2_outputs.png").exists()
    assert r.stdout.splitlines()[-1] == (f"wrote {out}/telemetry.csv, flight.tlog, flight.ulg, metrics.json, "
                                         "fig2_outputs.png, fig3_errors.png, fig4_inputs.png")  # fmt: skip
    report = json.loads((out / "metrics.json").read_text())
    assert report["diverged"] is False and report["diverged_at"] is None
    # The flight's pace, from the autopilot's publication times of its telemetry: most of the 2 s flight's ticks.
    rate = json.loads((out / "rate.json").read_text())
    assert 1.0 < rate["simulated_s"] <= 2.2 and rate["wall_s"] > 0
    assert rate["ticks_per_s"] == pytest.approx(rate["simulated_s"] / 0.001 / rate["wall_s"])


WINDY = ("--wind", "3,90", "--turbulence", "moderate", "--gust", "2,0,0.5,0.3", "--wind-seed", "4")


def test_fly_equals_sim_in_a_wind_with_turbulence_and_a_gust(tmp_path):
    """The plant process flies the wind options as sim's plant does: the same turbulence (its clock starts at
    lift-off, so fly's arming on the ground first changes nothing) and the gust 0.5 s into the flight."""
    runs = {}
    for name, command in (("fly", "fly"), ("sim", "sim"), ("calm", "sim")):
        wind = () if name == "calm" else WINDY
        argv = quadsitl(command, "--duration", "2", "--no-figures", "--quiet", "--out", str(tmp_path / name), *wind)
        r = subprocess.run(argv, capture_output=True, text=True, timeout=180)
        assert r.returncode == 0, r.stderr
        runs[name] = read_csv(tmp_path / name / "telemetry.csv")
    fly, sim, calm = runs["fly"], runs["sim"], runs["calm"]
    assert len(fly["t"]) == len(sim["t"]) == 2000
    for column in ("x", "y", "altitude", "vx", "vy", "roll", "pitch", "yaw"):
        assert np.abs(fly[column] - sim[column]).max() < 1e-3, column  # 8e-6 when written
    # the air moved the vehicle: 0.55 m in x, 0.39 m in y in 2 s when written
    assert np.hypot(sim["x"][-1] - calm["x"][-1], sim["y"][-1] - calm["y"][-1]) > 0.3
    for name in ("fly", "sim"):
        report = json.loads((tmp_path / name / "metrics.json").read_text())
        assert report["wind"]["turbulence"] == "moderate" and report["wind"]["gust_start_s"] == 0.5, name


@pytest.mark.parametrize("victim", ["plant", "autopilot", "gcs"])
def test_killing_a_child_fails_the_flight_promptly_without_orphans(tmp_path, procs, victim):
    fly = subprocess.Popen(quadsitl("fly", "--speed", "1", "--duration", "60", "--out", str(tmp_path), "--quiet"),
                           stderr=subprocess.PIPE, text=True)  # fmt: skip
    procs.append(fly)
    module = {"plant": "sitl", "autopilot": "autopilot", "gcs": "groundstation"}[victim]
    deadline = time.monotonic() + 30
    kids: list[int] = []
    while time.monotonic() < deadline and not (tmp_path / "flight.tlog").exists():
        time.sleep(0.1)
    time.sleep(1.0)
    kids = children_of(fly.pid)
    cmdlines = {pid: Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0") for pid in kids}
    target = [pid for pid, cmd in cmdlines.items() if cmd[1:3] == [b"-m", module.encode()]]
    assert len(kids) == 3 and len(target) == 1, cmdlines
    os.kill(target[0], signal.SIGKILL)
    start = time.monotonic()
    _, err = fly.communicate(timeout=20)
    assert time.monotonic() - start < 10
    assert fly.returncode != 0
    assert f"the {victim} process was killed by signal 9 (SIGKILL)" in err
    time.sleep(0.2)
    assert not [pid for pid in kids if alive(pid)]


def test_sigterm_tears_everything_down(tmp_path, procs):
    fly = subprocess.Popen(quadsitl("fly", "--speed", "1", "--duration", "60", "--out", str(tmp_path), "--quiet"),
                           stderr=subprocess.PIPE, text=True)  # fmt: skip
    procs.append(fly)
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline and len(children_of(fly.pid)) < 3:
        time.sleep(0.1)
    kids = children_of(fly.pid)
    assert len(kids) == 3
    time.sleep(8.0)  # fly for a while (real time) before the interruption (its start takes 3–4 s on a busy host)
    fly.send_signal(signal.SIGTERM)
    _, err = fly.communicate(timeout=15)
    assert fly.returncode != 0 and "interrupted" in err
    time.sleep(0.2)
    assert not [pid for pid in kids if alive(pid)]

    # The logs are complete up to the interruption: every tick flown is a row, with no gap, and the
    # count matches the simulated time the .tlog saw flown after offboard was accepted.
    data = read_csv(tmp_path / "telemetry.csv")
    t = data["t"]
    assert len(t) > 500 and np.allclose(np.diff(t), 0.001)
    log = mavutil.mavlink_connection(str(tmp_path / "flight.tlog"))
    start_ms = last_ms = None
    offboard = False
    while (m := log.recv_match()) is not None:
        if m.get_type() == "COMMAND_ACK" and m.command == 176 and m.result == 0:
            offboard = True
        elif m.get_type() == "ATTITUDE" and offboard:
            start_ms = m.time_boot_ms if start_ms is None else start_ms
            last_ms = m.time_boot_ms
    assert start_ms is not None
    # each end within one ATTITUDE interval (fly's ground station reads the vehicle's clock at 10 Hz), and 40 ms more
    interval_ms = pacing.attitude_interval_us(SETPOINTS_AHEAD) // 1000
    assert abs(len(t) - (last_ms - start_ms)) <= 2 * interval_ms + 40, (len(t), last_ms - start_ms)


def test_setpoint_loss_failsafe_with_a_raw_pymavlink_client(procs):
    plant_port, gcs_port = free_ports_apart(2)
    procs.append(subprocess.Popen([sys.executable, "-m", "autopilot", "--no-zenoh", "--plant-listen",
                                   f"127.0.0.1:{plant_port}", "--gcs-listen", f"127.0.0.1:{gcs_port}",
                                   "--gcs-remote", "none", "--api-listen", "127.0.0.1:0",
                                   "--api-remote", "none"]))  # fmt: skip
    procs.append(subprocess.Popen([sys.executable, "-m", "sitl", "--autopilot", f"127.0.0.1:{plant_port}",
                                   "--speed", "2"]))  # fmt: skip
    gcs = mavutil.mavlink_connection(f"udpout:127.0.0.1:{gcs_port}", source_system=255, source_component=190)
    try:
        hb, end = None, time.monotonic() + 15
        while hb is None and time.monotonic() < end:  # a GCS heartbeats until the vehicle answers
            gcs.mav.heartbeat_send(6, 8, 0, 0, 0)
            hb = gcs.recv_match(type="HEARTBEAT", blocking=True, timeout=0.5)
        assert hb is not None and hb.autopilot == mavutil.mavlink.MAV_AUTOPILOT_PX4

        def setpoints():
            gcs.mav.set_attitude_target_send(0, 1, 1, 71, [1, 0, 0, 0], 0, 0, 0, 0)
            gcs.mav.set_position_target_local_ned_send(0, 1, 1, 1, 0b110111111011, 0, 0, -1.0, 0, 0, 0, 0, 0, 0, 0, 0)

        def command(cmd, *p):
            gcs.mav.command_long_send(1, 1, cmd, 0, *(list(p) + [0] * (7 - len(p))))
            end = time.monotonic() + 5
            while time.monotonic() < end:
                setpoints()
                ack = gcs.recv_match(type="COMMAND_ACK", blocking=True, timeout=0.05)
                if ack is not None and ack.command == cmd:
                    return ack.result
            return None

        # Arm once the vehicle says it may (SYS_STATUS's pre-arm check: the plant's states arrive), as a ground
        # station waits for it: the plant may take seconds to start on a loaded machine.
        prearm, end = False, time.monotonic() + 20
        while not prearm and time.monotonic() < end:
            setpoints()
            st = gcs.recv_match(type="SYS_STATUS", blocking=True, timeout=0.05)
            prearm = st is not None and bool(st.onboard_control_sensors_health & PREARM_CHECK)
        assert prearm, "the vehicle never said it may arm"
        assert command(400, 1) == 0
        assert command(176, 1, 6, 0) == 0
        # Fly to 1 m, streaming (3 s of wall time at --speed 2 on an idle machine; a loaded one's plant runs slower).
        pos, end = None, time.monotonic() + 30
        while time.monotonic() < end and not (pos is not None and abs(pos.z + 1.0) < 0.05 and abs(pos.vz) < 0.05):
            setpoints()
            pos = gcs.recv_match(type="LOCAL_POSITION_NED", blocking=True, timeout=0.05) or pos
        assert pos is not None and pos.z == pytest.approx(-1.0, abs=0.05), pos
        # Now stop streaming: after 1 s of simulated time the vehicle says so, lands and disarms.
        texts, disarmed = [], False
        end = time.monotonic() + 20
        while time.monotonic() < end and not disarmed:
            m = gcs.recv_match(type=["STATUSTEXT", "HEARTBEAT"], blocking=True, timeout=0.5)
            if m is None:
                continue
            if m.get_type() == "STATUSTEXT":
                texts.append(m.text)
            elif texts and not m.base_mode & mavutil.mavlink.MAV_MODE_FLAG_SAFETY_ARMED:
                disarmed = True
        assert any(t.startswith("Failsafe: offboard setpoints lost") for t in texts), texts
        assert "Landed, disarmed" in texts and disarmed
    finally:
        gcs.close()


def test_fly_mission_flies_a_qgroundcontrol_plan(tmp_path):
    """`quadsitl fly --mission` with the hand-written QGroundControl plan: takeoff, a 10 m square at 5 m, return.
    Every item is reached in order, the vehicle lands at home, and the mission figure is written."""
    plan = Path(__file__).parent / "data" / "square.plan"
    r = subprocess.run(quadsitl("fly", "--preset", "x500", "--mission", str(plan), "--out", str(tmp_path)),
                       capture_output=True, text=True, timeout=120)  # fmt: skip
    assert r.returncode == 0, r.stderr
    doc = json.loads((tmp_path / "mission.json").read_text())
    assert [x["seq"] for x in doc["reached"]] == [0, 1, 2, 3, 4] and doc["all_reached_in_order"]
    times = [x["t"] for x in doc["reached"]]
    assert times == sorted(times) and times[0] > 0
    corners = [(x["north"], x["east"]) for x in doc["items"][1:4]]
    assert np.allclose(corners, [(10, 0), (10, 10), (0, 10)], atol=0.05)
    data = read_csv(tmp_path / "telemetry.csv")
    assert data["altitude"].max() > 4.5  # it flew
    assert abs(data["altitude"][-1]) < 0.1 and math.hypot(data["x"][-1], data["y"][-1]) < 0.5  # landed at home
    assert data["t"][-1] >= times[-1]
    assert (tmp_path / "fig_mission_path.png").stat().st_size > 10_000
    assert r.stdout.splitlines()[-1].endswith("metrics.json, mission.json, fig2_outputs.png, fig3_errors.png, "
                                              "fig4_inputs.png, fig_mission_path.png")  # fmt: skip
    assert json.loads((tmp_path / "metrics.json").read_text())["mission"] == str(plan)


def test_fly_mission_refuses_a_bad_file_before_anything_starts(tmp_path):
    bad = tmp_path / "bad.plan"
    bad.write_text(json.dumps({"fileType": "Plan", "mission": {"items": [
        {"type": "SimpleItem", "command": 16, "frame": 3, "params": [0, 0, 0, None, 47.4, 8.5, 5]},
        {"type": "ComplexItem", "complexItemType": "StructureScan"}]}}))  # fmt: skip
    r = subprocess.run(quadsitl("fly", "--mission", str(bad), "--out", str(tmp_path)), capture_output=True, text=True,
                       timeout=60)  # fmt: skip
    assert r.returncode == 2
    assert r.stderr.strip().splitlines() == [
        f"quadsitl fly: error: mission {bad}, item 1, type: ComplexItem (StructureScan) has no saved items; allowed: "
        "SimpleItem, or a survey or corridor scan with its TransectStyleComplexItem.Items"
    ]
    assert not (tmp_path / "telemetry.csv").exists()
    r = subprocess.run(quadsitl("fly", "--mission", str(bad), "--trajectory", "sine"), capture_output=True, text=True,
                       timeout=60)  # fmt: skip
    assert r.returncode == 2 and "--trajectory 'sine' with --mission" in r.stderr


def test_fly_mission_that_overruns_duration_fails_and_keeps_what_was_flown(tmp_path):
    """A mission longer than --duration: exit 1 with a line that says where the mission was, and the flight so
    far kept (telemetry.csv, flight.tlog, mission.json with the items reached and no disarm time)."""
    plan = Path(__file__).parent / "data" / "square.plan"
    r = subprocess.run(quadsitl("fly", "--preset", "x500", "--mission", str(plan), "--duration", "6", "-q",
                                "--out", str(tmp_path)), capture_output=True, text=True, timeout=120)  # fmt: skip
    assert r.returncode == 1
    line = next(x for x in r.stderr.splitlines() if "did not end within --duration 6 simulated s" in x)
    doc = json.loads((tmp_path / "mission.json").read_text())
    reached = [x["seq"] for x in doc["reached"]]
    assert 1 <= len(reached) < len(doc["items"]) and reached == list(range(len(reached)))
    assert f"{len(reached)} items reached" in line and f"current item {reached[-1] + 1} of 5" in line
    assert doc["disarmed_t"] is None and not doc["all_reached_in_order"]
    data = read_csv(tmp_path / "telemetry.csv")
    assert data["altitude"].max() > 4.0 and data["t"][-1] >= 6.0  # it flew, and the csv holds the flight
    assert (tmp_path / "flight.tlog").stat().st_size > 10_000
