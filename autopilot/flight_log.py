"""A flight's ULog (``flight.ulg``): its telemetry as PX4's uORB topics, with PX4's topic and field names, so that
pyulog, PlotJuggler and Flight Review read a quadsitl flight as they read PX4's (docs/telemetry.md#ulog).

One function for every runtime: the telemetry's columns (:data:`groundstation.telemetry_csv.COLUMNS`, the truth's
after them in sensor mode: ``quadsitl sim``'s :func:`groundstation.offline.telemetry_columns`, or ``fly``'s
``telemetry.csv`` read back) → :class:`quadsitl.ulog.Log`. Each topic is sampled at PX4's default logging interval
(``src/modules/logger/logged_topics.cpp``: the first row of each interval), its timestamp the row's t [µs].

| topic | from the telemetry (what the autopilot flew on: the estimate in sensor mode) |
|---|---|
| ``vehicle_attitude`` (50 ms) | q from roll, pitch, yaw (FRD → NED) |
| ``vehicle_attitude_setpoint`` (50 ms) | q_d from roll_ref, pitch_ref, yaw_ref; thrust_body z = −u1 / (4 F_max) |
| ``vehicle_angular_velocity`` (20 ms) | xyz = p, q, r [rad/s, FRD] |
| ``vehicle_local_position`` (100 ms) | x, y, z, vx, vy, vz [m, m/s, NED], heading = yaw, the origin |
| ``vehicle_local_position_setpoint`` (100 ms) | x_ref, y_ref (NaN while not controlled), z = −altitude_ref, yaw |
| ``vehicle_global_position`` (200 ms) | lat, lon (PX4's projection from the origin), alt AMSL |
| ``actuator_outputs`` (100 ms) | noutputs 4, output[0..3] = f1..f4 / F_max (each motor's command, 0..1) |
| ``vehicle_status`` (1 s) | arming_state 2 (armed), nav_state (offboard 14 or mission 3) |
| ``battery_status`` (200 ms) | a vehicle with a battery: voltage_v, current_a, discharged_mah, remaining |
| ``vehicle_local_position_groundtruth``, ``vehicle_attitude_groundtruth`` | sensor mode: the truth (as PX4 SITL) |
| ``sensor_combined`` (5 ms) | sensor mode: gyro_rad, accelerometer_m_s2 (the samples the estimator took, FRD) |
| ``vehicle_magnetometer`` (200 ms) | sensor mode: magnetometer_ga [gauss, FRD] |
| ``vehicle_air_data`` (200 ms) | sensor mode: baro_alt_meter, and pressure, temperature, density of the ISA there |
| ``estimator_status`` (200 ms) | sensor mode: solution_status_flags, the test ratios, the position accuracies |

The parameters are the autopilot's (:func:`autopilot.params.values_from`); the information names the system
(``sys_name``, ``ver_hw``: SITL, ``ver_sw``), the preset and the controller."""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np

from autopilot.commander import CommanderSettings
from autopilot.params import CONTROLLER_TYPES, SPECS, commander_settings, values_from
from quadsitl import __version__, earth, ulog
from quadsitl.config import Preset
from quadsitl.frames import PX4_HOME, euler_to_quaternion, ned_to_geodetic
from quadsitl.telemetry import SENSING, TRUTH, record_dtype

# PX4's default logging intervals [ms] (logged_topics.cpp, add_default_topics)
INTERVAL_MS = {"vehicle_attitude": 50, "vehicle_attitude_setpoint": 50, "vehicle_angular_velocity": 20,
               "vehicle_local_position": 100, "vehicle_local_position_setpoint": 100, "vehicle_global_position": 200,
               "actuator_outputs": 100, "vehicle_status": 1000, "battery_status": 200, "vehicle_magnetometer": 200,
               "vehicle_air_data": 200, "estimator_status": 200,
               # logged as published (interval 0), at IMU_INTEG_RATE: 200 Hz
               "sensor_combined": 5}  # fmt: skip
SENSOR_TOPICS = ("sensor_combined", "vehicle_magnetometer", "vehicle_air_data", "estimator_status")  # sensor mode's
NAV_OFFBOARD, NAV_MISSION = 14, 3  # vehicle_status.nav_state
# vehicle_status.nav_state of each of the autopilot's modes (quadsitl.telemetry.MODES): hold AUTO_LOITER, offboard,
# land AUTO_LAND, takeoff AUTO_TAKEOFF, rtl AUTO_RTL, mission AUTO_MISSION, posctl POSCTL, altctl ALTCTL,
# stabilized STAB, orbit ORBIT, follow AUTO_FOLLOW_TARGET
NAV_STATE = {0: 4, 1: NAV_OFFBOARD, 2: 18, 3: 17, 4: 5, 5: NAV_MISSION, 6: 2, 7: 1, 8: 15, 9: 21, 10: 19}
STANDBY, ARMED = 1, 2  # vehicle_status.arming_state


def _slot(t: np.ndarray, interval_ms: int) -> np.ndarray:
    return np.floor(np.round(np.asarray(t) * 1e6) / (interval_ms * 1000.0)).astype(np.int64)


def sampled(t: np.ndarray, interval_ms: int, before: float | None = None) -> np.ndarray:
    """The rows logged at ``interval_ms``: the first of each interval of the flight's time ``t`` [s]; ``before``:
    the time of the row before ``t[0]`` (a flight logged in parts), None: ``t`` starts the flight."""
    if len(t) == 0:
        return np.zeros(0, dtype=np.int64)
    slot = _slot(t, interval_ms)
    first = before is None or slot[0] != _slot(before, interval_ms)
    return np.flatnonzero(np.concatenate([[first], slot[1:] != slot[:-1]]))


def quaternions(roll: np.ndarray, pitch: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """(N, 4) unit quaternions [w, x, y, z] of ZYX Euler angles (FRD → NED): :func:`quadsitl.frames.euler_to_quaternion`
    of each row."""
    return np.array([euler_to_quaternion(*angles) for angles in zip(roll.tolist(), pitch.tolist(), yaw.tolist())]
                    ).reshape(-1, 4)  # fmt: skip


def _topic(name: str, fields: list[str], t: np.ndarray, rows: np.ndarray, values: dict[str, np.ndarray],
           sampled_at: bool = False) -> ulog.Topic:  # fmt: skip
    """Topic ``name`` with the rows ``rows`` of the flight's time ``t`` [s] as its timestamps [µs] (and, with
    ``sampled_at``, as its ``timestamp_sample`` too: the row's measurement is the row's)."""
    stamp = np.round(t[rows] * 1e6).astype(np.uint64)
    if sampled_at:
        fields, values = ["uint64_t timestamp_sample", *fields], {"timestamp_sample": stamp, **values}
    return ulog.Topic(name, ["uint64_t timestamp", *fields], {"timestamp": stamp, **values})


def _attitude(name: str, t: np.ndarray, c: Mapping[str, np.ndarray], before: float | None) -> ulog.Topic:
    rows = sampled(t, INTERVAL_MS["vehicle_attitude"], before)
    q = quaternions(c["roll"][rows], c["pitch"][rows], c["yaw"][rows])
    return _topic(name, ["float[4] q"], t, rows, {"q": q}, sampled_at=True)


def _local_position(name: str, t: np.ndarray, c: Mapping[str, np.ndarray], home: tuple,
                    before: float | None) -> ulog.Topic:  # fmt: skip
    rows = sampled(t, INTERVAL_MS["vehicle_local_position"], before)
    n = len(rows)
    ones = np.ones(n)
    values = {"xy_valid": ones, "z_valid": ones,
              "v_xy_valid": ones, "v_z_valid": ones, "heading": c["yaw"][rows], "xy_global": ones,
              "z_global": ones, "ref_lat": np.full(n, home[0]), "ref_lon": np.full(n, home[1]),
              "ref_alt": np.full(n, home[2])}  # fmt: skip
    for k in ("x", "y", "z", "vx", "vy", "vz"):
        values[k] = c[k][rows]
    fields = ["bool xy_valid", "bool z_valid", "bool v_xy_valid", "bool v_z_valid",
              "float x", "float y", "float z", "float vx", "float vy", "float vz", "float heading", "bool xy_global",
              "bool z_global", "double ref_lat", "double ref_lon", "float ref_alt"]  # fmt: skip
    return _topic(name, fields, t, rows, values, sampled_at=True)


def logged_streams(sensing: bool) -> tuple[str, ...]:
    """The telemetry records a flight log is made of (:mod:`quadsitl.telemetry`'s streams): the truth's and the
    sensors' too in sensor mode."""
    return ("state", "setpoint", "actuators", *(SENSING if sensing else ()))


def record_columns(records: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Telemetry columns ({column: values}, as :func:`topics_of` takes them) of the autopilot's telemetry records
    ({stream: structured array}, :mod:`quadsitl.telemetry`'s streams, each the same ticks): each field by its name,
    the truth's with ``_true`` (the sensors' are telemetry.csv's columns by their own names)."""
    columns: dict[str, np.ndarray] = {}
    for stream, rows in records.items():
        suffix = "_true" if stream == TRUTH else ""
        for name in rows.dtype.names:
            columns.setdefault(name if name in ("tick", "t") else name + suffix, rows[name])
    return columns


def topics_of(columns: Mapping[str, np.ndarray], f_max: float, home: tuple = PX4_HOME, mission: bool = False,
              before: float | None = None, *, period: float) -> list[ulog.Topic]:  # fmt: skip
    """The topics of a flight's telemetry ``columns`` ({column: values}, telemetry.csv's; with ``armed`` and ``mode``
    (the status record's) when the autopilot logs them) flown from ``home`` (lat, lon [deg], alt [m AMSL]) with
    motors of ``f_max`` [N] each, at the control period ``period`` [s] (one IMU sample each); ``mission``: without a
    ``mode`` column, a mission's flight (nav_state AUTO_MISSION, else OFFBOARD); ``before``: the time [s] of the row
    logged before these (a flight logged in parts)."""
    c = columns
    t = np.asarray(c["t"], dtype=np.float64)
    topics = [_attitude("vehicle_attitude", t, c, before)]
    rows = sampled(t, INTERVAL_MS["vehicle_attitude_setpoint"], before)
    thrust = np.zeros((len(rows), 3))
    thrust[:, 2] = -c["u1"][rows] / (4.0 * f_max)
    topics.append(_topic("vehicle_attitude_setpoint", ["float[4] q_d", "float[3] thrust_body"], t, rows,
                         {"q_d": quaternions(c["roll_ref"][rows], c["pitch_ref"][rows], c["yaw_ref"][rows]),
                          "thrust_body": thrust}))  # fmt: skip
    rows = sampled(t, INTERVAL_MS["vehicle_angular_velocity"], before)
    xyz = np.column_stack([c["p"][rows], c["q"][rows], c["r"][rows]]).reshape(-1, 3)
    topics.append(_topic("vehicle_angular_velocity", ["float[3] xyz"], t, rows, {"xyz": xyz}, sampled_at=True))
    topics.append(_local_position("vehicle_local_position", t, c, home, before))
    rows = sampled(t, INTERVAL_MS["vehicle_local_position_setpoint"], before)
    n = len(rows)
    nan = np.full(n, math.nan)
    topics.append(_topic("vehicle_local_position_setpoint",
                         ["float x", "float y", "float z", "float vx", "float vy", "float vz", "float yaw"], t, rows,
                         {"x": c["x_ref"][rows], "y": c["y_ref"][rows], "z": -c["altitude_ref"][rows], "vx": nan,
                          "vy": nan, "vz": nan, "yaw": c["yaw_ref"][rows]}))  # fmt: skip
    rows = sampled(t, INTERVAL_MS["vehicle_global_position"], before)
    lat_lon = np.array([ned_to_geodetic(float(x), float(y), home[0], home[1])
                        for x, y in zip(c["x"][rows], c["y"][rows])]).reshape(-1, 2)  # fmt: skip
    ones = np.ones(len(rows))
    topics.append(_topic("vehicle_global_position",
                         ["double lat", "double lon", "float alt", "bool lat_lon_valid", "bool alt_valid"], t, rows,
                         {"lat": lat_lon[:, 0], "lon": lat_lon[:, 1], "alt": home[2] - c["z"][rows],
                          "lat_lon_valid": ones, "alt_valid": ones}, sampled_at=True))  # fmt: skip
    rows = sampled(t, INTERVAL_MS["actuator_outputs"], before)
    output = np.zeros((len(rows), 16))
    for i in range(4):
        output[:, i] = c[f"f{i + 1}"][rows] / f_max
    topics.append(_topic("actuator_outputs", ["uint32_t noutputs", "float[16] output"], t, rows,
                         {"noutputs": np.full(len(rows), 4), "output": output}))  # fmt: skip
    rows = sampled(t, INTERVAL_MS["vehicle_status"], before)
    n = len(rows)
    if "mode" in c:  # the autopilot's own log: its arming state and modes as they were
        arming = np.where(c["armed"][rows] > 0, ARMED, STANDBY)
        nav = np.array([NAV_STATE[int(m)] for m in c["mode"][rows]], dtype=np.uint8)
    else:  # telemetry.csv: the flight's rows are the armed ones
        arming, nav = np.full(n, ARMED), np.full(n, NAV_MISSION if mission else NAV_OFFBOARD)
    topics.append(_topic("vehicle_status", ["uint64_t armed_time", "uint8_t arming_state", "uint8_t nav_state"], t,
                         rows, {"armed_time": np.zeros(n, dtype=np.uint64), "arming_state": arming,
                                "nav_state": nav}))  # fmt: skip
    if "battery_remaining" in c and np.isfinite(c["battery_remaining"]).all():  # a battery reports (status records)
        rows = sampled(t, INTERVAL_MS["battery_status"], before)
        values = {
            k: c[f"battery_{f}"][rows]
            for k, f in (("voltage_v", "v"), ("current_a", "a"), ("discharged_mah", "mah"), ("remaining", "remaining"))
        }
        topics.append(_topic("battery_status", ["bool connected", *(f"float {k}" for k in values)], t, rows,
                             {"connected": np.ones(len(rows)), **values}))  # fmt: skip
    if "z_true" in c:  # sensor mode: the truth, as PX4 SITL logs its ground truth
        truth = {k[: -len("_true")]: v for k, v in c.items() if k.endswith("_true")}
        topics.append(_attitude("vehicle_attitude_groundtruth", t, truth, before))
        topics.append(_local_position("vehicle_local_position_groundtruth", t, truth, home, before))
    if "accel_x" in c:  # sensor mode: what the estimator took, and its status
        topics += _sensor_topics(t, c, before, period)
    return topics


def _sensor_topics(t: np.ndarray, c: Mapping[str, np.ndarray], before: float | None,
                   period: float) -> list[ulog.Topic]:  # fmt: skip
    """sensor_combined, vehicle_magnetometer, vehicle_air_data and estimator_status of the sensors' columns."""

    def xyz(name: str, rows: np.ndarray) -> np.ndarray:
        return np.column_stack([c[f"{name}_{a}"][rows] for a in "xyz"]).reshape(-1, 3)

    rows = sampled(t, INTERVAL_MS["sensor_combined"], before)
    n, dt = len(rows), np.uint32(round(period * 1e6))  # one sample of one control period
    zero = np.zeros(n, dtype=np.uint8)
    topics = [_topic("sensor_combined", ["float[3] gyro_rad", "uint32_t gyro_integral_dt",
                                         "int32_t accelerometer_timestamp_relative", "float[3] accelerometer_m_s2",
                                         "uint32_t accelerometer_integral_dt", "uint8_t accelerometer_clipping",
                                         "uint8_t gyro_clipping"], t, rows,
                     {"gyro_rad": xyz("gyro", rows), "gyro_integral_dt": np.full(n, dt),
                      "accelerometer_timestamp_relative": np.zeros(n, dtype=np.int32),
                      "accelerometer_m_s2": xyz("accel", rows), "accelerometer_integral_dt": np.full(n, dt),
                      "accelerometer_clipping": zero, "gyro_clipping": zero})]  # fmt: skip
    rows = sampled(t, INTERVAL_MS["vehicle_magnetometer"], before)
    topics.append(_topic("vehicle_magnetometer", ["float[3] magnetometer_ga"], t, rows,
                         {"magnetometer_ga": xyz("mag", rows)}, sampled_at=True))  # fmt: skip
    rows = sampled(t, INTERVAL_MS["vehicle_air_data"], before)
    alt = c["baro_alt"][rows]
    isa = np.array([(earth.isa_pressure(h), earth.isa_temperature(h) - earth.ZERO_CELSIUS, earth.isa_density(h))
                    for h in alt.tolist()]).reshape(-1, 3)  # fmt: skip
    topics.append(_topic("vehicle_air_data", ["float baro_alt_meter", "float baro_temp_celcius",
                                              "float baro_pressure_pa", "float rho"], t, rows,
                         {"baro_alt_meter": alt, "baro_temp_celcius": isa[:, 1], "baro_pressure_pa": isa[:, 0],
                          "rho": isa[:, 2]}, sampled_at=True))  # fmt: skip
    rows = sampled(t, INTERVAL_MS["estimator_status"], before)
    # PX4's MAVLink ESTIMATOR_STATUS is made of these: flags ← solution_status_flags, mag_ratio ← hdg_test_ratio,
    # vel_ratio ← vel_test_ratio, pos_horiz_ratio ← pos_test_ratio, pos_vert_ratio ← hgt_test_ratio
    topics.append(_topic("estimator_status", ["float pos_horiz_accuracy", "float pos_vert_accuracy",
                                              "float hdg_test_ratio", "float vel_test_ratio", "float pos_test_ratio",
                                              "float hgt_test_ratio", "uint16_t solution_status_flags"], t, rows,
                         {"pos_horiz_accuracy": c["pos_horiz_accuracy"][rows],
                          "pos_vert_accuracy": c["pos_vert_accuracy"][rows], "hdg_test_ratio": c["mag_ratio"][rows],
                          "vel_test_ratio": c["vel_ratio"][rows], "pos_test_ratio": c["pos_horiz_ratio"][rows],
                          "hgt_test_ratio": c["pos_vert_ratio"][rows],
                          "solution_status_flags": c["estimator_flags"][rows].astype(np.uint16)},
                         sampled_at=True))  # fmt: skip
    return topics


def definitions(preset: Preset, controller: str, sensing: bool, home: tuple = PX4_HOME,
                parameters: Mapping[str, float] | None = None) -> ulog.Log:  # fmt: skip
    """A flight log's definitions, no samples: its topics (those of :func:`topics_of`: the truth's with
    ``sensing``), the parameters (``parameters``: the autopilot's as they are; None: its defaults for ``controller``
    on ``preset``) and the system's information."""
    streams = (*logged_streams(sensing), *(("status",) if preset.battery is not None else ()))  # the battery's too
    empty = {stream: np.zeros(0, dtype=record_dtype(stream)) for stream in streams}
    topics = topics_of(record_columns(empty), preset.actuators.max_thrust, home, period=preset.sim.period)
    if parameters is None:
        s = commander_settings(preset.position, CommanderSettings())
        built_in = controller in CONTROLLER_TYPES
        parameters = values_from(preset, controller if built_in else CONTROLLER_TYPES[0], s)
        if not built_in:
            parameters["CTL_TYPE"] = 2.0  # a controller that plugs in (autopilot.plugin)
    integer = {spec.name for spec in SPECS if spec.integer}
    info = {"char sys_name": "quadsitl", "char ver_hw": "SITL", "char ver_sw": __version__,
            "char sys_os_name": "Linux", "char sys_toolchain": "numba", "char quadsitl_preset": preset.name,
            "char quadsitl_controller": controller}  # fmt: skip
    values = {k: round(v) if k in integer else float(v) for k, v in parameters.items()}
    return ulog.Log(info=info, parameters=values, topics=topics)


def log_of(columns: Mapping[str, np.ndarray], preset: Preset, controller: str, home: tuple = PX4_HOME,
           mission: bool = False) -> ulog.Log:  # fmt: skip
    """The ULog of a whole flight's telemetry ``columns`` ({column: values}, telemetry.csv's), flown from ``home``
    (lat, lon [deg], alt [m AMSL]) by ``controller`` on ``preset``; ``mission``: a mission's flight."""
    log = definitions(preset, controller, "z_true" in columns, home)
    log.topics = topics_of(columns, preset.actuators.max_thrust, home, mission, period=preset.sim.period)
    return log
