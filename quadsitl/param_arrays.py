"""The parameters the compiled equations read, as flat float64 arrays, with one name per index.

numba takes a numpy array in a fraction of a microsecond, where a dataclass or a tuple of a dozen fields
costs it microseconds to inspect on every call. Each array is made once (when a preset is loaded or a
parameter changes) from the validated dataclasses of :mod:`quadsitl.config`; the index names are module
constants, which numba compiles in as literals.
"""

from __future__ import annotations

import numpy as np

from quadsitl.config import ActuatorParams, BatteryParams, VehicleParams

# ---- the vehicle: paper Table 1 symbols, SI units ------------------------------------------------------
MASS, IXX, IYY, IZZ, K1, K2, K3, K4, K5, K6, ARM, JR, B, D, G, D_OVER_B = range(16)
VEHICLE_SIZE = 16


def vehicle_array(v: VehicleParams) -> np.ndarray:
    """m, Ix, Iy, Iz, K1..K6, l, Jr, b, d, g, d/b."""
    return np.array(
        [v.mass, v.ixx, v.iyy, v.izz, *v.drag, v.arm_length, v.rotor_inertia, v.thrust_factor, v.drag_factor,
         v.gravity, v.d_over_b],
        dtype=np.float64,
    )  # fmt: skip


FIELD_COLUMNS: dict[str, tuple[int, ...]] = {
    "mass": (MASS,), "ixx": (IXX,), "iyy": (IYY,), "izz": (IZZ,), "drag": (K1, K2, K3, K4, K5, K6),
    "arm_length": (ARM,), "rotor_inertia": (JR,), "thrust_factor": (B,), "drag_factor": (D,), "gravity": (G,),
}  # fmt: skip
"""A :class:`quadsitl.config.VehicleParams` field → its columns in :func:`vehicle_array` (d/b is derived)."""


# ---- the motors and the battery they draw from -------------------------------------------------------------
# BAT_CAPACITY 0: an ideal supply (no [battery]); the rest is read only when it is not.
F_MIN, F_MAX, TAU_UP, TAU_DOWN = range(4)
(BAT_CAPACITY, BAT_CELLS, BAT_V_FULL, BAT_V_EMPTY, BAT_RESISTANCE, BAT_EFFICIENCY, BAT_AVIONICS,
 BAT_REMAINING) = range(4, 12)  # fmt: skip
ACTUATOR_SIZE = 12


def actuator_array(a: ActuatorParams, battery: BatteryParams | None = None) -> np.ndarray:
    """Force range [N] and first-order lag time constants [s] (0 = no lag); then the battery (None: an ideal
    supply): capacity [C], cells, a cell's full and empty open-circuit voltage [V], the pack's resistance [Ω], the
    motors' efficiency, the avionics' power [W], the share of the charge it starts with."""
    if battery is None:
        bat = [0.0] * (ACTUATOR_SIZE - BAT_CAPACITY)
    else:
        b = battery
        bat = [b.capacity_mah * 3.6, float(b.cells), b.v_full, b.v_empty, b.cells * b.cell_resistance_ohm,
               b.efficiency, b.avionics_w, b.remaining]  # fmt: skip
    return np.array([a.min_thrust, a.max_thrust, a.time_constant_up, a.time_constant_down, *bat], dtype=np.float64)
