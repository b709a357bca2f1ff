"""Sensor mode (``--state sensors``, docs/sensors.md): the plant sends what the sensors measure, the autopilot flies
on its estimator, and the ground truth never reaches the controllers."""

from __future__ import annotations

import dataclasses
import json
import math
import socket
import struct
import subprocess
import sys
import time

import numpy as np
import pytest

from autopilot import tick as kernel
from autopilot.commander import Commander, Mode
from autopilot.control_params import MEM_SIZE
from autopilot.estimator import Estimator
from autopilot.factory import make_controller
from autopilot.plugin import no_plug
from autopilot.stream_frames import StreamFrames
from groundstation.launcher import free_port
from groundstation.telemetry_csv import SENSOR_COLUMNS, read_csv
from quadsitl import codec, earth, frames, hil, wire
from quadsitl.config import SensorParams, load_preset
from sitl import tick as plant_tick
from sitl.plant import Plant
from tests.test_fly import procs, quadsitl  # noqa: F401 (procs: a fixture)

M = wire.mavlink
NAN = math.nan
X500 = load_preset("x500")


def test_the_plant_sends_hil_sensor_every_tick_gps_late_and_the_truth_in_px4_units(tmp_path):
    """A real plant process in sensor mode, answered by a pymavlink "autopilot": every datagram is decoded by
    pymavlink and checked for its schedule (fields_updated, the GPS's rate and delay), units and frames."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", 0))
    sock.settimeout(10.0)
    port = sock.getsockname()[1]
    ticks = 400
    err = (tmp_path / "plant.stderr").open("w")
    plant = subprocess.Popen([sys.executable, "-m", "sitl", "--preset", "x500", "--state", "sensors", "--autopilot",
                              f"127.0.0.1:{port}", "--ticks", str(ticks), "--quiet"], stderr=err)  # fmt: skip
    mav, ap = wire.link(1, wire.AUTOPILOT_COMPONENT_ID), wire.link(1, wire.AUTOPILOT_COMPONENT_ID)
    sensor, gps, truth, battery = {}, {}, {}, {}
    try:
        while len(sensor) < ticks:
            data, sender = sock.recvfrom(65535)
            msgs = mav.parse_buffer(data) or []
            kinds = [m.get_type() for m in msgs if m.get_type() != "HIL_GPS"]
            assert kinds == ["HIL_SENSOR", "HIL_STATE_QUATERNION", "BATTERY_STATUS"]  # the x500 has a battery
            t = msgs[0].time_usec
            sensor[t // 1000] = msgs[0]
            truth[t // 1000] = msgs[-2]
            battery[t // 1000] = msgs[-1]
            for m in msgs:
                if m.get_type() == "HIL_GPS":
                    gps[t // 1000] = m
            answer = wire.actuator_message(t, (0.0, 0.0, 0.0, 0.0), 1.0, False)
            sock.sendto(answer.pack(ap), sender)
        assert plant.wait(10) == 0
    finally:
        if plant.poll() is None:
            plant.kill()
        sock.close()
    assert sorted(sensor) == list(range(ticks))  # one HIL_SENSOR a tick, stamped with its simulated time
    for k, m in sensor.items():
        expected = hil.ACCEL_UPDATED | hil.GYRO_UPDATED
        expected |= hil.MAG_UPDATED if k % 10 == 0 else 0  # 100 Hz
        expected |= hil.BARO_UPDATED if k % 20 == 0 else 0  # 50 Hz
        assert m.fields_updated == expected, k
    # GPS: 10 Hz, each fix delivered 120 ms after it was measured (its time_usec)
    assert sorted(gps) == [120, 220, 320]
    lat0, lon0, alt0 = frames.PX4_HOME
    for k, g in gps.items():
        assert g.time_usec == (k - 120) * 1000
        assert (g.fix_type, g.satellites_visible, g.eph, g.epv) == (3, 10, 100, 200)  # eph/epv: cm
        assert abs(g.lat - lat0 * 1e7) < 1000 and abs(g.lon - lon0 * 1e7) < 1500  # within ~10 m (σ 1 m)
        assert abs(g.alt - alt0 * 1000) < 10_000  # mm (σ 2 m)
        assert max(abs(g.vn), abs(g.ve)) < 30 and abs(g.vd) < 60  # cm/s (σ 5 and 10 cm/s)
    # at rest, level, heading north, on the ground at home
    g = X500.vehicle.gravity
    acc = np.array([[m.xacc, m.yacc, m.zacc] for m in sensor.values()])
    assert np.allclose(acc.mean(axis=0), (0.0, 0.0, -g), atol=0.03)  # specific force, FRD: −g along z
    assert np.allclose(acc.std(axis=0), 6.37e-3 / math.sqrt(X500.sim.period), rtol=0.2)  # σ = ND/√dt
    gyro = np.array([[m.xgyro, m.ygyro, m.zgyro] for m in sensor.values()])
    assert np.allclose(gyro.mean(axis=0), 0.0, atol=0.005)
    mag = np.array([[m.xmag, m.ymag, m.zmag] for m in sensor.values() if m.fields_updated & hil.MAG_UPDATED])
    field = earth.magnetic_field_ned(earth.MAG_STRENGTH, math.radians(earth.MAG_DECLINATION_DEG),
                                     math.radians(earth.MAG_INCLINATION_DEG))  # fmt: skip
    assert np.allclose(mag.mean(axis=0), field, atol=0.01)  # gauss; level and heading north: body = NED
    baro = [m for m in sensor.values() if m.fields_updated & hil.BARO_UPDATED]
    assert np.mean([m.abs_pressure for m in baro]) == pytest.approx(earth.isa_pressure(alt0) / 100, abs=0.01)  # hPa
    assert np.mean([m.pressure_alt for m in baro]) == pytest.approx(alt0, abs=0.3)  # m AMSL
    assert np.mean([m.temperature for m in baro]) == pytest.approx(earth.isa_temperature(alt0) - 273.15, abs=1e-3)
    for m in truth.values():
        assert list(m.attitude_quaternion) == [1.0, 0.0, 0.0, 0.0]
        assert (m.lat, m.lon, m.alt) == (round(lat0 * 1e7), round(lon0 * 1e7), round(alt0 * 1000))
        assert (m.vx, m.vy, m.vz) == (0, 0, 0)
        assert m.zacc == round(-g / 9.80665e-3)  # mG
    for k, m in battery.items():  # a full 4-cell pack at rest, drawing the avionics' 5 W from the first step on
        assert (m.voltages[0], m.voltages[1], m.battery_remaining) == (16800 if k == 0 else 16794, 65535, 100)
        assert m.current_battery == (0 if k == 0 else round(5.0 / 16.8 * 100))  # cA


def sensor_datagrams(preset, ticks: int):
    """The plant's sensor datagrams and states of ``ticks`` ticks (a generator: send it each tick's forces)."""
    plant = Plant(preset)
    io = np.zeros(plant_tick.IO_SIZE, dtype=np.int64)
    io[plant_tick.SENSING] = 1
    tx = np.zeros(hil.DATAGRAM_MAX, dtype=np.uint8)
    for k in range(ticks):
        plant_tick.encode_tick(tx, io, plant.x, plant.out, plant.air, plant.sensors.arrays, k, plant.period)
        f = yield tx[: io[plant_tick.TX_LEN]].copy(), plant.state
        plant.step(f)


class SensorAutopilot:
    """The autopilot's compiled sensor-mode tick on its own arrays; :meth:`arm` arms it in offboard, 2 m, level."""

    def __init__(self, preset) -> None:
        s = preset.sensors
        self.ctl = make_controller(preset)
        self.est = Estimator.for_field(preset.sim.period, preset.vehicle.gravity, s.mag_strength_gauss,
                                       s.mag_declination_deg, s.mag_inclination_deg)  # fmt: skip
        self.cm = Commander()
        self.st, self.truth = np.zeros(codec.DECODED_SIZE), np.zeros(codec.DECODED_SIZE)
        self.mem, self.tx = np.zeros(MEM_SIZE), np.zeros(codec.FRAME_MAX, dtype=np.uint8)
        self.frame = np.zeros(codec.FRAME_MAX, dtype=np.uint8)
        self.io = np.zeros(kernel.IO_SIZE, dtype=np.int64)
        self.io[kernel.LAST_USEC], self.io[kernel.CAPACITY] = -1, 1
        self.batch = kernel.Batch(1)
        self.period, self.f_max = preset.sim.period, preset.actuators.max_thrust
        self.f_min = preset.actuators.min_thrust

    def arm(self) -> None:
        """As the process allows it: once the estimator has aligned."""
        assert self.est.aligned
        self.cm.on_altitude_setpoint(2.0)
        self.cm.on_attitude_setpoint(0.0, 0.0, 0.0)
        self.cm.arm()
        self.cm.set_mode(Mode.OFFBOARD)

    def tick(self, datagram: np.ndarray) -> bytes:
        self.io[kernel.ROWS] = 0
        rx = datagram.copy()
        flags = kernel.sensor_tick(rx, len(rx), self.frame, self.truth, frames.PX4_HOME, self.est.arrays, self.st,
                                   self.period, self.ctl.kind, no_plug(), self.cm.cm, self.mem, self.ctl.v,
                                   self.ctl.c, self.f_min, self.f_max, self.tx, self.io, self.batch.records,
                                   StreamFrames(2, frames.PX4_HOME, 40.0, False).out)  # fmt: skip
        assert flags & kernel.ANSWER
        return bytes(self.tx[: self.io[kernel.TX_LEN]])

    def truth_record(self) -> tuple:
        return struct.unpack("<Qd12d", self.batch.payload("truth", 1))


def with_truth(datagram: np.ndarray, state: tuple) -> np.ndarray:
    """``datagram`` with its HIL_STATE_QUATERNION replaced by one saying ``state`` (VehicleState order); the frames
    after it (the battery's) as they were."""
    n = 0
    while datagram[n + 7] != hil.TRUTH_ID:  # frame by frame: MAVLink 2 drops trailing zeros
        n += codec.HEADER_SIZE + int(datagram[n + 1]) + 2
    after = datagram[n + codec.HEADER_SIZE + int(datagram[n + 1]) + 2 :]
    out = np.zeros(hil.DATAGRAM_MAX + 64, dtype=np.uint8)
    out[:n] = datagram[:n]
    m = hil.encode_truth(out[n:], 0, 1, wire.PLANT_COMPONENT_ID, 0, state, 0.0, (0.0, 0.0, -9.81), frames.PX4_HOME)
    out[n + m : n + m + len(after)] = after
    return out[: n + m + len(after)]


def test_the_controllers_never_see_the_truth():
    """Two autopilots fly the same sensor datagrams, closed loop, the second with a lying truth message (100 m up,
    rolled 45°, moving at 10 m/s): every answer is the same to the byte, and only the telemetry's truth differs."""
    preset = dataclasses.replace(X500, sensors=SensorParams(seed=3))
    honest, fooled = SensorAutopilot(preset), SensorAutopilot(preset)
    lie = (5.0, -7.0, -100.0, 10.0, 0.0, 0.0, math.radians(45), 0.0, 1.0, 0.0, 0.0, 0.0)
    flight = sensor_datagrams(preset, 3000)
    datagram, state = next(flight)
    flown = 0.0
    for k in range(2999):
        if k == 1500:
            honest.arm()
            fooled.arm()
        answer = honest.tick(datagram)
        assert fooled.tick(with_truth(datagram, lie)) == answer
        assert np.array_equal(honest.st, fooled.st, equal_nan=True)
        assert honest.truth_record()[4] == pytest.approx(state.z, abs=2e-3)  # the real truth, to the mm
        assert fooled.truth_record()[4] == pytest.approx(-100.0, abs=2e-3)  # the lie reached telemetry only
        forces = wire.forces_from_message(wire.link(1, 1).parse_buffer(answer)[0], honest.f_max)
        flown = max(flown, -state.z)
        datagram, state = flight.send(forces)
    assert honest.est.aligned and not honest.est.diverged
    assert flown > 1.5  # it flew: climbed towards 2 m on the estimate


def test_an_autopilot_on_sensors_never_flies_odometry_and_says_why(tmp_path, procs):  # noqa: F811
    """A truth-mode plant (ODOMETRY) and a sensor-mode autopilot: no tick is flown (the plant's clock never
    advances) and the ground station is told what to change."""
    from tests.mavclient import Client

    plant_port, api = free_port(), free_port()
    ap = subprocess.Popen([sys.executable, "-m", "autopilot", "--preset", "x500", "--state", "sensors",
                           "--plant-listen", f"127.0.0.1:{plant_port}", "--gcs-listen", "127.0.0.1:0", "--gcs-remote",
                           "none", "--api-listen", f"127.0.0.1:{api}", "--api-remote", "none", "--no-zenoh"],
                          stderr=subprocess.DEVNULL)  # fmt: skip
    procs.append(ap)
    stats = tmp_path / "stats.json"
    plant = subprocess.Popen([sys.executable, "-m", "sitl", "--preset", "x500", "--state", "truth", "--autopilot",
                              f"127.0.0.1:{plant_port}", "--ticks", "5", "--stats", str(stats)],
                             stderr=subprocess.DEVNULL)  # fmt: skip
    procs.append(plant)
    c = Client.to(api)
    try:
        c.connect(timeout=30, armable=False)
        said = c.text_containing("true state (ODOMETRY)", timeout=10)
        assert "--state sensors" in said
        time.sleep(0.5)
        assert plant.poll() is None  # still at tick 0: nothing answered
    finally:
        c.conn.close()


def fly_on_sensors(out, *extra: str) -> dict[str, np.ndarray]:
    p = subprocess.Popen(
        quadsitl("fly", "--preset", "x500", "--state", "sensors", "--out", str(out), "--quiet", *extra)
    )
    try:
        assert p.wait(240) == 0
    finally:
        if p.poll() is None:
            p.kill()
    return read_csv(out / "telemetry.csv")


@pytest.fixture(scope="module")
def flown(tmp_path_factory) -> tuple:
    """``quadsitl fly --preset x500 --state sensors`` (the x500's 5 s of steps, the default sensors, seed 0)."""
    out = tmp_path_factory.mktemp("fly-sensors")
    return out, fly_on_sensors(out)


def test_fly_on_sensors_tracks_the_truth(flown):
    """The x500's steps flown on the estimate, closed loop, with the default sensors: telemetry.csv has the estimate
    and the truth, and they agree as docs/sensors.md says."""
    out, d = flown
    assert len(d["t"]) == round(X500.sim.duration / X500.sim.period)
    rms = {c: float(np.sqrt(np.mean((d[c] - d[c + "_true"]) ** 2))) for c in ("z", "roll", "pitch", "yaw", "vx")}
    assert rms["z"] < 0.1  # the bound: altitude RMS ≤ 0.1 m
    assert max(rms["roll"], rms["pitch"], rms["yaw"]) < math.radians(0.5)  # attitude RMS ≤ 0.5°
    assert 0.0 < rms["vx"] < 0.1  # an estimate, not the truth
    assert abs(d["roll_true"][-1] - math.radians(10)) < math.radians(1)  # the step was flown, in truth
    m = json.loads((out / "metrics.json").read_text())
    assert m["state"] == "sensors" and m["sensors"]["profile"] == "px4"
    assert m["estimate_rms"]["altitude_m"] == pytest.approx(rms["z"], rel=1e-3)
    assert m["estimate_rms"]["roll_deg"] == pytest.approx(math.degrees(rms["roll"]), rel=1e-3)


def test_fly_on_sensors_is_deterministic_per_seed(flown, tmp_path):
    """The plant holds its clock on the ground until the vehicle arms, so every run starts its flight after the same
    ticks of sensor noise: the same seed flies the same flight to the byte, another seed another."""
    out, _ = flown
    again = fly_on_sensors(tmp_path / "again")
    assert (tmp_path / "again" / "telemetry.csv").read_bytes() == (out / "telemetry.csv").read_bytes()
    other = fly_on_sensors(tmp_path / "seed1", "--sensor-seed", "1")
    assert np.max(np.abs(other["z"] - again["z"])) > 1e-3


@pytest.mark.timeout(420)  # sim's sensor path compiles cold in 160-230 s on an idle 2-core machine; more under load
def test_fly_equals_sim_on_sensors(flown, tmp_path, sensor_sim):
    """``quadsitl sim --state sensors`` flies what ``fly`` flies: the same sensor noise, estimator and controller,
    composed of the same compiled functions. The estimate agrees to float32's precision (the forces cross the wire
    as float32), the truth to HIL_STATE_QUATERNION's quantisation (1e-7 deg, 1 mm)."""
    _, d = flown
    p = subprocess.run(quadsitl("sim", "--preset", "x500", "--state", "sensors", "--out", str(tmp_path), "--quiet",
                                "--no-figures"), timeout=400)  # fmt: skip
    assert p.returncode == 0
    s = read_csv(tmp_path / "telemetry.csv")
    assert len(s["t"]) == len(d["t"])
    for c in ("x", "y", "z", "vx", "vy", "vz", "roll", "pitch", "yaw", "p", "q", "r", "u2", "u3", "u4"):
        assert np.max(np.abs(s[c] - d[c])) < 2e-5, c
    # u1 = m/(T·cφcθ)·B (28) turns the estimate's float32 differences (~1e-6 m/s) into 2000 times as many newtons.
    assert np.max(np.abs(s["u1"] - d["u1"])) < 2e-4
    for c in ("roll", "pitch", "yaw", "p", "q", "r"):
        assert np.max(np.abs(s[c + "_true"] - d[c + "_true"])) < 1e-6, c
    assert np.max(np.hypot(s["x_true"] - d["x_true"], s["y_true"] - d["y_true"])) < 0.01  # lat/lon: 1e-7 deg
    assert np.max(np.abs(s["z_true"] - d["z_true"])) < 6e-4  # altitude: mm
    assert np.max(np.abs(s["vx_true"] - d["vx_true"])) < 6e-3  # cm/s
    # What the estimator took (the same sensor datagram, encoded and decoded in both: float32's) and its status.
    for c in SENSOR_COLUMNS:
        assert np.max(np.abs(s[c] - d[c])) < 1e-5 * max(1.0, np.max(np.abs(d[c]))), c
    assert np.array_equal(s["estimator_flags"], d["estimator_flags"]) and (d["estimator_flags"] == 63).all()


@pytest.mark.timeout(120)
def test_up_on_sensors_arms_once_aligned_takes_off_on_the_estimate_and_publishes_the_truth():
    """``quadsitl up --state sensors`` flown with pymavlink as a user would: armable only once the estimator has
    aligned, ESTIMATOR_STATUS valid, a takeoff to 3 m flown on the estimate (LOCAL_POSITION_NED), and the truth on
    quadsitl/v1/truth beside the estimate on quadsitl/v1/state, with what the estimator took on quadsitl/v1/sensors."""
    import queue

    import zenoh

    from quadsitl import telemetry
    from tests.mavclient import Client, M, quadsitl_up

    with quadsitl_up("--preset", "x500", "--state", "sensors", "--speed", "8") as v:
        c = Client(v.gcs_port)
        session = zenoh.open(telemetry.zenoh_config(connect=[v.zenoh]))
        truth: queue.Queue = queue.Queue()
        sensors: queue.Queue = queue.Queue()
        try:
            session.declare_subscriber("quadsitl/v1/truth", lambda s: truth.put(s.payload.to_bytes()))
            session.declare_subscriber("quadsitl/v1/sensors", lambda s: sensors.put(s.payload.to_bytes()))
            c.wait_armable(30)
            status = c.wait("ESTIMATOR_STATUS", timeout=20)
            assert status.flags & M.ESTIMATOR_ATTITUDE and status.flags & M.ESTIMATOR_POS_HORIZ_ABS
            assert status.pos_horiz_accuracy > 0.0  # an estimate, with its uncertainty
            assert status.time_usec >= 1_000_000  # aligned after 1 s at rest
            assert c.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == M.MAV_RESULT_ACCEPTED
            c.conn.mav.command_int_send(1, 1, 0, M.MAV_CMD_NAV_TAKEOFF, 0, 0, NAN, NAN, NAN, NAN, 0, 0, 491.0)
            c.wait("LOCAL_POSITION_NED", lambda p: abs(-p.z - 3.0) < 0.1, 40)
            records = telemetry.records("state", truth.get(timeout=10))  # the truth: laid out as the state
            assert records and all(len(r) == len(telemetry.FIELDS["state"]) for r in records)
            c.pump(1.0)
            newest = truth.get(timeout=10)
            while not truth.empty():
                newest = truth.get()
            latest = telemetry.records("state", newest)[-1]
            assert abs(-latest[4] - 3.0) < 0.15  # the truth is where the estimate says, within its error
            received = [sensors.get(timeout=10)]
            while not sensors.empty():
                received.append(sensors.get())
            hovering = [r for payload in received for r in telemetry.records(telemetry.SENSORS, payload)][-500:]
            accel_z = np.mean([r[telemetry.SENSORS_FIELDS.index("accel_z")] for r in hovering])  # noise averaged
            took = dict(zip(telemetry.SENSORS_FIELDS, hovering[-1], strict=True))
            assert abs(accel_z + 9.8) < 0.5 and abs(took["baro_alt"] - 491.0) < 1.0  # hovering at 3 m
            assert int(took["estimator_flags"]) & 63 == 63 and 0.0 < took["pos_horiz_accuracy"] < 2.0
            # The vehicle's own log of the flight so far (written as it goes), with PX4's sensor topics
            from pyulog import ULog

            (path,) = v.logs.rglob("*.ulg")
            data = {d.name: d.data for d in ULog(str(path)).data_list}
            imu, est = data["sensor_combined"], data["estimator_status"]
            steps = np.diff(imu["timestamp"].astype(np.int64))  # from arming, then each 5 ms of the flight's clock
            assert (steps[1:] == 5000).all() and 0 < steps[0] <= 5000 and len(steps) > 100
            assert np.all(est["solution_status_flags"] & 63 == 63)
            assert abs(np.median(imu["accelerometer_m_s2[2]"]) + 9.8) < 0.5
            assert {"vehicle_magnetometer", "vehicle_air_data"} <= set(data)
            assert v.proc.poll() is None
        finally:
            session.close()
            c.close()


def payloads(datagram: np.ndarray) -> list[tuple[int, bytes]]:
    """Each MAVLink 2 frame's (message id, payload)."""
    out, at = [], 0
    while at < len(datagram):
        n = int(datagram[at + 1])
        msg_id = int(datagram[at + 7]) | int(datagram[at + 8]) << 8 | int(datagram[at + 9]) << 16
        out.append((msg_id, datagram[at + 10 : at + 10 + n].tobytes()))
        at += 12 + n
    return out


def test_sim_s_datagram_is_the_plants_without_the_truth():
    """SENSORS_ONLY (quadsitl sim, which records the plant's state itself): the same HIL_SENSOR and HIL_GPS frames,
    byte for byte, as the plant process sends, without the HIL_STATE_QUATERNION; the autopilot decodes the same
    measurements from it, and no truth."""
    preset = dataclasses.replace(X500, sensors=SensorParams())
    plants = [Plant(preset), Plant(preset)]
    ios = [np.zeros(plant_tick.IO_SIZE, dtype=np.int64) for _ in plants]
    ios[0][plant_tick.SENSING], ios[1][plant_tick.SENSING] = plant_tick.SENSORS, plant_tick.SENSORS_ONLY
    txs = [np.zeros(hil.DATAGRAM_MAX, dtype=np.uint8) for _ in plants]
    home = frames.PX4_HOME
    gps = 0
    for k in range(300):
        decoded = []
        for plant, io, tx in zip(plants, ios, txs):
            plant_tick.encode_tick(tx, io, plant.x, plant.out, plant.air, plant.sensors.arrays, k, plant.period)
            z, truth = np.zeros(hil.Z_SIZE), np.zeros(codec.DECODED_SIZE)
            frame = np.zeros(codec.FRAME_MAX, dtype=np.uint8)
            decoded.append((hil.decode_sensors(tx, io[plant_tick.TX_LEN], home, z, truth, frame), z, truth))
            plant.step((5.0, 5.0, 5.0, 5.0))
        (full, z_full, truth_full), (only, z_only, truth_only) = decoded
        n = ios[1][plant_tick.TX_LEN]
        assert ios[0][plant_tick.TX_LEN] > n
        without_truth = [p for p in payloads(txs[0][: ios[0][plant_tick.TX_LEN]]) if p[0] != hil.TRUTH_ID]
        assert without_truth == payloads(txs[1][:n])  # the same frames (the battery's too), the sequence numbers aside
        assert full == only and np.array_equal(z_full, z_only)
        assert np.isfinite(truth_full[:12]).all() and np.isnan(truth_only).all()
        gps += bool(full[1] & hil.GPS_NEW)
    assert gps >= 2  # fixes were in it too
