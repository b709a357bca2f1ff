"""Sensor calibration as PX4's commander runs it (``MAV_CMD_PREFLIGHT_CALIBRATION``; docs/mavlink.md#calibration):
pure, fed samples by the autopilot process, and saying what PX4 says (the ``[cal]`` status texts QGroundControl's
and MAVSDK's calibration screens parse).

Each calibration is PX4's worker routine written as a generator (``src/modules/commander/*_calibration.cpp``): it is
sent one :class:`Sample` at a time and says what it says through ``out``. We read PX4's code; we did not copy it.

- **gyro** (param1 = 1): 250 samples at rest, their mean the new offsets ``CAL_GYRO0_[XYZ]OFF``; retried (up to 20
  times, "motion, retrying..") when the median of the last 9 differs from the mean by more than 0.6°/s.
- **level** (param5 = 2): 0.5 s of the attitude estimate, its mean roll and pitch the board offsets
  ``SENS_BOARD_X_OFF`` and ``_Y_OFF`` [deg]; retried (up to 50 times) while roll or pitch varies by 0.5° or more;
  refused beyond 0.8 rad.
- **accel** (param5 = 1) and **mag** (param2 = 1) need the vehicle turned onto each of its six sides (and, for the
  magnetometer, rotated on each), which no simulated vehicle resting on the ground does. They run as on PX4 SITL:
  the side the vehicle rests on is detected ("down") and, for the accelerometer, measured; then the accelerometer's
  fails after five detections of the same side ("timeout: no motion") and the magnetometer's after 35 s without
  rotation ("This calibration requires rotation."). Nothing is saved.

A sample's gyro and accelerometer are the measurements as the estimator takes them (offsets and board rotation
applied: :func:`autopilot.estimator.calibrated`), averaged over the sample's interval as PX4's ``vehicle_imu``
integrates them; its attitude is the estimate's."""

from __future__ import annotations

import math
import statistics
from collections.abc import Callable, Generator
from dataclasses import dataclass, replace

from quadsitl import wire
from quadsitl.frames import body_to_ned, euler_to_quaternion, ned_to_body, quaternion_multiply, quaternion_to_euler
from quadsitl.keys import key
from quadsitl.keys import mavlink as param

mavlink = wire.mavlink
INFO, CRITICAL = mavlink.MAV_SEVERITY_INFO, mavlink.MAV_SEVERITY_CRITICAL
GYRO, MAG, ACCEL, LEVEL = "gyro", "mag", "accel", "level"
SIDES = ("back", "front", "left", "right", "up", "down")  # PX4's detect_orientation_str, in its order
GRAVITY = 9.80665  # CONSTANTS_ONE_G, which PX4's orientation detection compares with

# PX4's figures (gyro_calibration.cpp, level_calibration.cpp, calibration_routines.cpp, accelerometer_ and
# mag_calibration.cpp)
GYRO_SAMPLES, GYRO_TRIES, GYRO_MEDIAN_OF, GYRO_MAX_DIFF = 250, 20, 9, math.radians(0.6)
LEVEL_TIME, LEVEL_TRIES, LEVEL_MAX_SPREAD, LEVEL_MAX_ANGLE = 0.5, 50, math.radians(0.5), 0.8
ACCEL_SAMPLES, ORIENTATION_FAILURES = 750, 4
STILL_EMA, STILL_THRESHOLD, STILL_TIME, STILL_TIME_LENIENT, SIDE_ERROR = 0.5, 0.25, 1.3, 0.5, 5.0
DETECT_TIMEOUT = 90.0
NO_DATA = 100.0  # [s] wall: a calibration without samples fails (PX4: 1000 sensor polls of 100 ms)
MAG_ROTATION_DEADLINE, MAG_ROTATION = 42.0 / 6 * 5, 0.5  # [s] 5 sides' share of 42 s; [rad] the integral to reach


@dataclass(frozen=True)
class CalibrationParams:
    """What the calibrations save and the estimator applies to the measurements (sensor mode), as PX4's calibration
    parameters: body = R(roll, pitch)·(raw − offset). Units in the keys."""

    gyro_offset: tuple[float, float, float] = key(
        (0.0, 0.0, 0.0), length=3, unit="rad/s", low=-1.0, high=1.0, note="x, y, z (FRD)",
        doc="gyro offsets, subtracted from its measurements",
        mavlink=param(["CAL_GYRO0_XOFF", "CAL_GYRO0_YOFF", "CAL_GYRO0_ZOFF"],
                      [f"gyro offset, {a} (FRD), subtracted from its measurements" for a in "xyz"]),
    )  # fmt: skip
    board_roll_deg: float = key(0.0, unit="deg", low=-90.0, high=90.0, mavlink=param("SENS_BOARD_X_OFF"),
                                doc="the sensors' roll relative to the body (the level calibration's)")  # fmt: skip
    board_pitch_deg: float = key(0.0, unit="deg", low=-90.0, high=90.0, mavlink=param("SENS_BOARD_Y_OFF"),
                                 doc="the sensors' pitch relative to the body (the level calibration's)")  # fmt: skip


@dataclass(frozen=True)
class Sample:
    """What a calibration is fed: ``t`` [s] simulated time; ``gyro`` [rad/s] and ``accel`` [m/s²] FRD, as the
    estimator takes them, averaged since the last sample; ``roll``, ``pitch`` [rad] the attitude estimate."""

    t: float
    gyro: tuple[float, float, float]
    accel: tuple[float, float, float]
    roll: float
    pitch: float


Say = Callable[[int, str], None]
Worker = Generator[None, Sample, None]


def which(p: tuple[float, ...]) -> str | None:
    """PREFLIGHT_CALIBRATION's params 1–7 → the calibration they ask for (GYRO, MAG, ACCEL, LEVEL), "" for all zero
    (a cancel, or PX4's "RC calibration ended"), None for one not run here."""
    ints = [int(v) if math.isfinite(v) else -1 for v in p]
    if ints[0] == 1:
        return GYRO
    if ints[1] == 1:
        return MAG
    if ints[4] == 1:
        return ACCEL
    if ints[4] == 2:
        return LEVEL
    return "" if not any(ints) else None


NOT_RUN = (
    "Calibration: only the gyro (param1 = 1), magnetometer (param2 = 1), accelerometer (param5 = 1) and level "
    "(param5 = 2) calibrations run here; barometer, RC, airspeed, ESC, temperature and quick calibrations do not"
)


class Calibration:
    """One calibration running: :meth:`step` it with each sample; ``done`` once it has ended, ``saved`` the
    parameters it saves (None: it failed or was cancelled). ``params``: those in force at its start."""

    def __init__(self, kind: str, params: CalibrationParams, say: Say) -> None:
        self.kind, self.params, self.say = kind, params, say
        self.done = False
        self.saved: CalibrationParams | None = None
        workers = {GYRO: self._gyro, LEVEL: self._level, ACCEL: self._accel, MAG: self._mag}
        self._worker: Worker = workers[kind]()
        next(self._worker)  # to its first wait for a sample

    def step(self, s: Sample) -> None:
        if self.done:
            return
        try:
            self._worker.send(s)
        except StopIteration:
            self.done = True

    def no_data(self) -> None:
        """No sample for NO_DATA of wall time (the plant gone): it fails as PX4's does when its sensor stops."""
        if not self.done:
            self._worker.close()
            self.done = True
            self.say(CRITICAL, "[cal] calibration failed: reading sensor")

    def cancel(self) -> None:
        """PREFLIGHT_CALIBRATION with every param 0, while it runs."""
        if not self.done:
            self._worker.close()
            self.done = True
            self.say(CRITICAL, "[cal] calibration cancelled")

    # ---- the workers -----------------------------------------------------------------------------------------

    def _started(self) -> None:
        self.say(INFO, f"[cal] calibration started: 2 {self.kind}")  # 2: the version QGroundControl and MAVSDK know

    def _finish(self, saved: CalibrationParams | None) -> None:
        if saved is None:
            self.say(CRITICAL, f"[cal] calibration failed: {self.kind}")
        else:
            self.saved = saved
            self.say(INFO, f"[cal] calibration done: {self.kind}")

    def _gyro(self) -> Worker:
        self._started()
        for _ in range(GYRO_TRIES + 1):
            total, last, said = [0.0, 0.0, 0.0], [], -1
            for n in range(1, GYRO_SAMPLES + 1):
                s = yield
                total = [a + b for a, b in zip(total, s.gyro)]
                last = [*last, s.gyro][-GYRO_MEDIAN_OF:]
                progress = n * 100 // GYRO_SAMPLES
                if progress % 10 == 0 and progress != said:
                    said = progress
                    self.say(INFO, f"[cal] progress <{progress}>")
            mean = [a / GYRO_SAMPLES for a in total]
            medians = [statistics.median(v[i] for v in last) for i in range(3)]
            if all(math.isfinite(m) and abs(d - m) <= GYRO_MAX_DIFF for m, d in zip(mean, medians)):
                board = board_rotation(self.params)  # the samples are in body axes: the offset is the sensor's
                raw = [sum(board[r][i] * mean[r] for r in range(3)) for i in range(3)]
                offset = tuple(o + m for o, m in zip(self.params.gyro_offset, raw))
                if all(abs(o) <= 1.0 for o in offset):
                    self._finish(replace(self.params, gyro_offset=offset))
                else:
                    self.say(CRITICAL, "[cal] calibration save failed")
                    self._finish(None)
                return
            self.say(CRITICAL, "motion, retrying..")
        self.say(CRITICAL, "ERROR: Motion during calibration")
        self._finish(None)

    def _level(self) -> Worker:
        self._started()
        p = self.params
        board = euler_to_quaternion(math.radians(p.board_roll_deg), math.radians(p.board_pitch_deg), 0.0)
        for _ in range(LEVEL_TRIES):
            first = yield
            angles, said = [], -100
            s = first
            while s.t - first.t < LEVEL_TIME:
                progress = int(100 * (s.t - first.t) / LEVEL_TIME)
                if progress >= said + 20:
                    said = progress
                    self.say(INFO, f"[cal] progress <{progress}>")
                angles.append((s.roll, s.pitch, _board_angles(board, s.roll, s.pitch)))
                s = yield
            rolls, pitches = [a[0] for a in angles], [a[1] for a in angles]
            if max(rolls) - min(rolls) < LEVEL_MAX_SPREAD and max(pitches) - min(pitches) < LEVEL_MAX_SPREAD:
                break
        else:
            self.say(INFO, "[cal] progress <100>")
            self.say(CRITICAL, "motion during calibration")
            self._finish(None)
            return
        self.say(INFO, "[cal] progress <100>")
        roll = sum(a[2][0] for a in angles) / len(angles)
        pitch = sum(a[2][1] for a in angles) / len(angles)
        if abs(roll) > LEVEL_MAX_ANGLE or abs(pitch) > LEVEL_MAX_ANGLE:
            self.say(CRITICAL, f"excess {'roll' if abs(roll) > LEVEL_MAX_ANGLE else 'pitch'} angle")
            self._finish(None)
            return
        self._finish(replace(self.params, board_roll_deg=math.degrees(roll), board_pitch_deg=math.degrees(pitch)))

    def _orientations(self, lenient: bool, side: Callable[[int], Generator[None, Sample, bool]]
                      ) -> Generator[None, Sample, bool]:  # fmt: skip
        """PX4's calibrate_from_orientation: until every side is done, detect the side the vehicle rests on and
        run ``side`` on a new one (→ whether it succeeded) → whether all six were done."""
        done = [False] * 6
        failures = 0
        while not all(done):
            if failures > ORIENTATION_FAILURES:
                self.say(CRITICAL, "[cal] calibration failed: timeout: no motion")
                return False
            self.say(INFO, "[cal] pending: " + " ".join(SIDES[i] for i in range(6) if not done[i]))
            self.say(INFO, "[cal] hold vehicle still on a pending side")
            down = yield from self._detect(lenient)
            if down < 0:
                failures += 1
                self.say(INFO, "[cal] detected motion, hold still...")
                continue
            if done[down]:
                failures += 1
                self.say(INFO, f"[cal] {SIDES[down]} side already completed")
                continue
            for _ in range(2):
                self.say(INFO, f"[cal] {SIDES[down]} orientation detected")
            failures = 0
            if not (yield from side(down)):
                return False
            for _ in range(2):
                self.say(INFO, f"[cal] {SIDES[down]} side done, rotate to a different side")
            done[down] = True
        return True

    def _detect(self, lenient: bool) -> Generator[None, Sample, int]:
        """PX4's detect_orientation: the accelerometer's moving average and dispersion until it has been still long
        enough → the side down (index into SIDES), or −1."""
        threshold = (STILL_THRESHOLD * (3 if lenient else 1)) ** 2
        still_time = STILL_TIME_LENIENT if lenient else STILL_TIME
        ema, disp = [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]
        s = yield
        prev, still, timeout = s.t, None, s.t + DETECT_TIMEOUT
        while True:
            s = yield
            w = (s.t - prev) / STILL_EMA
            prev = s.t
            for i in range(3):
                d = s.accel[i] - ema[i]
                ema[i] += d * w
                disp[i] = max(disp[i] * (1.0 - w), min(d * d, threshold * 8.0))
            if max(disp) < threshold:
                if still is None:
                    self.say(INFO, "[cal] detected rest position, hold still...")
                    still, timeout = s.t, s.t + DETECT_TIMEOUT
                elif s.t > still + still_time:
                    break
            elif max(disp) > threshold * 4.0 and still is not None:
                self.say(INFO, "[cal] detected motion, hold still...")
                still = None
            if s.t > timeout:
                self.say(CRITICAL, "[cal] calibration failed: reading sensor")
                return -1
        for side, (axis, sign) in enumerate(((0, 1), (0, -1), (1, 1), (1, -1), (2, 1), (2, -1))):
            if all(abs(ema[i] - (sign * GRAVITY if i == axis else 0.0)) < SIDE_ERROR for i in range(3)):
                return side
        self.say(CRITICAL, "ERROR: invalid orientation")
        return -1

    def _accel(self) -> Worker:
        self._started()
        measured = 0

        def measure(side: int) -> Generator[None, Sample, bool]:
            nonlocal measured
            self.say(INFO, f"[cal] Hold still, measuring {SIDES[side]} side")
            total = [0.0, 0.0, 0.0]
            for _ in range(ACCEL_SAMPLES):
                s = yield
                total = [a + b for a, b in zip(total, s.accel)]
            mean = [a / ACCEL_SAMPLES for a in total]
            self.say(INFO, f"[cal] {SIDES[side]} side result: [{mean[0]:.3f} {mean[1]:.3f} {mean[2]:.3f}]")
            measured += 1
            self.say(INFO, f"[cal] progress <{17 * measured}>")
            return True

        yield from self._orientations(False, measure)
        self._finish(None)  # six sides cannot be had at rest (the module docstring): never saved

    def _mag(self) -> Worker:
        self._started()

        def rotate(side: int) -> Generator[None, Sample, bool]:
            self.say(INFO, "[cal] Rotate vehicle")
            s = yield
            deadline, turned, prev = s.t + MAG_ROTATION_DEADLINE, [0.0, 0.0, 0.0], s.t
            while all(abs(a) < MAG_ROTATION for a in turned):
                s = yield
                turned = [a + g * (s.t - prev) for a, g in zip(turned, s.gyro)]
                prev = s.t
                if s.t > deadline:
                    self.say(CRITICAL, "Failed: This calibration requires rotation.")
                    return False
            return False  # rotating: not at rest, which the ground does not simulate (module docstring)

        yield from self._orientations(True, rotate)
        self._finish(None)


def board_rotation(p: CalibrationParams) -> tuple[tuple[float, ...], ...]:
    """R(roll, pitch) of the board offsets (PX4's Dcm of the Euler angles, yaw 0) as rows: body = R·sensor."""
    q = euler_to_quaternion(math.radians(p.board_roll_deg), math.radians(p.board_pitch_deg), 0.0)
    columns = [body_to_ned(q, *axis) for axis in ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))]
    return tuple(tuple(c[i] for c in columns) for i in range(3))


def truth_sample(t: float, roll: float, pitch: float, rates: tuple[float, float, float], gravity: float) -> Sample:
    """Truth mode's ideal sensors at rest: the true body rates [rad/s], and the specific force of gravity alone in
    body axes [m/s²] (the true state carries no acceleration; a calibration runs disarmed, at rest)."""
    return Sample(t, rates, ned_to_body(euler_to_quaternion(roll, pitch, 0.0), 0.0, 0.0, -gravity), roll, pitch)


def _board_angles(board: tuple[float, float, float, float], roll: float, pitch: float) -> tuple[float, float]:
    """Roll and pitch [rad] of q_board ⊗ q(roll, pitch) (yaw ignored): the attitude the sensors themselves show, the
    board offsets in force taken back out (PX4's level calibration)."""
    roll, pitch, _ = quaternion_to_euler(*quaternion_multiply(board, euler_to_quaternion(roll, pitch, 0.0)))
    return roll, pitch
