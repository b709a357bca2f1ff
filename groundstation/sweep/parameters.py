"""What a sweep's spec can vary (:data:`PARAMETERS`), where each lands in the trials' arrays, and what each may take
(:func:`vary_rule`). Pure: no I/O, nothing compiled.

``plant.*`` the plant's vehicle (mass, ixx, iyy, izz, k1..k6, arm_length, rotor_inertia, thrust_factor, drag_factor;
SI units as in the presets), ``model.*`` the autopilot's model of it (default: the plant's), ``mismatch.*`` the model
as a factor of the plant's value (``mismatch.inertia`` scales ixx, iyy and izz by one draw), ``gains.*`` the
backstepping's rates k1..k8 [1/s] (pole λ = 1 − T·k), the PD's kp1..kp4 [1/s²], kd1..kd4 [1/s] (altitude, roll,
pitch, yaw) and the position loop's integral rates ki_alt, ki_xy [1/s], ``initial.*`` the initial state (altitude
[m], roll, pitch, yaw [rad], climb_rate [m/s], roll_rate, pitch_rate, yaw_rate [rad/s]: Euler-angle rates),
``reference.*`` (altitude [m], roll, pitch, yaw [rad]), ``wind.*`` and ``sensors.*``.

Where a name is a preset key, its bound is that key's declaration (:mod:`quadsitl.config`, :mod:`quadsitl.keys`):
the vehicle's lower bounds, the angles' and the rates' ranges. A trial's draw may go where a preset may not: a
vehicle parameter, a PD gain, an altitude unbounded above, the wind and the integral rates within wider ranges of
their own (below).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

from quadsitl.config import SCHEMA, TURBULENCE_W20_KNOTS, VehicleParams
from quadsitl.keys import Spec, bound_text, declared
from quadsitl.param_arrays import ARM, IXX, IYY, IZZ, JR, K1, MASS, B, D
from quadsitl.state import Reference, VehicleState

_DECLARED = declared(VehicleParams)
DRAG_FIELDS = tuple(f"k{i + 1}" for i in range(6))  # the drag tuple's elements, K1..K6, as names
_COLUMNS = {"mass": MASS, "ixx": IXX, "iyy": IYY, "izz": IZZ, **{k: K1 + i for i, k in enumerate(DRAG_FIELDS)},
            "arm_length": ARM, "rotor_inertia": JR, "thrust_factor": B, "drag_factor": D}  # fmt: skip
VEHICLE: dict[str, tuple[int, Spec]] = {
    name: (column, _DECLARED["drag" if name in DRAG_FIELDS else name]) for name, column in _COLUMNS.items()
}
"""A vehicle parameter's name → (its index in :func:`quadsitl.param_arrays.vehicle_array`, its preset key: the
lower bound a draw must keep)."""

# initial.* and reference.*: (the index in the state or the reference, a test of one value, what is allowed). The
# angles and rates take their preset keys' ranges; the altitude only >= 0 (a preset's stops at 10 km).
Rule = tuple[int, Callable[[float], bool], str]


def _as_key(index: int, key: Spec) -> Rule:
    return index, key.check, key.describe(bracket_unit=True)


_ALTITUDE = (lambda v: v >= 0.0), "a number >= 0 [m]"
_STATE_FIELDS = {"altitude": "z", "roll": "roll", "pitch": "pitch", "yaw": "yaw", "climb_rate": "vz",
                 "roll_rate": "roll_dot", "pitch_rate": "pitch_dot", "yaw_rate": "yaw_dot"}  # fmt: skip
INITIAL: dict[str, Rule] = {
    name: (VehicleState._fields.index(field), *_ALTITUDE) if name == "altitude"
    else _as_key(VehicleState._fields.index(field), SCHEMA["initial"][name])
    for name, field in _STATE_FIELDS.items()
}  # fmt: skip
REFERENCE: dict[str, Rule] = {
    name: (i, *_ALTITUDE) if name == "altitude" else _as_key(i, SCHEMA["reference"][name])
    for i, name in enumerate(Reference._fields)
}
RATES = tuple(f"k{i + 1}" for i in range(8))
PD_GAINS = tuple(f"kp{i + 1}" for i in range(4)) + tuple(f"kd{i + 1}" for i in range(4))
INTEGRAL = ("ki_alt", "ki_xy")  # the position controller's integral rates k_I [1/s] ([position] integral)
TURBULENCE_LEVELS = tuple(TURBULENCE_W20_KNOTS)  # wind.turbulence's values 0..3
# wind.* (the preset's [wind], WindParams' field) and sensors.*: (the field, a test, what is allowed)
WIND = {
    "speed": ("speed_m_s", lambda v: 0.0 <= v <= 100.0, "a number in [0, 100] [m/s]"),
    "from": ("from_deg", math.isfinite, "a finite number [deg, clockwise from north, where it blows from]"),
    "turbulence": ("turbulence", lambda v: v in (0.0, 1.0, 2.0, 3.0), "0, 1, 2 or 3 (none, light, moderate, severe)"),
    "gust": ("gust_m_s", lambda v: 0.0 <= v <= 100.0, "a number in [0, 100] [m/s]"),
    "gust_from": ("gust_from_deg", math.isfinite, "a finite number [deg]"),
    "gust_start": ("gust_start_s", lambda v: 0.0 <= v <= 3600.0, "a number in [0, 3600] [s after lift-off]"),
    "gust_rise": ("gust_rise_s", lambda v: 0.0 < v <= 3600.0, "a number in (0, 3600] [s]"),
    "seed": ("seed", lambda v: 0 <= v < 2**63, "a number in [0, 2^63) (its integer part seeds the turbulence)"),
}
assert len(TURBULENCE_LEVELS) == 4  # as wind.turbulence's words say
SENSOR_NOISE = ("gyro_noise_density_rad_s_sqrt_hz", "gyro_random_walk_rad_s2_sqrt_hz", "gyro_turn_on_bias_rad_s",
                "accel_noise_density_m_s2_sqrt_hz", "accel_random_walk_m_s3_sqrt_hz", "accel_turn_on_bias_m_s2",
                "mag_noise_density_gauss_sqrt_hz", "mag_random_walk_gauss_s_sqrt_hz", "baro_noise_pa", "gps_xy_error_m",
                "gps_z_error_m", "gps_xy_velocity_noise_m_s", "gps_z_velocity_noise_m_s")  # fmt: skip
"""The sensor figures ``sensors.noise`` scales (every noise, random walk, turn-on bias and GPS error)."""
SENSORS = {
    "noise": (lambda v: 0.0 <= v <= 100.0, "a factor in [0, 100] on every noise figure of the preset's [sensors]"),
    "seed": (lambda v: 0 <= v < 2**63, "a number in [0, 2^63) (its integer part seeds the sensors' noise)"),
}


def _at_least(key: Spec, what: str) -> tuple[Callable[[float], bool], str]:
    """A draw above the key's lower bound (not bounded above): a test and its words ("a number > 0")."""
    low, strict = key.low, key.low_open
    words = f"{what} {'>' if strict else '>='} {bound_text(low)}"
    return ((lambda v: v > low) if strict else (lambda v: v >= low)), words


def vary_rule(name: str) -> tuple[Any, str] | None:
    """(a test of one value, what is allowed in words) for a parameter's full name, or None: not a parameter."""
    group, _, key = name.partition(".")
    if group in ("plant", "model", "mismatch") and key in VEHICLE:
        return _at_least(VEHICLE[key][1], "a factor" if group == "mismatch" else "a number")
    if name == "mismatch.inertia":
        return (lambda v: v > 0.0), "a factor > 0 (scales ixx, iyy, izz)"
    if group == "gains" and key in RATES:
        return SCHEMA["controller"]["gains"].check, "a finite rate k [1/s] (pole λ = 1 − T·k)"
    if group == "gains" and key in PD_GAINS:
        return _at_least(SCHEMA["pd"]["kp" if key.startswith("kp") else "kd"], "a number")
    if group == "gains" and key in INTEGRAL:
        return (lambda v: 0.0 <= v <= 100.0), "an integral rate k_I in [0, 100] [1/s]"
    if group == "wind" and key in WIND:
        return WIND[key][1], WIND[key][2]
    if group == "sensors" and key in SENSORS:
        return SENSORS[key]
    if group == "initial" and key in INITIAL:
        return INITIAL[key][1], INITIAL[key][2]
    if group == "reference" and key in REFERENCE:
        return REFERENCE[key][1], REFERENCE[key][2]
    return None


PARAMETERS = (
    *(f"{g}.{k}" for g in ("plant", "model", "mismatch") for k in VEHICLE),
    "mismatch.inertia",
    *(f"gains.{k}" for k in RATES + PD_GAINS + INTEGRAL),
    *(f"initial.{k}" for k in INITIAL),
    *(f"reference.{k}" for k in REFERENCE),
    *(f"wind.{k}" for k in WIND),
    *(f"sensors.{k}" for k in SENSORS),
)
"""Every name a spec may vary."""
