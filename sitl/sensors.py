"""The plant's sensors: what a PX4 flight controller's IMU, magnetometer, barometer and GPS would measure of
the true state, with the noise PX4's simulators give them (docs/sensors.md). Pure and compiled
(:mod:`quadsitl.jit`): the plant will call :func:`sensors_tick` once per control tick.

- **Accelerometer** [m/s², FRD]: the specific force f = Rᵀ·(a − g), a the true acceleration (NED), g = (0, 0, g);
  at rest and level it reads (0, 0, −g). **Gyroscope** [rad/s, FRD]: the body rates (p, q, r), eq (1). Both
  every tick, as PX4's Gazebo IMU plugin (``gazebo_imu_plugin.cpp``): white noise of standard deviation
  σ = density/√dt plus a bias, a first-order Gauss–Markov process driven by the random walk (exact
  discretisation, Maybeck eq. 4-114) that starts at a random turn-on bias (σ given).
- **Magnetometer** [gauss, FRD]: Rᵀ·B, B the constant Earth field at home (:mod:`quadsitl.earth`), with white
  noise by density and a Gauss–Markov bias (``gazebo_magnetometer_plugin.cpp``), at ``mag_rate_hz``.
- **Barometer**: static pressure of the ISA at the home altitude + h, plus white noise [Pa] (as
  ``gazebo_barometer_plugin.cpp``), reported as ``abs_pressure`` [hPa], the pressure altitude of that noisy
  pressure [m AMSL] and the ISA temperature [°C], at ``baro_rate_hz``.
- **GPS**: position (NED, from the local origin = home) with an error that wanders slowly (a first-order
  Gauss–Markov process per axis, σ and correlation time given), velocity (NED) with white noise; measured at
  ``gps_rate_hz`` and delivered ``gps_delay_s`` later (PX4's Gazebo GPS plugin delays by 120 ms).

Every random number comes from :mod:`sitl.noise`'s seeded streams (one each for the IMU, the magnetometer,
the barometer and the GPS, so changing one sensor's rate leaves the others' samples alone): the same seed
gives the same samples, bit for bit.
"""

from __future__ import annotations

import math

import numpy as np

from quadsitl import failures
from quadsitl.compiled_frames import euler_rates_to_body_rates, euler_to_quaternion, ned_to_body
from quadsitl.config import GPS_QUEUE, SensorParams
from quadsitl.earth import ZERO_CELSIUS, isa_altitude, isa_pressure, isa_temperature, magnetic_field_ned
from quadsitl.frames import PX4_HOME
from quadsitl.hil import ACCEL_UPDATED, BARO_UPDATED, GYRO_UPDATED, MAG_UPDATED  # HIL_SENSOR.fields_updated
from quadsitl.jit import jit
from sitl.noise import gauss_markov_coefficients, normal, normal_pair, seed_streams

# ---- the parameter array (sensor_array) -----------------------------------------------------------------
# The noise processes' steps (φ, k: sitl.noise.gauss_markov_coefficients) come last: each sensor's samples are a
# fixed interval apart (the IMU's the control period), so they are computed once.
(GYRO_ND, GYRO_RW, GYRO_TAU, GYRO_BIAS0, ACC_ND, ACC_RW, ACC_TAU, ACC_BIAS0, MAG_ND, MAG_RW, MAG_TAU, MAG_N, MAG_E,
 MAG_D, BARO_NOISE, HOME_ALT_M, GPS_XY, GPS_Z, GPS_TAU, GPS_VXY, GPS_VZ, GRAVITY, HOME_LAT_DEG, HOME_LON_DEG,
 SATELLITES, GYRO_STEP, ACC_STEP, MAG_STEP, GPS_XY_STEP, GPS_Z_STEP, PARAM_SIZE) = (*range(25), 25, 27, 29, 31, 33,
                                                                                   35)  # fmt: skip
# ---- the integer schedule (``clock``, int64, µs), and the sensors failed (bits SENSOR_*: off, stuck) ---------
(MAG_INTERVAL, BARO_INTERVAL, GPS_INTERVAL, GPS_DELAY, NEXT_MAG, NEXT_BARO, NEXT_GPS, QUEUE_HEAD, QUEUE_COUNT,
 FAILED_OFF, FAILED_STUCK, CLOCK_SIZE) = range(12)  # fmt: skip
# ---- failure injection (MAV_CMD_INJECT_FAILURE, :func:`inject_failure`): the sensors, as clock[FAILED_*]'s bits ----
SENSOR_GYRO, SENSOR_ACCEL, SENSOR_MAG, SENSOR_BARO, SENSOR_GPS = 1, 2, 4, 8, 16
# ---- the noise processes' state (``bias``): gyro, accel, mag biases, GPS position error ---------------------
B_GYRO, B_ACC, B_MAG, E_GPS, BIAS_SIZE = 0, 3, 6, 9, 12
# ---- the random streams -----------------------------------------------------------------------------
IMU, MAG, BARO, GPS, STREAMS = range(5)
# ---- the GPS queue's rows: release time [µs], measurement time [µs], position NED [m], velocity NED [m/s] --
Q_RELEASE, Q_TIME, Q_POS, Q_VEL, Q_SIZE = 0, 1, 2, 5, 8
# ---- the output (``out``): a HIL_SENSOR's fields, then the GPS sample released this tick, if any ----------
(OUT_ACCEL, OUT_GYRO, OUT_MAG, OUT_PRESSURE, OUT_PRESSURE_ALT, OUT_TEMPERATURE, OUT_GPS_NEW, OUT_GPS_TIME,
 OUT_GPS_POS, OUT_GPS_VEL, OUT_SIZE) = 0, 3, 6, 9, 10, 11, 12, 13, 14, 17, 20  # fmt: skip


def sensor_array(s: SensorParams, period: float, gravity: float,
                 home: tuple[float, float, float] = PX4_HOME) -> np.ndarray:  # fmt: skip
    """The sensors' figures as the compiled functions read them (SI units, gauss; the field in NED). ``period``
    [s] is the IMU's sample interval (the control period); ``gravity`` [m/s²] is the plant's g (the accelerometer
    measures a − g); ``home`` = (lat [deg], lon [deg], alt [m AMSL]) is the local origin on the globe (the
    barometer's altitude, the GPS's latitude and longitude)."""
    field = magnetic_field_ned(
        s.mag_strength_gauss, math.radians(s.mag_declination_deg), math.radians(s.mag_inclination_deg)
    )
    clock = clock_array(s)
    mag_dt, gps_dt = clock[MAG_INTERVAL] * 1e-6, clock[GPS_INTERVAL] * 1e-6
    steps = (*bias_coefficients(period, s.gyro_bias_correlation_time_s, s.gyro_random_walk_rad_s2_sqrt_hz),
             *bias_coefficients(period, s.accel_bias_correlation_time_s, s.accel_random_walk_m_s3_sqrt_hz),
             *bias_coefficients(mag_dt, s.mag_bias_correlation_time_s, s.mag_random_walk_gauss_s_sqrt_hz),
             *gauss_markov_coefficients(gps_dt, s.gps_error_correlation_time_s, s.gps_xy_error_m),
             *gauss_markov_coefficients(gps_dt, s.gps_error_correlation_time_s, s.gps_z_error_m))  # fmt: skip
    return np.array(
        [s.gyro_noise_density_rad_s_sqrt_hz, s.gyro_random_walk_rad_s2_sqrt_hz, s.gyro_bias_correlation_time_s,
         s.gyro_turn_on_bias_rad_s, s.accel_noise_density_m_s2_sqrt_hz, s.accel_random_walk_m_s3_sqrt_hz,
         s.accel_bias_correlation_time_s, s.accel_turn_on_bias_m_s2, s.mag_noise_density_gauss_sqrt_hz,
         s.mag_random_walk_gauss_s_sqrt_hz, s.mag_bias_correlation_time_s, *field, s.baro_noise_pa, home[2],
         s.gps_xy_error_m, s.gps_z_error_m, s.gps_error_correlation_time_s, s.gps_xy_velocity_noise_m_s,
         s.gps_z_velocity_noise_m_s, gravity, home[0], home[1], s.gps_satellites, *steps],
        dtype=np.float64,
    )  # fmt: skip


def clock_array(s: SensorParams) -> np.ndarray:
    """The schedule: the intervals [µs] of the magnetometer, barometer and GPS, the GPS delay [µs]; the next
    sample of each is due at t = 0."""
    c = np.zeros(CLOCK_SIZE, dtype=np.int64)
    c[MAG_INTERVAL], c[BARO_INTERVAL] = round(1e6 / s.mag_rate_hz), round(1e6 / s.baro_rate_hz)
    c[GPS_INTERVAL], c[GPS_DELAY] = round(1e6 / s.gps_rate_hz), round(s.gps_delay_s * 1e6)
    return c


def bias_coefficients(dt: float, tau: float, random_walk: float) -> tuple[float, float]:
    """(φ, k) of a sensor bias's step over ``dt`` [s] (b⁺ = φ·b + k·w, :func:`sitl.noise.gauss_markov`): the
    Gauss–Markov process of PX4's Gazebo IMU plugin, dḃ = −b/τ·dt + σ_b·dW with σ_b the random walk (units of the
    bias per √s), whose stationary deviation is σ_b·√(τ/2)."""
    return gauss_markov_coefficients(dt, tau, random_walk * math.sqrt(0.5 * tau))


@jit
def _step(x: float, p: np.ndarray, at: int, w: float) -> float:
    """A noise process's step by its coefficients p[at], p[at + 1] (φ, k), ``w`` a standard normal deviate."""
    return p[at] * x + p[at + 1] * w


@jit
def sensors_reset(p: np.ndarray, rng: np.ndarray, bias: np.ndarray) -> None:
    """Power-on: the IMU's turn-on biases (σ given) and the GPS error drawn from its stationary distribution;
    the magnetometer's bias starts at zero (as the Gazebo plugin's)."""
    for i in range(3):
        bias[B_GYRO + i] = p[GYRO_BIAS0] * normal(rng, IMU)
    for i in range(3):
        bias[B_ACC + i] = p[ACC_BIAS0] * normal(rng, IMU)
    for i in range(3):
        bias[B_MAG + i] = 0.0
    bias[E_GPS] = p[GPS_XY] * normal(rng, GPS)
    bias[E_GPS + 1] = p[GPS_XY] * normal(rng, GPS)
    bias[E_GPS + 2] = p[GPS_Z] * normal(rng, GPS)


@jit
def specific_force(q: tuple, accel: tuple, gravity: float) -> tuple[float, float, float]:
    """What an ideal accelerometer reads [m/s², FRD]: Rᵀ·(a − g·e_down), a the acceleration [m/s², NED]."""
    return ned_to_body(q, accel[0], accel[1], accel[2] - gravity)


@jit(inline=True)
def imu(s: tuple, accel: tuple, p: np.ndarray, rng: np.ndarray, bias: np.ndarray, dt: float, out: np.ndarray) -> None:
    """The accelerometer and gyroscope of state ``s`` (VehicleState order) accelerating at ``accel`` [m/s², NED],
    one sample after ``dt`` [s], into ``out``."""
    q = euler_to_quaternion(s[6], s[7], s[8])
    f = specific_force(q, accel, p[GRAVITY])
    w = euler_rates_to_body_rates(s[6], s[7], s[9], s[10], s[11])  # eq (1)
    root = 1.0 / math.sqrt(dt)
    for i in range(3):  # each axis: its bias's step and its white noise, one Box–Muller pair
        walk, white = normal_pair(rng, IMU)
        bias[B_GYRO + i] = _step(bias[B_GYRO + i], p, GYRO_STEP, walk)
        out[OUT_GYRO + i] = w[i] + bias[B_GYRO + i] + p[GYRO_ND] * root * white
    for i in range(3):
        walk, white = normal_pair(rng, IMU)
        bias[B_ACC + i] = _step(bias[B_ACC + i], p, ACC_STEP, walk)
        out[OUT_ACCEL + i] = f[i] + bias[B_ACC + i] + p[ACC_ND] * root * white


@jit
def magnetometer(s: tuple, p: np.ndarray, rng: np.ndarray, bias: np.ndarray, dt: float, out: np.ndarray) -> None:
    """The magnetometer [gauss, FRD] of state ``s``, ``dt`` [s] after its last sample, into ``out``."""
    m = ned_to_body(euler_to_quaternion(s[6], s[7], s[8]), p[MAG_N], p[MAG_E], p[MAG_D])
    root = 1.0 / math.sqrt(dt)
    for i in range(3):
        walk, white = normal_pair(rng, MAG)
        bias[B_MAG + i] = _step(bias[B_MAG + i], p, MAG_STEP, walk)
        out[OUT_MAG + i] = m[i] + bias[B_MAG + i] + p[MAG_ND] * root * white


@jit(inline=True)
def barometer(s: tuple, p: np.ndarray, rng: np.ndarray, out: np.ndarray) -> None:
    """The barometer of state ``s`` into ``out``: absolute pressure [hPa], its pressure altitude [m AMSL],
    temperature [°C] (ISA at the true altitude)."""
    h = p[HOME_ALT_M] - s[2]
    pressure = isa_pressure(h) + p[BARO_NOISE] * normal(rng, BARO)
    out[OUT_PRESSURE] = 0.01 * pressure
    out[OUT_PRESSURE_ALT] = isa_altitude(pressure)
    out[OUT_TEMPERATURE] = isa_temperature(h) - ZERO_CELSIUS


@jit
def gps_measure(s: tuple, p: np.ndarray, rng: np.ndarray, bias: np.ndarray, row: np.ndarray) -> None:
    """A GPS fix of state ``s`` into a queue row: the position error advanced by one GPS interval (Gauss–Markov),
    the velocity with white noise."""
    bias[E_GPS] = _step(bias[E_GPS], p, GPS_XY_STEP, normal(rng, GPS))
    bias[E_GPS + 1] = _step(bias[E_GPS + 1], p, GPS_XY_STEP, normal(rng, GPS))
    bias[E_GPS + 2] = _step(bias[E_GPS + 2], p, GPS_Z_STEP, normal(rng, GPS))
    for i in range(3):
        row[Q_POS + i] = s[i] + bias[E_GPS + i]
    row[Q_VEL] = s[3] + p[GPS_VXY] * normal(rng, GPS)
    row[Q_VEL + 1] = s[4] + p[GPS_VXY] * normal(rng, GPS)
    row[Q_VEL + 2] = s[5] + p[GPS_VZ] * normal(rng, GPS)


@jit(inline=True)
def sensors_tick(t_us: int, s: tuple, accel: tuple, dt: float, p: np.ndarray, rng: np.ndarray, bias: np.ndarray,
                 clock: np.ndarray, queue: np.ndarray, out: np.ndarray) -> int:  # fmt: skip
    """Every sensor due at time ``t_us`` [µs] for state ``s`` (VehicleState order) with true acceleration
    ``accel`` [m/s², NED]; ``dt`` [s] is the control period (the IMU's sample interval). Writes ``out`` and
    returns HIL_SENSOR's ``fields_updated`` for this tick; out[OUT_GPS_NEW] = 1 when a GPS fix (measured at
    out[OUT_GPS_TIME] µs) is delivered this tick.

    Failed sensors (:func:`inject_failure`), as PX4's simulator fails them: one that is off sends nothing (its
    fields not updated, its fix not delivered), one that is stuck sends its last sample again. Every sample is
    still drawn, so a failure changes no other sensor's noise."""
    stuck = clock[FAILED_STUCK]
    kept = out
    if stuck != 0:  # the samples sent last, sent again
        kept = out.copy()
    imu(s, accel, p, rng, bias, dt, out)
    fields = ACCEL_UPDATED | GYRO_UPDATED
    if t_us >= clock[NEXT_MAG]:
        magnetometer(s, p, rng, bias, clock[MAG_INTERVAL] * 1e-6, out)
        clock[NEXT_MAG] += clock[MAG_INTERVAL]
        fields |= MAG_UPDATED
    if t_us >= clock[NEXT_BARO]:
        barometer(s, p, rng, out)
        clock[NEXT_BARO] += clock[BARO_INTERVAL]
        fields |= BARO_UPDATED
    if t_us >= clock[NEXT_GPS]:  # a fix is taken now and joins the queue
        row = queue[(clock[QUEUE_HEAD] + clock[QUEUE_COUNT]) % GPS_QUEUE]
        gps_measure(s, p, rng, bias, row)
        row[Q_TIME] = t_us
        row[Q_RELEASE] = t_us + clock[GPS_DELAY]
        clock[QUEUE_COUNT] += 1
        clock[NEXT_GPS] += clock[GPS_INTERVAL]
    out[OUT_GPS_NEW] = 0.0
    if clock[QUEUE_COUNT] > 0 and queue[clock[QUEUE_HEAD], Q_RELEASE] <= t_us:  # the oldest fix is due
        row = queue[clock[QUEUE_HEAD]]
        out[OUT_GPS_NEW], out[OUT_GPS_TIME] = 1.0, row[Q_TIME]
        for i in range(6):
            out[OUT_GPS_POS + i] = row[Q_POS + i]
        clock[QUEUE_HEAD] = (clock[QUEUE_HEAD] + 1) % GPS_QUEUE
        clock[QUEUE_COUNT] -= 1
    if stuck != 0:
        for bit, first, n in ((SENSOR_GYRO, OUT_GYRO, 3), (SENSOR_ACCEL, OUT_ACCEL, 3), (SENSOR_MAG, OUT_MAG, 3),
                              (SENSOR_BARO, OUT_PRESSURE, 3)):  # fmt: skip
            if stuck & bit:
                for i in range(first, first + n):
                    out[i] = kept[i]
    off = clock[FAILED_OFF]
    if off != 0:
        for bit, updated in ((SENSOR_GYRO, GYRO_UPDATED), (SENSOR_ACCEL, ACCEL_UPDATED), (SENSOR_MAG, MAG_UPDATED),
                             (SENSOR_BARO, BARO_UPDATED)):  # fmt: skip
            if off & bit:
                fields &= ~updated
        if off & SENSOR_GPS:
            out[OUT_GPS_NEW] = 0.0
    return fields


# MAV_CMD_INJECT_FAILURE's sensor units (quadsitl.failures) as clock[FAILED_*]'s bits
SENSOR_UNITS = {failures.GYRO: SENSOR_GYRO, failures.ACCEL: SENSOR_ACCEL, failures.MAG: SENSOR_MAG,
                failures.BARO: SENSOR_BARO, failures.GPS: SENSOR_GPS}  # fmt: skip


def inject_failure(clock: np.ndarray, unit: int, kind: int) -> bool:
    """Fail (or, ``kind`` OK, restore) the sensor ``unit`` (FAILURE_UNIT_SENSOR_*) in the schedule ``clock``: off,
    stuck or OK (:data:`quadsitl.failures.TAKEN`). False, and nothing changed, for a unit or type not taken."""
    if unit not in SENSOR_UNITS or kind not in failures.TAKEN[unit]:
        return False
    bit = SENSOR_UNITS[unit]
    clock[FAILED_OFF] &= ~bit
    clock[FAILED_STUCK] &= ~bit
    if kind == failures.OFF:
        clock[FAILED_OFF] |= bit
    elif kind == failures.STUCK:
        clock[FAILED_STUCK] |= bit
    return True


class Sensors:
    """The sensors of one vehicle, with their noise processes and schedule (the arrays the compiled tick works
    on). ``gravity`` [m/s²]: the plant's; ``home``: the local origin's latitude, longitude [deg] and altitude
    [m AMSL]."""

    def __init__(self, params: SensorParams, period: float, gravity: float,
                 home: tuple[float, float, float] = PX4_HOME) -> None:  # fmt: skip
        self.params = params
        self.period = period
        self.p = sensor_array(params, period, gravity, home)
        self.rng = seed_streams(params.seed, STREAMS)
        self.bias = np.zeros(BIAS_SIZE)
        self.clock = clock_array(params)
        self.queue = np.zeros((GPS_QUEUE, Q_SIZE))
        self.out = np.zeros(OUT_SIZE)
        sensors_reset(self.p, self.rng, self.bias)

    def tick(self, t_us: int, state: tuple, accel: tuple) -> int:
        """The samples of time ``t_us`` [µs] into ``self.out``; returns ``fields_updated`` (see
        :func:`sensors_tick`)."""
        return sensors_tick(t_us, tuple(state), tuple(accel), self.period, self.p, self.rng, self.bias, self.clock,
                            self.queue, self.out)  # fmt: skip

    @property
    def arrays(self) -> tuple:
        """What the plant's compiled tick works on (:func:`sitl.tick.encode_tick`): parameters, random streams,
        noise state, schedule, GPS queue, output."""
        return self.p, self.rng, self.bias, self.clock, self.queue, self.out

    @property
    def gps_new(self) -> bool:
        return self.out[OUT_GPS_NEW] != 0.0
