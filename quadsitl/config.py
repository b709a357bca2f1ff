"""Presets: vehicle, actuator, simulation, controller and reference settings from TOML.

Presets ship inside the package (``quadsitl/presets/*.toml``); a path to any TOML file works too.
Loading validates every key: unknown keys, wrong types and out-of-range values raise
:class:`ConfigError` with a message that names the key, the value and what is allowed.
"""

from __future__ import annotations

import dataclasses
import json
import math
import sys
from dataclasses import asdict, dataclass, field, replace
from importlib import resources
from pathlib import Path
from typing import Any

from quadsitl.controller_names import ALLOWED, is_controller_name
from quadsitl.keys import REQUIRED, SEED_MAX, Spec, declared, grouped, key, mavlink, section_of, spec
from quadsitl.state import Reference, VehicleState

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - exercised on Python 3.10 only
    import tomli as tomllib


class ConfigError(ValueError):
    """A preset or option value was refused. The message names key, value and what is allowed."""


# --------------------------------------------------------------------------------------------
# The parameter groups: every key declared once, as the field that holds it (quadsitl.keys: its default, unit,
# range, doc and MAVLink parameter); the schema, the refusals and the parameter table are made from these.

PD_CHANNELS = ("ALT", "ROLL", "PITCH", "YAW")  # the PD's channels, as its MAVLink parameters name them
# Ranges two sections share: [initial] and [reference] hold the same angles and altitude.
ALTITUDE = spec(unit="m", low=0, high=10000)
TILT = spec(unit="rad", low=-math.pi / 2, high=math.pi / 2, low_open=True, high_open=True)
HEADING = spec(unit="rad", low=-math.pi, high=math.pi)
# A tilt bound: below 89° (the 1/(cφcθ) factor stays finite).
TILT_BOUND = spec(unit="rad", low=0, low_open=True, high=1.5533, note="< 89°")
SPEED_LIMIT = spec(unit="m/s", low=0, low_open=True, high=100)  # [position]'s speeds and rates
INERTIA = spec(unit="kg·m²", low=0, low_open=True, unit_in_text=False)  # Ix, Iy, Iz


@dataclass(frozen=True)
class VehicleParams:
    """Paper Table 1 symbols. Units: SI; inertias [kg·m²]. Each key is also the autopilot's model parameter VM_*
    (its model of the vehicle, :mod:`autopilot.params`)."""

    mass: float = key(unit="kg", low=0, low_open=True, unit_in_text=False, doc="mass m",
                      mavlink=mavlink("VM_MASS", high=1e4))  # fmt: skip
    ixx: float = INERTIA.field(doc="inertia Ix", mavlink=mavlink("VM_IXX", high=1e4))
    iyy: float = INERTIA.field(doc="inertia Iy", mavlink=mavlink("VM_IYY", high=1e4))
    izz: float = INERTIA.field(doc="inertia Iz", mavlink=mavlink("VM_IZZ", high=1e4))
    drag: tuple[float, float, float, float, float, float] = key(
        length=6, low=0, note="K1..K6", doc="drag coefficients K1..K6 (K1–K3 [N·s/m], K4–K6 [N·s])",
        mavlink=mavlink([f"VM_K{i}" for i in range(1, 7)], [f"drag coefficient K{i}" for i in range(1, 7)],
                        high=1e4, unit=["N·s/m"] * 3 + ["N·s"] * 3),
    )  # fmt: skip
    arm_length: float = key(unit="m", low=0, low_open=True, unit_in_text=False, doc="arm length l",
                            mavlink=mavlink("VM_ARM_LEN", high=100))  # fmt: skip
    rotor_inertia: float = key(unit="kg·m²", low=0, unit_in_text=False, doc="rotor inertia Jr",
                               mavlink=mavlink("VM_JR", high=1e4))  # fmt: skip
    thrust_factor: float = key(unit="N·s²", low=0, low_open=True, unit_in_text=False, doc="thrust factor b: F = b·Ω²",
                               mavlink=mavlink("VM_THRUST_B", "thrust factor b", high=1e4))  # fmt: skip
    drag_factor: float = key(unit="N·m·s²", low=0, low_open=True, unit_in_text=False,
                             doc="rotor drag factor d: rotor drag torque = d·Ω²",
                             mavlink=mavlink("VM_DRAG_D", "rotor drag factor d", high=1e4))  # fmt: skip
    gravity: float = key(9.81, unit="m/s²", low=0, high=100, unit_in_text=False, doc="gravity g",
                         mavlink=mavlink("VM_GRAVITY"))  # fmt: skip

    @property
    def d_over_b(self) -> float:
        """Yaw torque per newton of thrust [m] (eq (8))."""
        return self.drag_factor / self.thrust_factor


@dataclass(frozen=True)
class ActuatorParams:
    """Motor model. ``ideal``: reversible, F ∈ [−F_max, F_max], no lag (the paper's assumption).
    ``realistic``: F ∈ [0, F_max] with first-order lag (time constants up/down, 0 = none)."""

    model: str = key(choices=("ideal", "realistic"), doc="ideal: reversible, no lag; realistic: F ≥ 0, with lag")
    max_thrust: float = key(unit="N", low=0, low_open=True, unit_in_text=False, doc="F_max per motor")
    time_constant_up: float = key(0.0, unit="s", low=0, high=1, doc="motor time constant, speeding up (0: none)")
    time_constant_down: float = key(0.0, unit="s", low=0, high=1, doc="motor time constant, slowing (0: none)")

    @property
    def reversible(self) -> bool:
        return self.model == "ideal"

    @property
    def min_thrust(self) -> float:
        """The least force a motor gives [N]: −F_max when reversible, else 0."""
        return -self.max_thrust if self.reversible else 0.0


@dataclass(frozen=True)
class SimParams:
    """The simulation: the control period T [s], the simulated duration [s], the integrator and its sub-steps."""

    period: float = key(unit="s", low=1e-5, high=0.1, doc="control period T")
    duration: float = key(unit="s", low=0, low_open=True, high=3600, doc="simulated duration")
    integrator: str = key(choices=("euler", "rk4"), doc="the plant's integrator")
    substeps: int = key(1, low=1, high=1000, doc="integration sub-steps per control period")


@dataclass(frozen=True, kw_only=True)
class ControllerParams:
    """Controller choice, gains and limits.

    Backstepping gains: either ``gains`` (rates k_i [1/s], pole λ_i = 1 − T·k_i) or ``poles`` (λ_i
    directly); exactly one is set. PD gains per channel (altitude, roll, pitch, yaw): the closed loop
    of the linearised channel is ë + kd·ė + kp·e = 0 (the [pd] section's kp, kd).
    """

    type: str = key(kind="string", check=is_controller_name, says=ALLOWED + " (a relative path: from the working "
                    "directory)", doc="the controller", mavlink=None)  # fmt: skip
    gains: tuple[float, ...] | None = key(
        None, length=8, unit="1/s", note="rates k_i, {unit}", doc="backstepping rates k1..k8 (pole λ = 1 − T·k)",
        mavlink=mavlink([f"BS_K{i}" for i in range(1, 9)],
                        [f"backstepping rate k{i} (pole λ{i} = 1 − T·k{i})" for i in range(1, 9)],
                        low=0, low_open=True, high=1e6),
    )  # fmt: skip
    poles: tuple[float, ...] | None = key(None, length=8, note="poles λ_i", doc="backstepping poles λ1..λ8")
    max_tilt: float = TILT_BOUND.field(doc="bound on |roll|, |pitch| references",
                                       mavlink=mavlink("ATT_TILT_MAX"))  # fmt: skip
    thrust_min: float = key(unit="N", unit_in_text=False, doc="lower bound on u1 (total thrust)",
                            mavlink=mavlink("THR_MIN", low=-1e7, high=1e7))  # fmt: skip
    thrust_max: float = key(unit="N", unit_in_text=False, doc="upper bound on u1 (total thrust)",
                            mavlink=mavlink("THR_MAX", low=-1e7, high=1e7))  # fmt: skip
    pd_kp: tuple[float, float, float, float] = key(
        length=4, low=0, unit="1/s²", note="altitude, roll, pitch, yaw", doc="PD kp per channel",
        mavlink=mavlink([f"PD_{ch}_P" for ch in PD_CHANNELS], [f"PD kp, {ch.lower()}" for ch in PD_CHANNELS], high=1e6),
    )  # fmt: skip
    pd_kd: tuple[float, float, float, float] = key(
        length=4, low=0, unit="1/s", note="altitude, roll, pitch, yaw", doc="PD kd per channel",
        mavlink=mavlink([f"PD_{ch}_D" for ch in PD_CHANNELS], [f"PD kd, {ch.lower()}" for ch in PD_CHANNELS], high=1e6),
    )  # fmt: skip


@dataclass(frozen=True)
class PositionParams:
    """The flight controller around the paper's loops (docs/position.md): the horizontal backstepping loop's
    rates k9..k12 [1/s] (x position, x velocity, y position, y velocity: pole λ = 1 − T·k), the integral
    rates [1/s] of the altitude and horizontal loops (0: off, as the paper's law), the bound on the integral's
    share of a virtual velocity [m/s], and PX4's limits (their MAVLink names)."""

    gains: tuple[float, float, float, float] = key(
        (1.0, 2.0, 1.0, 2.0), length=4, low=0, low_open=True, unit="1/s", note="k9..k12: x, vx, y, vy rates, {unit}",
        doc="horizontal backstepping rates k9..k12",
        mavlink=mavlink([f"BS_K{i}" for i in range(9, 13)],
                        [f"horizontal backstepping rate k{i}, {what}" for i, what in
                         zip(range(9, 13), ("x position", "x velocity", "y position", "y velocity"))], high=1e6),
    )  # fmt: skip
    integral: tuple[float, float] = key(
        (0.0, 0.0), length=2, low=0, unit="1/s", note="altitude, horizontal integral rates, {unit}; 0 = off",
        doc="integral rates k_I, altitude and horizontal",
        mavlink=mavlink(["BS_KI_ALT", "BS_KI_XY"], ["altitude integral rate k_I (0 = off, the paper's law)",
                                                    "horizontal integral rate k_I (0 = off)"], high=1e6),
    )  # fmt: skip
    integral_limit: float = SPEED_LIMIT.field(1.0, doc="bound on an integrator's share of a virtual velocity",
                                              mavlink=mavlink("BS_I_LIM"))  # fmt: skip
    xy_vel_max: float = SPEED_LIMIT.field(12.0, doc="horizontal speed limit", mavlink=mavlink("MPC_XY_VEL_MAX"))
    z_vel_max_up: float = SPEED_LIMIT.field(3.0, doc="climb rate limit", mavlink=mavlink("MPC_Z_VEL_MAX_UP"))
    z_vel_max_dn: float = SPEED_LIMIT.field(1.5, doc="descent rate limit", mavlink=mavlink("MPC_Z_VEL_MAX_DN"))
    tilt_max_air: float = TILT_BOUND.field(
        math.radians(45.0), doc="tilt limit of the position loop's thrust",
        mavlink=mavlink("MPC_TILTMAX_AIR", high=89, unit="deg", to_param=math.degrees, from_param=math.radians),
    )  # fmt: skip
    acc_hor: float = SPEED_LIMIT.field(3.0, unit="m/s²", doc="acceleration of the auto modes' references",
                                       mavlink=mavlink("MPC_ACC_HOR"))  # fmt: skip
    xy_cruise: float = SPEED_LIMIT.field(5.0, doc="speed of goto and return", mavlink=mavlink("MPC_XY_CRUISE"))
    takeoff_speed: float = SPEED_LIMIT.field(1.5, doc="takeoff climb rate", mavlink=mavlink("MPC_TKO_SPEED"))


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
_PX4 = IMU_PROFILES["px4"]  # the [sensors] defaults of the IMU figures
GPS_QUEUE = 32  # GPS samples in flight at most (gps_delay_s · gps_rate_hz < GPS_QUEUE)


@dataclass(frozen=True)
class SensorParams:
    """The simulated sensors (docs/sensors.md): noise figures, rates, the Earth's field, the seed. Units are in
    the names. IMU noise as PX4's Gazebo IMU plugin models it (white noise by density, σ = density/√dt, and a
    Gauss–Markov bias driven by the random walk, starting at a random turn-on bias); defaults: the ``px4``
    profile (:data:`IMU_PROFILES`), a [sensors] section without them takes its ``profile``'s."""

    profile: str = key("px4", choices=tuple(IMU_PROFILES), doc="the IMU figures not given")
    seed: int = key(0, low=0, high=SEED_MAX, doc="the sensors' noise seed")
    gyro_noise_density_rad_s_sqrt_hz: float = key(_PX4["gyro_noise_density_rad_s_sqrt_hz"], unit="rad/s/√Hz", low=0,
                                                  high=0.1, doc="gyro white noise density")  # fmt: skip
    gyro_random_walk_rad_s2_sqrt_hz: float = key(_PX4["gyro_random_walk_rad_s2_sqrt_hz"], unit="rad/s²/√Hz", low=0,
                                                 high=0.01, doc="gyro bias random walk")  # fmt: skip
    gyro_bias_correlation_time_s: float = key(_PX4["gyro_bias_correlation_time_s"], unit="s", low=0, low_open=True,
                                              high=1e6, doc="gyro bias correlation time")  # fmt: skip
    gyro_turn_on_bias_rad_s: float = key(_PX4["gyro_turn_on_bias_rad_s"], unit="rad/s", low=0, high=0.5,
                                         doc="gyro turn-on bias (σ)")  # fmt: skip
    accel_noise_density_m_s2_sqrt_hz: float = key(_PX4["accel_noise_density_m_s2_sqrt_hz"], unit="m/s²/√Hz", low=0,
                                                  high=1, doc="accelerometer white noise density")  # fmt: skip
    accel_random_walk_m_s3_sqrt_hz: float = key(_PX4["accel_random_walk_m_s3_sqrt_hz"], unit="m/s³/√Hz", low=0,
                                                high=0.1, doc="accelerometer bias random walk")  # fmt: skip
    accel_bias_correlation_time_s: float = key(_PX4["accel_bias_correlation_time_s"], unit="s", low=0, low_open=True,
                                               high=1e6, doc="accelerometer bias correlation time")  # fmt: skip
    accel_turn_on_bias_m_s2: float = key(_PX4["accel_turn_on_bias_m_s2"], unit="m/s²", low=0, high=2,
                                         doc="accelerometer turn-on bias (σ)")  # fmt: skip
    mag_rate_hz: float = key(100.0, unit="Hz", low=1, high=1000,
                             doc="magnetometer rate (PX4's Gazebo plugin), at most the control rate")  # fmt: skip
    mag_noise_density_gauss_sqrt_hz: float = key(4e-4, unit="gauss/√Hz", low=0, high=0.01,
                                                 doc="magnetometer white noise density")  # fmt: skip
    mag_random_walk_gauss_s_sqrt_hz: float = key(6.4e-6, unit="gauss/s/√Hz", low=0, high=0.001,
                                                 doc="magnetometer bias random walk")  # fmt: skip
    mag_bias_correlation_time_s: float = key(600.0, unit="s", low=0, low_open=True, high=1e6,
                                             doc="magnetometer bias correlation time")  # fmt: skip
    mag_strength_gauss: float = key(0.4807, unit="gauss", low=0.2, high=0.7, note="the Earth's field",
                                    doc="the field's strength (jMAVSim's Zürich field, quadsitl.earth)")  # fmt: skip
    mag_declination_deg: float = key(2.75, unit="deg", low=-180, high=180, doc="the field's declination")
    mag_inclination_deg: float = key(63.39, unit="deg", low=-90, high=90, doc="the field's inclination")
    baro_rate_hz: float = key(50.0, unit="Hz", low=1, high=1000,
                              doc="barometer rate (PX4's Gazebo plugin), at most the control rate")  # fmt: skip
    baro_noise_pa: float = key(1.0, unit="Pa", low=0, high=100, doc="barometer noise (σ)")
    gps_rate_hz: float = key(10.0, unit="Hz", low=1, high=100, doc="GPS rate, at most the control rate")
    gps_delay_s: float = key(0.12, unit="s", low=0, high=1, doc="GPS delay (PX4's Gazebo plugin); "
                             f"gps_delay_s · gps_rate_hz < {GPS_QUEUE - 1}")  # fmt: skip
    gps_xy_error_m: float = key(1.0, unit="m", low=0, high=100, doc="σ of the slowly wandering horizontal position "
                                "error (docs/sensors.md)")  # fmt: skip
    gps_z_error_m: float = key(2.0, unit="m", low=0, high=100, doc="σ of the wandering vertical position error")
    gps_error_correlation_time_s: float = key(60.0, unit="s", low=0, low_open=True, high=1e5,
                                              doc="correlation time of the position error")  # fmt: skip
    gps_xy_velocity_noise_m_s: float = key(0.05, unit="m/s", low=0, high=10, doc="horizontal velocity noise (σ)")
    gps_z_velocity_noise_m_s: float = key(0.1, unit="m/s", low=0, high=10, doc="vertical velocity noise (σ)")
    gps_satellites: int = key(10, low=4, high=64, doc="satellites the GPS reports")


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

    speed_m_s: float = key(0.0, unit="m/s", low=0, high=50, doc="the mean wind")
    from_deg: float = key(0.0, unit="deg", low=0, high=360, note="clockwise from north",
                          doc="where the mean wind blows from (270: from the west, the air moving east)")  # fmt: skip
    turbulence: str = key("none", choices=tuple(TURBULENCE_W20_KNOTS),
                          doc="Dryden turbulence, MIL-F-8785C's levels (W20 = 15, 30, 45 kt)")  # fmt: skip
    gust_m_s: float = key(0.0, unit="m/s", low=0, high=50, doc="a 1 − cos gust's speed")
    gust_rise_s: float = key(1.0, unit="s", low=0, low_open=True, high=100, doc="the gust's rise time; then it holds")
    gust_start_s: float = key(0.0, unit="s", low=0, high=3600, doc="when the gust starts [s after lift-off]")
    gust_from_deg: float = key(0.0, unit="deg", low=0, high=360, doc="where the gust blows from")
    seed: int = key(0, low=0, high=SEED_MAX, doc="the turbulence's seed; same seed, same air")
    force_n: tuple[float, float, float] = key((0.0, 0.0, 0.0), length=3, unit="N", low=-1000, high=1000,
                                              note="north, east, down",
                                              doc="a constant external force on the vehicle, NED")  # fmt: skip


@dataclass(frozen=True)
class BatteryParams:
    """The battery the motors draw from (docs/battery.md): a pack of ``cells`` lithium cells in series holding
    ``capacity_mah``, its open-circuit voltage falling linearly with the charge drawn from ``v_full`` to
    ``v_empty`` per cell, behind an internal resistance; the motors and ESCs turn electric power into shaft power
    at ``efficiency``; the rest of the vehicle draws ``avionics_w``. It starts at ``remaining`` of its charge.
    Empty, it powers nothing. No [battery] section: an ideal supply (the paper's)."""

    capacity_mah: float = key(unit="mAh", low=0, low_open=True, high=1e6, doc="the charge of a full pack")
    cells: int = key(integer=True, low=1, high=14, doc="cells in series (PX4's BAT1_N_CELLS)")
    v_full: float = key(4.2, unit="V", low=2, high=5, doc="a full cell's open-circuit voltage")
    v_empty: float = key(3.5, unit="V", low=2, high=5, doc="an empty cell's open-circuit voltage, below v_full")
    cell_resistance_ohm: float = key(0.005, unit="Ω", low=0, high=1, doc="a cell's internal resistance")
    efficiency: float = key(0.8, low=0, low_open=True, high=1, doc="shaft power / electric power, motors and ESCs")
    avionics_w: float = key(5.0, unit="W", low=0, high=1000, doc="the power the rest of the vehicle draws")
    remaining: float = key(1.0, low=0, low_open=True, high=1, doc="the share of the charge it starts with")


@dataclass(frozen=True)
class InitialState:
    """Where the vehicle starts: altitude [m], ZYX Euler angles [rad], climb rate [m/s] (up) and Euler-angle
    rates φ̇, θ̇, ψ̇ [rad/s] (not body rates); at the origin, otherwise at rest."""

    altitude: float = ALTITUDE.field(0.0, doc="altitude above the ground")
    roll: float = TILT.field(0.0, doc="roll φ")
    pitch: float = TILT.field(0.0, doc="pitch θ")
    yaw: float = HEADING.field(0.0, doc="yaw ψ")
    climb_rate: float = key(0.0, unit="m/s", doc="climb rate (up)")
    roll_rate: float = key(0.0, unit="rad/s", doc="Euler-angle rate φ̇")
    pitch_rate: float = key(0.0, unit="rad/s", doc="Euler-angle rate θ̇")
    yaw_rate: float = key(0.0, unit="rad/s", doc="Euler-angle rate ψ̇")


# [reference]: the set-points of the paper's experiment (quadsitl.state.Reference), every key required.
REFERENCE_KEYS: dict[str, Spec] = {
    "altitude": ALTITUDE.with_default(REQUIRED),
    "roll": dataclasses.replace(TILT, doc="roll φ"),
    "pitch": dataclasses.replace(TILT, doc="pitch θ"),
    "yaw": dataclasses.replace(HEADING, doc="yaw ψ"),
}


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
    battery: BatteryParams | None = None  # None: no [battery] section, an ideal supply
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
# Validation: the schema, made from the declared keys (quadsitl.keys)

_VEHICLE = declared(VehicleParams)
_INERTIA = ("ixx", "iyy", "izz")  # one key in the TOML: inertia = [Ix, Iy, Iz]
_VEHICLE_KEYS = {("inertia" if name == "ixx" else name): grouped([_VEHICLE[i] for i in _INERTIA], "Ix, Iy, Iz")
                 if name == "ixx" else s for name, s in _VEHICLE.items() if name not in _INERTIA[1:]}  # fmt: skip
SCHEMA: dict[str, dict[str, Spec]] = {
    "vehicle": _VEHICLE_KEYS,
    "actuators": section_of(ActuatorParams),
    "sim": section_of(SimParams),
    "controller": section_of(ControllerParams, only=("type", "gains", "poles", "max_tilt", "thrust_min", "thrust_max")),
    "pd": section_of(ControllerParams, rename={"pd_kp": "kp", "pd_kd": "kd"}, only=("pd_kp", "pd_kd")),
    "reference": REFERENCE_KEYS,
    "position": section_of(PositionParams),
    # the IMU's figures default to the profile's (None here: filled in by _sensors)
    "sensors": {k: s.with_default(None) if k in _PX4 else s for k, s in section_of(SensorParams).items()},
    "wind": section_of(WindParams),
    "battery": section_of(BatteryParams),
    "initial": section_of(InitialState),
}
# [model]: the autopilot's model of the vehicle, key by key over [vehicle]'s values (each key optional).
SCHEMA["model"] = {name: s.with_default(None) for name, s in SCHEMA["vehicle"].items()}
TOP_LEVEL_KEYS = {"description"}
OPTIONAL_SECTIONS = {"initial", "position", "sensors", "model", "wind", "battery"}


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
    for name in raw:
        if name not in SCHEMA and name not in TOP_LEVEL_KEYS:
            allowed = ", ".join(sorted([*SCHEMA, *TOP_LEVEL_KEYS]))
            raise ConfigError(f"{where}: unknown key {name!r}; allowed top-level keys: {allowed}")
    for part, specs in SCHEMA.items():
        table = raw.get(part)
        if table is None:
            if part in OPTIONAL_SECTIONS:
                table = {}
            else:
                raise ConfigError(f"{where}: missing section [{part}]")
        if not isinstance(table, dict):
            raise ConfigError(f"{where}: {part} = {table!r}: expected a table [{part}]")
        for name in table:
            if name not in specs:
                raise ConfigError(f"{where}: unknown key {part}.{name}; allowed in [{part}]: {', '.join(specs)}")
        values: dict[str, Any] = {}
        for name, s in specs.items():
            if name in table:
                values[name] = check_value(f"{part}.{name}", table[name], s, where)
            elif s.required and part in raw:  # an optional section left out has no keys to miss
                raise ConfigError(f"{where}: missing key {part}.{name} ({s.allowed})")
            else:
                values[name] = s.default
        out[part] = values
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
    for k, value in v["model"].items():
        if value is not None:
            model += zip(("ixx", "iyy", "izz"), value) if k == "inertia" else [(k, value)]
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
    actuators = ActuatorParams(**v["actuators"])
    battery = _battery(v["battery"], vehicle, actuators, where) if "battery" in raw else None
    return Preset(
        name=name,
        description=desc,
        vehicle=vehicle,
        actuators=actuators,
        sim=sim,
        controller=controller,
        reference=ref,
        initial=InitialState(**v["initial"]),
        position=PositionParams(**v["position"]),
        sensors=sensors,
        wind=WindParams(**v["wind"]),
        battery=battery,
        model=tuple(model),
    )


def full_power(vehicle: VehicleParams, actuators: ActuatorParams, battery: BatteryParams) -> float:
    """The electric power [W] the vehicle draws with every motor at its largest force: the shaft power d·Ω³ of each
    (Ω = √(F_max/b), F = b·Ω²) over the efficiency, and the avionics."""
    omega = math.sqrt(actuators.max_thrust / vehicle.thrust_factor)
    return 4.0 * vehicle.drag_factor * omega**3 / battery.efficiency + battery.avionics_w


def _battery(values: dict[str, Any], vehicle: VehicleParams, actuators: ActuatorParams, where: str) -> BatteryParams:
    """The [battery] section, checked across keys: v_empty below v_full, and a pack that can give the motors' full
    power even when empty (its largest power, V²/4R at the empty voltage, above :func:`full_power`)."""
    b = BatteryParams(**values)
    if b.v_empty >= b.v_full:
        raise ConfigError(f"{where}: battery.v_empty = {b.v_empty!r}: must be below battery.v_full = {b.v_full!r}")
    need = full_power(vehicle, actuators, b)
    resistance = b.cells * b.cell_resistance_ohm
    most = math.inf if resistance == 0.0 else (b.cells * b.v_empty) ** 2 / (4.0 * resistance)
    if need >= most:
        raise ConfigError(
            f"{where}: battery.cell_resistance_ohm = {b.cell_resistance_ohm!r}: an empty pack of {b.cells} cells "
            f"gives at most {most:.4g} W through it, and the motors at full thrust draw {need:.4g} W; "
            f"allowed: below {b.cells * b.v_empty**2 / (4.0 * need):.4g} Ω per cell"
        )
    return b


def _sensors(values: dict[str, Any], sim: SimParams, where: str) -> SensorParams:
    """The [sensors] section: the profile's IMU figures where no key gives them, and the checks across keys (no
    sensor faster than the control tick, the GPS samples in flight within the queue)."""
    values = {k: IMU_PROFILES[values["profile"]][k] if value is None else value for k, value in values.items()}
    tick_rate = 1.0 / sim.period
    for name in ("mag_rate_hz", "baro_rate_hz", "gps_rate_hz"):
        if values[name] > tick_rate * (1 + 1e-9):
            raise ConfigError(
                f"{where}: sensors.{name} = {values[name]!r}: must not exceed the control rate 1/sim.period = "
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
    for name in values:
        if name not in specs:
            raise ConfigError(f"wind: unknown key {name!r}; allowed: {', '.join(specs)}")
    return {name: check_value(f"wind.{name}", value, specs[name]) for name, value in values.items()}


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
    if preset.battery is not None:
        sections["battery"] = asdict(preset.battery)
    lines = [f"description = {_toml_value(preset.description)}"]
    for part, values in sections.items():
        lines += ["", f"[{part}]", *(f"{k} = {_toml_value(x)}" for k, x in values.items())]
    return "\n".join(lines) + "\n"


def parse_preset(text: str, name: str = "preset") -> Preset:
    """Parse and validate a preset from TOML text."""
    where = f"preset {name!r}"
    try:
        raw = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{where}: not valid TOML: {exc}") from None
    return _build(name, raw, where)
