"""``quadsitl replay``: a real telemetry.csv (from ``quadsitl sim``), a real flight.tlog (from ``quadsitl fly``)
and hand-made tlogs played onto Zenoh by the real process and received by a real Zenoh subscriber."""

from __future__ import annotations

import math
import os
import signal
import socket
import struct
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest
import zenoh

from groundstation import pacing, recording
from groundstation.launcher import SETPOINTS_AHEAD, free_port
from groundstation.logger import TelemetryLogger
from groundstation.telemetry_csv import COLUMNS, read_csv
from quadsitl import telemetry, wire
from quadsitl.frames import euler_to_quaternion

M = wire.mavlink
REPLAY = [sys.executable, "-m", "groundstation.replay"]
F_MAX = 10000.0  # the paper preset's F_max per motor [N] (ideal, reversible motors)


def f32(x: float) -> float:
    """A value as MAVLink's float32 fields carry it."""
    return struct.unpack("<f", struct.pack("<f", x))[0]


# ---- fixtures and helpers --------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def sim_csv(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("sim")
    argv = ["sim", "--preset", "paper", "--duration", "0.5", "--no-figures", "--quiet", "--out", str(out)]
    r = subprocess.run([sys.executable, "-m", "groundstation.cli", *argv], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    return out / "telemetry.csv"


@pytest.fixture(scope="module")
def fly_run(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("fly")
    argv = ["fly", "--preset", "paper", "--duration", "2.5", "--no-figures", "--quiet", "--out", str(out)]
    r = subprocess.run([sys.executable, "-m", "groundstation.cli", *argv], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    return out


def _records_bytes(sub: Subscriber, stream: str) -> list[bytes]:
    """Every full-rate record of ``stream`` the subscriber got, as bytes."""
    size = telemetry.STREAMS[stream].size
    with sub._lock:
        data = b"".join(d for s, d, _ in sub.samples if s == stream)
    return [data[i : i + size] for i in range(0, len(data), size)]


class Subscriber:
    """A Zenoh session listening on a free loopback port, subscribed to quadsitl/<vehicle>/**: the replay
    connects to it, so the subscription exists before anything is published."""

    def __init__(self, vehicle: str) -> None:
        self.endpoint = f"tcp/127.0.0.1:{free_port(socket.SOCK_STREAM)}"
        self.session = zenoh.open(telemetry.zenoh_config(listen=[self.endpoint]))
        # stream, payload, when it was published [s] (its Zenoh timestamp: the replay's pace, not this process's
        # delays in taking it; a loaded machine may hold this subscriber back for a while)
        self.samples: list[tuple[str, bytes, float]] = []
        self._lock = threading.Lock()
        self._sub = self.session.declare_subscriber(f"quadsitl/{vehicle}/**", self._on_sample)

    def _on_sample(self, sample: zenoh.Sample) -> None:
        stream = str(sample.key_expr).split("/", 2)[2]  # "state", or "slow/overview" (the overview)
        with self._lock:
            self.samples.append((stream, sample.payload.to_bytes(), sample.timestamp.get_time().timestamp()))

    def records(self, stream: str) -> list[tuple]:
        with self._lock:
            samples = [data for s, data, _ in self.samples if s == stream]
        return [rec for data in samples for rec in telemetry.records(stream.rsplit("/", 1)[-1], data)]

    def wait_for(self, count: int, seconds: float = 5.0) -> None:
        """Until every stream has ``count`` records (or the time is up)."""
        end = time.monotonic() + seconds
        while time.monotonic() < end and min(len(self.records(s)) for s in telemetry.STREAMS) < count:
            time.sleep(0.02)

    def close(self) -> None:
        self._sub.undeclare()
        self.session.close()


@contextmanager
def subscriber(vehicle: str) -> Iterator[Subscriber]:
    sub = Subscriber(vehicle)
    try:
        yield sub
    finally:
        sub.close()


def run_replay(*args: str, timeout: float = 30) -> subprocess.CompletedProcess:
    return subprocess.run([*REPLAY, *args], capture_output=True, text=True, timeout=timeout)


def play(path: Path, vehicle: str, *extra: str, expect: int) -> tuple[subprocess.CompletedProcess, Subscriber]:
    """Replay ``path`` to a fresh subscriber; return the finished process and the subscriber (closed)."""
    with subscriber(vehicle) as sub:
        r = run_replay(str(path), "--vehicle", vehicle, "--zenoh-connect", sub.endpoint, *extra)
        assert r.returncode == 0, r.stderr
        sub.wait_for(expect)
    return r, sub


class TlogWriter:
    """A tlog as quadsitl gcs, MAVProxy and QGroundControl write it: 8-byte big-endian µs timestamp +
    MAVLink 2 frame, packed by wire.link() for the vehicle (1, 1), the ground station (255, 190) and
    another vehicle (2, 1)."""

    def __init__(self) -> None:
        self.vehicle, self.gcs, self.other = wire.link(1, 1), wire.link(255, 190), wire.link(2, 1)
        self.data = bytearray()
        self.usec = 1_700_000_000_000_000

    def add(self, link, msg) -> None:
        self.usec += 137
        self.data += struct.pack(">Q", self.usec) + msg.pack(link)

    def garbage(self, n: int) -> None:
        self.data += bytes((i * 73 + 11) % 256 for i in range(n))

    def save(self, path: Path) -> Path:
        path.write_bytes(bytes(self.data))
        return path


def heartbeat(armed: bool, mode: wire.Mode, status: int = M.MAV_STATE_ACTIVE):
    base = M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | (M.MAV_MODE_FLAG_SAFETY_ARMED if armed else 0)
    return M.MAVLink_heartbeat_message(M.MAV_TYPE_QUADROTOR, M.MAV_AUTOPILOT_PX4, base, mode.px4_custom_mode, status, 3)


# ---- telemetry.csv ---------------------------------------------------------------------------------------


def test_csv_every_tick_arrives_in_order_with_the_csv_values(sim_csv):
    csv = read_csv(sim_csv)
    n = len(csv["t"])
    assert n == 500
    with subscriber("csv") as sub:
        logger = TelemetryLogger(sub.session, "csv", 0.001)  # the ground station's own Zenoh logger, too
        r = run_replay(str(sim_csv), "--vehicle", "csv", "--zenoh-connect", sub.endpoint, "--speed", "0")
        assert r.returncode == 0, r.stderr
        sub.wait_for(n)
        logger.drain()
        rows = logger.rows()
        logger.close()
    # ...which rebuilds the CSV's rows from the replay, as `quadsitl fly` builds them from the autopilot
    assert sorted(rows) == list(range(n))
    logged, want = np.array([rows[k] for k in range(n)]), np.column_stack([csv[c] for c in COLUMNS])
    np.testing.assert_allclose(logged[:, 0], want[:, 0], rtol=0, atol=1e-12)  # the logger's t is k·T
    np.testing.assert_array_equal(logged[:, 1:], want[:, 1:])
    for stream, fields in telemetry.FIELDS.items():
        recs = sub.records(stream)
        assert [rec[0] for rec in recs] == list(range(n)), stream  # every tick, once, in tick order
        got = np.array([rec[1:] for rec in recs], dtype=float)
        if stream == "status":
            assert (got[:, 1:5] == [1, 1, 0, 0]).all()  # armed, offboard, no failsafe, flight started at tick 0
            assert np.isnan(got[:, 5:]).all()  # the paper's CSV: no battery
            want = np.column_stack([csv["t"]])
            np.testing.assert_array_equal(got[:, :1], want)
        else:  # exactly the CSV's numbers: the replay sends what the CSV says
            want = np.column_stack([csv[f] for f in fields[1:]])
            np.testing.assert_array_equal(got, want, err_msg=stream)
    # Batched as the autopilot does: at full speed far fewer samples than records.
    assert len([s for s, _, _ in sub.samples if s == "state"]) < n / 10
    # The overview, as an autopilot puts it: the newest record of each stream, in one sample on
    # quadsitl/<vehicle>/slow/overview, the first at once, then at most one per SLOW_PERIOD, and the last one, owed,
    # at the end: it ends on the last record.
    every = {stream: _records_bytes(sub, stream) for stream in telemetry.STREAMS}
    deadline = time.monotonic() + 5
    while True:
        with sub._lock:
            slow = [telemetry.split_overview(data) for s, data, _ in sub.samples if s == "slow/overview"]
        if (slow and slow[-1]["state"] == every["state"][-1]) or time.monotonic() > deadline:
            break
        time.sleep(0.02)
    assert len(slow) >= 2
    for stream in telemetry.STREAMS:
        assert slow[0][stream] in set(every[stream]) and slow[-1][stream] == every[stream][-1], stream
    # the four records of one overview sample are of one tick
    assert all(len({telemetry.STREAMS[s].unpack(o[s])[0] for s in o}) == 1 for o in slow)
    assert "published 500 state, 500 setpoint, 500 actuators, 500 status records" in r.stderr
    assert "0.500 s simulated" in r.stderr


def test_csv_pure_part_matches_the_file(sim_csv):
    rec = recording.records_from_csv(sim_csv)
    assert len(rec) == 500 and rec.period == pytest.approx(0.001)
    assert list(rec.ticks) == list(range(500)) and rec.duration == pytest.approx(0.5)
    csv = read_csv(sim_csv)
    np.testing.assert_array_equal([s[8] for s in rec.records("state")], csv["roll"])
    np.testing.assert_array_equal([s[2] for s in rec.records("setpoint")], csv["altitude_ref"])


def test_speed_one_plays_in_real_time(sim_csv):
    with subscriber("rt") as sub:
        start = time.monotonic()
        r = run_replay(str(sim_csv), "--vehicle", "rt", "--zenoh-connect", sub.endpoint, "--speed", "1")
        wall = time.monotonic() - start
        assert r.returncode == 0, r.stderr
        sub.wait_for(500)
    published = [t for s, _, t in sub.samples if s == "state"]
    assert len(sub.records("state")) == 500
    assert published[-1] - published[0] >= 0.4  # 0.5 s of simulated time at 1× real time
    assert wall < 10.0


def test_speed_two_takes_half_the_time(sim_csv):
    with subscriber("x2") as sub:
        r = run_replay(str(sim_csv), "--vehicle", "x2", "--zenoh-connect", sub.endpoint, "--speed", "2")
        assert r.returncode == 0, r.stderr
        sub.wait_for(500)
    published = [t for s, _, t in sub.samples if s == "state"]
    assert 0.2 <= published[-1] - published[0] < 0.45


# ---- tlog -----------------------------------------------------------------------------------------------


def vehicle_tlog(path: Path) -> tuple[Path, list[dict]]:
    """A tlog with everything the autopilot can stream, garbage between frames, a second vehicle and an
    arm → offboard → land sequence; returns it and what was put in at each ATTITUDE tick."""
    w = TlogWriter()
    w.add(w.gcs, M.MAVLink_heartbeat_message(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, M.MAV_STATE_ACTIVE, 3))
    w.add(w.vehicle, heartbeat(False, wire.Mode.HOLD, M.MAV_STATE_STANDBY))
    put = []
    for i in range(30):
        ms = 1000 + 10 * i  # ATTITUDE at 100 Hz: ticks 1000, 1010, ...
        v = {"tick": ms, "t": ms / 1000, "roll": 0.01 * i, "pitch": -0.02 * i, "yaw": 0.5 + 0.001 * i,
             "p": 0.1, "q": -0.2, "r": 0.3, "x": 1.0 + i, "y": -2.0, "z": -0.1 * i, "vx": 0.5, "vy": 0.0, "vz": -1.0,
             "roll_ref": 0.2, "pitch_ref": -0.1, "yaw_ref": 0.7, "z_ref": -5.0 - 0.01 * i,
             "controls": (0.1 + 0.01 * i, 0.2, -0.3, 0.4)}  # fmt: skip
        w.add(w.vehicle, M.MAVLink_attitude_message(ms, v["roll"], v["pitch"], v["yaw"], v["p"], v["q"], v["r"]))
        w.add(w.other, M.MAVLink_attitude_message(ms, 3.0, 3.0, 3.0, 3.0, 3.0, 3.0))  # another vehicle: ignored
        w.add(w.vehicle, M.MAVLink_local_position_ned_message(ms, v["x"], v["y"], v["z"], v["vx"], v["vy"], v["vz"]))
        q = euler_to_quaternion(v["roll_ref"], v["pitch_ref"], v["yaw_ref"])
        w.add(w.vehicle, M.MAVLink_attitude_target_message(ms, 7, q, 0, 0, 0, 0.5))
        w.garbage(13)
        mask = 1 | 2 | 8 | 16 | 32 | 64 | 128 | 256 | 2048
        w.add(w.vehicle, M.MAVLink_position_target_local_ned_message(ms, M.MAV_FRAME_LOCAL_NED, mask, 0, 0,
                                                                     v["z_ref"], 0, 0, 0, 0, 0, 0, 0.7, 0))  # fmt: skip
        w.add(w.vehicle, M.MAVLink_actuator_output_status_message(ms * 1000, 0b1111, [*v["controls"], *[0.0] * 28]))
        if i >= 15:  # a battery reports from tick 1150 on: 16.7 V in the first cell, 80 mAh and 5 kJ drawn, 80 % left
            w.add(w.vehicle, M.MAVLink_battery_status_message(0, 1, 1, 32767, [16700, *[65535] * 9], 1820 + i, 80,
                                                              50, 80, 0, 0, [0] * 4, 0, 0))  # fmt: skip
        if i == 4:  # the ground station arms: the ack counts before the next heartbeat
            w.add(w.gcs, M.MAVLink_command_long_message(1, 1, M.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0))
            w.add(w.vehicle, M.MAVLink_command_ack_message(M.MAV_CMD_COMPONENT_ARM_DISARM, M.MAV_RESULT_ACCEPTED))
        if i == 10:
            w.add(w.vehicle, heartbeat(True, wire.Mode.OFFBOARD))
        if i == 20:  # a failsafe the heartbeat reports, then a landing the ground station commands
            w.add(w.vehicle, heartbeat(True, wire.Mode.OFFBOARD, M.MAV_STATE_CRITICAL))
            w.add(w.gcs, M.MAVLink_command_long_message(1, 1, M.MAV_CMD_NAV_LAND, 0, 0, 0, 0, 0, 0, 0, 0))
            w.add(w.vehicle, M.MAVLink_command_ack_message(M.MAV_CMD_NAV_LAND, M.MAV_RESULT_ACCEPTED))
        put.append(v)
    return w.save(path), put


def test_tlog_values_arrive_decoded(tmp_path):
    path, put = vehicle_tlog(tmp_path / "vehicle.tlog")
    r, sub = play(path, "tlog", "--speed", "0", expect=len(put))
    state, setpoint = sub.records("state"), sub.records("setpoint")
    actuators, status = sub.records("actuators"), sub.records("status")
    assert [s[0] for s in state] == [v["tick"] for v in put]  # tick = time_boot_ms at T = 1 ms
    for s, sp, a, st, v in zip(state, setpoint, actuators, status, put):
        rec = dict(zip(telemetry.FIELDS["state"], s))
        assert rec["t"] == v["t"]
        for f in ("x", "y", "z", "vx", "vy", "vz", "roll", "pitch", "yaw", "p", "q", "r"):
            assert rec[f] == f32(v[f]), f  # exactly what the MAVLink float32 fields carried
        assert sp[2] == -f32(v["z_ref"])  # altitude_ref = −z
        assert sp[3:6] == pytest.approx((v["roll_ref"], v["pitch_ref"], v["yaw_ref"]), abs=1e-6)
        assert math.isnan(sp[6]) and math.isnan(sp[7])  # the type_mask ignores x and y: not controlled
        assert all(math.isnan(u) for u in a[2:6])  # u1..u4 are not in MAVLink
        assert a[6:] == tuple(f32(c) * F_MAX for c in v["controls"])  # F_j = actuator[j]·F_max
        i = (v["tick"] - 1000) // 10
        armed = 1 if i >= 4 else 0
        mode = 0 if i < 10 else (1 if i < 20 else 2)
        offboard_tick = 1100 if 10 <= i < 20 else -1
        assert st[2:6] == (armed, mode, 1 if i >= 20 else 0, offboard_tick), i
        battery = (16.7, (1820 + i) / 100, 80.0, 5000.0, 0.8) if i >= 15 else (math.nan,) * 5
        assert st[6:] == pytest.approx(battery, nan_ok=True), i
    assert "skipped 390 bytes" in r.stderr  # the 13 bytes of garbage × 30
    assert "f1..f4 from ACTUATOR_OUTPUT_STATUS" in r.stderr


def test_tlog_falls_back_on_the_ground_stations_setpoints_and_servo_outputs(tmp_path):
    """What `quadsitl fly` logs: ATTITUDE and the ground station's setpoints, no LOCAL_POSITION_NED."""
    w = TlogWriter()
    for i in range(10):
        ms = 20 * i
        w.add(w.vehicle, M.MAVLink_attitude_message(ms, 0.1, 0.2, 0.3, 0.0, 0.0, 0.0))
        q = euler_to_quaternion(0.4, -0.3, 1.0)
        w.add(w.gcs, M.MAVLink_set_attitude_target_message(ms, 1, 1, 71, q, 0, 0, 0, 0))
        w.add(w.gcs, M.MAVLink_set_position_target_local_ned_message(ms, 1, 1, M.MAV_FRAME_LOCAL_NED, 0b110111111011,
                                                                     0, 0, -3.0, 0, 0, 0, 0, 0, 0, 0, 0))  # fmt: skip
        w.add(w.gcs, M.MAVLink_set_attitude_target_message(ms, 2, 1, 71, [1, 0, 0, 0], 0, 0, 0, 0))  # not ours
        w.add(w.vehicle, M.MAVLink_servo_output_raw_message(ms * 1000, 0, 1750, 1500, 1000, 0, *[0] * 12))
    path = w.save(tmp_path / "flight.tlog")
    r, sub = play(path, "fallback", "--speed", "0", expect=10)
    state, setpoint, actuators = sub.records("state"), sub.records("setpoint"), sub.records("actuators")
    assert [s[0] for s in state] == [20 * i for i in range(10)]
    assert all(math.isnan(x) for s in state for x in s[2:8])  # no LOCAL_POSITION_NED: x..vz NaN
    for sp in setpoint:
        assert sp[2] == 3.0 and sp[3:6] == pytest.approx((0.4, -0.3, 1.0), abs=1e-6)
        assert math.isnan(sp[6]) and math.isnan(sp[7])  # z only: the horizontal position is not controlled
    # SERVO_OUTPUT_RAW, reversible motors (paper preset): 1000..2000 µs = −F_max..F_max; 0 µs = off
    assert actuators[-1][6:] == (0.5 * F_MAX, 0.0, -F_MAX, 0.0)
    assert sub.records("status")[0][2:6] == (0, recording.MODE_UNKNOWN, 0, -1)  # nothing known yet
    assert "no LOCAL_POSITION_NED" in r.stderr and "from SET_ATTITUDE_TARGET" in r.stderr
    assert "x_ref, y_ref from nothing: NaN" in r.stderr


POSITION_VELOCITY_YAW = 2496  # MAVSDK's position + velocity mask: x, y, z, vx, vy, vz and yaw are targets


def test_tlog_position_targets_become_x_ref_y_ref_when_the_type_mask_says_so(tmp_path):
    """POSITION_TARGET_LOCAL_NED's x, y are the reference while its type_mask makes them a target (2496, 2552);
    a z-only or velocity mask (3576 − x, y ignored), or another frame, leaves x_ref, y_ref NaN. Before the
    vehicle says anything, the ground station's SET_POSITION_TARGET_LOCAL_NED counts, read the same way."""
    w = TlogWriter()
    z_only = 0b110111111011
    velocity = 1 | 2 | 4 | 64 | 128 | 256 | 1024 | 2048
    for i in range(12):
        ms = 20 * i
        w.add(w.vehicle, M.MAVLink_attitude_message(ms, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0))
        if i < 3:  # the ground station's command only
            frame, mask = M.MAV_FRAME_LOCAL_NED, POSITION_VELOCITY_YAW
            w.add(w.gcs, M.MAVLink_set_position_target_local_ned_message(
                ms, 1, 1, frame, mask, 4.0, -1.5, -2.0, 1, 0, 0, 0, 0, 0, 0.3, 0))  # fmt: skip
        elif i < 9:  # the vehicle's own target: position (2496 or 2552), then z only, then velocity
            pv = POSITION_VELOCITY_YAW
            mask = (pv, 2552, pv, z_only, velocity, pv)[i - 3]
            frame = M.MAV_FRAME_BODY_NED if i == 8 else M.MAV_FRAME_LOCAL_NED
            w.add(w.vehicle, M.MAVLink_position_target_local_ned_message(
                ms, frame, mask, 10.0 + i, -i, -5.0, 0, 0, 0, 0, 0, 0, 0, 0))  # fmt: skip
    rec = recording.records_from_tlog(w.save(tmp_path / "position.tlog"), 0.001)
    got = [(sp[0], sp[6], sp[7]) for sp in rec.records("setpoint")]
    want_x = [4.0, 4.0, 4.0, 13.0, 14.0, 15.0, None, None, None, None, None, None]
    want_y = [-1.5, -1.5, -1.5, -3.0, -4.0, -5.0]
    for i, (tick, x_ref, y_ref) in enumerate(got):
        assert tick == 20 * i
        if want_x[i] is None:  # z only, velocity; a BODY_NED target is not read, the last one stays (NaN)
            assert math.isnan(x_ref) and math.isnan(y_ref), i
        else:
            assert (x_ref, y_ref) == (want_x[i], want_y[i]), i
    notes = " / ".join(rec.notes)
    assert "x_ref, y_ref from POSITION_TARGET_LOCAL_NED and SET_POSITION_TARGET_LOCAL_NED" in notes


def test_a_telemetry_csv_from_before_schema_v3_replays_with_nan_position_references(tmp_path, sim_csv):
    """A telemetry.csv without x_ref, y_ref (written before the columns existed) still replays, with NaN."""
    lines = sim_csv.read_text().splitlines()
    header = lines[0].split(",")
    keep = [i for i, h in enumerate(header) if h not in ("x_ref", "y_ref")]
    assert len(keep) == len(header) - 2
    old = tmp_path / "old.csv"
    old.write_text("\n".join(",".join(line.split(",")[i] for i in keep) for line in lines[:50]) + "\n")
    rec = recording.records_from_csv(old)
    setpoints = rec.records("setpoint")
    assert len(setpoints) == 49 and all(math.isnan(sp[6]) and math.isnan(sp[7]) for sp in setpoints)
    assert setpoints[0][2] == read_csv(sim_csv)["altitude_ref"][0]
    assert any("no x_ref, y_ref columns" in note for note in rec.notes)


@pytest.mark.timeout(120)
def test_real_fly_tlog_matches_the_flights_csv(fly_run):
    """The tlog of a real `quadsitl fly`: every ATTITUDE becomes a record whose attitude is the CSV's at the
    same tick (to float32), and the offboard start it infers is within one ATTITUDE interval of the truth."""
    csv = read_csv(fly_run / "telemetry.csv")
    n = len(csv["t"])
    rec = recording.records_from_tlog(fly_run / "flight.tlog", 0.001, F_MAX, True)
    assert len(rec) > 10
    with subscriber("fly") as sub:
        r = run_replay(str(fly_run / "flight.tlog"), "--vehicle", "fly", "--zenoh-connect", sub.endpoint,
                       "--speed", "0")  # fmt: skip
        assert r.returncode == 0, r.stderr
        sub.wait_for(len(rec))
    state, status = sub.records("state"), sub.records("status")
    assert [s[0] for s in state] == list(rec.ticks)
    # The CSV's row k is tick (offboard start + k): find the start from the first tick that moved.
    roll = {s[0]: s[8] for s in state}
    moving = [k for k in sorted(roll) if roll[k] != 0.0]
    first = moving[0]
    interval = pacing.attitude_interval_us(SETPOINTS_AHEAD) // 1000  # [ticks] ATTITUDE's in `fly`'s log (10 Hz)
    start = next(s for s in range(first - interval - 5, first + 1) if 0 <= first - s < n
                 and abs(csv["roll"][first - s] - roll[first]) < 1e-6)  # fmt: skip
    compared = 0
    for tick, value in roll.items():
        if 0 <= tick - start < n:
            assert value == pytest.approx(csv["roll"][tick - start], abs=1e-6), tick
            compared += 1
    assert compared >= 20
    offboard = {st[5] for st in status if st[5] >= 0}
    assert len(offboard) == 1 and abs(offboard.pop() - start) <= interval
    # `fly` turns LOCAL_POSITION_NED off once connected: x is NaN, or the x = 0 of one sent before that
    assert math.isnan(state[-1][2]) or state[-1][2] == 0.0


def test_tlog_scanner_resynchronises_after_garbage():
    w = TlogWriter()
    w.garbage(50)
    for ms in range(5):
        w.add(w.vehicle, M.MAVLink_attitude_message(ms, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0))
        w.garbage(7)
    w.data += b"\x00" * 8 + b"\xfd\x30\x00"  # a truncated last frame
    scan = recording.tlog_messages(bytes(w.data))
    assert [m.time_boot_ms for m in scan.messages] == list(range(5))
    assert scan.skipped == 50 + 5 * 7 + 11 and scan.unknown == 0


# ---- the command line -----------------------------------------------------------------------------------


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_loop_until_interrupted_exits_cleanly(sim_csv, sig):
    with subscriber("loop") as sub:
        proc = subprocess.Popen([*REPLAY, str(sim_csv), "--vehicle", "loop", "--zenoh-connect", sub.endpoint,
                                 "--loop", "--speed", "5"], stderr=subprocess.PIPE, text=True,
                                # started as a script's background job is: SIGINT ignored
                                preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_IGN))  # fmt: skip
        try:
            end = time.monotonic() + 15
            while time.monotonic() < end and len(sub.records("state")) < 600:  # into the second pass
                time.sleep(0.05)
            proc.send_signal(sig)
            _, err = proc.communicate(timeout=10)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
    ticks = [s[0] for s in sub.records("state")]
    assert ticks[:500] == list(range(500)) and ticks[500:600] == list(range(100))  # each pass from tick 0
    assert proc.returncode == 0, err  # --loop runs until stopped: the stop is its normal end
    assert "Traceback" not in err
    assert "interrupted;" in err and "complete pass" in err


def bad_csv(tmp_path: Path, sim_csv: Path, drop: str | None = None, poison: str | None = None) -> Path:
    lines = sim_csv.read_text().splitlines()
    header = lines[0].split(",")
    rows = [line.split(",") for line in lines[1:4]]
    if drop:
        i = header.index(drop)
        header.pop(i)
        for row in rows:
            row.pop(i)
    if poison:
        rows[1][header.index(poison)] = "oops"
    path = tmp_path / "bad.csv"
    path.write_text("\n".join(",".join(row) for row in [header, *rows]) + "\n")
    return path


@pytest.mark.parametrize(
    "case, message",
    [
        ("missing", "missing.csv: no such file; expected a telemetry.csv"),
        ("extension", "flight.txt: unknown file type '.txt'; expected .csv"),
        ("column", "bad.csv: missing column pitch_ref; a telemetry CSV has the columns t, x,"),
        ("number", "bad.csv: line 3, column roll: 'oops' is not a number"),
        ("header-only", "header.csv: no data rows after the header"),
        ("speed", "--speed -1.0: expected a number in [0, 1000] (0 = as fast as possible)"),
        ("too-fast", "--speed 1001.0: expected a number in [0, 1000]"),
        ("period", "--period 0.0: expected a number in (0, 1]"),
        ("empty-tlog", "empty.tlog: empty file; expected 8-byte big-endian timestamps"),
        ("garbage-tlog", "garbage.tlog: no MAVLink messages in 4000 bytes"),
        ("no-attitude", "gcs.tlog: 1 MAVLink message but no ATTITUDE from an autopilot (component 1)"),
        ("preset", "--preset: unknown preset 'nope'"),
    ],
)
def test_bad_input_is_one_line_and_exit_2(tmp_path, sim_csv, case, message):
    args: list[str] = []
    if case == "missing":
        args = [str(tmp_path / "missing.csv")]
    elif case == "extension":
        (tmp_path / "flight.txt").write_text("t\n0\n")
        args = [str(tmp_path / "flight.txt")]
    elif case == "column":
        args = [str(bad_csv(tmp_path, sim_csv, drop="pitch_ref"))]
    elif case == "number":
        args = [str(bad_csv(tmp_path, sim_csv, poison="roll"))]
    elif case == "header-only":
        (tmp_path / "header.csv").write_text(sim_csv.read_text().splitlines()[0] + "\n")
        args = [str(tmp_path / "header.csv")]
    elif case == "speed":
        args = [str(sim_csv), "--speed", "-1"]
    elif case == "too-fast":
        args = [str(sim_csv), "--speed", "1001"]
    elif case == "period":
        args = [str(sim_csv), "--period", "0"]
    elif case == "empty-tlog":
        (tmp_path / "empty.tlog").write_bytes(b"")
        args = [str(tmp_path / "empty.tlog")]
    elif case == "garbage-tlog":
        (tmp_path / "garbage.tlog").write_bytes(np.random.default_rng(1).bytes(4000))
        args = [str(tmp_path / "garbage.tlog")]
    elif case == "no-attitude":
        w = TlogWriter()
        w.add(w.gcs, M.MAVLink_heartbeat_message(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, 0, 3))
        args = [str(w.save(tmp_path / "gcs.tlog"))]
    elif case == "preset":
        path, _ = vehicle_tlog(tmp_path / "v.tlog")
        args = [str(path), "--preset", "nope"]
    r = run_replay(*args, "--zenoh-listen", "tcp/127.0.0.1:0")
    assert r.returncode == 2, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("quadsitl replay: error: "), r.stderr
    assert message in lines[0]
    assert "Traceback" not in r.stderr


def test_help_has_examples():
    r = run_replay("--help")
    assert r.returncode == 0
    assert "examples:" in r.stdout and "quadsitl replay runs/fly/telemetry.csv --speed 2" in r.stdout
    assert "quadsitl dashboard" in r.stdout and "--zenoh-connect" in r.stdout


def test_the_quadsitl_command_dispatches_replay():
    from groundstation import cli

    if "replay" not in cli.PROCESSES:
        pytest.skip("groundstation/cli.py does not map `quadsitl replay` yet")
    r = subprocess.run([sys.executable, "-m", "groundstation.cli", "replay", "--help"], capture_output=True,
                       text=True, timeout=30, env={**os.environ, "COLUMNS": "120"})  # fmt: skip
    assert r.returncode == 0 and "usage: quadsitl replay" in r.stdout
