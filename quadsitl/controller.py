"""The interface a flight controller meets to plug into the vehicle (docs/controllers.md).

A controller is a class with a compiled law and declared parameters; ``--controller path/to/file.py:Name`` (or
``package.module:Name``) flies it in ``sim``, ``fly``, ``up`` and ``sweep``, in the one vehicle every runtime
composes (:mod:`groundstation.vehicle`). The autopilot keeps everything around it: the commander and its modes, the
setpoints and missions, the estimator on sensors, the allocation to the motors and the failsafes.
``examples/controllers/template.py`` is a complete one to start from.

The class has:

- ``parameters``: a tuple of :class:`Parameter` (name, default, unit, range, what it is); the law reads them in that
  order from ``k``; the autopilot process serves them as MAVLink parameters, each value checked against its range;
- ``memory``: how many floats the law keeps from one tick to the next in ``mem`` (zero at each arming);
- ``law(t, dt, x, sp, model, k, mem, u)``: a ``@staticmethod`` that numba compiles (plain Python on numbers and
  arrays, no objects): at time ``t`` [s], every control period ``dt`` [s], the state ``x`` and the setpoint ``sp``
  (the indices below), the autopilot's model of the vehicle ``model`` (:mod:`quadsitl.param_arrays`' MASS, IXX,
  IYY, IZZ, ARM, G, …; SI units), it writes the command into ``u``: U_THRUST [N] along the body's −z axis, U_ROLL,
  U_PITCH, U_YAW the torques [N·m] about the body's x, y, z axes (FRD). ``u`` holds NaN on entry: a command not
  written, or not finite, trips the failsafe;
- optionally ``check(k, model)``: a ``@staticmethod`` given the parameters and the model as dicts of name → value,
  returning why they cannot fly (a string) or None; run on every change, as the backstepping's conditions
  (41)–(44) are.

Frames and units are DESIGN.md's: positions NED [m] from home, altitude up [m], angles [rad] (ZYX Euler), body
rates FRD [rad/s].
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

from quadsitl.param_arrays import ARM, IXX, IYY, IZZ, MASS, VEHICLE_SIZE, G  # noqa: F401 (the model's indices)

# ---- x: the state the controller is given ----------------------------------------------------------------
# Position NED [m], velocity NED [m/s], roll, pitch, yaw [rad], their rates [rad/s] (the paper's state), then the
# body rates p, q, r [rad/s] (FRD, by eq (1)).
X, Y, Z, VX, VY, VZ, ROLL, PITCH, YAW, ROLL_RATE, PITCH_RATE, YAW_RATE, P, Q, R = range(15)
STATE_SIZE = 15

# ---- sp: the setpoint to fly this tick, as PX4's trajectory setpoint (NaN: not controlled) -----------------------
# Horizontal position [m, NED], velocity [m/s] and acceleration [m/s²] (x and y NaN: the horizontal position is free,
# fly SP_ROLL and SP_PITCH, the attitude setpoint); altitude [m, up] (NaN: fly the climb rate alone), climb rate
# [m/s, up] and its rate [m/s²]; roll and pitch [rad]; yaw [rad] (NaN: fly the yaw rate alone) and yaw rate [rad/s].
# Then the limits the autopilot's parameters set on it: the horizontal speed, the climb and descent rates [m/s]
# (MPC_XY_VEL_MAX, MPC_Z_VEL_MAX_UP, MPC_Z_VEL_MAX_DN; inf where the setpoint is not limited: offboard), and the tilt
# [rad] (MPC_TILTMAX_AIR).
(SP_X, SP_Y, SP_VX, SP_VY, SP_AX, SP_AY, SP_ALTITUDE, SP_CLIMB, SP_CLIMB_ACC, SP_ROLL, SP_PITCH, SP_YAW,
 SP_YAW_RATE, SP_SPEED_MAX, SP_CLIMB_MAX, SP_DESCENT_MAX, SP_TILT_MAX) = range(17)  # fmt: skip
SETPOINT_SIZE = 17

# ---- u: the command -----------------------------------------------------------------------------------------------
U_THRUST, U_ROLL, U_PITCH, U_YAW = range(4)

MAVLINK_NAME = re.compile(r"[A-Z][A-Z0-9_]{0,15}")


@dataclass(frozen=True)
class Parameter:
    """One of a controller's parameters: ``name`` (a Python identifier; its MAVLink name is ``mavlink`` or the name
    in capitals, at most 16 characters), ``default`` in ``unit``, its range [low, high], and what it is (``doc``)."""

    name: str
    default: float
    unit: str
    low: float
    high: float
    doc: str
    mavlink: str = ""

    @property
    def param_id(self) -> str:
        return self.mavlink or self.name.upper()

    def allowed(self) -> str:
        unit = f" {self.unit}" if self.unit else ""
        return f"a number in [{self.low:g}, {self.high:g}]{unit}"

    def accepts(self, value: float) -> bool:
        return math.isfinite(value) and self.low <= value <= self.high


class Controller:
    """A base a controller may derive from (nothing requires it): no parameters, no memory, no check."""

    parameters: tuple[Parameter, ...] = ()
    memory: int = 0

    @staticmethod
    def check(k: dict[str, float], model: dict[str, float]) -> str | None:
        return None
