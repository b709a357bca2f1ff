"""A complete controller to start yours from: a cascaded PD (position → acceleration → thrust vector → attitude →
torques) with integral action on altitude. It flies everything the built-in controllers fly:

    quadsitl sim --preset x500 --controller examples/controllers/template.py:Template --trajectory circle

The interface (quadsitl.controller, docs/controllers.md): the class declares its parameters and how many floats of
memory it keeps; ``law`` is compiled by numba, so it works on numbers and numpy arrays only, and any function it
calls is compiled too (``@njit``). Frames: NED positions from home [m], altitude up [m], ZYX Euler angles [rad],
FRD body rates [rad/s]. Units: SI.
"""

import math

from numba import njit

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
    SP_PITCH,
    SP_ROLL,
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
    Q,
    R,
    X,
    Y,
    Z,
)

INTEGRAL_LIMIT = 2.0  # [m·s]: the altitude integral's bound (anti-windup)


@njit
def axis_acceleration(position_sp: float, velocity_sp: float, acceleration_sp: float, position: float,
                      velocity: float, kp: float, kv: float) -> float:  # fmt: skip
    """One horizontal axis: the acceleration [m/s²] toward the setpoint (NaN fields are not controlled: the
    acceleration feed-forward alone when neither position nor velocity is given)."""
    a = acceleration_sp if math.isfinite(acceleration_sp) else 0.0
    if math.isfinite(position_sp):
        a += kp * (position_sp - position)
    if math.isfinite(position_sp) or math.isfinite(velocity_sp):
        a += kv * ((velocity_sp if math.isfinite(velocity_sp) else 0.0) - velocity)
    return a


@njit
def wrap(angle: float) -> float:
    """``angle`` on (−π, π]."""
    return math.atan2(math.sin(angle), math.cos(angle))


class Template(Controller):
    """A cascaded PD with altitude integral action (see the module's docstring)."""

    parameters = (
        Parameter("kp_xy", 4.0, "1/s²", 0.0, 50.0, "horizontal position gain"),
        Parameter("kv_xy", 4.0, "1/s", 0.0, 50.0, "horizontal velocity gain"),
        Parameter("kp_z", 4.0, "1/s²", 0.0, 50.0, "altitude gain"),
        Parameter("kv_z", 4.0, "1/s", 0.0, 50.0, "climb rate gain"),
        Parameter("ki_z", 0.5, "1/s³", 0.0, 20.0, "altitude integral gain"),
        Parameter("kp_att", 100.0, "1/s²", 0.0, 2000.0, "roll and pitch gain"),
        Parameter("kd_att", 20.0, "1/s", 0.0, 200.0, "roll and pitch rate gain"),
        Parameter("kp_yaw", 16.0, "1/s²", 0.0, 500.0, "yaw gain"),
        Parameter("kd_yaw", 8.0, "1/s", 0.0, 100.0, "yaw rate gain"),
        Parameter("max_tilt", 0.6, "rad", 0.05, 1.2, "bound on the tilt the position loop asks for", "TPL_MAX_TILT"),
    )
    memory = 1  # mem[0]: the integral of the altitude error [m·s]

    @staticmethod
    def law(t, dt, x, sp, model, k, mem, u):
        kp_xy, kv_xy, kp_z, kv_z, ki_z, kp_att, kd_att, kp_yaw, kd_yaw, max_tilt = (
            k[0],
            k[1],
            k[2],
            k[3],
            k[4],
            k[5],
            k[6],
            k[7],
            k[8],
            k[9],
        )
        m, g = model[MASS], model[G]
        # Vertical: the acceleration up [m/s²] (altitude with integral action, or the climb rate alone).
        altitude, climb = -x[Z], -x[VZ]
        az = sp[SP_CLIMB_ACC] if math.isfinite(sp[SP_CLIMB_ACC]) else 0.0
        climb_sp = sp[SP_CLIMB] if math.isfinite(sp[SP_CLIMB]) else 0.0
        if math.isfinite(sp[SP_ALTITUDE]):
            error = sp[SP_ALTITUDE] - altitude
            mem[0] = min(max(mem[0] + error * dt, -INTEGRAL_LIMIT), INTEGRAL_LIMIT)
            az += kp_z * error + ki_z * mem[0]
        az += kv_z * (climb_sp - climb)
        yaw_sp = sp[SP_YAW] if math.isfinite(sp[SP_YAW]) else x[YAW]
        yaw_rate_sp = sp[SP_YAW_RATE] if math.isfinite(sp[SP_YAW_RATE]) else 0.0
        free = math.isnan(sp[SP_X]) and math.isnan(sp[SP_VX]) and math.isnan(sp[SP_AX])
        if free and math.isnan(sp[SP_Y]) and math.isnan(sp[SP_VY]) and math.isnan(sp[SP_AY]):
            # the attitude setpoint: thrust for the vertical acceleration through the tilt
            roll_sp, pitch_sp = sp[SP_ROLL], sp[SP_PITCH]
            thrust = m * (g + az) / max(math.cos(roll_sp) * math.cos(pitch_sp), 0.2)
        else:
            # the thrust vector for the acceleration wanted, its tilt bounded: f = m·(a − g·e_down), NED
            an = axis_acceleration(sp[SP_X], sp[SP_VX], sp[SP_AX], x[X], x[VX], kp_xy, kv_xy)
            ae = axis_acceleration(sp[SP_Y], sp[SP_VY], sp[SP_AY], x[Y], x[VY], kp_xy, kv_xy)
            lift = max(g + az, 0.1 * g)
            bound = lift * math.tan(max_tilt)
            horizontal = math.hypot(an, ae)
            if horizontal > bound:
                an, ae = an * bound / horizontal, ae * bound / horizontal
            fn, fe, fd = m * an, m * ae, -m * lift
            thrust = math.sqrt(fn * fn + fe * fe + fd * fd)
            # the body's z axis points along −f; roll and pitch that put it there at the yaw wanted
            zn, ze, zd = -fn / thrust, -fe / thrust, -fd / thrust
            c, s = math.cos(yaw_sp), math.sin(yaw_sp)
            roll_sp = math.asin(max(-1.0, min(1.0, -(-s * zn + c * ze))))
            pitch_sp = math.atan2(c * zn + s * ze, zd)
        # Attitude: PD on the Euler angles, damped on the body rates, scaled by the inertia.
        u[U_THRUST] = thrust
        u[U_ROLL] = model[IXX] * (kp_att * wrap(roll_sp - x[ROLL]) - kd_att * x[P])
        u[U_PITCH] = model[IYY] * (kp_att * wrap(pitch_sp - x[PITCH]) - kd_att * x[Q])
        u[U_YAW] = model[IZZ] * (kp_yaw * wrap(yaw_sp - x[YAW]) + kd_yaw * (yaw_rate_sp - x[R]))

    @staticmethod
    def check(k, model):
        """The altitude loop s³ + kv·s² + kp·s + ki is stable (Routh–Hurwitz) only when kv·kp > ki."""
        if k["kv_z"] * k["kp_z"] <= k["ki_z"]:
            return (f"kv_z·kp_z = {k['kv_z'] * k['kp_z']:g} must exceed ki_z = {k['ki_z']:g} (the altitude loop is "
                    "unstable otherwise)")  # fmt: skip
        return None
