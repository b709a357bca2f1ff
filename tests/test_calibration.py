"""The calibrations (autopilot.calibration) as PX4's commander runs them, fed samples; the estimator applying what they
save (autopilot.estimator.calibrated); a gyro calibration closed on the plant's sensors (ADIS16448: turn-on biases),
whose offsets are the plant's own gyro bias; and the parameters, which truth mode keeps at 0."""

from __future__ import annotations

import dataclasses
import math
import random

import numpy as np
import pytest

from autopilot import calibration as cal
from autopilot.calibration import ACCEL, GYRO, LEVEL, MAG, Calibration, CalibrationParams, Sample
from autopilot.commander import CommanderSettings
from autopilot.estimator import (
    CAL_COUNT,
    IMU_NEW,
    MAG_NEW,
    Z_ACCEL,
    Z_GYRO,
    Z_MAG,
    Estimator,
    calibrated,
)
from autopilot.params import NO_SENSORS, ParamStore
from quadsitl import hil, wire
from quadsitl.config import IMU_PROFILES, SensorParams, load_preset
from sitl import tick as plant_tick
from sitl.plant import Plant
from sitl.sensors import B_GYRO
from tests.test_sensor_mode import SensorAutopilot

DT = 0.004  # [s] the process's sample interval


def feed(c: Calibration, sample, seconds: float = 200.0) -> float:
    """Samples every DT until it ends (``sample(t)``) → the time it took [s]."""
    t = 0.0
    while not c.done and t < seconds:
        t += DT
        c.step(sample(t))
    return t


def calibration(kind: str, params: CalibrationParams | None = None) -> tuple[Calibration, list[tuple[int, str]]]:
    said: list[tuple[int, str]] = []
    return Calibration(kind, params or CalibrationParams(), lambda s, t: said.append((s, t))), said


def texts(said) -> list[str]:
    return [t for _, t in said]


def test_which_reads_preflight_calibrations_params_as_px4s_commander():
    assert cal.which((1, 0, 0, 0, 0, 0, 0)) == GYRO
    assert cal.which((0, 1, 0, 0, 0, 0, 0)) == MAG
    assert cal.which((0, 0, 0, 0, 1, 0, 0)) == ACCEL
    assert cal.which((0, 0, 0, 0, 2, 0, 0)) == LEVEL
    assert cal.which((0,) * 7) == ""  # a cancel (PX4: also "RC calibration ended")
    for p in ((0, 0, 1, 0, 0, 0, 0), (0, 0, 0, 1, 0, 0, 0), (0, 0, 0, 0, 4, 0, 0), (0, 0, 0, 0, 0, 1, 0),
              (0, 0, 0, 0, 0, 0, 1), (math.nan, 0, 0, 0, 0, 0, 0)):  # fmt: skip
        assert cal.which(p) is None, p  # baro, RC, quick accel, airspeed, ESC, NaN: not run here


def test_the_gyro_calibration_saves_the_mean_rate_at_rest_and_says_its_progress():
    rng = random.Random(1)
    c, said = calibration(GYRO, CalibrationParams(gyro_offset=(0.001, 0.0, -0.002)))
    feed(c, lambda t: Sample(t, (0.01 + rng.gauss(0, 0.002), -0.02 + rng.gauss(0, 0.002), rng.gauss(0, 0.002)),
                             (0.0, 0.0, -9.8), 0.0, 0.0))  # fmt: skip
    assert c.done and c.saved is not None
    offset = c.saved.gyro_offset  # what it measured, on top of the offsets in force (the samples are corrected)
    assert offset == pytest.approx((0.011, -0.02, -0.002), abs=5e-4)
    progress = [t for t in texts(said) if "progress" in t]
    assert progress == [f"[cal] progress <{p}>" for p in range(0, 101, 10)]
    assert texts(said)[0] == "[cal] calibration started: 2 gyro" and texts(said)[-1] == "[cal] calibration done: gyro"


def test_the_gyro_calibration_takes_a_board_rotation_back_out_of_its_samples():
    """The samples are in body axes (the board rotation applied): the offset saved is the sensor's."""
    params = CalibrationParams(board_roll_deg=90.0)
    c, _ = calibration(GYRO, params)
    feed(c, lambda t: Sample(t, (0.0, 0.0, 0.01), (0.0, 0.0, -9.8), 0.0, 0.0))  # body z = sensor y (rolled 90°)
    assert c.saved.gyro_offset == pytest.approx((0.0, 0.01, 0.0), abs=1e-12)


def test_the_gyro_calibration_retries_on_motion_and_fails_when_it_goes_on():
    c, said = calibration(GYRO)
    n = [0]

    def moving(t):  # each try's last samples 5°/s off its mean
        n[0] += 1
        return Sample(t, (0.1 if n[0] % 250 > 240 else 0.0, 0.0, 0.0), (0.0, 0.0, -9.8), 0.0, 0.0)

    feed(c, moving)
    assert c.done and c.saved is None
    assert texts(said).count("motion, retrying..") == cal.GYRO_TRIES + 1
    assert texts(said)[-2:] == ["ERROR: Motion during calibration", "[cal] calibration failed: gyro"]


def test_the_level_calibration_saves_the_mean_attitude_as_board_offsets():
    c, said = calibration(LEVEL)
    took = feed(c, lambda t: Sample(t, (0.0, 0.0, 0.0), (0.0, 0.0, -9.8), 0.01, -0.02))
    assert took == pytest.approx(cal.LEVEL_TIME + 2 * DT, abs=2 * DT)
    assert (c.saved.board_roll_deg, c.saved.board_pitch_deg) == pytest.approx((math.degrees(0.01),
                                                                              math.degrees(-0.02)))  # fmt: skip
    assert texts(said)[-1] == "[cal] calibration done: level"
    # with offsets in force, the attitude shown is the rest: the new offsets are the whole tilt
    c, _ = calibration(LEVEL, CalibrationParams(board_roll_deg=2.0))
    feed(c, lambda t: Sample(t, (0.0, 0.0, 0.0), (0.0, 0.0, -9.8), math.radians(0.5), 0.0))
    assert c.saved.board_roll_deg == pytest.approx(2.5, abs=1e-9)


def test_the_level_calibration_refuses_motion_and_a_tilt_beyond_px4s_limit():
    c, said = calibration(LEVEL)
    feed(c, lambda t: Sample(t, (0.0, 0.0, 0.0), (0.0, 0.0, -9.8), 0.02 * math.sin(40 * t), 0.0))
    assert c.saved is None and "motion during calibration" in texts(said)
    c, said = calibration(LEVEL)
    feed(c, lambda t: Sample(t, (0.0, 0.0, 0.0), (0.0, 0.0, -9.8), 0.0, 0.9))
    assert c.saved is None and texts(said)[-2:] == ["excess pitch angle", "[cal] calibration failed: level"]


def test_the_accelerometer_calibration_measures_the_side_down_then_fails_as_px4s_does_at_rest():
    c, said = calibration(ACCEL)
    took = feed(c, lambda t: Sample(t, (0.0, 0.0, 0.0), (0.05, -0.1, -9.7), 0.0, 0.0))
    assert c.done and c.saved is None
    t = texts(said)
    assert t[:3] == ["[cal] calibration started: 2 accel", "[cal] pending: back front left right up down",
                     "[cal] hold vehicle still on a pending side"]  # fmt: skip
    assert t.count("[cal] down orientation detected") == 2
    assert "[cal] down side result: [0.050 -0.100 -9.700]" in t
    assert t.count("[cal] down side already completed") == cal.ORIENTATION_FAILURES + 1
    assert t[-2:] == ["[cal] calibration failed: timeout: no motion", "[cal] calibration failed: accel"]
    assert 10.0 < took < 40.0  # six detections of 1.3 s still (after their average settles) and 750 samples


def test_the_accelerometer_calibration_tells_each_side_from_gravity():
    """PX4's detect_orientation: the side down from the accelerometer's direction (here on its back: "up")."""
    c, said = calibration(ACCEL)
    feed(c, lambda t: Sample(t, (0.0, 0.0, 0.0), (0.0, 0.0, 9.8), 0.0, 0.0), seconds=8.0)
    assert "[cal] up orientation detected" in texts(said)
    c, said = calibration(ACCEL)  # no side at all: 45° between two
    feed(c, lambda t: Sample(t, (0.0, 0.0, 0.0), (6.93, 0.0, -6.93), 0.0, 0.0), seconds=8.0)
    assert "ERROR: invalid orientation" in texts(said)


def test_the_magnetometer_calibration_fails_without_rotation_after_px4s_deadline():
    c, said = calibration(MAG)
    took = feed(c, lambda t: Sample(t, (0.0, 0.0, 0.0), (0.0, 0.0, -9.8), 0.0, 0.0))
    assert c.saved is None
    t = texts(said)
    assert "[cal] Rotate vehicle" in t and "Failed: This calibration requires rotation." in t
    assert t[-1] == "[cal] calibration failed: mag"
    assert took == pytest.approx(cal.MAG_ROTATION_DEADLINE + 2.5, abs=2.5)  # after detecting "down" (lenient)


def test_a_cancelled_calibration_says_so_and_saves_nothing():
    c, said = calibration(GYRO)
    feed(c, lambda t: Sample(t, (0.0, 0.0, 0.0), (0.0, 0.0, -9.8), 0.0, 0.0), seconds=0.2)
    c.cancel()
    assert c.done and c.saved is None and texts(said)[-1] == "[cal] calibration cancelled"
    c.step(Sample(1.0, (0.0, 0.0, 0.0), (0.0, 0.0, -9.8), 0.0, 0.0))  # nothing after the end
    assert texts(said)[-1] == "[cal] calibration cancelled"


def test_a_calibration_without_samples_fails_reading_the_sensor():
    c, said = calibration(LEVEL)
    c.no_data()
    assert c.done and c.saved is None and texts(said)[-1] == "[cal] calibration failed: reading sensor"


def test_the_estimator_applies_the_calibration_to_each_new_measurement_and_collects_them():
    est = Estimator(0.001, 9.8, (0.2, 0.0, 0.4))
    board = cal.board_rotation(CalibrationParams(board_pitch_deg=10.0))
    est.calibrate((0.01, 0.02, 0.03), board)
    est.collect(True)
    z, c = est.z, est.cal
    R = np.array(board)
    for flags in (IMU_NEW | MAG_NEW, 0):
        z[Z_GYRO : Z_GYRO + 3], z[Z_ACCEL : Z_ACCEL + 3], z[Z_MAG : Z_MAG + 3] = (
            (0.11, 0.22, 0.33),
            (1, 2, -9),
            (0.2, 0.0, 0.4),
        )
        calibrated(flags, z, c)
        if flags:
            assert z[Z_GYRO : Z_GYRO + 3] == pytest.approx(R @ [0.1, 0.2, 0.3])
            assert z[Z_ACCEL : Z_ACCEL + 3] == pytest.approx(R @ [1, 2, -9])
            assert z[Z_MAG : Z_MAG + 3] == pytest.approx(R @ [0.2, 0.0, 0.4])
        else:  # no new measurement: the last one, corrected already, is left as it is
            assert list(z[Z_GYRO : Z_GYRO + 3]) == [0.11, 0.22, 0.33]
    assert c[CAL_COUNT] == 1
    gyro, accel = est.take()
    assert gyro == pytest.approx(tuple(R @ [0.1, 0.2, 0.3])) and accel == pytest.approx(tuple(R @ [1, 2, -9]))
    assert est.take() is None  # taken: nothing since


def test_the_gyro_calibration_on_the_plants_sensors_finds_their_bias_and_removes_it():
    """ADIS16448 (turn-on bias σ 0.0087 rad/s): closed on the plant's sensor datagrams and the compiled sensor tick,
    every 4 ticks a sample as the process takes them; the offsets saved are the plant's own gyro bias, and once
    applied the corrected gyro at rest reads zero."""
    preset = load_preset("x500")
    s = dataclasses.replace(SensorParams(), profile="adis16448", **IMU_PROFILES["adis16448"])
    preset = dataclasses.replace(preset, sensors=s)
    ap, plant = SensorAutopilot(preset), Plant(preset)
    io = np.zeros(plant_tick.IO_SIZE, dtype=np.int64)
    io[plant_tick.SENSING] = 1
    tx = np.zeros(hil.DATAGRAM_MAX, dtype=np.uint8)
    c = Calibration(GYRO, CalibrationParams(), lambda *a: None)
    ap.est.collect(True)
    measured, bias = [], None
    for k in range(8000):
        plant_tick.encode_tick(tx, io, plant.x, plant.out, plant.air, plant.sensors.arrays, k, plant.period)
        answer = ap.tick(tx[: io[plant_tick.TX_LEN]].copy())
        if k >= 1000 and k % 4 == 0:  # aligned; a sample every 4 ms
            taken = ap.est.take()
            if not c.done:
                c.step(Sample(k * 0.001, *taken, ap.st[6], ap.st[7]))
                bias = plant.sensors.bias[B_GYRO : B_GYRO + 3].copy()
                if c.done:
                    ap.est.calibrate(c.saved.gyro_offset, cal.board_rotation(c.saved))
            elif k > 4000:
                measured.append(taken[0])
        plant.step(wire.forces_from_message(wire.link(1, 1).parse_buffer(answer)[0], ap.f_max))
    assert c.saved is not None
    assert np.abs(bias).max() > 3e-3  # a bias worth finding
    assert c.saved.gyro_offset == pytest.approx(tuple(bias), abs=1.5e-3)
    assert np.abs(np.mean(measured, axis=0)).max() < 1.5e-3  # removed


def test_the_calibrations_parameters_are_honoured_in_sensor_mode_and_kept_at_zero_in_truth_mode():
    x500 = load_preset("x500")
    truth = ParamStore(x500, "backstepping", CommanderSettings())
    reason = truth.set("CAL_GYRO0_XOFF", 0.1)
    assert reason == f"CAL_GYRO0_XOFF = 0.1: expected 0 ({NO_SENSORS})"
    assert truth.set("CAL_GYRO0_XOFF", 0.0) == ""
    sensing = ParamStore(dataclasses.replace(x500, sensors=SensorParams()), "backstepping", CommanderSettings())
    assert sensing.set("CAL_GYRO0_YOFF", 0.1) == "" and sensing.set("SENS_BOARD_X_OFF", -3.0) == ""
    assert sensing.applied().calibration == CalibrationParams(gyro_offset=(0.0, 0.1, 0.0), board_roll_deg=-3.0)
    assert "expected a number in [-90, 90] deg" in sensing.set("SENS_BOARD_Y_OFF", 91.0)
