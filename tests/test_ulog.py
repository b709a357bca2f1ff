"""flight.ulg (quadsitl.ulog, autopilot.flight_log): PX4's ULog, read back by PX4's own reader (pyulog, its
``ulog_info`` and ``ulog2csv``) and compared with the flight's telemetry.csv."""

from __future__ import annotations

import csv
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from pyulog import ULog

from autopilot.flight_log import INTERVAL_MS, SENSOR_TOPICS, definitions, record_columns, topics_of
from autopilot.onboard_log import OnboardLog, kept_ms
from autopilot.tick import Batch
from groundstation.telemetry_csv import read_csv
from quadsitl import earth, frames, ulog
from quadsitl.config import load_preset
from quadsitl.telemetry import SENSING, SENSORS, record_dtype
from tests.test_fly import quadsitl

pytestmark = pytest.mark.timeout(300)
BIN = Path(sys.executable).parent
F32 = 1e-6  # float32's relative resolution, with room


def topics(path: Path) -> dict[str, dict[str, np.ndarray]]:
    return {d.name: d.data for d in ULog(str(path)).data_list}


def rows_at(telemetry: dict[str, np.ndarray], stamps: np.ndarray) -> np.ndarray:
    """The telemetry rows whose t [µs] are ``stamps``."""
    index = np.searchsorted(np.round(telemetry["t"] * 1e6).astype(np.int64), stamps.astype(np.int64))
    assert np.array_equal(np.round(telemetry["t"][index] * 1e6), stamps)
    return index


def close(a: np.ndarray, b: np.ndarray) -> bool:
    return np.allclose(a, b, rtol=F32, atol=1e-6, equal_nan=True)


def assert_sensor_topics(data: dict[str, dict[str, np.ndarray]], t: dict[str, np.ndarray], period: float,
                         home_alt: float) -> None:  # fmt: skip
    """The sensor mode's topics are telemetry.csv's sensor columns at PX4's intervals, and say what a vehicle
    holding 2 m on its sensors measures."""
    for name in SENSOR_TOPICS:
        stamps = data[name]["timestamp"].astype(np.int64)
        assert len(stamps) == math.floor(t["t"][-1] / (INTERVAL_MS[name] / 1000.0)) + 1, name
        assert (np.diff(stamps) == INTERVAL_MS[name] * 1000).all(), name
    imu = data["sensor_combined"]
    i = rows_at(t, imu["timestamp"])
    for j, axis in enumerate("xyz"):
        assert close(imu[f"gyro_rad[{j}]"], t[f"gyro_{axis}"][i]), axis
        assert close(imu[f"accelerometer_m_s2[{j}]"], t[f"accel_{axis}"][i]), axis
    assert (imu["gyro_integral_dt"] == round(period * 1e6)).all()
    assert np.mean(imu["accelerometer_m_s2[2]"]) == pytest.approx(-9.8, abs=0.3)  # holding: −g along down
    mag = data["vehicle_magnetometer"]
    i = rows_at(t, mag["timestamp"])
    assert all(close(mag[f"magnetometer_ga[{j}]"], t[f"mag_{a}"][i]) for j, a in enumerate("xyz"))
    assert np.linalg.norm([mag[f"magnetometer_ga[{j}]"][-1] for j in range(3)]) == pytest.approx(0.48, abs=0.05)
    air = data["vehicle_air_data"]
    i = rows_at(t, air["timestamp"])
    assert close(air["baro_alt_meter"], t["baro_alt"][i])
    assert air["baro_alt_meter"][-1] == pytest.approx(home_alt + 2.0, abs=1.0)
    assert air["baro_pressure_pa"][-1] == pytest.approx(earth.isa_pressure(float(air["baro_alt_meter"][-1])), rel=1e-6)
    est = data["estimator_status"]
    i = rows_at(t, est["timestamp"])
    assert (est["solution_status_flags"] == t["estimator_flags"][i]).all()
    assert (est["solution_status_flags"] & 63 == 63).all()  # attitude, velocity, position: valid throughout
    for topic, column in (("vel_test_ratio", "vel_ratio"), ("pos_test_ratio", "pos_horiz_ratio"),
                          ("hgt_test_ratio", "pos_vert_ratio"), ("hdg_test_ratio", "mag_ratio"),
                          ("pos_horiz_accuracy", "pos_horiz_accuracy")):  # fmt: skip
        assert close(est[topic], t[column][i]), topic
    assert 0.0 < est["pos_horiz_accuracy"][-1] < 2.0 and 0.0 < est["pos_vert_accuracy"][-1] < 1.0


@pytest.fixture(scope="module")
def circle(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("circle")
    r = subprocess.run(quadsitl("sim", "--preset", "x500", "--trajectory", "circle", "--no-figures", "--out", str(out)),
                       capture_output=True, text=True)  # fmt: skip
    assert r.returncode == 0, r.stderr
    return out


def test_sim_writes_a_ulog_pyulog_reads_with_pxs_topics_as_the_telemetry_says(circle):
    data, t = topics(circle / "flight.ulg"), read_csv(circle / "telemetry.csv")
    assert {"vehicle_attitude", "vehicle_attitude_setpoint", "vehicle_angular_velocity", "vehicle_local_position",
            "vehicle_local_position_setpoint", "vehicle_global_position", "actuator_outputs",
            "vehicle_status"} <= set(data)  # fmt: skip
    duration = t["t"][-1]
    assert not set(SENSOR_TOPICS) & set(data)  # on the true state: no sensors
    for name, interval in INTERVAL_MS.items():  # PX4's default logging intervals
        if name in SENSOR_TOPICS:
            continue
        stamps = data[name]["timestamp"]
        assert len(stamps) == math.floor(duration / (interval / 1000.0)) + 1, name
        assert (np.diff(stamps.astype(np.int64)) == interval * 1000).all(), name
    lp = data["vehicle_local_position"]
    i = rows_at(t, lp["timestamp"])
    for k in ("x", "y", "z", "vx", "vy", "vz"):
        assert close(lp[k], t[k][i]), k
    assert close(lp["heading"], t["yaw"][i]) and (lp["ref_lat"] == frames.PX4_HOME[0]).all()
    att = data["vehicle_attitude"]
    i = rows_at(t, att["timestamp"])
    q = np.column_stack([att[f"q[{j}]"] for j in range(4)])
    euler = np.array([frames.quaternion_to_euler(*row) for row in q.astype(float)])
    assert np.allclose(euler, np.column_stack([t["roll"][i], t["pitch"][i], t["yaw"][i]]), atol=1e-5)
    sp = data["vehicle_local_position_setpoint"]
    i = rows_at(t, sp["timestamp"])
    assert close(sp["x"], t["x_ref"][i]) and close(sp["z"], -t["altitude_ref"][i])
    x500 = load_preset("x500")
    out = data["actuator_outputs"]
    i = rows_at(t, out["timestamp"])
    assert (out["noutputs"] == 4).all() and close(out["output[2]"], t["f3"][i] / x500.actuators.max_thrust)
    gp = data["vehicle_global_position"]
    i = rows_at(t, gp["timestamp"])
    k = len(i) - 1
    lat, lon = frames.ned_to_geodetic(t["x"][i[k]], t["y"][i[k]], frames.PX4_HOME[0], frames.PX4_HOME[1])
    assert gp["lat"][k] == pytest.approx(lat, abs=1e-12) and gp["lon"][k] == pytest.approx(lon, abs=1e-12)
    assert close(gp["alt"], frames.PX4_HOME[2] - t["z"][i])
    status = data["vehicle_status"]
    assert (status["arming_state"] == 2).all() and (status["nav_state"] == 14).all()  # armed, offboard


def test_the_parameters_and_information_are_the_autopilots(circle):
    log = ULog(str(circle / "flight.ulg"))
    x500 = load_preset("x500")
    assert log.initial_parameters["MPC_XY_VEL_MAX"] == pytest.approx(x500.position.xy_vel_max)
    assert log.initial_parameters["CTL_TYPE"] == 0 and isinstance(log.initial_parameters["CTL_TYPE"], int)
    assert log.msg_info_dict["sys_name"] == "quadsitl" and log.msg_info_dict["ver_hw"] == "SITL"
    assert log.msg_info_dict["quadsitl_preset"] == "x500"


def test_pyulogs_commands_read_it(circle, tmp_path):
    info = subprocess.run([str(BIN / "ulog_info"), str(circle / "flight.ulg")], capture_output=True, text=True)
    assert info.returncode == 0 and "vehicle_local_position" in info.stdout, info.stderr
    r = subprocess.run([str(BIN / "ulog2csv"), "-o", str(tmp_path), "-m", "vehicle_local_position",
                        str(circle / "flight.ulg")], capture_output=True, text=True)  # fmt: skip
    assert r.returncode == 0, r.stderr
    (path,) = tmp_path.glob("*vehicle_local_position_0.csv")
    with open(path) as f:
        rows = list(csv.DictReader(f))
    t = read_csv(circle / "telemetry.csv")
    last = rows[-1]
    i = rows_at(t, np.array([int(last["timestamp"])]))[0]
    assert float(last["x"]) == pytest.approx(t["x"][i], rel=F32, abs=1e-6)


def test_in_sensor_mode_the_estimate_is_flown_and_the_truth_logged_beside_it(tmp_path, sensor_sim):
    r = subprocess.run(quadsitl("sim", "--preset", "x500", "--state", "sensors", "--trajectory",
                                "hold:altitude=2,duration=3", "--no-figures", "--out", str(tmp_path)),
                       capture_output=True, text=True)  # fmt: skip
    assert r.returncode == 0, r.stderr
    data, t = topics(tmp_path / "flight.ulg"), read_csv(tmp_path / "telemetry.csv")
    for name, suffix in (("vehicle_local_position", ""), ("vehicle_local_position_groundtruth", "_true")):
        lp = data[name]
        i = rows_at(t, lp["timestamp"])
        assert close(lp["z"], t["z" + suffix][i]) and close(lp["vx"], t["vx" + suffix][i]), name
    assert not np.allclose(data["vehicle_local_position"]["x"], data["vehicle_local_position_groundtruth"]["x"])
    x500 = load_preset("x500")
    assert_sensor_topics(data, t, x500.sim.period, frames.PX4_HOME[2])


def test_the_writer_interleaves_topics_in_time_and_logs_strings(tmp_path):
    a = ulog.Topic("a", ["uint64_t timestamp", "float v", "int32_t[2] n"],
                   {"timestamp": np.array([0, 20, 40]), "v": np.array([1.0, 2.0, 3.0]),
                    "n": np.array([[1, 2], [3, 4], [5, 6]])})  # fmt: skip
    b = ulog.Topic("b", ["uint64_t timestamp", "double w"],
                   {"timestamp": np.array([10, 30]), "w": np.array([0.5, 1.5])})  # fmt: skip
    path = tmp_path / "x.ulg"
    ulog.write(path, ulog.Log({"char sys_name": "test"}, {"P1": 2.5, "P2": 3}, [a, b],
                              [(25, "warning", "a warning"), (5, "info", "hello")]))  # fmt: skip
    log = ULog(str(path))
    data = {d.name: d.data for d in log.data_list}
    assert list(data["a"]["n[1]"]) == [2, 4, 6] and list(data["b"]["w"]) == [0.5, 1.5]
    assert [(m.timestamp, m.log_level_str(), m.message) for m in log.logged_messages] == [
        (5, "INFO", "hello"), (25, "WARNING", "a warning")]  # fmt: skip
    assert log.initial_parameters == {"P1": 2.5, "P2": 3}
    raw = path.read_bytes()
    order = [raw.index(s) for s in (b"hello", b"a warning")]
    assert order == sorted(order)  # the data section in time order: 0 a, 5 hello, 10 b, 20 a, 25 warning, ...
    with pytest.raises(ValueError, match="first field must be 'uint64_t timestamp'"):
        ulog.encode(ulog.Log(topics=[ulog.Topic("c", ["float v"], {"v": np.zeros(1)})]))
    with pytest.raises(ValueError, match="type 'float32' is not one of"):
        ulog.encode(ulog.Log(topics=[ulog.Topic("c", ["uint64_t timestamp", "float32 v"],
                                                 {"timestamp": np.zeros(1), "v": np.zeros(1)})]))  # fmt: skip


def test_fly_writes_the_same_log_from_its_telemetry_on_sensors(tmp_path):
    """`quadsitl fly` (plant, autopilot and ground station processes) writes flight.ulg from its telemetry.csv by
    the same mapping as sim: the estimate flown and the truth, at PX4's intervals."""
    r = subprocess.run(quadsitl("fly", "--preset", "x500", "--state", "sensors", "--trajectory",
                                "hold:altitude=2,duration=3", "--no-figures", "--quiet", "--out", str(tmp_path)),
                       capture_output=True, text=True, timeout=240)  # fmt: skip
    assert r.returncode == 0, r.stderr
    data, t = topics(tmp_path / "flight.ulg"), read_csv(tmp_path / "telemetry.csv")
    for name, suffix in (("vehicle_local_position", ""), ("vehicle_local_position_groundtruth", "_true")):
        lp = data[name]
        i = rows_at(t, lp["timestamp"])
        assert len(i) == math.floor(t["t"][-1] / 0.1) + 1
        assert close(lp["x"], t["x" + suffix][i]) and close(lp["z"], t["z" + suffix][i]), name
    assert (data["vehicle_status"]["nav_state"] == 14).all()
    assert ULog(str(tmp_path / "flight.ulg")).msg_info_dict["quadsitl_controller"] == "backstepping"
    assert_sensor_topics(data, t, load_preset("x500").sim.period, frames.PX4_HOME[2])


def test_a_written_log_in_one_append_is_the_encoded_log(tmp_path):
    a = ulog.Topic("a", ["uint64_t timestamp", "float v"], {"timestamp": np.array([0, 20]), "v": np.array([1.0, 2.0])})
    log = ulog.Log({"char sys_name": "test"}, {"P1": 2.5}, [a], [(5, "info", "hello")], start_us=7)
    w = ulog.Writer(tmp_path / "w.ulg", log)
    w.close()
    assert (tmp_path / "w.ulg").read_bytes() == ulog.encode(log)


def fill(batch: Batch, records: dict[str, np.ndarray]) -> int:
    """The records ({stream: structured rows}) into ``batch``'s regions → their count."""
    for stream, rows in records.items():
        at, _ = batch.regions[stream]
        batch.records[at : at + rows.nbytes] = rows.view(np.uint8)
    return len(next(iter(records.values())))


def test_the_autopilots_log_written_batch_by_batch_is_the_flight_logged_whole(tmp_path):
    """OnboardLog keeps the first row of each 5 ms of each batch (sensor mode's sensor_combined; 10 ms on the true
    state, the other topics' intervals' divisor) and writes them every second: what it writes is
    what flight_log makes of the whole flight's rows at once, from arming to disarming (sensor mode: the truth and
    the sensors too); the status texts said in flight are logged, those said on the ground are not."""
    rng = np.random.default_rng(3)
    n, armed_from, armed_to = 5000, 700, 4300
    streams = ("state", "setpoint", "actuators", *SENSING)
    records = {s: np.zeros(n, dtype=record_dtype(s)) for s in (*streams, "status")}
    t = 0.25 + np.arange(n) * 0.001
    for rows in records.values():
        rows["tick"], rows["t"] = np.arange(n), t
        for name in rows.dtype.names[2:]:
            if rows.dtype[name].kind == "f":
                rows[name] = rng.normal(size=n)
    records["status"]["armed"][armed_from:armed_to] = 1
    records["status"]["mode"] = 1
    records[SENSORS]["estimator_flags"] = rng.integers(0, 2048, size=n)
    preset = load_preset("x500")
    log = OnboardLog(tmp_path, lambda: definitions(preset, "backstepping", True), preset.actuators.max_thrust,
                     frames.PX4_HOME, streams, preset.sim.period)  # fmt: skip
    batch = Batch(2048)
    at = 0
    for size in rng.integers(1, 2048, size=50):  # batches of every size, as the wall clock cuts them
        size = min(int(size), n - at)
        if size == 0:
            break
        if at <= 2000 < at + size:
            log.say(float(t[2000]), 4, "in flight")
        if at <= 4500 < at + size:
            log.say(float(t[4500]), 6, "on the ground")
        at += log.add(batch, fill(batch, {s: r[at : at + size] for s, r in records.items()})) or size
    log.close()
    (path,) = tmp_path.glob("*/*.ulg")
    whole = definitions(preset, "backstepping", True)
    columns = record_columns({s: r[armed_from:armed_to] for s, r in records.items()})
    whole.topics = topics_of(columns, preset.actuators.max_thrust, frames.PX4_HOME, period=preset.sim.period)
    ulog.write(tmp_path / "whole.ulg", whole)
    written, expected = topics(path), topics(tmp_path / "whole.ulg")
    assert set(written) == set(expected) and {"vehicle_attitude_groundtruth", *SENSOR_TOPICS} <= set(written)
    for name, data in expected.items():
        for field, values in data.items():
            assert np.array_equal(written[name][field], values, equal_nan=True), (name, field)
    assert [m.message for m in ULog(str(path)).logged_messages] == ["in flight"]
    assert (log.kept_ms, kept_ms(False)) == (5, 10)
