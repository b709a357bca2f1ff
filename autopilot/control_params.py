"""The controllers' parameters as one flat float64 array (see :mod:`quadsitl.param_arrays` for why), with
one name per index. Both controllers read the same array, so the autopilot switches between them
(``CTL_TYPE``) without rebuilding anything."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

# λ1..λ8 (backstepping poles), PD kp and kd per channel (altitude, roll, pitch, yaw), the control period
# T [s], the tilt bound [rad] and its cosine, and the bounds on u1 [N].
POLES, KP, KD, PERIOD, MAX_TILT, COS_MAX_TILT, THRUST_MIN, THRUST_MAX = 0, 8, 12, 16, 17, 18, 19, 20
SIZE = 21

# A controller's memory and outputs (``mem``): the command u1..u4 (the previous one on entry: its Ωr is the one
# the backstepping assumes), the motor forces [N], the errors e1..e8 and the Ωr of the last step.
MEM_U, MEM_FORCES, MEM_ERRORS, MEM_OMEGA_R, MEM_SIZE = 0, 4, 8, 16, 17

BACKSTEPPING, PD = 0, 1
KINDS = {"backstepping": BACKSTEPPING, "pd": PD}
"""Controller names (presets, ``--controller``, ``CTL_TYPE`` order) → the code the compiled step takes."""


def control_array(
    poles: Sequence[float],
    period: float,
    kp: Sequence[float] = (0.0,) * 4,
    kd: Sequence[float] = (0.0,) * 4,
    max_tilt: float = math.radians(80.0),
    thrust_min: float = -math.inf,
    thrust_max: float = math.inf,
) -> np.ndarray:
    """The array the compiled controllers read."""
    c = np.zeros(SIZE)
    c[POLES : POLES + 8] = poles
    c[KP : KP + 4] = kp
    c[KD : KD + 4] = kd
    c[PERIOD], c[MAX_TILT], c[COS_MAX_TILT] = period, max_tilt, math.cos(max_tilt)
    c[THRUST_MIN], c[THRUST_MAX] = thrust_min, thrust_max
    return c
