"""PX4's multicopter controller, the cascade PX4 flies, as a controller that plugs in (:mod:`quadsitl.controller`):
``--controller px4``. docs/controllers.md#px4s-cascade says where each part was read from and what differs.

- **mc_pos_control** (``src/modules/mc_pos_control/PositionControl/PositionControl.cpp``): P on position with the
  velocity feed-forward (the P part first within the horizontal speed limit, ``ControlMath::constrainXY``); PID on
  velocity, the D on the measured acceleration (low-passed at MPC_VELD_LP), the integrator clamped to ±g vertically
  and, horizontally, wound back while the thrust saturates; the acceleration to a thrust vector along
  (−a_x, −a_y, g) (MPC_ACC_DECOUPLE), its tilt limited (``ControlMath::limitTilt``), the collective from the hover
  thrust, within MPC_THR_MIN..MPC_THR_MAX keeping MPC_THR_XY_MARG for the horizontal; then the attitude setpoint
  from the thrust vector and the yaw (``ControlMath::bodyzToAttitude``);
- **mc_att_control** (``src/modules/mc_att_control/AttitudeControl/AttitudeControl.cpp``): the quaternion attitude P
  of Brescianini et al. (2013), the tilt first, the yaw weighted by MC_YAW_WEIGHT, the yaw-rate feed-forward, the
  rate limits;
- **mc_rate_control** (``src/lib/rate_control/rate_control.cpp``): PID on the body rates, the D on the measured
  angular acceleration, the feed-forward, the integrator attenuated for large errors and limited (MC_*_INT_LIM), the
  yaw torque low-passed at MC_YAW_TQ_CUTOFF.

PX4's outputs are normalised: the collective thrust T (a fraction of the motors' range) and torques τ_n (fractions
of the allocation's range). quadsitl's vehicle takes newtons and newton-metres, so T·m·g/MPC_THR_HOVER [N] (the
position controller's own assumption, a = g·T/T_hover) and τ_n·I·α [N·m] per axis, α the angular acceleration
[rad/s²] a unit of normalised torque gives PX4's x500 (from its allocation and Gazebo model): the gains see the
vehicle they were tuned on, whatever its mass and inertia.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from quadsitl.compiled_frames import euler_to_quaternion
from quadsitl.controller import (
    IXX,
    IYY,
    IZZ,
    MASS,
    PITCH,
    ROLL,
    SP_ALTITUDE,
    SP_AX,
    SP_AY,
    SP_CLIMB,
    SP_CLIMB_ACC,
    SP_CLIMB_MAX,
    SP_DESCENT_MAX,
    SP_PITCH,
    SP_ROLL,
    SP_SPEED_MAX,
    SP_TILT_MAX,
    SP_VX,
    SP_VY,
    SP_X,
    SP_Y,
    SP_YAW,
    SP_YAW_RATE,
    U_PITCH,
    U_ROLL,
    U_THRUST,
    U_YAW,
    VX,
    VY,
    VZ,
    YAW,
    Controller,
    G,
    P,
    Parameter,
    X,
    Y,
    Z,
)

# Ranges are PX4's (each parameter's file); defaults PX4 v1.16.1's, MPC_THR_HOVER the x500 airframe's
# (ROMFS/px4fmu_common/init.d-posix/airframes/4001_gz_x500). main has MC_ROLL_P = MC_PITCH_P = 4.0 since 2025-06.
PARAMETERS = (
    Parameter("mpc_xy_p", 0.95, "1/s", 0.0, 2.0, "horizontal position gain", "MPC_XY_P"),
    Parameter("mpc_z_p", 1.0, "1/s", 0.1, 1.5, "vertical position gain", "MPC_Z_P"),
    Parameter("mpc_xy_vel_p", 1.8, "1/s", 1.2, 5.0, "horizontal velocity P", "MPC_XY_VEL_P_ACC"),
    Parameter("mpc_xy_vel_i", 0.4, "1/s²", 0.0, 60.0, "horizontal velocity I", "MPC_XY_VEL_I_ACC"),
    Parameter("mpc_xy_vel_d", 0.2, "", 0.1, 2.0, "horizontal velocity D", "MPC_XY_VEL_D_ACC"),
    Parameter("mpc_z_vel_p", 4.0, "1/s", 2.0, 15.0, "vertical velocity P", "MPC_Z_VEL_P_ACC"),
    Parameter("mpc_z_vel_i", 2.0, "1/s²", 0.2, 3.0, "vertical velocity I", "MPC_Z_VEL_I_ACC"),
    Parameter("mpc_z_vel_d", 0.0, "", 0.0, 2.0, "vertical velocity D", "MPC_Z_VEL_D_ACC"),
    Parameter("mpc_thr_min", 0.12, "", 0.05, 1.0, "minimum collective thrust (normalised)", "MPC_THR_MIN"),
    Parameter("mpc_thr_max", 1.0, "", 0.0, 1.0, "maximum collective thrust (normalised)", "MPC_THR_MAX"),
    Parameter("mpc_thr_hover", 0.6, "", 0.1, 0.8, "hover thrust (normalised)", "MPC_THR_HOVER"),
    Parameter("mpc_thr_xy_marg", 0.3, "", 0.0, 0.5, "thrust kept for horizontal control", "MPC_THR_XY_MARG"),
    Parameter("mpc_veld_lp", 5.0, "Hz", 0.0, 10.0, "velocity derivative low-pass (0: none)", "MPC_VELD_LP"),
    Parameter("mc_roll_p", 6.5, "1/s", 0.0, 12.0, "roll P", "MC_ROLL_P"),
    Parameter("mc_pitch_p", 6.5, "1/s", 0.0, 12.0, "pitch P", "MC_PITCH_P"),
    Parameter("mc_yaw_p", 2.8, "1/s", 0.0, 5.0, "yaw P", "MC_YAW_P"),
    Parameter("mc_yaw_weight", 0.4, "", 0.0, 1.0, "yaw weight against tilt", "MC_YAW_WEIGHT"),
    Parameter("mc_rollrate_max", 220.0, "deg/s", 0.0, 1800.0, "roll rate limit", "MC_ROLLRATE_MAX"),
    Parameter("mc_pitchrate_max", 220.0, "deg/s", 0.0, 1800.0, "pitch rate limit", "MC_PITCHRATE_MAX"),
    Parameter("mc_yawrate_max", 200.0, "deg/s", 0.0, 1800.0, "yaw rate limit", "MC_YAWRATE_MAX"),
    Parameter("mc_rollrate_p", 0.15, "", 0.01, 0.5, "roll rate P", "MC_ROLLRATE_P"),
    Parameter("mc_rollrate_i", 0.2, "", 0.0, 10.0, "roll rate I", "MC_ROLLRATE_I"),
    Parameter("mc_rollrate_d", 0.003, "", 0.0, 0.01, "roll rate D", "MC_ROLLRATE_D"),
    Parameter("mc_rollrate_ff", 0.0, "", 0.0, 10.0, "roll rate feed-forward", "MC_ROLLRATE_FF"),
    Parameter("mc_rollrate_k", 1.0, "", 0.01, 5.0, "roll rate PID gain", "MC_ROLLRATE_K"),
    Parameter("mc_pitchrate_p", 0.15, "", 0.01, 0.6, "pitch rate P", "MC_PITCHRATE_P"),
    Parameter("mc_pitchrate_i", 0.2, "", 0.0, 10.0, "pitch rate I", "MC_PITCHRATE_I"),
    Parameter("mc_pitchrate_d", 0.003, "", 0.0, 0.01, "pitch rate D", "MC_PITCHRATE_D"),
    Parameter("mc_pitchrate_ff", 0.0, "", 0.0, 10.0, "pitch rate feed-forward", "MC_PITCHRATE_FF"),
    Parameter("mc_pitchrate_k", 1.0, "", 0.01, 5.0, "pitch rate PID gain", "MC_PITCHRATE_K"),
    Parameter("mc_yawrate_p", 0.2, "", 0.0, 0.6, "yaw rate P", "MC_YAWRATE_P"),
    Parameter("mc_yawrate_i", 0.1, "", 0.0, 10.0, "yaw rate I", "MC_YAWRATE_I"),
    Parameter("mc_yawrate_d", 0.0, "", 0.0, 0.01, "yaw rate D", "MC_YAWRATE_D"),
    Parameter("mc_yawrate_ff", 0.0, "", 0.0, 10.0, "yaw rate feed-forward", "MC_YAWRATE_FF"),
    Parameter("mc_yawrate_k", 1.0, "", 0.01, 5.0, "yaw rate PID gain", "MC_YAWRATE_K"),
    Parameter("mc_rr_int_lim", 0.3, "", 0.0, 1.0, "roll rate integrator limit", "MC_RR_INT_LIM"),
    Parameter("mc_pr_int_lim", 0.3, "", 0.0, 1.0, "pitch rate integrator limit", "MC_PR_INT_LIM"),
    Parameter("mc_yr_int_lim", 0.3, "", 0.0, 1.0, "yaw rate integrator limit", "MC_YR_INT_LIM"),
    Parameter("mc_yaw_tq_cutoff", 2.0, "Hz", 0.0, 10.0, "yaw torque low-pass (0: none)", "MC_YAW_TQ_CUTOFF"),
    Parameter("imu_dgyro_cutoff", 20.0, "Hz", 0.0, 1000.0, "angular acceleration low-pass", "IMU_DGYRO_CUTOFF"),
    # Not PX4's: the angular acceleration [rad/s²] a unit of PX4's normalised torque gives its x500 (the
    # allocation's linear model on the Gazebo x500: 2.604, 4.207, 0.522 N·m over Ixx, Iyy, Izz).
    Parameter("roll_accel", 120.2, "rad/s²", 1.0, 10000.0, "roll acceleration per unit torque", "QS_ROLL_ACC"),
    Parameter("pitch_accel", 194.2, "rad/s²", 1.0, 10000.0, "pitch acceleration per unit torque", "QS_PITCH_ACC"),
    Parameter("yaw_accel", 13.05, "rad/s²", 0.1, 10000.0, "yaw acceleration per unit torque", "QS_YAW_ACC"),
)
(XY_P, Z_P, XY_VEL_P, XY_VEL_I, XY_VEL_D, Z_VEL_P, Z_VEL_I, Z_VEL_D, THR_MIN, THR_MAX, THR_HOVER, THR_XY_MARG,
 VELD_LP, ROLL_P, PITCH_P, YAW_P, YAW_WEIGHT, ROLLRATE_MAX, PITCHRATE_MAX, YAWRATE_MAX, RATE_GAINS, INT_LIMS,
 YAW_TQ_CUTOFF, DGYRO_CUTOFF, ACCEL) = (0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15, 16, 17, 18, 19, 20,
                                         35, 38, 39, 40)  # fmt: skip
# RATE_GAINS: P, I, D, FF, K per axis (roll, pitch, yaw), 5 each; INT_LIMS and ACCEL: one per axis.

# The memory: the velocity integral [m/s², NED], the last velocity and its filtered derivative, the rate integral,
# the last body rates and their filtered derivative, the filtered yaw torque, and 1 once started.
M_VEL_INT, M_VEL_PREV, M_VEL_DOT, M_RATE_INT, M_RATE_PREV, M_RATE_DOT, M_YAW_TQ, M_STARTED, MEMORY = (
    0, 3, 6, 9, 12, 15, 18, 19, 20)  # fmt: skip


@njit(cache=True)
def _low_pass(state: float, value: float, dt: float, cutoff: float) -> float:
    """PX4's AlphaFilter: α = dt/(dt + 1/(2π·f_c)); no filter at f_c = 0."""
    if cutoff <= 0.0:
        return value
    alpha = dt / (dt + 1.0 / (2.0 * math.pi * cutoff))
    return state + alpha * (value - state)


@njit(cache=True)
def _add_if_not_nan(setpoint: float, addition: float) -> float:
    """PositionControl's addIfNotNan: both finite → the sum; one NaN → the other."""
    if not math.isfinite(setpoint):
        return addition
    if not math.isfinite(addition):
        return setpoint
    return setpoint + addition


@njit(cache=True)
def constrain_xy(v0x: float, v0y: float, v1x: float, v1y: float, vmax: float) -> tuple[float, float]:
    """ControlMath::constrainXY: v0 + v1 within |·| ≤ vmax, v0 (the P part) first."""
    sx, sy = v0x + v1x, v0y + v1y
    if math.hypot(sx, sy) <= vmax:
        return sx, sy
    n0 = math.hypot(v0x, v0y)
    if n0 >= vmax:
        return v0x / n0 * vmax, v0y / n0 * vmax
    if math.hypot(v1x - v0x, v1y - v0y) < 0.001:
        return v0x / n0 * vmax, v0y / n0 * vmax
    if n0 < 0.001:
        n1 = math.hypot(v1x, v1y)
        return v1x / n1 * vmax, v1y / n1 * vmax
    n1 = math.hypot(v1x, v1y)
    ux, uy = v1x / n1, v1y / n1
    m = ux * v0x + uy * v0y
    c = v0x * v0x + v0y * v0y - vmax * vmax
    s = -m + math.sqrt(m * m - c)
    return v0x + ux * s, v0y + uy * s


@njit(cache=True)
def limit_tilt(bx: float, by: float, bz: float, max_tilt: float) -> tuple[float, float, float]:
    """ControlMath::limitTilt against the world's up (0, 0, 1)."""
    d = bz
    angle = min(math.acos(max(-1.0, min(1.0, d))), max_tilt)
    rx, ry, rz = bx, by, bz - d
    if rx * rx + ry * ry + rz * rz < 1.1920929e-07:  # FLT_EPSILON
        rx = 1.0
    n = math.sqrt(rx * rx + ry * ry + rz * rz)
    return math.sin(angle) * rx / n, math.sin(angle) * ry / n, math.cos(angle) + math.sin(angle) * rz / n


@njit(cache=True)
def dcm_to_quaternion(r00: float, r01: float, r02: float, r10: float, r11: float, r12: float, r20: float,
                      r21: float, r22: float) -> tuple[float, float, float, float]:  # fmt: skip
    """matrix::Quaternion(Dcm): Shepperd's method, PX4's branches."""
    t = r00 + r11 + r22
    if t > 0.0:
        t = math.sqrt(1.0 + t)
        w = 0.5 * t
        t = 0.5 / t
        return w, (r21 - r12) * t, (r02 - r20) * t, (r10 - r01) * t
    if r00 > r11 and r00 > r22:
        t = math.sqrt(1.0 + r00 - r11 - r22)
        x = 0.5 * t
        t = 0.5 / t
        return (r21 - r12) * t, x, (r10 + r01) * t, (r02 + r20) * t
    if r11 > r22:
        t = math.sqrt(1.0 - r00 + r11 - r22)
        y = 0.5 * t
        t = 0.5 / t
        return (r02 - r20) * t, (r10 + r01) * t, y, (r21 + r12) * t
    t = math.sqrt(1.0 - r00 - r11 + r22)
    z = 0.5 * t
    t = 0.5 / t
    return (r10 - r01) * t, (r02 + r20) * t, (r21 + r12) * t, z


@njit(cache=True)
def bodyz_to_attitude(bx: float, by: float, bz: float, yaw: float) -> tuple[float, float, float, float]:
    """ControlMath::bodyzToAttitude: the attitude (FRD → NED) whose body z axis points along (bx, by, bz) [NED] (PX4
    passes the negated thrust vector), at heading ``yaw`` [rad]."""
    n2 = bx * bx + by * by + bz * bz
    if n2 < 1.1920929e-07:
        bx, by, bz = 0.0, 0.0, 1.0
        n2 = 1.0
    n = math.sqrt(n2)
    bx, by, bz = bx / n, by / n, bz / n
    cx, cy, cz = -math.sin(yaw), math.cos(yaw), 0.0
    xx, xy, xz = cy * bz - cz * by, cz * bx - cx * bz, cx * by - cy * bx  # y_C × body_z
    if bz < 0.0:
        xx, xy, xz = -xx, -xy, -xz
    if abs(bz) < 1e-6:
        xx, xy, xz = 0.0, 0.0, 1.0
    n = math.sqrt(xx * xx + xy * xy + xz * xz)
    xx, xy, xz = xx / n, xy / n, xz / n
    yx, yy, yz = by * xz - bz * xy, bz * xx - bx * xz, bx * xy - by * xx  # body_z × body_x
    return dcm_to_quaternion(xx, yx, bx, xy, yy, by, xz, yz, bz)


@njit(cache=True)
def _multiply(a: tuple, b: tuple) -> tuple[float, float, float, float]:
    return (a[0] * b[0] - a[1] * b[1] - a[2] * b[2] - a[3] * b[3],
            a[0] * b[1] + a[1] * b[0] + a[2] * b[3] - a[3] * b[2],
            a[0] * b[2] - a[1] * b[3] + a[2] * b[0] + a[3] * b[1],
            a[0] * b[3] + a[1] * b[2] - a[2] * b[1] + a[3] * b[0])  # fmt: skip


@njit(cache=True)
def _canonical(q: tuple) -> tuple[float, float, float, float]:
    """matrix::Quaternion::canonical: the first component of magnitude above FLT_EPSILON made positive."""
    for i in range(4):
        if abs(q[i]) > 1.1920929e-07:
            if q[i] < 0.0:
                return -q[0], -q[1], -q[2], -q[3]
            return q[0], q[1], q[2], q[3]
    return q[0], q[1], q[2], q[3]


@njit(cache=True)
def _dcm_z(q: tuple) -> tuple[float, float, float]:
    """The body z axis in the world frame: R(q)'s third column."""
    w, x, y, z = q
    return 2.0 * (w * y + x * z), 2.0 * (y * z - w * x), w * w - x * x - y * y + z * z


@njit(cache=True)
def _from_two_vectors(s: tuple, d: tuple) -> tuple[float, float, float, float]:
    """matrix::Quaternion(src, dst): the shortest rotation taking ``s`` to ``d``."""
    cx, cy, cz = s[1] * d[2] - s[2] * d[1], s[2] * d[0] - s[0] * d[2], s[0] * d[1] - s[1] * d[0]
    dot = s[0] * d[0] + s[1] * d[1] + s[2] * d[2]
    if math.sqrt(cx * cx + cy * cy + cz * cz) < 1e-5 and dot < 0.0:
        ax, ay, az = abs(s[0]), abs(s[1]), abs(s[2])
        if ax < ay:
            e = (1.0, 0.0, 0.0) if ax < az else (0.0, 0.0, 1.0)
        else:
            e = (0.0, 1.0, 0.0) if ay < az else (0.0, 0.0, 1.0)
        q = (0.0, s[1] * e[2] - s[2] * e[1], s[2] * e[0] - s[0] * e[2], s[0] * e[1] - s[1] * e[0])
    else:
        n = (s[0] * s[0] + s[1] * s[1] + s[2] * s[2]) * (d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
        q = (dot + math.sqrt(n), cx, cy, cz)
    n = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    return q[0] / n, q[1] / n, q[2] / n, q[3] / n


@njit(cache=True)
def attitude_control(q: tuple, qd: tuple, yawspeed: float, k: tuple, yaw_weight: float,
                     limits: tuple) -> tuple[float, float, float]:  # fmt: skip
    """AttitudeControl::update: the body rate setpoint [rad/s, FRD] toward ``qd`` from ``q`` (both FRD → NED): the tilt
    first, the yaw weighted, ``k`` = (MC_ROLL_P, MC_PITCH_P, MC_YAW_P / MC_YAW_WEIGHT)."""
    qd_red = _from_two_vectors(_dcm_z(q), _dcm_z(qd))
    corner = abs(qd_red[1]) > 1.0 - 1e-5 or abs(qd_red[2]) > 1.0 - 1e-5  # 180° away: the whole attitude
    qd_red = qd if corner else _multiply(qd_red, q)
    qd_dyaw = _canonical(_multiply((qd_red[0], -qd_red[1], -qd_red[2], -qd_red[3]), qd))
    w = max(-1.0, min(1.0, qd_dyaw[0]))
    z = max(-1.0, min(1.0, qd_dyaw[3]))
    qd = _multiply(qd_red, (math.cos(yaw_weight * math.acos(w)), 0.0, 0.0, math.sin(yaw_weight * math.asin(z))))
    qe = _canonical(_multiply((q[0], -q[1], -q[2], -q[3]), qd))
    rate = [2.0 * qe[1] * k[0], 2.0 * qe[2] * k[1], 2.0 * qe[3] * k[2]]
    if math.isfinite(yawspeed):  # the world's z axis in body axes: R(q)ᵀ's third column, R's third row
        w_, x_, y_, z_ = q
        zb = (2.0 * (x_ * z_ - w_ * y_), 2.0 * (y_ * z_ + w_ * x_), w_ * w_ - x_ * x_ - y_ * y_ + z_ * z_)
        for i in range(3):
            rate[i] += zb[i] * yawspeed
    for i in range(3):
        rate[i] = max(-limits[i], min(limits[i], rate[i]))
    return rate[0], rate[1], rate[2]


@njit(cache=True)
def position_control(pos: tuple, vel: tuple, vel_dot: tuple, pos_sp: tuple, vel_sp_in: tuple, acc_sp: tuple,
                     kp: tuple, kvp: tuple, kvi: tuple, kvd: tuple, vel_limits: tuple, tilt_max: float, thr_min: float,
                     thr_max: float, xy_margin: float, hover: float, g: float, vel_int: np.ndarray,
                     dt: float) -> tuple[float, float, float, float]:  # fmt: skip
    """PositionControl::update (mc_pos_control), NED: the position, velocity and its derivative, the setpoints (NaN:
    not controlled), the gains (x, y, z), the velocity limits (horizontal, up, down) [m/s], the tilt limit [rad], the
    thrust limits, margin and hover thrust (normalised), g [m/s²]; ``vel_int`` the velocity integral [m/s²], advanced
    by ``dt`` [s]. Returns the normalised thrust vector (NED, up is −z) and its vertical part before the saturation."""
    # _positionControl: P on position, the velocity setpoint a feed-forward; the limits
    vel_sp = [vel_sp_in[0], vel_sp_in[1], vel_sp_in[2]]
    vp = [0.0, 0.0, 0.0]
    for i in range(3):
        p_part = (pos_sp[i] - pos[i]) * kp[i]
        vel_sp[i] = _add_if_not_nan(vel_sp[i], p_part)
        vp[i] = p_part if math.isfinite(p_part) else 0.0
    vel_sp[0], vel_sp[1] = constrain_xy(vp[0], vp[1], vel_sp[0] - vp[0], vel_sp[1] - vp[1], vel_limits[0])
    vel_sp[2] = max(-vel_limits[1], min(vel_limits[2], vel_sp[2]))
    # _velocityControl: PID, the D on the measured acceleration
    vel_int[2] = max(-g, min(g, vel_int[2]))
    e = [vel_sp[i] - vel[i] for i in range(3)]
    acc = [_add_if_not_nan(acc_sp[i], e[i] * kvp[i] + vel_int[i] - vel_dot[i] * kvd[i]) for i in range(3)]
    # _accelerationControl: the thrust vector (horizontal and vertical decoupled, MPC_ACC_DECOUPLE)
    bx, by, bz = -acc[0], -acc[1], g
    n = math.sqrt(bx * bx + by * by + bz * bz)
    bx, by, bz = limit_tilt(bx / n, by / n, bz / n, tilt_max)
    thrust_z = acc[2] * (hover / g) - hover
    collective = min(thrust_z / bz, -thr_min)
    tx, ty, tz = bx * collective, by * collective, bz * collective
    # anti-windup of the vertical integral, on the thrust before its saturation
    if (tz >= -thr_min and e[2] >= 0.0) or (tz <= -thr_max and e[2] <= 0.0):
        e[2] = 0.0
    # the vertical thrust first, a margin kept for the horizontal
    nxy = math.hypot(tx, ty)
    tz = max(tz, -math.sqrt(thr_max * thr_max - min(nxy, xy_margin) ** 2))
    room = thr_max * thr_max - tz * tz
    txy_max = math.sqrt(room) if room > 0.0 else 0.0
    if nxy > txy_max:
        tx, ty = tx / nxy * txy_max, ty / nxy * txy_max
    # the horizontal integral wound back while the thrust is limited (Rundqwist 1990)
    ax, ay = tx * (g / hover), ty * (g / hover)
    if acc[0] * acc[0] + acc[1] * acc[1] > ax * ax + ay * ay:
        e[0] -= 2.0 / kvp[0] * (acc[0] - ax)
        e[1] -= 2.0 / kvp[1] * (acc[1] - ay)
    for i in range(3):
        if math.isfinite(e[i]):
            vel_int[i] += e[i] * kvi[i] * dt
    return tx, ty, tz, thrust_z


class PX4Cascade(Controller):
    """PX4's multicopter cascade (the module's docstring); ``--controller px4``."""

    parameters = PARAMETERS
    memory = MEMORY

    @staticmethod
    def law(t, dt, x, sp, model, k, mem, u):
        g, hover = model[G], k[THR_HOVER]
        thr_min, thr_max = k[THR_MIN], k[THR_MAX]
        if mem[M_STARTED] == 0.0:  # no derivative before the second tick
            mem[M_STARTED] = 1.0
            for i in range(3):
                mem[M_VEL_PREV + i] = x[VX + i]
                mem[M_RATE_PREV + i] = x[P + i]
        # ---- mc_pos_control: the velocity's derivative, low-passed (MPC_VELD_LP) ---------------------------
        for i in range(3):
            raw = (x[VX + i] - mem[M_VEL_PREV + i]) / dt
            mem[M_VEL_DOT + i] = _low_pass(mem[M_VEL_DOT + i], raw, dt, k[VELD_LP])
            mem[M_VEL_PREV + i] = x[VX + i]
        yaw_sp = sp[SP_YAW] if math.isfinite(sp[SP_YAW]) else x[YAW]
        yawspeed = sp[SP_YAW_RATE] if math.isfinite(sp[SP_YAW_RATE]) else 0.0
        free = (math.isnan(sp[SP_X]) and math.isnan(sp[SP_VX]) and math.isnan(sp[SP_AX]) and math.isnan(sp[SP_Y])
                and math.isnan(sp[SP_VY]) and math.isnan(sp[SP_AY]))  # fmt: skip
        # The setpoint in PX4's frame (NED: z down); NaN where not controlled.
        pos = (x[X], x[Y], x[Z])
        vel = (x[VX], x[VY], x[VZ])
        pos_sp = (sp[SP_X], sp[SP_Y], -sp[SP_ALTITUDE])
        vel_sp = (sp[SP_VX], sp[SP_VY], -sp[SP_CLIMB])
        acc_sp = (sp[SP_AX], sp[SP_AY], -sp[SP_CLIMB_ACC])
        kp = (k[XY_P], k[XY_P], k[Z_P])
        kvp = (k[XY_VEL_P], k[XY_VEL_P], k[Z_VEL_P])
        kvi = (k[XY_VEL_I], k[XY_VEL_I], k[Z_VEL_I])
        kvd = (k[XY_VEL_D], k[XY_VEL_D], k[Z_VEL_D])
        if free:  # PX4 resets the horizontal integral when no horizontal setpoint is given
            mem[M_VEL_INT], mem[M_VEL_INT + 1] = 0.0, 0.0
        tx, ty, tz, thrust_z = position_control(
            pos,
            vel,
            (mem[M_VEL_DOT], mem[M_VEL_DOT + 1], mem[M_VEL_DOT + 2]),
            pos_sp,
            vel_sp,
            acc_sp,
            kp,
            kvp,
            kvi,
            kvd,
            (sp[SP_SPEED_MAX], sp[SP_CLIMB_MAX], sp[SP_DESCENT_MAX]),
            sp[SP_TILT_MAX],
            thr_min,
            thr_max,
            k[THR_XY_MARG],
            hover,
            g,
            mem[M_VEL_INT : M_VEL_INT + 3],
            dt,
        )
        # the attitude setpoint and the collective thrust (normalised)
        if free:  # the attitude setpoint, the collective for the vertical thrust through the tilt
            qd = euler_to_quaternion(sp[SP_ROLL], sp[SP_PITCH], yaw_sp)
            tilt = max(math.cos(sp[SP_ROLL]) * math.cos(sp[SP_PITCH]), 0.1)
            thrust = max(thr_min, min(thr_max, -min(thrust_z, -thr_min) / tilt))
        else:
            qd = bodyz_to_attitude(-tx, -ty, -tz, yaw_sp)
            thrust = math.sqrt(tx * tx + ty * ty + tz * tz)
        # ---- mc_att_control --------------------------------------------------------------------------
        q = euler_to_quaternion(x[ROLL], x[PITCH], x[YAW])
        weight = k[YAW_WEIGHT]
        k_att = (k[ROLL_P], k[PITCH_P], k[YAW_P] / weight if weight > 1e-4 else k[YAW_P])
        limits = (math.radians(k[ROLLRATE_MAX]), math.radians(k[PITCHRATE_MAX]), math.radians(k[YAWRATE_MAX]))
        rate_sp = attitude_control(q, qd, yawspeed, k_att, weight, limits)
        # ---- mc_rate_control -------------------------------------------------------------------------
        torque = [0.0, 0.0, 0.0]
        for i in range(3):
            raw = (x[P + i] - mem[M_RATE_PREV + i]) / dt
            mem[M_RATE_DOT + i] = _low_pass(mem[M_RATE_DOT + i], raw, dt, k[DGYRO_CUTOFF])
            mem[M_RATE_PREV + i] = x[P + i]
            gp, gi, gd, ff, gk = (k[RATE_GAINS + 5 * i], k[RATE_GAINS + 5 * i + 1], k[RATE_GAINS + 5 * i + 2],
                                  k[RATE_GAINS + 5 * i + 3], k[RATE_GAINS + 5 * i + 4])  # fmt: skip
            err = rate_sp[i] - x[P + i]
            torque[i] = gk * gp * err + mem[M_RATE_INT + i] - gk * gd * mem[M_RATE_DOT + i] + ff * rate_sp[i]
            f = err / math.radians(400.0)  # the integral attenuated for large errors; then limited
            f = max(0.0, 1.0 - f * f)
            r = mem[M_RATE_INT + i] + f * gk * gi * err * dt
            if math.isfinite(r):
                mem[M_RATE_INT + i] = max(-k[INT_LIMS + i], min(k[INT_LIMS + i], r))
        mem[M_YAW_TQ] = _low_pass(mem[M_YAW_TQ], torque[2], dt, k[YAW_TQ_CUTOFF])
        torque[2] = mem[M_YAW_TQ]
        # ---- PX4's normalised outputs as the vehicle's newtons and newton-metres -------------------------
        u[U_THRUST] = thrust * model[MASS] * g / hover
        u[U_ROLL] = max(-1.0, min(1.0, torque[0])) * model[IXX] * k[ACCEL]
        u[U_PITCH] = max(-1.0, min(1.0, torque[1])) * model[IYY] * k[ACCEL + 1]
        u[U_YAW] = max(-1.0, min(1.0, torque[2])) * model[IZZ] * k[ACCEL + 2]

    @staticmethod
    def check(k: dict[str, float], model: dict[str, float]) -> str | None:
        """PX4's own: the thrust limits in order, and the hover thrust between them."""
        if not k["mpc_thr_min"] < k["mpc_thr_hover"] < k["mpc_thr_max"]:
            return (f"MPC_THR_HOVER = {k['mpc_thr_hover']:g} must lie between MPC_THR_MIN = {k['mpc_thr_min']:g} "
                    f"and MPC_THR_MAX = {k['mpc_thr_max']:g}")  # fmt: skip
        return None
