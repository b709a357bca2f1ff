"""flight.ulg (quadsitl.ulog, groundstation.flight_log): PX4's ULog, read back by PX4's own reader (pyulog, its
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

from groundstation.flight_log import INTERVAL_MS
from groundstation.telemetry_csv import read_csv
from quadsitl import frames, ulog
from quadsitl.config import load_preset
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
    for name, interval in INTERVAL_MS.items():  # PX4's default logging intervals
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


def test_in_sensor_mode_the_estimate_is_flown_and_the_truth_logged_beside_it(tmp_path):
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
