"""The controllers' parameters as one flat float64 array (see :mod:`quadsitl.param_arrays` for why), with
one name per index. Both controllers read the same array, so the autopilot switches between them
(``CTL_TYPE``) without rebuilding anything."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from quadsitl.config import PositionParams

# λ1..λ8 (backstepping poles), PD kp and kd per channel (altitude, roll, pitch, yaw), the control period
# T [s], the tilt bound [rad] and its cosine, and the bounds on u1 [N].
POLES, KP, KD, PERIOD, MAX_TILT, COS_MAX_TILT, THRUST_MIN, THRUST_MAX = 0, 8, 12, 16, 17, 18, 19, 20
# The flight controller around them (docs/position.md): λ9..λ12 of the horizontal loop (x, vx, y, vy), the
# integral rates k_I [1/s] of the altitude and horizontal loops (0: off; the gain is κ = k_I·k of the loop's
# position rate) and the bound on κ·ζ [m/s],
# the velocity limits [m/s] (horizontal norm, up, down) and tan of the thrust vector's tilt limit.
POLES_XY, KI_ALT, KI_XY, INT_LIM, XY_VEL_MAX, Z_VEL_UP, Z_VEL_DN, TAN_TILT_AIR = 21, 25, 26, 27, 28, 29, 30, 31
SIZE = 32

# A controller's memory and outputs (``mem``): the command u1..u4 (the previous one on entry: its Ωr is the one
# the backstepping assumes), the motor forces [N], the errors e1..e8 and the Ωr of the last step; then the
# integrator states ζ (altitude, x, y) [m·s], the horizontal errors e9..e12, and the roll and pitch references
# the position loop made (NaN when the horizontal position is not controlled); 1.0 once a plugged controller
# commanded a non-finite value (it is not flown again until the next arming), and the last tick one did + 1 (0:
# none; kept after disarming, for the shell to say).
(MEM_U, MEM_FORCES, MEM_ERRORS, MEM_OMEGA_R, MEM_ZETA, MEM_ERRORS_XY, MEM_ATTITUDE_REF, MEM_PLUG_FAILED,
 MEM_PLUG_FAILED_TICK) = 0, 4, 8, 16, 17, 20, 24, 26, 27  # fmt: skip
MEM_SIZE = 28

# What a channel's reference controls (docs/position.md): its position (with optional velocity and acceleration
# feed-forward), its velocity only (the position is free), or its acceleration only.
POSITION, VELOCITY, ACCELERATION = 0, 1, 2

BACKSTEPPING, PD, PLUGGED = 0, 1, 2
KINDS = {"backstepping": BACKSTEPPING, "pd": PD}
"""Controller names (presets, ``--controller``, ``CTL_TYPE`` order) → the code the compiled step takes; PLUGGED: a
controller loaded from a file or module (:mod:`autopilot.plugin`), flown through the tick's ``plug``."""


def control_array(
    poles: Sequence[float],
    period: float,
    kp: Sequence[float] = (0.0,) * 4,
    kd: Sequence[float] = (0.0,) * 4,
    max_tilt: float = math.radians(80.0),
    thrust_min: float = -math.inf,
    thrust_max: float = math.inf,
    position: PositionParams | None = None,
) -> np.ndarray:
    """The array the compiled controllers read (``position``: the defaults when None)."""
    p = position or PositionParams()
    c = np.zeros(SIZE)
    c[POLES : POLES + 8] = poles
    c[KP : KP + 4] = kp
    c[KD : KD + 4] = kd
    c[PERIOD], c[MAX_TILT], c[COS_MAX_TILT] = period, max_tilt, math.cos(max_tilt)
    c[THRUST_MIN], c[THRUST_MAX] = thrust_min, thrust_max
    c[POLES_XY : POLES_XY + 4] = [1.0 - period * k for k in p.gains]
    c[KI_ALT], c[KI_XY] = p.integral
    c[INT_LIM], c[XY_VEL_MAX], c[Z_VEL_UP], c[Z_VEL_DN] = p.integral_limit, p.xy_vel_max, p.z_vel_max_up, p.z_vel_max_dn
    c[TAN_TILT_AIR] = math.tan(min(p.tilt_max_air, max_tilt))  # the attitude references' bound binds too
    return c
