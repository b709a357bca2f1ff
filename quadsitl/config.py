"""Presets: vehicle, actuator, simulation, controller and reference settings from TOML.

Presets ship inside the package (``quadsitl/presets/*.toml``); a path to any TOML file works too.
Loading validates every key: unknown keys, wrong types and out-of-range values raise
:class:`ConfigError` with a message that names the key, the value and what is allowed.
"""

from __future__ import annotations

import json
import math
import sys
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace
from importlib import resources
from pathlib import Path
from typing import Any

from quadsitl.controller_names import ALLOWED, is_controller_name
from quadsitl.state import Reference, VehicleState

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - exercised on Python 3.10 only
    import tomli as tomllib


class ConfigError(ValueError):
    """A preset or option value was refused. The message names key, value and what is allowed."""


# --------------------------------------------------------------------------------------------
# The parameter groups


@dataclass(frozen=True)
class VehicleParams:
    """Paper Table 1 symbols. Units: SI; inertias [kg·m²]."""

    mass: float  # m [kg]
    ixx: float  # Ix
    iyy: float  # Iy
    izz: float  # Iz
    drag: tuple[float, float, float, float, float, float]  # K1..K6 (K1–K3 [N·s/m], K4–K6 [N·s])
    arm_length: float  # l [m]
    rotor_inertia: float  # Jr [kg·m²]
    thrust_factor: float  # b [N·s²]: F = b·Ω²
    drag_factor: float  # d [N·m·s²]: rotor drag torque = d·Ω²
    gravity: float  # g [m/s²]

    @property
    def d_over_b(self) -> float:
        """Yaw torque per newton of thrust [m] (eq (8))."""
        return self.drag_factor / self.thrust_factor


@dataclass(frozen=True)
class ActuatorParams:
    """Motor model. ``ideal``: reversible, F ∈ [−F_max, F_max], no lag (the paper's assumption).
    ``realistic``: F ∈ [0, F_max] with first-order lag (time constants up/down, 0 = none)."""

    model: str
    max_thrust: float  # F_max per motor [N]
    time_constant_up: float = 0.0  # [s]
    time_constant_down: float = 0.0  # [s]

    @property
    def reversible(self) -> bool:
        return self.model == "ideal"

    @property
    def min_thrust(self) -> float:
        return -self.max_thrust if self.reversible else 0.0


@dataclass(frozen=True)
class SimParams:
    period: float  # control period T [s]
    duration: float  # [s]
    integrator: str  # "euler" | "rk4"
    substeps: int  # integration sub-steps per control period


@dataclass(frozen=True)
class ControllerParams:
    """Controller choice, gains and limits.

    Backstepping gains: either ``gains`` (rates k_i [1/s], pole λ_i = 1 − T·k_i) or ``poles`` (λ_i
    directly); exactly one is set. PD gains per channel (altitude, roll, pitch, yaw): the closed loop
    of the linearised channel is ë + kd·ė + kp·e = 0.
    """

    type: str  # "backstepping" | "pd"
    gains: tuple[float, ...] | None
    poles: tuple[float, ...] | None
    max_tilt: float  # [rad], bound on |roll|, |pitch| references and on the 1/(cφcθ) factor
    thrust_min: float  # u1 bounds [N]
    thrust_max: float
    pd_kp: tuple[float, float, float, float]  # [1/s²]
    pd_kd: tuple[float, float, float, float]  # [1/s]


@dataclass(frozen=True)
class PositionParams:
    """The flight controller around the paper's loops (docs/position.md): the horizontal backstepping loop's
    rates k9..k12 [1/s] (x position, x velocity, y position, y velocity: pole λ = 1 − T·k), the integral
    rates [1/s] of the altitude and horizontal loops (0: off, as the paper's law), the bound on the integral's
    share of a virtual velocity [m/s], and PX4's limits (names in brackets)."""

    gains: tuple[float, float, float, float] = (1.0, 2.0, 1.0, 2.0)
    integral: tuple[float, float] = (0.0, 0.0)  # altitude, horizontal [1/s]
    integral_limit: float = 1.0  # [m/s]
    xy_vel_max: float = 12.0  # [m/s] MPC_XY_VEL_MAX
    z_vel_max_up: float = 3.0  # [m/s] MPC_Z_VEL_MAX_UP
    z_vel_max_dn: float = 1.5  # [m/s] MPC_Z_VEL_MAX_DN
    tilt_max_air: float = math.radians(45.0)  # [rad] MPC_TILTMAX_AIR (a MAVLink parameter in degrees, as PX4's)
    acc_hor: float = 3.0  # [m/s²] MPC_ACC_HOR: acceleration of the auto modes' references
    xy_cruise: float = 5.0  # [m/s] MPC_XY_CRUISE: speed of goto and return
    takeoff_speed: float = 1.5  # [m/s] MPC_TKO_SPEED


# The IMU figures of the two profiles (PX4's Gazebo IMU plugin, PX4-SITL_gazebo-classic
# include/gazebo_imu_plugin.h): "px4", its defaults since 2025 (an IIM42653: no random walk, no turn-on bias),
# and "adis16448", its former defaults (an ADIS16448: densities doubled by the plugin's authors).
IMU_PROFILES: dict[str, dict[str, float]] = {
    "px4": {
        "gyro_noise_density_rad_s_sqrt_hz": 8.7266e-4,
        "gyro_random_walk_rad_s2_sqrt_hz": 0.0,
        "gyro_bias_correlation_time_s": 1000.0,
        "gyro_turn_on_bias_rad_s": 0.0,
        "accel_noise_density_m_s2_sqrt_hz": 6.37e-3,
        "accel_random_walk_m_s3_sqrt_hz": 0.0,
        "accel_bias_correlation_time_s": 300.0,
        "accel_turn_on_bias_m_s2": 0.0,
    },
    "adis16448": {
        "gyro_noise_density_rad_s_sqrt_hz": 3.394e-4,
        "gyro_random_walk_rad_s2_sqrt_hz": 3.8785e-5,
        "gyro_bias_correlation_time_s": 1000.0,
        "gyro_turn_on_bias_rad_s": 0.0087,
        "accel_noise_density_m_s2_sqrt_hz": 4e-3,
        "accel_random_walk_m_s3_sqrt_hz": 6e-3,
        "accel_bias_correlation_time_s": 300.0,
        "accel_turn_on_bias_m_s2": 0.196,
    },
}
GPS_QUEUE = 32  # GPS samples in flight at most (gps_delay_s · gps_rate_hz < GPS_QUEUE)


@dataclass(frozen=True)
class SensorParams:
    """The simulated sensors (docs/sensors.md): noise figures, rates, the Earth's field, the seed. Units are in
    the names. IMU noise as PX4's Gazebo IMU plugin models it (white noise by density, σ = density/√dt, and a
    Gauss–Markov bias driven by the random walk, starting at a random turn-on bias); defaults: the ``px4``
    profile (:data:`IMU_PROFILES`)."""

    profile: str = "px4"
    seed: int = 0
    gyro_noise_density_rad_s_sqrt_hz: float = 8.7266e-4
    gyro_random_walk_rad_s2_sqrt_hz: float = 0.0
    gyro_bias_correlation_time_s: float = 1000.0
    gyro_turn_on_bias_rad_s: float = 0.0
    accel_noise_density_m_s2_sqrt_hz: float = 6.37e-3
    accel_random_walk_m_s3_sqrt_hz: float = 0.0
    accel_bias_correlation_time_s: float = 300.0
    accel_turn_on_bias_m_s2: float = 0.0
    mag_rate_hz: float = 100.0  # PX4 Gazebo magnetometer plugin
    mag_noise_density_gauss_sqrt_hz: float = 4e-4
    mag_random_walk_gauss_s_sqrt_hz: float = 6.4e-6
    mag_bias_correlation_time_s: float = 600.0
    mag_strength_gauss: float = 0.4807  # jMAVSim's Zürich field (quadsitl.earth)
    mag_declination_deg: float = 2.75
    mag_inclination_deg: float = 63.39
    baro_rate_hz: float = 50.0  # PX4 Gazebo barometer plugin
    baro_noise_pa: float = 1.0
    gps_rate_hz: float = 10.0
    gps_delay_s: float = 0.12  # PX4 Gazebo GPS plugin
    gps_xy_error_m: float = 1.0  # the slowly wandering position error (σ), see docs/sensors.md
    gps_z_error_m: float = 2.0
    gps_error_correlation_time_s: float = 60.0
    gps_xy_velocity_noise_m_s: float = 0.05
    gps_z_velocity_noise_m_s: float = 0.1
    gps_satellites: int = 10


# A flight on sensors (`fly` and `sim` with --state sensors) waits on the ground this long first, motors off: the
# estimator aligns at rest in its first second. `fly`'s plant holds its clock there until the vehicle arms, so both
# start flying at the same tick, with the same sensor noise behind them.
SENSOR_GROUND_S = 2.0  # [s]

# MIL-F-8785C's turbulence levels by the wind speed at 20 ft, W20 [knots] (sitl/wind.py's Dryden model)
TURBULENCE_W20_KNOTS = {"none": 0.0, "light": 15.0, "moderate": 30.0, "severe": 45.0}


@dataclass(frozen=True)
class WindParams:
    """The air the plant flies in and a disturbing force (docs/sensors.md, "Wind"): a mean wind of ``speed_m_s``
    [m/s] blowing FROM ``from_deg`` [deg, clockwise from north, as weather reports give it: 270 = from the west];
    Dryden turbulence at a MIL-F-8785C level; one discrete 1 − cos gust of ``gust_m_s`` [m/s] from
    ``gust_from_deg``, rising over ``gust_rise_s`` from ``gust_start_s`` [s after lift-off] and then held; a
    constant external force ``force_n`` [N, NED] on the vehicle (for tests: a payload, a tether). ``seed`` seeds
    the turbulence. The default is calm: the plant flies exactly as with no [wind] section."""

    speed_m_s: float = 0.0
    from_deg: float = 0.0
    turbulence: str = "none"
    gust_m_s: float = 0.0
    gust_rise_s: float = 1.0
    gust_start_s: float = 0.0
    gust_from_deg: float = 0.0
    seed: int = 0
    force_n: tuple[float, float, float] = (0.0, 0.0, 0.0)


@dataclass(frozen=True)
class InitialState:
    """Where the vehicle starts: altitude [m], ZYX Euler angles [rad], climb rate [m/s] (up) and Euler-angle
    rates φ̇, θ̇, ψ̇ [rad/s] (not body rates); at the origin, otherwise at rest."""

    altitude: float = 0.0
    roll: float = 0.0
    pitch: float = 0.0
    yaw: float = 0.0
    climb_rate: float = 0.0
    roll_rate: float = 0.0
    pitch_rate: float = 0.0
    yaw_rate: float = 0.0


# Divergence: the bounds a state must stay within (``lim``, LIMITS_SIZE): |x|, |y|, |z| [m]; |vx|, |vy|, |vz|
# [m/s]; |roll|, |pitch| [rad] (strictly below); |Euler-angle rates| [rad/s]; and the yaw within 1000 turns. The
# check itself is compiled (:func:`sitl.plant.inside`); a sweep's ``[limits]`` table names them.
L_POSITION, L_SPEED, L_TILT, L_RATE = range(4)
LIMITS_SIZE = 4
LIMIT_NAMES = ("position", "speed", "tilt", "rate")
DEFAULT_LIMITS = (1e5, 1e4, math.pi / 2, 1e3)
MAX_YAW = 1e3 * 2.0 * math.pi  # [rad]


@dataclass(frozen=True)
class Preset:
    name: str
    description: str
    vehicle: VehicleParams
    actuators: ActuatorParams
    sim: SimParams
    controller: ControllerParams
    reference: Reference
    initial: InitialState = field(default_factory=InitialState)
    position: PositionParams = field(default_factory=PositionParams)
    sensors: SensorParams | None = None  # None: no [sensors] section, the autopilot gets the true state
    wind: WindParams = field(default_factory=WindParams)  # no [wind] section: calm
    model: tuple[tuple[str, float], ...] = ()  # the [model] section: (VehicleParams field, value), in file order

    @property
    def autopilot_model(self) -> VehicleParams:
        """The autopilot's model of the vehicle, what its controllers and allocation are built on: the vehicle's
        parameters with the [model] section's keys over them (none: the vehicle itself). A model unlike the
        vehicle is a mismatch, as a sweep's ``mismatch.*`` draws make."""
        return replace(self.vehicle, **dict(self.model)) if self.model else self.vehicle

    def poles(self) -> tuple[float, ...]:
        """The eight discrete poles λ_1..λ_8 (from rates k when given as rates: λ = 1 − T·k)."""
        c = self.controller
        if c.poles is not None:
            return c.poles
        assert c.gains is not None
        return tuple(1.0 - self.sim.period * k for k in c.gains)


# --------------------------------------------------------------------------------------------
# Validation: one small spec per key


@dataclass(frozen=True)
class Spec:
    """What a key accepts. ``check`` returns an error phrase or None."""

    kind: str  # "number" | "int" | "string" | "numbers"
    allowed: str  # human description of what is allowed
    check: Callable[[Any], bool] = lambda v: True
    length: int | None = None
    required: bool = True
    default: Any = None


def _num(allowed: str, ok: Callable[[float], bool], **kw: Any) -> Spec:
    return Spec("number", allowed, ok, **kw)


POSITIVE = _num("a finite number > 0", lambda v: 0 < v < math.inf)
NONNEG = _num("a finite number >= 0", lambda v: 0 <= v < math.inf)
FINITE = _num("a finite number", math.isfinite)


def _sensor(key: str, allowed: str, ok: Callable[[float], bool]) -> Spec:
    """An optional key of [sensors], defaulting to :class:`SensorParams`' value."""
    return _num(allowed, ok, required=False, default=getattr(SensorParams, key))


SCHEMA: dict[str, dict[str, Spec]] = {
    "vehicle": {
        "mass": POSITIVE,
        "inertia": Spec("numbers", "3 finite numbers > 0 (Ix, Iy, Iz)", lambda v: 0 < v < math.inf, 3),
        "drag": Spec("numbers", "6 finite numbers >= 0 (K1..K6)", lambda v: 0 <= v < math.inf, 6),
        "arm_length": POSITIVE,
        "rotor_inertia": NONNEG,
        "thrust_factor": POSITIVE,
        "drag_factor": POSITIVE,
        "gravity": _num("a number in [0, 100]", lambda v: 0 <= v <= 100, required=False, default=9.81),
    },
    "actuators": {
        "model": Spec("string", "one of: ideal, realistic", lambda v: v in ("ideal", "realistic")),
        "max_thrust": POSITIVE,
        "time_constant_up": _num("a number in [0, 1] s", lambda v: 0 <= v <= 1, required=False, default=0.0),
        "time_constant_down": _num("a number in [0, 1] s", lambda v: 0 <= v <= 1, required=False, default=0.0),
    },
    "sim": {
        "period": _num("a number in [1e-5, 0.1] s", lambda v: 1e-5 <= v <= 0.1),
        "duration": _num("a number in (0, 3600] s", lambda v: 0 < v <= 3600),
        "integrator": Spec("string", "one of: euler, rk4", lambda v: v in ("euler", "rk4")),
        "substeps": Spec("int", "an integer in [1, 1000]", lambda v: 1 <= v <= 1000, required=False, default=1),
    },
    "controller": {
        "type": Spec("string", ALLOWED + " (a relative path: from the working directory)", is_controller_name),
        "gains": Spec("numbers", "8 finite numbers (rates k_i, 1/s)", math.isfinite, 8, required=False),
        "poles": Spec("numbers", "8 finite numbers (poles λ_i)", math.isfinite, 8, required=False),
        "max_tilt": _num("a number in (0, 1.5533] rad (< 89°)", lambda v: 0 < v <= 1.5533),
        "thrust_min": FINITE,
        "thrust_max": FINITE,
    },
    "pd": {
        "kp": Spec(
            "numbers",
            "4 finite numbers >= 0 (altitude, roll, pitch, yaw) [1/s²]",
            lambda v: 0 <= v < math.inf,
            4,
        ),
        "kd": Spec(
            "numbers",
            "4 finite numbers >= 0 (altitude, roll, pitch, yaw) [1/s]",
            lambda v: 0 <= v < math.inf,
            4,
        ),
    },
    "reference": {
        "altitude": _num("a number in [0, 10000] m", lambda v: 0 <= v <= 10000),
        "roll": _num("a number in (−π/2, π/2) rad", lambda v: abs(v) < math.pi / 2),
        "pitch": _num("a number in (−π/2, π/2) rad", lambda v: abs(v) < math.pi / 2),
        "yaw": _num("a number in [−π, π] rad", lambda v: abs(v) <= math.pi),
    },
    "position": {
        "gains": Spec(
            "numbers",
            "4 finite numbers > 0 (k9..k12: x, vx, y, vy rates, 1/s)",
            lambda v: 0 < v < math.inf,
            4,
            required=False,
            default=PositionParams.gains,
        ),
        "integral": Spec(
            "numbers",
            "2 finite numbers >= 0 (altitude, horizontal integral rates, 1/s; 0 = off)",
            lambda v: 0 <= v < math.inf,
            2,
            required=False,
            default=PositionParams.integral,
        ),
        "integral_limit": _num("a number in (0, 100] m/s", lambda v: 0 < v <= 100, required=False, default=1.0),
        "xy_vel_max": _num("a number in (0, 100] m/s", lambda v: 0 < v <= 100, required=False, default=12.0),
        "z_vel_max_up": _num("a number in (0, 100] m/s", lambda v: 0 < v <= 100, required=False, default=3.0),
        "z_vel_max_dn": _num("a number in (0, 100] m/s", lambda v: 0 < v <= 100, required=False, default=1.5),
        "tilt_max_air": _num(
            "a number in (0, 1.5533] rad (< 89°)",
            lambda v: 0 < v <= 1.5533,
            required=False,
            default=PositionParams.tilt_max_air,
        ),
        "acc_hor": _num("a number in (0, 100] m/s²", lambda v: 0 < v <= 100, required=False, default=3.0),
        "xy_cruise": _num("a number in (0, 100] m/s", lambda v: 0 < v <= 100, required=False, default=5.0),
        "takeoff_speed": _num("a number in (0, 100] m/s", lambda v: 0 < v <= 100, required=False, default=1.5),
    },
    "sensors": {
        "profile": Spec("string", "one of: px4, adis16448", lambda v: v in IMU_PROFILES, required=False, default="px4"),
        "seed": Spec("int", "an integer in [0, 2**63 - 1]", lambda v: 0 <= v < 2**63, required=False, default=0),
        # the IMU's defaults come from the profile
        "gyro_noise_density_rad_s_sqrt_hz": _num(
            "a number in [0, 0.1] rad/s/√Hz", lambda v: 0 <= v <= 0.1, required=False
        ),
        "gyro_random_walk_rad_s2_sqrt_hz": _num(
            "a number in [0, 0.01] rad/s²/√Hz", lambda v: 0 <= v <= 0.01, required=False
        ),
        "gyro_bias_correlation_time_s": _num("a number in (0, 1e6] s", lambda v: 0 < v <= 1e6, required=False),
        "gyro_turn_on_bias_rad_s": _num("a number in [0, 0.5] rad/s", lambda v: 0 <= v <= 0.5, required=False),
        "accel_noise_density_m_s2_sqrt_hz": _num("a number in [0, 1] m/s²/√Hz", lambda v: 0 <= v <= 1, required=False),
        "accel_random_walk_m_s3_sqrt_hz": _num(
            "a number in [0, 0.1] m/s³/√Hz", lambda v: 0 <= v <= 0.1, required=False
        ),
        "accel_bias_correlation_time_s": _num("a number in (0, 1e6] s", lambda v: 0 < v <= 1e6, required=False),
        "accel_turn_on_bias_m_s2": _num("a number in [0, 2] m/s²", lambda v: 0 <= v <= 2, required=False),
        "mag_rate_hz": _sensor("mag_rate_hz", "a number in [1, 1000] Hz", lambda v: 1 <= v <= 1000),
        "mag_noise_density_gauss_sqrt_hz": _sensor(
            "mag_noise_density_gauss_sqrt_hz", "a number in [0, 0.01] gauss/√Hz", lambda v: 0 <= v <= 0.01
        ),
        "mag_random_walk_gauss_s_sqrt_hz": _sensor(
            "mag_random_walk_gauss_s_sqrt_hz", "a number in [0, 0.001] gauss/s/√Hz", lambda v: 0 <= v <= 0.001
        ),
        "mag_bias_correlation_time_s": _sensor(
            "mag_bias_correlation_time_s", "a number in (0, 1e6] s", lambda v: 0 < v <= 1e6
        ),
        "mag_strength_gauss": _sensor(
            "mag_strength_gauss", "a number in [0.2, 0.7] gauss (the Earth's field)", lambda v: 0.2 <= v <= 0.7
        ),
        "mag_declination_deg": _sensor("mag_declination_deg", "a number in [-180, 180] deg", lambda v: abs(v) <= 180),
        "mag_inclination_deg": _sensor("mag_inclination_deg", "a number in [-90, 90] deg", lambda v: abs(v) <= 90),
        "baro_rate_hz": _sensor("baro_rate_hz", "a number in [1, 1000] Hz", lambda v: 1 <= v <= 1000),
        "baro_noise_pa": _sensor("baro_noise_pa", "a number in [0, 100] Pa", lambda v: 0 <= v <= 100),
        "gps_rate_hz": _sensor("gps_rate_hz", "a number in [1, 100] Hz", lambda v: 1 <= v <= 100),
        "gps_delay_s": _sensor("gps_delay_s", "a number in [0, 1] s", lambda v: 0 <= v <= 1),
        "gps_xy_error_m": _sensor("gps_xy_error_m", "a number in [0, 100] m", lambda v: 0 <= v <= 100),
        "gps_z_error_m": _sensor("gps_z_error_m", "a number in [0, 100] m", lambda v: 0 <= v <= 100),
        "gps_error_correlation_time_s": _sensor(
            "gps_error_correlation_time_s", "a number in (0, 1e5] s", lambda v: 0 < v <= 1e5
        ),
        "gps_xy_velocity_noise_m_s": _sensor(
            "gps_xy_velocity_noise_m_s", "a number in [0, 10] m/s", lambda v: 0 <= v <= 10
        ),
        "gps_z_velocity_noise_m_s": _sensor(
            "gps_z_velocity_noise_m_s", "a number in [0, 10] m/s", lambda v: 0 <= v <= 10
        ),
        "gps_satellites": Spec("int", "an integer in [4, 64]", lambda v: 4 <= v <= 64, required=False, default=10),
    },
    "wind": {
        "speed_m_s": _num("a number in [0, 50] m/s", lambda v: 0 <= v <= 50, required=False, default=0.0),
        "from_deg": _num(
            "a number in [0, 360] deg (clockwise from north)", lambda v: 0 <= v <= 360, required=False, default=0.0
        ),
        "turbulence": Spec(
            "string",
            f"one of: {', '.join(TURBULENCE_W20_KNOTS)}",
            lambda v: v in TURBULENCE_W20_KNOTS,
            required=False,
            default="none",
        ),
        "gust_m_s": _num("a number in [0, 50] m/s", lambda v: 0 <= v <= 50, required=False, default=0.0),
        "gust_rise_s": _num("a number in (0, 100] s", lambda v: 0 < v <= 100, required=False, default=1.0),
        "gust_start_s": _num("a number in [0, 3600] s", lambda v: 0 <= v <= 3600, required=False, default=0.0),
        "gust_from_deg": _num("a number in [0, 360] deg", lambda v: 0 <= v <= 360, required=False, default=0.0),
        "seed": Spec("int", "an integer in [0, 2**63 - 1]", lambda v: 0 <= v < 2**63, required=False, default=0),
        "force_n": Spec(
            "numbers",
            "3 numbers in [-1000, 1000] N (north, east, down)",
            lambda v: abs(v) <= 1000,
            3,
            required=False,
            default=(0.0, 0.0, 0.0),
        ),
    },
    "initial": {
        "altitude": _num("a number in [0, 10000] m", lambda v: 0 <= v <= 10000, required=False, default=0.0),
        "roll": _num("a number in (−π/2, π/2) rad", lambda v: abs(v) < math.pi / 2, required=False, default=0.0),
        "pitch": _num("a number in (−π/2, π/2) rad", lambda v: abs(v) < math.pi / 2, required=False, default=0.0),
        "yaw": _num("a number in [−π, π] rad", lambda v: abs(v) <= math.pi, required=False, default=0.0),
        "climb_rate": _num("a finite number [m/s]", math.isfinite, required=False, default=0.0),
        "roll_rate": _num("a finite number [rad/s]", math.isfinite, required=False, default=0.0),
        "pitch_rate": _num("a finite number [rad/s]", math.isfinite, required=False, default=0.0),
        "yaw_rate": _num("a finite number [rad/s]", math.isfinite, required=False, default=0.0),
    },
}
# [model]: the autopilot's model of the vehicle, key by key over [vehicle]'s values (each key optional).
SCHEMA["model"] = {key: replace(spec, required=False, default=None) for key, spec in SCHEMA["vehicle"].items()}
TOP_LEVEL_KEYS = {"description"}
OPTIONAL_SECTIONS = {"initial", "position", "sensors", "model", "wind"}


def _is_number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def check_value(key: str, value: Any, spec: Spec, where: str = "") -> Any:
    """Validate one value against its spec; return it normalised (floats, tuples)."""
    prefix = f"{where}: " if where else ""

    def fail() -> ConfigError:
        return ConfigError(f"{prefix}{key} = {value!r}: expected {spec.allowed}")

    if spec.kind == "number":
        if not _is_number(value) or not spec.check(float(value)):
            raise fail()
        return float(value)
    if spec.kind == "int":
        if not isinstance(value, int) or isinstance(value, bool) or not spec.check(value):
            raise fail()
        return value
    if spec.kind == "string":
        if not isinstance(value, str) or not spec.check(value):
            raise fail()
        return value
    if spec.kind == "numbers":
        if not isinstance(value, (list, tuple)) or (spec.length is not None and len(value) != spec.length):
            raise fail()
        if not all(_is_number(v) and spec.check(float(v)) for v in value):
            raise fail()
        return tuple(float(v) for v in value)
    raise AssertionError(spec.kind)


def _validate(raw: dict[str, Any], where: str) -> dict[str, dict[str, Any]]:
    out: dict[str, dict[str, Any]] = {}
    for key in raw:
        if key not in SCHEMA and key not in TOP_LEVEL_KEYS:
            allowed = ", ".join(sorted([*SCHEMA, *TOP_LEVEL_KEYS]))
            raise ConfigError(f"{where}: unknown key {key!r}; allowed top-level keys: {allowed}")
    for section, specs in SCHEMA.items():
        table = raw.get(section)
        if table is None:
            if section in OPTIONAL_SECTIONS:
                table = {}
            else:
                raise ConfigError(f"{where}: missing section [{section}]")
        if not isinstance(table, dict):
            raise ConfigError(f"{where}: {section} = {table!r}: expected a table [{section}]")
        for key in table:
            if key not in specs:
                raise ConfigError(f"{where}: unknown key {section}.{key}; allowed in [{section}]: {', '.join(specs)}")
        values: dict[str, Any] = {}
        for key, spec in specs.items():
            if key in table:
                values[key] = check_value(f"{section}.{key}", table[key], spec, where)
            elif spec.required:
                raise ConfigError(f"{where}: missing key {section}.{key} ({spec.allowed})")
            else:
                values[key] = spec.default
        out[section] = values
    return out


def _build(name: str, raw: dict[str, Any], where: str) -> Preset:
    v = _validate(raw, where)
    desc = raw.get("description", "")
    if not isinstance(desc, str):
        raise ConfigError(f"{where}: description = {desc!r}: expected a string")
    veh = v["vehicle"]
    ix, iy, iz = veh.pop("inertia")
    vehicle = VehicleParams(ixx=ix, iyy=iy, izz=iz, **veh)
    model: list[tuple[str, Any]] = []
    for key, value in v["model"].items():
        if value is not None:
            model += zip(("ixx", "iyy", "izz"), value) if key == "inertia" else [(key, value)]
    c = v["controller"]
    if (c["gains"] is None) == (c["poles"] is None):
        raise ConfigError(
            f"{where}: controller.gains / controller.poles: give exactly one of them "
            "(gains = 8 rates k_i in 1/s, or poles = 8 discrete poles λ_i)"
        )
    if c["thrust_min"] >= c["thrust_max"]:
        raise ConfigError(
            f"{where}: controller.thrust_min = {c['thrust_min']!r}: must be below "
            f"controller.thrust_max = {c['thrust_max']!r}"
        )
    controller = ControllerParams(pd_kp=v["pd"]["kp"], pd_kd=v["pd"]["kd"], **c)
    ref = Reference(**v["reference"])
    for axis in ("roll", "pitch"):
        if abs(getattr(ref, axis)) > controller.max_tilt:
            raise ConfigError(
                f"{where}: reference.{axis} = {getattr(ref, axis)!r}: exceeds controller.max_tilt = "
                f"{controller.max_tilt!r} rad"
            )
    sim = SimParams(**v["sim"])
    sensors = _sensors(v["sensors"], sim, where) if "sensors" in raw else None
    return Preset(
        name=name,
        description=desc,
        vehicle=vehicle,
        actuators=ActuatorParams(**v["actuators"]),
        sim=sim,
        controller=controller,
        reference=ref,
        initial=InitialState(**v["initial"]),
        position=PositionParams(**v["position"]),
        sensors=sensors,
        wind=WindParams(**v["wind"]),
        model=tuple(model),
    )


def _sensors(values: dict[str, Any], sim: SimParams, where: str) -> SensorParams:
    """The [sensors] section: the profile's IMU figures where no key gives them, and the checks across keys (no
    sensor faster than the control tick, the GPS samples in flight within the queue)."""
    values = {key: IMU_PROFILES[values["profile"]][key] if value is None else value for key, value in values.items()}
    tick_rate = 1.0 / sim.period
    for key in ("mag_rate_hz", "baro_rate_hz", "gps_rate_hz"):
        if values[key] > tick_rate * (1 + 1e-9):
            raise ConfigError(
                f"{where}: sensors.{key} = {values[key]!r}: must not exceed the control rate 1/sim.period = "
                f"{tick_rate:g} Hz"
            )
    if values["gps_delay_s"] * values["gps_rate_hz"] >= GPS_QUEUE - 1:
        raise ConfigError(
            f"{where}: sensors.gps_delay_s = {values['gps_delay_s']!r}: with sensors.gps_rate_hz = "
            f"{values['gps_rate_hz']!r}, gps_delay_s · gps_rate_hz must be below {GPS_QUEUE - 1} "
            "(the GPS samples in flight)"
        )
    return SensorParams(**values)


def default_sensors(sim: SimParams) -> SensorParams:
    """The sensors of a preset without a [sensors] section, flown on sensors (``--state sensors``): the defaults,
    checked against the control rate as a section's are."""
    return _sensors(asdict(SensorParams()), sim, "--state sensors")


def wind_change(payload: bytes | str) -> dict[str, Any]:
    """A change of the wind while a plant flies (the Zenoh key ``quadsitl/<vehicle>/wind``): a JSON object with
    any of the [wind] keys, each checked as in a preset; returns them checked and normalised, for
    ``dataclasses.replace`` over the wind in effect. Anything else raises :class:`ConfigError` naming the key,
    the value and what is allowed."""
    try:
        values = json.loads(payload)
    except (ValueError, UnicodeDecodeError) as exc:
        raise ConfigError(f"wind: not JSON: {exc}") from None
    if not isinstance(values, dict) or not values:
        raise ConfigError(f"wind: {values!r}: expected a JSON object with any of: {', '.join(SCHEMA['wind'])}")
    specs = SCHEMA["wind"]
    for key in values:
        if key not in specs:
            raise ConfigError(f"wind: unknown key {key!r}; allowed: {', '.join(specs)}")
    return {key: check_value(f"wind.{key}", value, specs[key]) for key, value in values.items()}


def available_presets() -> list[str]:
    """Names of the presets shipped with the package."""
    folder = resources.files("quadsitl") / "presets"
    return sorted(p.name[:-5] for p in folder.iterdir() if p.name.endswith(".toml"))


def initial_state(preset: Preset) -> VehicleState:
    """The preset's initial state: at the origin, at the given altitude and attitude, climbing at its climb rate
    and turning at its Euler-angle rates (NED: z = −altitude, vz = −climb rate)."""
    i = preset.initial
    return VehicleState(z=-i.altitude, vz=-i.climb_rate, roll=i.roll, pitch=i.pitch, yaw=i.yaw, roll_dot=i.roll_rate,
                        pitch_dot=i.pitch_rate, yaw_dot=i.yaw_rate)  # fmt: skip


def load_preset(name_or_path: str) -> Preset:
    """Load a shipped preset by name (``paper``) or any TOML file by path, validated."""
    text, name = read_preset(name_or_path)
    return parse_preset(text, name)


def read_preset(name_or_path: str) -> tuple[str, str]:
    """A shipped preset's (``paper``) or a TOML file's text, and the preset's name: (text, name)."""
    if name_or_path.endswith(".toml") or "/" in name_or_path or "\\" in name_or_path:
        path = Path(name_or_path)
        if not path.is_file():
            raise ConfigError(f"preset file {name_or_path!r} does not exist")
        text = path.read_text(encoding="utf-8")
        name = path.stem
    else:
        names = available_presets()
        if name_or_path not in names:
            raise ConfigError(f"unknown preset {name_or_path!r}; available presets: {', '.join(names)}")
        text = (resources.files("quadsitl") / "presets" / f"{name_or_path}.toml").read_text(encoding="utf-8")
        name = name_or_path
    return text, name


def _toml_value(value: Any) -> str:
    """One value as TOML: floats by ``repr`` (which reads back to the same bits), strings JSON-quoted (a JSON
    string is a TOML basic string), sequences as arrays."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (tuple, list)):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    if isinstance(value, str):
        return json.dumps(value, ensure_ascii=False)
    if isinstance(value, float):
        return repr(value) if math.isfinite(value) else ("nan" if math.isnan(value) else repr(value))
    return str(value)


def preset_toml(preset: Preset) -> str:
    """The preset as TOML text that :func:`parse_preset` reads back to a preset that flies the same, every number
    to the bit (the one difference: a [model] that gave one inertia reads back as giving all three, at the same
    values): how a sweep's trial becomes a preset file ``quadsitl fly`` and ``quadsitl sim`` take."""
    v, c = preset.vehicle, preset.controller
    vehicle = {"mass": v.mass, "inertia": (v.ixx, v.iyy, v.izz), "drag": v.drag, "arm_length": v.arm_length,
               "rotor_inertia": v.rotor_inertia, "thrust_factor": v.thrust_factor, "drag_factor": v.drag_factor,
               "gravity": v.gravity}  # fmt: skip
    sections: dict[str, dict[str, Any]] = {"vehicle": vehicle}
    if preset.model:
        m, given = preset.autopilot_model, dict(preset.model)
        model = {k: getattr(m, k) for k in sections["vehicle"] if k in given}
        if {"ixx", "iyy", "izz"} & set(given):
            model["inertia"] = (m.ixx, m.iyy, m.izz)
        sections["model"] = model
    sections["actuators"] = asdict(preset.actuators)
    sections["sim"] = asdict(preset.sim)
    controller = {"type": c.type, "max_tilt": c.max_tilt, "thrust_min": c.thrust_min, "thrust_max": c.thrust_max}
    controller.update({"gains": c.gains} if c.gains is not None else {"poles": c.poles})
    sections["controller"] = controller
    sections["pd"] = {"kp": c.pd_kp, "kd": c.pd_kd}
    sections["reference"] = preset.reference._asdict()
    sections["initial"] = asdict(preset.initial)
    sections["position"] = asdict(preset.position)
    if preset.sensors is not None:
        sections["sensors"] = asdict(preset.sensors)
    if preset.wind != WindParams():
        sections["wind"] = asdict(preset.wind)
    lines = [f"description = {_toml_value(preset.description)}"]
    for section, values in sections.items():
        lines += ["", f"[{section}]", *(f"{k} = {_toml_value(x)}" for k, x in values.items())]
    return "\n".join(lines) + "\n"


def parse_preset(text: str, name: str = "preset") -> Preset:
    """Parse and validate a preset from TOML text."""
    where = f"preset {name!r}"
    try:
        raw = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{where}: not valid TOML: {exc}") from None
    return _build(name, raw, where)
