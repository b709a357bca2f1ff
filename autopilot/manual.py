"""The sticks' math of PX4's manual modes, pure and compiled: MANUAL_CONTROL's sticks (as PX4's
``manual_control_setpoint``: pitch forward, roll right, throttle up, yaw right, each −1..1) shaped and turned into what
the commander's references are made of (:mod:`autopilot.commander`, docs/manual.md).

Frames and units: tilts [rad] as the roll and pitch of ZYX Euler angles (body FRD), velocities [m/s] local NED, yaw
[rad] from north, thrust [N] total.
"""

from __future__ import annotations

import math

from quadsitl.jit import jit


@jit
def expo_deadzone(value: float, expo: float, deadzone: float) -> float:
    """PX4's ``math::expo_deadzone``: the stick within ±1, zero within ``deadzone`` of the centre and rescaled to reach
    ±1 at full deflection beyond it, then ``(1 − e)·x + e·x³`` (``expo`` e in [0, 1]: softer about the centre)."""
    x = min(max(value, -1.0), 1.0)
    dz = min(max(deadzone, 0.0), 0.99)
    x = 0.0 if abs(x) <= dz else (x - math.copysign(dz, x)) / (1.0 - dz)
    e = min(max(expo, 0.0), 1.0)
    return (1.0 - e) * x + e * x * x * x


@jit
def unit_length(a: float, b: float) -> tuple[float, float]:
    """The stick pair (a, b) cut to length 1 at most (PX4's ``Sticks::limitStickUnitLengthXY``): a diagonal asks no
    more than a full stick along one axis."""
    n = math.sqrt(a * a + b * b)
    return (a / n, b / n) if n > 1.0 else (a, b)


@jit
def tilt(roll_stick: float, pitch_stick: float, tilt_max: float) -> tuple[float, float]:
    """STABILIZED's and ALTCTL's attitude from the sticks (PX4's ``mc_att_control`` and ``ManualAltitude``): the
    roll [rad] and pitch [rad] of a tilt of up to ``tilt_max`` along the stick pair's direction; the pitch stick
    forward tilts the nose down (a negative pitch), and flies forward."""
    r, p = unit_length(roll_stick, pitch_stick)
    return r * tilt_max, -p * tilt_max


@jit
def throttle_curve(throttle: float, low: float, hover: float, high: float) -> float:
    """STABILIZED's thrust [N] for the throttle stick (−1..1), PX4's ``MPC_THR_CURVE`` 0: ``low`` at the bottom,
    ``hover`` (the weight, as PX4's hover-thrust estimate finds it) at the centre, ``high`` at the top, linear in
    between."""
    t = min(max(throttle, -1.0), 1.0)
    h = min(max(hover, low), high)
    return h + t * (h - low) if t < 0.0 else h + t * (high - h)


@jit
def climb_rate(throttle: float, up: float, down: float) -> float:
    """ALTCTL's and POSCTL's climb rate [m/s, up] for the shaped throttle stick (−1..1): ``up`` at the top (PX4's
    MPC_Z_VEL_MAX_UP), ``down`` at the bottom (MPC_Z_VEL_MAX_DN)."""
    return throttle * up if throttle > 0.0 else throttle * down


@jit
def velocity(forward: float, right: float, yaw: float, speed: float) -> tuple[float, float]:
    """POSCTL's velocity (north, east) [m/s] for the shaped pitch (``forward``) and roll (``right``) sticks, cut to
    length 1, flown relative to the heading ``yaw`` [rad] at up to ``speed`` (MPC_VEL_MANUAL)."""
    f, r = unit_length(forward, right)
    c, s = math.cos(yaw), math.sin(yaw)
    return (f * c - r * s) * speed, (f * s + r * c) * speed
