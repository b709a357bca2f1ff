"""An x500 flight on the true state (the backstepping controller, no position loop), with the plant's sensors
sampled every tick: the truth and the sensor records, for the estimator's open-loop tests.

Schedule: 3 s on the ground, motors off (the estimator aligns in its first second); from 3 s, climb to and hover at
2 m; from 9 s, roll and pitch 10° and yaw 30° (the x500 preset's steps; the vehicle accelerates to about 7 m/s);
from 13 s, level, heading north, 3 m.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from autopilot.estimator import (
    BARO_NEW,
    GPS_NEW,
    IMU_GAPS,
    IMU_NEW,
    MAG_NEW,
    Z_ACCEL,
    Z_BARO,
    Z_GPS_POS,
    Z_GPS_TIME,
    Z_GYRO,
    Z_MAG,
    Z_SIZE,
    Estimator,
    EstimatorParams,
)
from autopilot.factory import make_controller
from quadsitl.codec import usec_of
from quadsitl.config import SensorParams, load_preset
from quadsitl.mixer import allocate
from quadsitl.state import Reference
from sitl.plant import OUT_MEAN_ACCEL, Plant
from sitl.sensors import (
    BARO_UPDATED,
    MAG_UPDATED,
    OUT_ACCEL,
    OUT_GPS_POS,
    OUT_GPS_TIME,
    OUT_GYRO,
    OUT_MAG,
    OUT_PRESSURE_ALT,
    Sensors,
)

GROUND = 3.0  # [s]


def reference(t: float) -> Reference:
    if t < 9.0:
        return Reference(2.0, 0.0, 0.0, 0.0)
    if t < 13.0:
        return Reference(2.0, math.radians(10), math.radians(10), math.radians(30))
    return Reference(3.0, 0.0, 0.0, 0.0)


@dataclass
class Flight:
    period: float
    gravity: float
    sensors: SensorParams
    truth: np.ndarray  # (n, 12) VehicleState
    z: np.ndarray  # (n, Z_SIZE) the estimator's measurements
    flags: np.ndarray  # (n,) IMU_NEW | MAG_NEW | BARO_NEW | GPS_NEW
    gyro_bias: np.ndarray  # (n, 3) the true gyro bias [rad/s]


def fly(sensor_params: SensorParams, duration: float = 18.0) -> Flight:
    preset = load_preset("x500")
    T, g = preset.sim.period, preset.vehicle.gravity
    plant = Plant(preset)
    controller = make_controller(preset, position_loop=False)
    act, d_over_b = preset.actuators, preset.vehicle.d_over_b
    sensors = Sensors(sensor_params, T, g)
    out = sensors.out
    n = round(duration / T)
    truth, z, flags, bias = np.empty((n, 12)), np.zeros((n, Z_SIZE)), np.zeros(n, dtype=np.int64), np.empty((n, 3))
    for k in range(n):
        x = tuple(plant.x)
        fields = sensors.tick(usec_of(k, T), x, tuple(plant.out[OUT_MEAN_ACCEL : OUT_MEAN_ACCEL + 3]))
        truth[k], bias[k] = x, sensors.bias[0:3]
        z[k, Z_GYRO : Z_GYRO + 3] = out[OUT_GYRO : OUT_GYRO + 3]
        z[k, Z_ACCEL : Z_ACCEL + 3] = out[OUT_ACCEL : OUT_ACCEL + 3]
        z[k, Z_MAG : Z_MAG + 3] = out[OUT_MAG : OUT_MAG + 3]
        z[k, Z_BARO] = out[OUT_PRESSURE_ALT]
        z[k, Z_GPS_POS : Z_GPS_POS + 6] = out[OUT_GPS_POS : OUT_GPS_POS + 6]
        z[k, Z_GPS_TIME] = out[OUT_GPS_TIME]  # when the fix was measured [µs], as HIL_GPS stamps it
        flags[k] = (IMU_NEW | (MAG_NEW if fields & MAG_UPDATED else 0) | (BARO_NEW if fields & BARO_UPDATED else 0)
                    | (GPS_NEW if sensors.gps_new else 0))  # fmt: skip
        t = k * T
        if t < GROUND:
            forces = (0.0, 0.0, 0.0, 0.0)
        else:
            forces = allocate(controller.step(plant.state, reference(t)), d_over_b, act.min_thrust, act.max_thrust)
        plant.step(forces)
    return Flight(T, g, sensor_params, truth, z, flags, bias)


@dataclass
class Estimate:
    state: np.ndarray  # (n, 12)
    aligned: np.ndarray  # (n,) bool
    diverged: np.ndarray  # (n,) bool
    gyro_bias: np.ndarray  # (n, 3)
    lost: np.ndarray  # (n,) the sensors lost (estimator.LOST_*)
    imu_gaps: int  # IMU intervals lost (the estimator's count)


def estimate(f: Flight, params: EstimatorParams | None = None, skip: np.ndarray | None = None,
             stamped: bool = True) -> Estimate:  # fmt: skip
    """The estimator run open-loop on the flight's sensor records, as the autopilot makes it for these sensors
    (``params`` None: its defaults, the sensors' GPS delay), each tick stamped with its time; ``skip``: ticks whose
    datagram is lost (the estimate stays the last one); ``stamped`` False: each fix stamped when it is delivered."""
    s = f.sensors
    est = Estimator.for_sensors(s, f.period, f.gravity)
    if params is not None:
        est = Estimator.for_field(f.period, f.gravity, s.mag_strength_gauss, s.mag_declination_deg,
                                  s.mag_inclination_deg, params=params)  # fmt: skip
    n = len(f.truth)
    state, aligned, diverged, bias = np.empty((n, 12)), np.zeros(n, bool), np.zeros(n, bool), np.empty((n, 3))
    lost = np.zeros(n, dtype=np.int64)
    for k in range(n):
        if skip is None or not skip[k]:
            est.z[:] = f.z[k]
            if not stamped:
                est.z[Z_GPS_TIME] = usec_of(k, f.period)
            est.tick(int(f.flags[k]), usec_of(k, f.period))
        state[k], aligned[k], diverged[k], bias[k] = est.out, est.aligned, est.diverged, est.gyro_bias
        lost[k] = est.lost
    return Estimate(state, aligned, diverged, bias, lost, int(est.io[IMU_GAPS]))


def attitude_error(truth: np.ndarray, state: np.ndarray) -> np.ndarray:
    """(n,) the angle [rad] of the rotation between the true and the estimated attitude."""
    from quadsitl.frames import euler_to_quaternion

    angles = np.empty(len(truth))
    for k in range(len(truth)):
        a = euler_to_quaternion(*truth[k, 6:9])
        b = euler_to_quaternion(*state[k, 6:9])
        dot = abs(sum(a[i] * b[i] for i in range(4)))
        angles[k] = 2.0 * math.acos(min(1.0, dot))
    return angles


def wrapped(err: np.ndarray) -> np.ndarray:
    return (err + math.pi) % (2 * math.pi) - math.pi
