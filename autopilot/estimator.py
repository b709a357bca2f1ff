"""The autopilot's state estimator: the vehicle's state from its sensors, pure and compiled (docs/sensors.md).

An error-state extended Kalman filter (Solà, "Quaternion kinematics for the error-state Kalman filter",
arXiv:1711.02508, 2017, §5–§7; the same structure as PX4's EKF2, reduced to 15 error states):

- nominal state: position p and velocity v (NED), attitude quaternion q (FRD → NED), gyro bias b_g, accelerometer
  bias b_a; error state δx = (δθ, δv, δp, δb_g, δb_a), δθ a rotation vector in body axes (q_true = q ⊗ Exp(δθ));
- prediction by the IMU every tick (strapdown mechanisation): ω = ω_m − b_g, f = f_m − b_a, a = R(q)·f + g·e_down,
  p⁺ = p + v·dt + a·dt²/2, v⁺ = v + a·dt, q⁺ = q ⊗ Exp(ω·dt); the covariance, as EKF2 predicts it, every
  EKF2_PREDICT_US (``predict_period_s``) and before any fusion, over the time Δ since its last prediction at the
  samples' mean ω and f: P⁺ = F·P·Fᵀ + Q·Δ with F = I + A·Δ,
  A[δθ,δθ] = −[ω]×, A[δθ,δb_g] = −I, A[δv,δθ] = −R·[f]×, A[δv,δb_a] = −R, A[δp,δv] = I;
- updates, one scalar at a time (K = P·hᵀ/(h·P·hᵀ + r)): GPS velocity (N, E, D) and horizontal position, the
  barometer's altitude (relative to its reading at alignment) and the magnetometer's three axes against the
  known Earth field (h(x) = R(q)ᵀ·B, Jacobian [R(q)ᵀ·B]× on δθ);
- the time stamps: each IMU sample's interval is the time from the last one (HIL_SENSOR's ``time_usec``), so a lost
  datagram is a longer interval, predicted over and counted (``io[IMU_GAPS]``); a fix is taken as measured when
  its HIL_GPS ``time_usec`` says (the plant stamps the measurement, ``sensors.gps_delay_s`` before delivery), or,
  stamped at or after the tick it arrives with (a receiver that stamps its delivery), ``gps_delay_s`` before it
  (PX4's EKF2_GPS_DELAY; the preset's ``sensors.gps_delay_s``);
- the GPS delay: every tick's estimated position and velocity are kept for ``HISTORY`` ticks; a fix that arrives
  after it was measured is compared with the estimate of *that* time (older than the history: refused, counted in
  ``io[GPS_TOO_OLD]``), and the correction
  is applied now and to the kept history (so the next fix, measured before this one was applied, does not count
  it twice; the history is kept net of the corrections, their running sum beside it). PX4's EKF2 instead runs
  the whole filter on a delayed time horizon and predicts forward to now; the innovation here is the same, the
  covariance used is the current one (an approximation, good while the delay is short against the filter's time
  constants);
- innovation gates: a measurement whose normalised innovation y²/S exceeds ``gate``² is not fused; when one
  sensor's measurements keep arriving and have all been refused, at least ``REFUSALS_TO_DIVERGE`` in a row over
  ``divergence_time`` seconds (or the state is not finite), the filter reports itself diverged (:data:`DIVERGED`);
- timeouts, distinct from divergence: a sensor from which nothing has arrived for its timeout (``lost_time_s``, and
  at least ``LOST_INTERVALS`` of its intervals; the IMU after ``imu_lost_time_s``) is lost (``io[LOST]``: LOST_GPS,
  LOST_BARO, LOST_MAG, LOST_IMU), each said and
  acted on by the autopilot as PX4 does (docs/sensors.md#when-a-sensor-fails). With the barometer lost, the GPS
  altitude is fused instead (PX4's height source fallback); with the magnetometer lost, the heading is the gyro's;
  with the GPS lost, position and velocity are the IMU's alone, and the autopilot lands; with the IMU lost, the
  filter predicts on its last sample, and the autopilot lands on what remains.

The filter aligns first: for ``align_time`` seconds at rest it averages the accelerometer (roll and pitch), the
magnetometer (yaw, with the known declination) and the barometer (the altitude reference), then starts at the
given position. Its output is the :class:`quadsitl.state.VehicleState` the controllers take (Euler-angle rates
from the bias-corrected gyro, by the inverse of eq (1)).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from quadsitl.compiled_frames import (
    body_rates_to_euler_rates,
    body_to_ned,
    euler_to_quaternion,
    ned_to_body,
    normalize_quaternion,
    quaternion_multiply,
    quaternion_to_euler,
    rotation_vector_to_quaternion,
)
from quadsitl.config import SensorParams
from quadsitl.earth import magnetic_field_ned
from quadsitl.hil import (
    BARO_NEW,
    GPS_NEW,
    IMU_NEW,
    MAG_NEW,
    Z_ACCEL,
    Z_BARO,
    Z_GPS_POS,
    Z_GPS_TIME,
    Z_GPS_VEL,
    Z_GYRO,
    Z_MAG,
    Z_SIZE,
)
from quadsitl.jit import jit
from quadsitl.state import VehicleState

# ESTIMATOR_STATUS's flags (MAVLink's ESTIMATOR_STATUS_FLAGS)
ESTIMATOR_ATTITUDE, ESTIMATOR_VELOCITY_HORIZ, ESTIMATOR_VELOCITY_VERT, ESTIMATOR_POS_HORIZ_REL = 1, 2, 4, 8
ESTIMATOR_POS_HORIZ_ABS, ESTIMATOR_POS_VERT_ABS, ESTIMATOR_GPS_GLITCH = 16, 32, 1024

# ---- the nominal state (x) and the error state (rows and columns of P) ---------------------------------------
X_P, X_V, X_Q, X_BG, X_BA, X_SIZE = 0, 3, 6, 10, 13, 16
DTH, DV, DP, DBG, DBA, N = 0, 3, 6, 9, 12, 15
HISTORY = 1024  # ticks of estimated position and velocity kept for delayed fixes
CORRECTION = HISTORY  # hist's last row: the corrections applied since alignment, which the history is kept net of


# ---- the parameters (e) -----------------------------------------------------------------------------------
(GYRO_NOISE, ACC_NOISE, GYRO_BIAS_NOISE, ACC_BIAS_NOISE, GPS_POS_NOISE, GPS_VEL_NOISE, GPS_VZ_NOISE, BARO_NOISE,
 MAG_NOISE, FIELD_N, FIELD_E, FIELD_D, GRAVITY, GATE, INIT_TILT, INIT_YAW, INIT_VEL, INIT_POS, INIT_ALT,
 INIT_GYRO_BIAS, INIT_ACC_BIAS, PREDICT_PERIOD, PARAM_SIZE) = range(23)  # fmt: skip

# ---- the integer bookkeeping (io) ---------------------------------------------------------------------------
# ticks seen, alignment ticks, GPS delay [ticks], divergence limits [ticks], the flags, and per measurement group the
# ticks since one was last fused (SINCE_*) and the refusals in a row (ROW_*); measurements refused in all; the last
# IMU sample's time [µs] and its tick (of the clock: time / period), the IMU intervals lost, the fixes older than the
# history; per sensor the tick it was last heard at (HEARD_*) and its timeout [ticks] (LOST_*_TICKS); what is lost.
(TICK, ALIGN_TICKS, DELAY_TICKS, DIVERGE_TICKS, ALIGNED, DIVERGED, SINCE_GPS_POS, SINCE_GPS_VEL, SINCE_BARO,
 SINCE_MAG, REFUSED, LAST_USEC, NOW_TICK, IMU_GAPS, GPS_TOO_OLD, ROW_GPS_POS, ROW_GPS_VEL, ROW_BARO, ROW_MAG,
 HEARD_GPS, HEARD_BARO, HEARD_MAG, HEARD_IMU, LOST_GPS_TICKS, LOST_BARO_TICKS, LOST_MAG_TICKS, LOST_IMU_TICKS, LOST,
 IO_SIZE) = range(29)  # fmt: skip
GROUPS = 4  # GPS position, GPS velocity, baro, mag: io[SINCE_GPS_POS + g], io[ROW_GPS_POS + g]
# io[LOST]; io[HEARD_GPS + i], io[LOST_GPS_TICKS + i] for bit 1 << i
LOST_GPS, LOST_BARO, LOST_MAG, LOST_IMU, SENSORS = 1, 2, 4, 8, 4
REFUSALS_TO_DIVERGE = 3  # one refused fix of a 1 Hz GPS is not a divergence
LOST_INTERVALS = 3  # a sensor is lost after at least this many of its intervals without a measurement

# ---- the accumulators of the alignment (acc) and the innovation test ratios (ratio) -------------------------
# then, once aligned, the samples since the covariance's last prediction: their delta angle [rad] and delta velocity
# [m/s] (FRD, bias-corrected) and their time [s] (A_DANG..A_DT: _catch_up)
(A_ACCEL, A_MAG, A_BARO, A_N_IMU, A_N_MAG, A_N_BARO, A_BARO_REF, A_DANG, A_DVEL, A_DT,
 ACC_SIZE) = 0, 3, 6, 7, 8, 9, 10, 11, 14, 17, 18  # fmt: skip

# ---- the calibration (cal): what is applied to each new measurement before the filter takes it, as PX4's sensor
# calibrations apply it (body = R_board·(raw − offset): autopilot.calibration), and what a calibration running collects
# from the corrected samples (their sums and count since it last took them; only while CAL_COLLECT is set)
(CAL_GYRO_OFFSET, CAL_BOARD, CAL_BOARD_ON, CAL_COLLECT, CAL_SUM_GYRO, CAL_SUM_ACCEL, CAL_COUNT,
 CAL_SIZE) = 0, 3, 12, 13, 14, 17, 20, 21  # fmt: skip

# ---- the measurements of a tick (z: Z_*) and which are new (flags: MAG_NEW, BARO_NEW, GPS_NEW) are laid out as
# the plant link's decoder writes them (quadsitl.hil)


@dataclass(frozen=True)
class EstimatorParams:
    """What the filter assumes of the sensors (its own figures, as PX4's EKF2_* parameters: larger than the
    simulated sensors' own, to cover what the model leaves out) and its settings. Units in the names."""

    gyro_noise_rad_s_sqrt_hz: float = 1.5e-3  # process noise: gyro white noise density
    accel_noise_m_s2_sqrt_hz: float = 1.5e-2
    gyro_bias_noise_rad_s2_sqrt_hz: float = 1e-5  # bias random walks
    accel_bias_noise_m_s3_sqrt_hz: float = 1e-4
    gps_pos_noise_m: float = 0.5  # EKF2_GPS_P_NOISE
    gps_vel_noise_m_s: float = 0.1
    gps_vz_noise_m_s: float = 0.2
    baro_noise_m: float = 0.1
    mag_noise_gauss: float = 5e-3
    gps_delay_s: float = 0.12  # EKF2_GPS_DELAY, for fixes stamped at delivery (the preset's sensors.gps_delay_s)
    gate_sigma: float = 5.0  # innovation gate
    divergence_time_s: float = 1.0
    lost_time_s: float = 0.5  # a sensor silent this long (and LOST_INTERVALS of its intervals) is lost
    imu_lost_time_s: float = 0.1  # the IMU, the filter's clock: ticks without a sample predict on the last one
    align_time_s: float = 1.0
    init_tilt_rad: float = 0.01  # initial standard deviations (tilt: beyond the accelerometer bias's share)
    init_yaw_rad: float = 0.1
    init_vel_m_s: float = 0.05  # the alignment is at rest
    init_pos_m: float = 2.0
    init_alt_m: float = 0.2  # without a barometer sample during the alignment (else: the baro noise / √samples)
    init_gyro_bias_rad_s: float = 0.01
    init_accel_bias_m_s2: float = 0.05  # PX4's EKF2_ABIAS_INIT is 0.2; see docs/sensors.md
    predict_period_s: float = 0.01  # EKF2_PREDICT_US: the covariance's prediction period (the state's: every sample)


def parameter_array(e: EstimatorParams, field_ned: tuple[float, float, float], gravity: float) -> np.ndarray:
    """The figures the compiled filter reads: ``field_ned`` the Earth's field at home [gauss, NED], ``gravity``."""
    return np.array(
        [e.gyro_noise_rad_s_sqrt_hz, e.accel_noise_m_s2_sqrt_hz, e.gyro_bias_noise_rad_s2_sqrt_hz,
         e.accel_bias_noise_m_s3_sqrt_hz, e.gps_pos_noise_m, e.gps_vel_noise_m_s, e.gps_vz_noise_m_s, e.baro_noise_m,
         e.mag_noise_gauss, *field_ned, gravity, e.gate_sigma, e.init_tilt_rad, e.init_yaw_rad, e.init_vel_m_s,
         e.init_pos_m, e.init_alt_m, e.init_gyro_bias_rad_s, e.init_accel_bias_m_s2,
         e.predict_period_s - 1e-9],  # a period's worth of samples, however their intervals round
        dtype=np.float64,
    )  # fmt: skip


# report(): the newest measurements the filter took (accelerometer [m/s²], gyro [rad/s], magnetometer [gauss], FRD,
# after the calibration; barometric altitude [m AMSL]), then its health as ESTIMATOR_STATUS says it
REPORT_ACCEL, REPORT_GYRO, REPORT_MAG, REPORT_BARO, REPORT_FLAGS, REPORT_SIZE = 0, 3, 6, 9, 10, 17
VALID = (ESTIMATOR_ATTITUDE | ESTIMATOR_VELOCITY_HORIZ | ESTIMATOR_VELOCITY_VERT | ESTIMATOR_POS_HORIZ_REL
         | ESTIMATOR_POS_HORIZ_ABS | ESTIMATOR_POS_VERT_ABS)  # fmt: skip


@jit(inline=True)
def report(z: np.ndarray, x: np.ndarray, P: np.ndarray, io: np.ndarray, ratio: np.ndarray) -> tuple:
    """The filter's report (REPORT_SIZE floats, REPORT_*), for every reader: the telemetry's ``sensors`` record (the
    autopilot's tick and ``sim``), HIGHRES_IMU and ESTIMATOR_STATUS. First the newest measurements it took (``z``:
    accelerometer, gyro, magnetometer, barometric altitude); then its health as PX4's EKF2 reports it: the flags of
    what is valid (ESTIMATOR_*: attitude, velocity, relative and absolute horizontal position, absolute vertical
    position; none while aligning or diverged or the IMU is lost; no absolute horizontal position while the GPS is
    lost; GPS_GLITCH while GPS positions are refused), the innovation test ratios (> 1: refused) of the velocity,
    horizontal position, vertical position (barometer) and magnetometer (each the largest of its components, at the
    last fusion), and the 1σ horizontal and vertical position accuracy [m] from P."""
    aligned = io[ALIGNED] != 0
    valid = aligned and io[DIVERGED] == 0
    flags = VALID if valid else 0
    if valid and io[LOST] & LOST_GPS:  # dead reckoning: no absolute horizontal position
        flags &= ~ESTIMATOR_POS_HORIZ_ABS
    if valid and io[LOST] & LOST_IMU:  # predicting on the last samples: nothing is to be trusted
        flags = 0
    r = ratio
    if aligned and max(r[0], r[1]) > 1.0:
        flags |= ESTIMATOR_GPS_GLITCH
    return (z[Z_ACCEL], z[Z_ACCEL + 1], z[Z_ACCEL + 2], z[Z_GYRO], z[Z_GYRO + 1], z[Z_GYRO + 2], z[Z_MAG], z[Z_MAG + 1],
            z[Z_MAG + 2], z[Z_BARO], float(flags), max(r[2], r[3], r[4]), max(r[0], r[1]), r[5], max(r[6], r[7], r[8]),
            math.sqrt(max(P[DP, DP] + P[DP + 1, DP + 1], 0.0)), math.sqrt(max(P[DP + 2, DP + 2], 0.0)))  # fmt: skip


@jit(inline=True)
def report_of(est: tuple) -> tuple:
    """:func:`report` of a filter's arrays (:attr:`Estimator.arrays`, as the compiled ticks carry them)."""
    return report(est[0], est[1], est[2], est[4], est[7])


@jit(inline=True)
def _quaternion(x: np.ndarray) -> tuple[float, float, float, float]:
    return (x[X_Q], x[X_Q + 1], x[X_Q + 2], x[X_Q + 3])


@jit
def calibrated(flags: int, z: np.ndarray, cal: np.ndarray) -> None:
    """The new measurements in ``z`` (``flags``: IMU_NEW, MAG_NEW) corrected in place by the calibration ``cal``:
    the gyro's offsets subtracted, then gyro, accelerometer and magnetometer turned from the sensors' axes to the
    body's by the board rotation (when not the identity); the corrected IMU sample collected while a calibration
    runs."""
    if flags & IMU_NEW:
        for i in range(3):
            z[Z_GYRO + i] -= cal[CAL_GYRO_OFFSET + i]
        if cal[CAL_BOARD_ON] != 0.0:
            _rotate(z, Z_GYRO, cal)
            _rotate(z, Z_ACCEL, cal)
        if cal[CAL_COLLECT] != 0.0:
            for i in range(3):
                cal[CAL_SUM_GYRO + i] += z[Z_GYRO + i]
                cal[CAL_SUM_ACCEL + i] += z[Z_ACCEL + i]
            cal[CAL_COUNT] += 1.0
    if flags & MAG_NEW and cal[CAL_BOARD_ON] != 0.0:
        _rotate(z, Z_MAG, cal)


@jit(inline=True)
def _rotate(z: np.ndarray, at: int, cal: np.ndarray) -> None:
    a, b, c = z[at], z[at + 1], z[at + 2]
    for i in range(3):
        r = CAL_BOARD + 3 * i
        z[at + i] = cal[r] * a + cal[r + 1] * b + cal[r + 2] * c


@jit
def align(x: np.ndarray, P: np.ndarray, acc: np.ndarray, e: np.ndarray, p0: tuple) -> None:
    """Start the filter from the alignment's averages: roll and pitch from the mean specific force, yaw from the
    mean magnetic field (tilt-compensated, with the field's declination), the barometer's reference altitude,
    position ``p0`` [m, NED], at rest, biases zero; P diagonal from the initial standard deviations."""
    fx, fy, fz = acc[A_ACCEL] / acc[A_N_IMU], acc[A_ACCEL + 1] / acc[A_N_IMU], acc[A_ACCEL + 2] / acc[A_N_IMU]
    roll = math.atan2(-fy, -fz)
    pitch = math.atan2(fx, math.sqrt(fy * fy + fz * fz))
    yaw = 0.0
    if acc[A_N_MAG] > 0:
        m = body_to_ned(euler_to_quaternion(roll, pitch, 0.0), acc[A_MAG] / acc[A_N_MAG],
                        acc[A_MAG + 1] / acc[A_N_MAG], acc[A_MAG + 2] / acc[A_N_MAG])  # fmt: skip
        yaw = math.atan2(e[FIELD_E], e[FIELD_N]) - math.atan2(m[1], m[0])
    q = euler_to_quaternion(roll, pitch, yaw)
    x[:] = 0.0
    for i in range(3):
        x[X_P + i] = p0[i]
    for i in range(4):
        x[X_Q + i] = q[i]
    acc[A_BARO_REF] = (acc[A_BARO] / acc[A_N_BARO] + p0[2]) if acc[A_N_BARO] > 0 else math.nan  # baro alt at z = 0
    P[:, :] = 0.0
    sd = (e[INIT_TILT], e[INIT_TILT], e[INIT_YAW], e[INIT_VEL], e[INIT_VEL], e[INIT_VEL], e[INIT_POS], e[INIT_POS],
          e[INIT_ALT], e[INIT_GYRO_BIAS], e[INIT_GYRO_BIAS], e[INIT_GYRO_BIAS], e[INIT_ACC_BIAS], e[INIT_ACC_BIAS],
          e[INIT_ACC_BIAS])  # fmt: skip
    for i in range(N):
        P[i, i] = sd[i] * sd[i]
    if acc[A_N_BARO] > 0:  # the altitude's reference is the mean of the barometer's samples: known to r/n
        P[DP + 2, DP + 2] = e[BARO_NOISE] * e[BARO_NOISE] / acc[A_N_BARO]
    # The tilt came from the accelerometer, so it carries the accelerometer's bias: level, an unknown bias δb
    # tilts the estimate by δθ_x = δb_y/g (roll), δθ_y = −δb_x/g (pitch). Said so in P, the velocity fixes
    # correct tilt and bias together instead of trading one for the other.
    var_b, g = e[INIT_ACC_BIAS] ** 2, e[GRAVITY]
    P[DTH, DTH] += var_b / (g * g)
    P[DTH + 1, DTH + 1] += var_b / (g * g)
    P[DTH, DBA + 1] = P[DBA + 1, DTH] = var_b / g
    P[DTH + 1, DBA] = P[DBA, DTH + 1] = -var_b / g


@jit(inline=True)
def _f_times(tt: tuple, vt: tuple, vb: tuple, dt: float, u: np.ndarray, out: np.ndarray) -> None:
    """out = F·u for F = I + A·dt given by its blocks that are not I or 0: ``tt`` = F[δθ, δθ], ``vt`` = F[δv, δθ],
    ``vb`` = F[δv, δb_a] (row-major, 9 each); F[δθ, δb_g] = −I·dt, F[δp, δv] = I·dt. Each sum runs over the row's
    nonzero entries in column order from 0.0, so it equals the dense product's to the bit."""
    for i in range(3):
        out[DTH + i] = (0.0 + tt[3 * i] * u[DTH] + tt[3 * i + 1] * u[DTH + 1] + tt[3 * i + 2] * u[DTH + 2]
                        - dt * u[DBG + i])  # fmt: skip
        out[DV + i] = (0.0 + vt[3 * i] * u[DTH] + vt[3 * i + 1] * u[DTH + 1] + vt[3 * i + 2] * u[DTH + 2] + u[DV + i]
                       + vb[3 * i] * u[DBA] + vb[3 * i + 1] * u[DBA + 1] + vb[3 * i + 2] * u[DBA + 2])  # fmt: skip
        out[DP + i] = 0.0 + dt * u[DV + i] + u[DP + i]
        out[DBG + i] = 0.0 + u[DBG + i]
        out[DBA + i] = 0.0 + u[DBA + i]


@jit(inline=True)
def predict_state(x: np.ndarray, gyro: tuple, accel: tuple, dt: float, e: np.ndarray) -> tuple:
    """The strapdown prediction of the nominal state over ``dt`` [s] by the IMU sample (``gyro`` [rad/s], ``accel``
    [m/s²], FRD). Returns the bias-corrected rate ω and specific force f (FRD) it flew on."""
    q = _quaternion(x)
    w = (gyro[0] - x[X_BG], gyro[1] - x[X_BG + 1], gyro[2] - x[X_BG + 2])
    f = (accel[0] - x[X_BA], accel[1] - x[X_BA + 1], accel[2] - x[X_BA + 2])
    a = body_to_ned(q, f[0], f[1], f[2])
    a = (a[0], a[1], a[2] + e[GRAVITY])
    for i in range(3):
        x[X_P + i] += x[X_V + i] * dt + 0.5 * a[i] * dt * dt
        x[X_V + i] += a[i] * dt
    q = normalize_quaternion(quaternion_multiply(q, rotation_vector_to_quaternion(w[0] * dt, w[1] * dt, w[2] * dt)))
    for i in range(4):
        x[X_Q + i] = q[i]
    return w, f


@jit
def predict_covariance(x: np.ndarray, P: np.ndarray, FP: np.ndarray, w: tuple, f: tuple, dt: float,
                       e: np.ndarray) -> None:  # fmt: skip
    """P = F·P·Fᵀ + Q·dt over ``dt`` [s] with F = I + A·dt linearised at the rate ``w`` and specific force ``f``
    (bias-corrected, FRD) and the attitude now (``FP``: (N + 2)×N scratch: F·P, then two rows of work)."""
    q = _quaternion(x)
    # F = I + A·dt (R the rotation after the attitude step: the same to first order), by its blocks:
    tt = (1.0, w[2] * dt, -w[1] * dt, -w[2] * dt, 1.0, w[0] * dt, w[1] * dt, -w[0] * dt, 1.0)  # I − [ω]×·dt
    c0 = body_to_ned(q, 0.0, f[2], -f[1])  # −R·[f]×·dt: column j of [f]× is f × e_j
    c1 = body_to_ned(q, -f[2], 0.0, f[0])
    c2 = body_to_ned(q, f[1], -f[0], 0.0)
    vt = (-c0[0] * dt, -c1[0] * dt, -c2[0] * dt, -c0[1] * dt, -c1[1] * dt, -c2[1] * dt, -c0[2] * dt, -c1[2] * dt,
          -c2[2] * dt)  # fmt: skip
    r0 = body_to_ned(q, 1.0, 0.0, 0.0)  # −R·dt
    r1 = body_to_ned(q, 0.0, 1.0, 0.0)
    r2 = body_to_ned(q, 0.0, 0.0, 1.0)
    vb = (-r0[0] * dt, -r1[0] * dt, -r2[0] * dt, -r0[1] * dt, -r1[1] * dt, -r2[1] * dt, -r0[2] * dt, -r1[2] * dt,
          -r2[2] * dt)  # fmt: skip
    # P = F·P·Fᵀ + Q: (F·P)'s column j is F times P's row j (P is symmetric); then row i of F·P·Fᵀ is F times
    # row i of F·P (the upper triangle kept, mirrored)
    col, row = FP[N], FP[N + 1]
    for j in range(N):
        _f_times(tt, vt, vb, dt, P[j], col)
        for i in range(N):
            FP[i, j] = col[i]
    for i in range(N):
        _f_times(tt, vt, vb, dt, FP[i], row)
        for j in range(i, N):
            P[i, j] = row[j]
            P[j, i] = row[j]
    for i in range(3):
        P[DTH + i, DTH + i] += e[GYRO_NOISE] * e[GYRO_NOISE] * dt
        P[DV + i, DV + i] += e[ACC_NOISE] * e[ACC_NOISE] * dt
        P[DBG + i, DBG + i] += e[GYRO_BIAS_NOISE] * e[GYRO_BIAS_NOISE] * dt
        P[DBA + i, DBA + i] += e[ACC_BIAS_NOISE] * e[ACC_BIAS_NOISE] * dt


@jit
def predict(x: np.ndarray, P: np.ndarray, FP: np.ndarray, gyro: tuple, accel: tuple, dt: float,
            e: np.ndarray) -> None:  # fmt: skip
    """The state's and the covariance's prediction over ``dt`` [s] by one IMU sample (:func:`predict_state`, then
    :func:`predict_covariance` on what it flew)."""
    w, f = predict_state(x, gyro, accel, dt, e)
    predict_covariance(x, P, FP, w, f, dt, e)


@jit
def _catch_up(x: np.ndarray, P: np.ndarray, FP: np.ndarray, acc: np.ndarray, e: np.ndarray) -> None:
    """The covariance brought to now over the samples since its last prediction (acc[A_DT] [s]), linearised at
    their mean rate and specific force (the delta angle and delta velocity over the interval), as EKF2 predicts
    its covariance on the IMU's samples down-sampled to EKF2_PREDICT_US."""
    dt = acc[A_DT]
    if dt <= 0.0:
        return
    w = (acc[A_DANG] / dt, acc[A_DANG + 1] / dt, acc[A_DANG + 2] / dt)
    f = (acc[A_DVEL] / dt, acc[A_DVEL + 1] / dt, acc[A_DVEL + 2] / dt)
    predict_covariance(x, P, FP, w, f, dt, e)
    for i in range(A_DANG, A_DT + 1):
        acc[i] = 0.0


@jit
def inject(x: np.ndarray, dx: np.ndarray) -> None:
    """Fold the estimated error ``dx`` into the nominal state (q ⊗ Exp(δθ)); the error is then zero again."""
    q = quaternion_multiply(_quaternion(x), rotation_vector_to_quaternion(dx[DTH], dx[DTH + 1], dx[DTH + 2]))
    q = normalize_quaternion(q)
    for i in range(4):
        x[X_Q + i] = q[i]
    for i in range(3):
        x[X_V + i] += dx[DV + i]
        x[X_P + i] += dx[DP + i]
        x[X_BG + i] += dx[DBG + i]
        x[X_BA + i] += dx[DBA + i]


@jit
def fuse(x: np.ndarray, P: np.ndarray, h: np.ndarray, y: float, r: float, gate: float, pht: np.ndarray,
         dx: np.ndarray) -> float:  # fmt: skip
    """One scalar measurement: innovation ``y``, Jacobian row ``h`` (N), noise variance ``r``. Fused unless its
    normalised innovation y²/S exceeds gate²; returns that test ratio y²/(S·gate²) (fused when ≤ 1). ``dx``
    holds the correction applied (zero when refused)."""
    # P·hᵀ over h's nonzero entries (at most three: every measurement here has one or two), in the dense
    # product's order from 0.0, so to the bit the dense product; a wider h takes the dense product.
    j0, j1, j2, wide = -1, -1, -1, False
    for j in range(N):
        if h[j] != 0.0:
            if j0 < 0:
                j0 = j
            elif j1 < 0:
                j1 = j
            elif j2 < 0:
                j2 = j
            else:
                wide = True
    s = r
    for i in range(N):
        acc = 0.0
        if wide:
            for j in range(N):
                acc += P[i, j] * h[j]
        else:
            if j0 >= 0:
                acc += P[i, j0] * h[j0]
            if j1 >= 0:
                acc += P[i, j1] * h[j1]
            if j2 >= 0:
                acc += P[i, j2] * h[j2]
        pht[i] = acc
        s += h[i] * acc
    ratio = y * y / (s * gate * gate)
    dx[:] = 0.0
    if not ratio <= 1.0:  # also refuses a NaN
        return ratio
    for i in range(N):
        dx[i] = pht[i] / s * y
    for i in range(N):
        for j in range(i, N):
            v = P[i, j] - pht[i] * pht[j] / s
            P[i, j] = v
            P[j, i] = v
    inject(x, dx)
    return ratio


@jit(inline=True)
def _fused(io: np.ndarray, group: int, ratio: float) -> None:
    """Bookkeeping of a measurement of ``group``: fused (all its components: the clock since the last fusion
    and the refusals in a row restart) or refused (the largest test ratio ``ratio`` above 1)."""
    if ratio <= 1.0:
        io[SINCE_GPS_POS + group] = 0
        io[ROW_GPS_POS + group] = 0
    else:
        io[REFUSED] += 1
        io[ROW_GPS_POS + group] += 1


@jit
def _reset_to_gps(z: np.ndarray, x: np.ndarray, P: np.ndarray, hist: np.ndarray, then: int, e: np.ndarray) -> None:
    """A fix after the GPS was lost (the dead-reckoned position has drifted beyond any gate): the horizontal position
    and the velocity take the fix's (its innovation against the estimate of its time, hist[then], applied whole:
    :func:`_reset_axis`), as PX4's EKF2 resets to the GPS when it comes back."""
    for i in range(5):
        if i < 2:
            at, col = X_P + i, DP + i
            value = z[Z_GPS_POS + i] - (hist[then, i] + hist[CORRECTION, i]) + x[at]
            r = e[GPS_POS_NOISE] ** 2
        else:
            at, col = X_V + i - 2, DV + i - 2
            value = z[Z_GPS_VEL + i - 2] - (hist[then, 1 + i] + hist[CORRECTION, 1 + i]) + x[at]
            r = (e[GPS_VZ_NOISE] if i == 4 else e[GPS_VEL_NOISE]) ** 2
        _reset_axis(x, P, hist, at, col, value, r)


@jit
def _reset_axis(x: np.ndarray, P: np.ndarray, hist: np.ndarray, at: int, col: int, value: float, r: float) -> None:
    """x[at] (a position or velocity component, X_P..X_V + 2) set to ``value``, the history shifted with it, its error
    state ``col``'s variance ``r`` and its correlations cleared."""
    hist[CORRECTION, at - X_P] += value - x[at]  # X_P..X_V + 2 are the history's columns 0..5
    x[at] = value
    for j in range(N):
        P[col, j] = 0.0
        P[j, col] = 0.0
    P[col, col] = r


@jit(inline=True)
def _interval(t_usec: int, period: float, io: np.ndarray) -> int:
    """The IMU sample stamped ``t_usec`` [µs]: how many control periods since the last one (1, or more when
    datagrams were lost: counted in io[IMU_GAPS]; 1 for the first, or after a jump of the clock back or by more
    than the history, a restarted plant); io[NOW_TICK] becomes its tick."""
    period_us = period * 1e6
    k = round(t_usec / period_us)
    steps = 1
    if io[LAST_USEC] >= 0:
        n = round((t_usec - io[LAST_USEC]) / period_us)
        if 1 <= n <= HISTORY:
            steps = n
            io[IMU_GAPS] += n - 1
    io[LAST_USEC] = t_usec
    io[NOW_TICK] = k
    return steps


@jit(inline=True)
def estimator_tick(flags: int, z: np.ndarray, t_usec: int, period: float, p0: tuple, x: np.ndarray, P: np.ndarray,
                   hist: np.ndarray, io: np.ndarray, acc: np.ndarray, e: np.ndarray, ratio: np.ndarray,
                   scratch: np.ndarray, out: np.ndarray) -> None:  # fmt: skip
    """One control tick, stamped ``t_usec`` [µs] (HIL_SENSOR's time_usec; ``period`` [s] the control period): the IMU
    sample z[Z_GYRO], z[Z_ACCEL] (new when ``flags`` has IMU_NEW, else the last one again), and the magnetometer,
    barometer altitude [m AMSL] and GPS fix (position [m, NED], velocity [m/s, NED], measured at z[Z_GPS_TIME] [µs])
    when ``flags`` says they are new. ``out`` gets the state in VehicleState order (12; zeros while aligning);
    ``ratio`` the last test ratio of each group (GPS pos N/E, GPS vel N/E/D, baro, mag x/y/z, GPS altitude)."""
    tick = io[TICK]
    io[TICK] = tick + 1
    steps = _interval(t_usec, period, io)
    k = io[NOW_TICK]
    dt = steps * period
    gyro = (z[Z_GYRO], z[Z_GYRO + 1], z[Z_GYRO + 2])
    if io[ALIGNED] == 0:  # average the sensors at rest, then start
        for i in range(3):
            acc[A_ACCEL + i] += z[Z_ACCEL + i]
        acc[A_N_IMU] += 1
        if flags & MAG_NEW:
            for i in range(3):
                acc[A_MAG + i] += z[Z_MAG + i]
            acc[A_N_MAG] += 1
        if flags & BARO_NEW:
            acc[A_BARO] += z[Z_BARO]
            acc[A_N_BARO] += 1
        out[:] = 0.0
        if tick + 1 >= io[ALIGN_TICKS]:
            align(x, P, acc, e, p0)
            io[ALIGNED] = 1
            hist[:, :] = 0.0
            for j in range(HISTORY):
                for i in range(3):
                    hist[j, i] = x[X_P + i]
            for i in range(SENSORS):  # every sensor's timeout counts from here
                io[HEARD_GPS + i] = k
        return
    FP = scratch[: N + 2, :]
    h, pht, dx = scratch[N + 2, :], scratch[N + 3, :], scratch[N + 4, :]
    w, f = predict_state(x, gyro, (z[Z_ACCEL], z[Z_ACCEL + 1], z[Z_ACCEL + 2]), dt, e)
    for i in range(3):
        acc[A_DANG + i] += w[i] * dt
        acc[A_DVEL + i] += f[i] * dt
    acc[A_DT] += dt
    # The covariance at EKF2's rate (EKF2_PREDICT_US), and before any measurement is fused or reset against it.
    if acc[A_DT] >= e[PREDICT_PERIOD] or flags & (BARO_NEW | MAG_NEW | GPS_NEW):
        _catch_up(x, P, FP, acc, e)
    # This tick's estimate joins the history net of the corrections so far (hist[CORRECTION]): an estimate of the
    # history read back plus the corrections then is the estimate shifted by every correction applied since. The
    # history is kept by the clock's ticks: those of lost datagrams get this estimate too.
    for j in range(steps):
        now = (k - j) % HISTORY
        for i in range(3):
            hist[now, i] = x[X_P + i] - hist[CORRECTION, i]
            hist[now, 3 + i] = x[X_V + i] - hist[CORRECTION, 3 + i]
    gate = e[GATE]
    for g in range(GROUPS):
        io[SINCE_GPS_POS + g] += steps
    if flags & BARO_NEW:
        io[HEARD_BARO] = k
    if flags & MAG_NEW:
        io[HEARD_MAG] = k
    if flags & GPS_NEW:
        io[HEARD_GPS] = k
    if flags & IMU_NEW:
        io[HEARD_IMU] = k
    if flags & BARO_NEW:  # altitude above the origin: −p_D
        if io[LOST] & LOST_BARO:  # back after a loss: the height reset to it, the reference again (PX4's reset)
            _reset_axis(x, P, hist, X_P + 2, DP + 2, acc[A_BARO_REF] - z[Z_BARO], e[BARO_NOISE] ** 2)
        h[:] = 0.0
        h[DP + 2] = -1.0
        ratio[5] = fuse(x, P, h, (z[Z_BARO] - acc[A_BARO_REF]) + x[X_P + 2], e[BARO_NOISE] ** 2, gate, pht, dx)
        _fused(io, 2, ratio[5])
    if flags & MAG_NEW:  # the body-frame field Rᵀ·B, Jacobian [Rᵀ·B]× on δθ
        for i in range(3):
            m = ned_to_body(_quaternion(x), e[FIELD_N], e[FIELD_E], e[FIELD_D])
            h[:] = 0.0
            if i == 0:
                h[DTH + 1], h[DTH + 2] = -m[2], m[1]
            elif i == 1:
                h[DTH], h[DTH + 2] = m[2], -m[0]
            else:
                h[DTH], h[DTH + 1] = -m[1], m[0]
            ratio[6 + i] = fuse(x, P, h, z[Z_MAG + i] - m[i], e[MAG_NOISE] ** 2, gate, pht, dx)
        _fused(io, 3, max(ratio[6], ratio[7], ratio[8]))
    age = k - round(z[Z_GPS_TIME] / (period * 1e6))  # [ticks] since the fix was measured, by its time stamp
    if age <= 0:  # stamped when delivered: measured EKF2_GPS_DELAY before
        age = io[DELAY_TICKS]
    if flags & GPS_NEW and age >= HISTORY:
        io[GPS_TOO_OLD] += 1
    elif flags & GPS_NEW and io[LOST] & LOST_GPS:  # back after a loss: the position and velocity reset to the fix
        _reset_to_gps(z, x, P, hist, (k - age) % HISTORY, e)
        _fused(io, 0, 0.0)
        _fused(io, 1, 0.0)
    elif flags & GPS_NEW:  # against the estimate of the fix's time, kept in hist; corrections shift the history too
        then = (k - age) % HISTORY
        # the altitude too while the barometer is lost (PX4's height source fallback)
        last = 6 if io[LOST] & LOST_BARO else 5
        for i in range(last):
            h[:] = 0.0
            if i < 2:
                h[DP + i] = 1.0
                y = z[Z_GPS_POS + i] - (hist[then, i] + hist[CORRECTION, i])
                r = e[GPS_POS_NOISE] ** 2
            elif i < 5:
                h[DV + i - 2] = 1.0
                y = z[Z_GPS_VEL + i - 2] - (hist[then, 1 + i] + hist[CORRECTION, 1 + i])
                r = (e[GPS_VZ_NOISE] if i == 4 else e[GPS_VEL_NOISE]) ** 2
            else:
                h[DP + 2] = 1.0
                y = z[Z_GPS_POS + 2] - (hist[then, 2] + hist[CORRECTION, 2])
                r = (1.5 * e[GPS_POS_NOISE]) ** 2  # the vertical error of a fix: 1.5 times the horizontal
            at = i if i < 5 else 9  # ratio[9]: the GPS altitude
            ratio[at] = fuse(x, P, h, y, r, gate, pht, dx)
            if ratio[at] <= 1.0:
                for j in range(3):
                    hist[CORRECTION, j] += dx[DP + j]
                    hist[CORRECTION, 3 + j] += dx[DV + j]
        _fused(io, 0, max(ratio[0], ratio[1]))
        _fused(io, 1, max(ratio[2], ratio[3], ratio[4]))
        if last == 6:  # the height's clock: the GPS altitude stands in for the barometer
            _fused(io, 2, ratio[9])
    lost = 0
    for i in range(SENSORS):
        if k - io[HEARD_GPS + i] > io[LOST_GPS_TICKS + i]:
            lost |= 1 << i
    io[LOST] = lost
    diverged = False
    for g in range(GROUPS):
        if io[ROW_GPS_POS + g] >= REFUSALS_TO_DIVERGE and io[SINCE_GPS_POS + g] > io[DIVERGE_TICKS]:
            diverged = True
    for i in range(X_SIZE):
        if not math.isfinite(x[i]):
            diverged = True
    io[DIVERGED] = 1 if diverged else 0
    roll, pitch, yaw = quaternion_to_euler(x[X_Q], x[X_Q + 1], x[X_Q + 2], x[X_Q + 3])
    rates = body_rates_to_euler_rates(roll, pitch, gyro[0] - x[X_BG], gyro[1] - x[X_BG + 1], gyro[2] - x[X_BG + 2])
    for i in range(6):
        out[i] = x[i]
    out[6], out[7], out[8] = roll, pitch, yaw
    out[9], out[10], out[11] = rates


class Estimator:
    """The filter of one vehicle (its arrays), for the autopilot process and the tests.

    ``period`` [s]: the control period (one IMU sample a tick); ``field_ned``: the Earth's field at home [gauss,
    NED], as the sensors' preset section gives it; ``start``: the position [m, NED] at alignment (the vehicle
    starts at rest there); ``rates``: the GPS's, barometer's and magnetometer's rates [Hz] (their timeouts are at
    least LOST_INTERVALS of their intervals; None: ``lost_time_s`` alone)."""

    def __init__(
        self,
        period: float,
        gravity: float,
        field_ned: tuple[float, float, float],
        params: EstimatorParams | None = None,
        start: tuple[float, float, float] = (0.0, 0.0, 0.0),
        rates: tuple[float, float, float] | None = None,
    ) -> None:
        p = params or EstimatorParams()
        delay = round(p.gps_delay_s / period)
        if not 0 <= delay < HISTORY:
            raise ValueError(f"gps_delay_s = {p.gps_delay_s!r}: expected at most {(HISTORY - 1) * period:g} s")
        lost = [p.lost_time_s if rates is None else max(p.lost_time_s, LOST_INTERVALS / r) for r in rates or (1, 1, 1)]
        self.params, self.period, self.start = p, period, tuple(float(v) for v in start)
        self.e = parameter_array(p, field_ned, gravity)
        self.x = np.zeros(X_SIZE)
        self.P = np.zeros((N, N))
        self.hist = np.zeros((HISTORY + 1, 6))
        self.io = np.zeros(IO_SIZE, dtype=np.int64)
        self.io[ALIGN_TICKS] = max(1, round(p.align_time_s / period))
        self.io[DELAY_TICKS] = delay
        self.io[DIVERGE_TICKS] = round(p.divergence_time_s / period)
        self.io[LAST_USEC] = -1
        for i in range(3):
            self.io[LOST_GPS_TICKS + i] = round(lost[i] / period)
        self.io[LOST_IMU_TICKS] = round(p.imu_lost_time_s / period)
        self.acc = np.zeros(ACC_SIZE)
        self.ratio = np.zeros(10)
        self.scratch = np.zeros((N + 5, N))
        self.z = np.zeros(Z_SIZE)
        self.out = np.zeros(12)
        self.cal = np.zeros(CAL_SIZE)
        self.calibrate((0.0, 0.0, 0.0), ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0)))

    @classmethod
    def for_field(cls, period: float, gravity: float, strength: float, declination_deg: float,
                  inclination_deg: float, **kw) -> Estimator:  # fmt: skip
        """An estimator for the Earth field given as the sensors' preset keys give it (gauss, degrees)."""
        field = magnetic_field_ned(strength, math.radians(declination_deg), math.radians(inclination_deg))
        return cls(period, gravity, field, **kw)

    @classmethod
    def for_sensors(cls, s: SensorParams, period: float, gravity: float, params: EstimatorParams | None = None
                    ) -> Estimator:  # fmt: skip
        """The autopilot's estimator for the preset's ``[sensors]`` ``s``: its Earth field, its GPS delay for fixes
        stamped at delivery (EKF2_GPS_DELAY) and its sensors' rates for their timeouts. Every runtime makes its
        estimator here (the processes, ``sim``, the sweeps)."""
        p = dataclasses.replace(params or EstimatorParams(), gps_delay_s=s.gps_delay_s)
        return cls.for_field(period, gravity, s.mag_strength_gauss, s.mag_declination_deg, s.mag_inclination_deg,
                             params=p, rates=(s.gps_rate_hz, s.baro_rate_hz, s.mag_rate_hz))  # fmt: skip

    def tick(self, flags: int | None = None, t_usec: int | None = None) -> None:
        """One tick on the measurements in ``self.z`` (flags: MAG_NEW | BARO_NEW | GPS_NEW), stamped ``t_usec``
        [µs] (None: a period after the last); the state goes to ``self.out``."""
        if t_usec is None:
            last = int(self.io[LAST_USEC])
            t_usec = 0 if last < 0 else last + round(self.period * 1e6)
        estimator_tick(flags or 0, self.z, t_usec, self.period, self.start, self.x, self.P, self.hist, self.io,
                       self.acc, self.e, self.ratio, self.scratch, self.out)  # fmt: skip

    @property
    def arrays(self) -> tuple:
        """What the autopilot's compiled tick works on (:func:`autopilot.tick.sensor_tick`): the measurements, then
        :func:`estimator_tick`'s arrays, then the calibration (:func:`calibrated`)."""
        return (self.z, self.x, self.P, self.hist, self.io, self.acc, self.e, self.ratio, self.scratch, self.out,
                self.cal)  # fmt: skip

    def calibrate(self, gyro_offset: tuple[float, float, float], board: tuple[tuple[float, ...], ...]) -> None:
        """The calibration applied from the next measurement on: the gyro's offsets [rad/s, sensor axes] and the
        board rotation (body = board·sensor)."""
        self.cal[CAL_GYRO_OFFSET : CAL_GYRO_OFFSET + 3] = gyro_offset
        self.cal[CAL_BOARD : CAL_BOARD + 9] = np.asarray(board, dtype=np.float64).ravel()
        self.cal[CAL_BOARD_ON] = float(not np.array_equal(self.cal[CAL_BOARD : CAL_BOARD + 9], np.eye(3).ravel()))

    def collect(self, on: bool) -> None:
        """Collect the corrected IMU samples for a calibration (:meth:`take`), or stop."""
        self.cal[CAL_COLLECT] = float(on)
        self.cal[CAL_SUM_GYRO : CAL_COUNT + 1] = 0.0

    def take(self) -> tuple[tuple[float, float, float], tuple[float, float, float]] | None:
        """The mean corrected gyro [rad/s] and accelerometer [m/s²] sample (FRD) since the last call, and start
        again; None when no sample came."""
        n = self.cal[CAL_COUNT]
        if n == 0.0:
            return None
        c = (self.cal[CAL_SUM_GYRO : CAL_SUM_ACCEL + 3] / n).tolist()
        self.cal[CAL_SUM_GYRO : CAL_COUNT + 1] = 0.0
        return (c[0], c[1], c[2]), (c[3], c[4], c[5])

    @property
    def state(self) -> VehicleState:
        return VehicleState._make(self.out.tolist())

    @property
    def aligned(self) -> bool:
        return bool(self.io[ALIGNED])

    @property
    def lost(self) -> int:
        """The sensors lost (LOST_GPS | LOST_BARO | LOST_MAG | LOST_IMU): nothing heard from them for their
        timeouts."""
        return int(self.io[LOST])

    @property
    def diverged(self) -> bool:
        """An innovation-bound failure: one sensor's measurements refused (REFUSALS_TO_DIVERGE in a row) for
        ``divergence_time_s``, or a non-finite state. A sensor that stops is lost (:attr:`lost`), not diverged."""
        return bool(self.io[DIVERGED])

    def report(self) -> tuple[float, ...]:
        """What the filter took and how it is (:func:`report`): the telemetry's ``sensors`` record's fields."""
        return report_of(self.arrays)

    def status(self) -> tuple[int, float, float, float, float, float, float]:
        """The filter's health as ``ESTIMATOR_STATUS`` says it: flags, then the test ratios and accuracies
        (:func:`report`'s last seven)."""
        r = self.report()
        return (int(r[REPORT_FLAGS]), *r[REPORT_FLAGS + 1 :])

    def measurements(self) -> tuple[float, ...]:
        """The newest measurements it took, as HIGHRES_IMU says them (:func:`report`'s first ten)."""
        return self.report()[:REPORT_FLAGS]

    @property
    def gyro_bias(self) -> np.ndarray:
        """The estimated gyro bias [rad/s, FRD]."""
        return self.x[X_BG : X_BG + 3].copy()
