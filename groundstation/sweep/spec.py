"""A sweep's spec: what is flown and what varies, from TOML, validated before anything runs. Pure: no I/O
besides reading the file, nothing compiled.

    description = "±20 % mass and inertia mismatch on the paper's experiment"
    preset = "paper"              # a shipped preset's name or a preset TOML's path
    controller = "backstepping"   # or "pd" (default: the preset's)
    task = "step"                 # the preset's reference from its initial state (the paper's experiment), or
                                  # "hover": hold the reference altitude, level, from there
    duration = 5.0                # [s] simulated per trial (default: the preset's)
    seed = 2020                   # the sweep's seed (default 0)
    trials = 1000                 # (default: the grid's size, else 1)
    keep = [0, 1]                 # trials whose whole trajectory is written (default: none)
    inadmissible = "refuse"       # gains that can break (41)–(44): "refuse" the spec, or "record" such trials
    engine = "batch"              # or "sitl": every trial a whole `quadsitl fly` (sitl_engine.py)

    [limits]                      # a trial whose state leaves these ends there, diverged (defaults shown)
    position = 1e5                # |x|, |y|, |z| [m]
    speed = 1e4                   # |vx|, |vy|, |vz| [m/s]
    tilt = 1.5707963267948966     # |roll|, |pitch| [rad], below
    rate = 1e3                    # |Euler-angle rates| [rad/s]

    [vary]
    mismatch.mass = { dist = "uniform", low = 0.8, high = 1.2 }
    gains.k1 = { dist = "grid", values = [5.0, 10.0, 20.0] }
    initial.roll = { dist = "normal", mean = 0.0, std = 0.1, low = -0.5, high = 0.5 }

What can vary (:data:`PARAMETERS`): ``plant.*`` the plant's vehicle (mass, ixx, iyy, izz, k1..k6, arm_length,
rotor_inertia, thrust_factor, drag_factor; SI units as in the presets), ``model.*`` the autopilot's model of it
(default: the plant's), ``mismatch.*`` the model as a factor of the plant's value (``mismatch.inertia`` scales
ixx, iyy and izz by one draw), ``gains.*`` the backstepping's rates k1..k8 [1/s] (pole λ = 1 − T·k) and the PD's
kp1..kp4 [1/s²], kd1..kd4 [1/s] (altitude, roll, pitch, yaw), ``initial.*`` the initial state (altitude [m],
roll, pitch, yaw [rad], climb_rate [m/s], roll_rate, pitch_rate, yaw_rate [rad/s]: Euler-angle rates) and
``reference.*`` (altitude [m], roll, pitch, yaw [rad]).

Distributions: a number (fixed), ``fixed`` (value), ``uniform`` (low < high), ``normal`` (mean, std > 0, and
optional low < high: redrawn until inside), ``grid`` (values, or low, high and num ≥ 2 evenly spaced) and
``choice`` (values, optional weights). Grids make a product, the names in sorted order, the first varying
slowest; trial i flies grid point i mod G, and the number of trials must be a multiple of G. Every other draw
comes from trial i's own generator, ``numpy.random.SeedSequence(seed, spawn_key=(i,))``, the names in sorted
order, one value each: a trial's parameters depend on the seed and its number only, never on how the trials
are split into chunks or workers.

Refused with one line naming the key, the value and what is allowed (:class:`quadsitl.config.ConfigError`):
unknown keys, wrong types, bad bounds, a distribution that can reach a non-physical value (a normal mass
without a positive lower bound), ``model.X`` with ``mismatch.X``, a gain the controller does not have, and,
with ``inadmissible = "refuse"``, gains that can break the paper's conditions (41)–(44) for some trial: the
conditions only get harder as |λ| grows, so the spec is checked at the largest |λ| each gain can take.
"""

from __future__ import annotations

import dataclasses
import json
import math
import re
import sys
from dataclasses import dataclass, field, replace
from importlib import resources
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from autopilot.control_params import KD, KI_ALT, KI_XY, KP, POLES, control_array
from autopilot.gains import GainError, stability_interval
from quadsitl.config import DEFAULT_LIMITS as PLANT_LIMITS
from quadsitl.config import (
    LIMIT_NAMES,
    SCHEMA,
    ConfigError,
    InitialState,
    Preset,
    SensorParams,
    Spec,
    WindParams,
    check_value,
    initial_state,
    parse_preset,
    read_preset,
)
from quadsitl.controller_names import ALLOWED, absolute, is_controller_name, is_plugin
from quadsitl.keys import spec
from quadsitl.param_arrays import (
    ARM,
    D_OVER_B,
    FIELD_COLUMNS,
    IXX,
    IYY,
    IZZ,
    JR,
    K1,
    MASS,
    B,
    D,
    actuator_array,
    vehicle_array,
)

if TYPE_CHECKING:
    from groundstation.mission_files import Mission

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - exercised on Python 3.10 only
    import tomli as tomllib

# ---- what can vary ----------------------------------------------------------------------------------------

POSITIVE, NONNEG, FINITE = "> 0", ">= 0", "finite"
VEHICLE = {"mass": (MASS, POSITIVE), "ixx": (IXX, POSITIVE), "iyy": (IYY, POSITIVE), "izz": (IZZ, POSITIVE),
           **{f"k{i + 1}": (K1 + i, NONNEG) for i in range(6)}, "arm_length": (ARM, POSITIVE),
           "rotor_inertia": (JR, NONNEG), "thrust_factor": (B, POSITIVE), "drag_factor": (D, POSITIVE)}  # fmt: skip
"""A vehicle parameter's name → (its index in :func:`quadsitl.param_arrays.vehicle_array`, what it must be)."""
HALF_PI = math.pi / 2
# initial.* and reference.*: (index, what is allowed as a test, as words)
INITIAL = {
    "altitude": (2, lambda v: v >= 0.0, "a number >= 0 [m]"),
    "roll": (6, lambda v: abs(v) < HALF_PI, "a number in (−π/2, π/2) [rad]"),
    "pitch": (7, lambda v: abs(v) < HALF_PI, "a number in (−π/2, π/2) [rad]"),
    "yaw": (8, lambda v: abs(v) <= math.pi, "a number in [−π, π] [rad]"),
    "climb_rate": (5, math.isfinite, "a finite number [m/s]"),
    "roll_rate": (9, math.isfinite, "a finite number [rad/s]"),
    "pitch_rate": (10, math.isfinite, "a finite number [rad/s]"),
    "yaw_rate": (11, math.isfinite, "a finite number [rad/s]"),
}
REFERENCE = {
    "altitude": (0, lambda v: v >= 0.0, "a number >= 0 [m]"),
    "roll": (1, lambda v: abs(v) < HALF_PI, "a number in (−π/2, π/2) [rad]"),
    "pitch": (2, lambda v: abs(v) < HALF_PI, "a number in (−π/2, π/2) [rad]"),
    "yaw": (3, lambda v: abs(v) <= math.pi, "a number in [−π, π] [rad]"),
}
RATES = tuple(f"k{i + 1}" for i in range(8))
PD_GAINS = tuple(f"kp{i + 1}" for i in range(4)) + tuple(f"kd{i + 1}" for i in range(4))
INTEGRAL = ("ki_alt", "ki_xy")  # the position controller's integral rates k_I [1/s] ([position] integral)
TURBULENCE_LEVELS = ("none", "light", "moderate", "severe")  # wind.turbulence's values 0..3
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
SENSOR_NOISE = ("gyro_noise_density_rad_s_sqrt_hz", "gyro_random_walk_rad_s2_sqrt_hz", "gyro_turn_on_bias_rad_s",
                "accel_noise_density_m_s2_sqrt_hz", "accel_random_walk_m_s3_sqrt_hz", "accel_turn_on_bias_m_s2",
                "mag_noise_density_gauss_sqrt_hz", "mag_random_walk_gauss_s_sqrt_hz", "baro_noise_pa", "gps_xy_error_m",
                "gps_z_error_m", "gps_xy_velocity_noise_m_s", "gps_z_velocity_noise_m_s")  # fmt: skip
"""The sensor figures ``sensors.noise`` scales (every noise, random walk, turn-on bias and GPS error)."""
SENSORS = {
    "noise": (lambda v: 0.0 <= v <= 100.0, "a factor in [0, 100] on every noise figure of the preset's [sensors]"),
    "seed": (lambda v: 0 <= v < 2**63, "a number in [0, 2^63) (its integer part seeds the sensors' noise)"),
}


def _allowed(name: str) -> tuple[Any, str] | None:
    """(a test of one value, what is allowed in words) for a parameter's full name, or None: not a parameter."""
    group, _, key = name.partition(".")
    if group in ("plant", "model", "mismatch") and key in VEHICLE:
        kind = VEHICLE[key][1]
        unit = "a factor" if group == "mismatch" else "a number"
        if kind == POSITIVE:
            return (lambda v: v > 0.0), f"{unit} > 0"
        return (lambda v: v >= 0.0), f"{unit} >= 0"
    if name == "mismatch.inertia":
        return (lambda v: v > 0.0), "a factor > 0 (scales ixx, iyy, izz)"
    if group == "gains" and key in RATES:
        return math.isfinite, "a finite rate k [1/s] (pole λ = 1 − T·k)"
    if group == "gains" and key in PD_GAINS:
        return (lambda v: v >= 0.0), "a number >= 0"
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

# ---- distributions ----------------------------------------------------------------------------------------

DISTRIBUTIONS = {
    "fixed": ("value",),
    "uniform": ("low", "high"),
    "normal": ("mean", "std", "low", "high"),
    "grid": ("values", "low", "high", "num"),
    "choice": ("values", "weights"),
}
MIN_NORMAL_MASS = 0.01  # a bounded normal must keep at least this probability inside its bounds (redraws)


@dataclass(frozen=True)
class Distribution:
    """One parameter's distribution. ``values``: the grid's or the choice's values (a fixed value: one)."""

    kind: str
    low: float = -math.inf
    high: float = math.inf
    mean: float = 0.0
    std: float = 0.0
    values: tuple[float, ...] = ()
    weights: tuple[float, ...] = ()

    def support(self) -> tuple[float, ...]:
        """The values it can take at the ends of its range (all of them for a finite set)."""
        if self.kind in ("fixed", "grid", "choice"):
            return self.values if self.kind != "choice" else tuple(v for v, w in zip(self.values, self.weights) if w)
        return (self.low, self.high)

    def draw(self, rng: np.random.Generator) -> float:
        """One value from ``rng`` (not for grids, which are not drawn)."""
        if self.kind == "fixed":
            return self.values[0]
        if self.kind == "uniform":
            return float(rng.uniform(self.low, self.high))
        if self.kind == "choice":
            return self.values[int(rng.choice(len(self.values), p=np.asarray(self.weights) / sum(self.weights)))]
        while True:  # normal, redrawn until inside its bounds (validated to hold enough probability)
            v = float(rng.normal(self.mean, self.std))
            if self.low <= v <= self.high:
                return v

    def describe(self) -> dict[str, Any]:
        """For summary.json."""
        out: dict[str, Any] = {"dist": self.kind}
        if self.kind in ("uniform", "normal"):
            if self.kind == "normal":
                out.update(mean=self.mean, std=self.std)
            if math.isfinite(self.low):
                out["low"] = self.low
            if math.isfinite(self.high):
                out["high"] = self.high
        else:
            out["values"] = list(self.values)
            if self.kind == "choice":
                out["weights"] = list(self.weights)
        return out


def _normal_mass(mean: float, std: float, low: float, high: float) -> float:
    """P(low ≤ X ≤ high) for X ~ N(mean, std²)."""

    def cdf(x: float) -> float:
        return 0.5 * (1.0 + math.erf((x - mean) / (std * math.sqrt(2.0)))) if math.isfinite(x) else float(x > 0)

    return cdf(high) - cdf(low)


def parse_distribution(key: str, raw: Any, where: str) -> Distribution:
    """A [vary] value (a number, or a table with ``dist``) → its Distribution, its own bounds checked."""

    def fail(what: str, value: Any = raw) -> ConfigError:
        return ConfigError(f"{where}: vary.{key} = {value!r}: expected {what}")

    def number(k: str, v: Any, ok: Any = math.isfinite, allowed: str = "a finite number") -> float:
        if not isinstance(v, (int, float)) or isinstance(v, bool) or not ok(float(v)):
            raise ConfigError(f"{where}: vary.{key}.{k} = {v!r}: expected {allowed}")
        return float(v)

    def numbers(k: str, v: Any) -> tuple[float, ...]:
        if not isinstance(v, list) or not v:
            raise ConfigError(f"{where}: vary.{key}.{k} = {v!r}: expected a non-empty list of finite numbers")
        return tuple(number(f"{k}[{i}]", x) for i, x in enumerate(v))

    if isinstance(raw, (int, float)) and not isinstance(raw, bool):
        return Distribution("fixed", values=(number("value", raw),))
    if not isinstance(raw, dict) or "dist" not in raw:
        raise fail(f"a number or a table with dist = one of {', '.join(DISTRIBUTIONS)}")
    kind = raw["dist"]
    if kind not in DISTRIBUTIONS:
        raise ConfigError(f"{where}: vary.{key}.dist = {kind!r}: expected one of {', '.join(DISTRIBUTIONS)}")
    for k in raw:
        if k != "dist" and k not in DISTRIBUTIONS[kind]:
            raise ConfigError(f"{where}: vary.{key}.{k}: unknown key for dist = {kind!r}; allowed: "
                              f"{', '.join(DISTRIBUTIONS[kind])}")  # fmt: skip
    need = {"fixed": ("value",), "uniform": ("low", "high"), "normal": ("mean", "std"), "choice": ("values",)}
    for k in need.get(kind, ()):
        if k not in raw:
            raise ConfigError(f"{where}: vary.{key}: dist = {kind!r} needs {' and '.join(need[kind])}")
    if kind == "fixed":
        return Distribution(kind, values=(number("value", raw["value"]),))
    if kind == "uniform":
        low, high = number("low", raw["low"]), number("high", raw["high"])
        if not low < high:
            raise ConfigError(f"{where}: vary.{key}.high = {raw['high']!r}: expected a number above low = {low!r}")
        return Distribution(kind, low=low, high=high)
    if kind == "normal":
        mean = number("mean", raw["mean"])
        std = number("std", raw["std"], lambda v: 0 < v < math.inf, "a finite number > 0")
        low = number("low", raw["low"]) if "low" in raw else -math.inf
        high = number("high", raw["high"]) if "high" in raw else math.inf
        if not low < high:
            raise ConfigError(f"{where}: vary.{key}.high = {raw['high']!r}: expected a number above low = {low!r}")
        mass = _normal_mass(mean, std, low, high)
        if mass < MIN_NORMAL_MASS:
            raise ConfigError(f"{where}: vary.{key}: [low, high] = [{low:g}, {high:g}] holds {mass:.2g} of "
                              f"N({mean:g}, {std:g}²); expected at least {MIN_NORMAL_MASS:g}")  # fmt: skip
        return Distribution(kind, low=low, high=high, mean=mean, std=std)
    if kind == "grid":
        if "values" in raw:
            if any(k in raw for k in ("low", "high", "num")):
                raise ConfigError(f"{where}: vary.{key}: a grid takes values, or low, high and num, not both")
            return Distribution(kind, values=numbers("values", raw["values"]))
        if not all(k in raw for k in ("low", "high", "num")):
            raise ConfigError(f"{where}: vary.{key}: dist = 'grid' needs values, or low, high and num")
        low, high = number("low", raw["low"]), number("high", raw["high"])
        num = raw["num"]
        if not isinstance(num, int) or isinstance(num, bool) or not 2 <= num <= 100_000:
            raise ConfigError(f"{where}: vary.{key}.num = {num!r}: expected an integer in [2, 100000]")
        if not low < high:
            raise ConfigError(f"{where}: vary.{key}.high = {raw['high']!r}: expected a number above low = {low!r}")
        return Distribution(kind, values=tuple(float(v) for v in np.linspace(low, high, num)))
    values = numbers("values", raw["values"])  # choice
    if "weights" in raw:
        weights = numbers("weights", raw["weights"])
        if len(weights) != len(values) or min(weights) < 0 or sum(weights) <= 0:
            raise ConfigError(f"{where}: vary.{key}.weights = {raw['weights']!r}: expected {len(values)} numbers "
                              ">= 0, not all 0 (one per value)")  # fmt: skip
    else:
        weights = (1.0,) * len(values)
    return Distribution(kind, values=values, weights=weights)


# ---- the spec ---------------------------------------------------------------------------------------------

TASKS = ("step", "hover")
INADMISSIBLE = ("refuse", "record")
DEFAULT_LIMITS = dict(zip(LIMIT_NAMES, PLANT_LIMITS))  # the plant process's (quadsitl.config.DEFAULT_LIMITS)
MAX_TRIALS = 100_000_000

STATES = ("truth", "sensors")  # what the autopilot flies on (sensors: the preset's [sensors], else the defaults)
ENGINES = ("batch", "sitl")  # the batch engine (engine.py), or every trial a whole `quadsitl fly` (sitl_engine.py)
TOP: dict[str, Spec] = {
    "preset": spec(kind="string", says="a shipped preset's name or a preset TOML's path"),
    "controller": spec(None, kind="string", check=is_controller_name,
                       says=f"{ALLOWED} (a file: the spec's folder is its base)"),
    "task": spec("step", choices=TASKS),
    "duration": SCHEMA["sim"]["duration"].with_default(None),  # default: the preset's
    "seed": spec(0, low=0),
    "trials": spec(None, integer=True, low=1, high=MAX_TRIALS),
    "inadmissible": spec("refuse", choices=INADMISSIBLE),
    "description": spec("", kind="string", says="a string"),
    "engine": spec("batch", choices=ENGINES),
    "trajectory": spec(None, kind="string", says="a trajectory `quadsitl fly --trajectory` flies (circle[:...], "
                       "figure8[:...], hold[:...], a CSV file: the spec's folder is its base)"),
    "mission": spec(None, kind="string", says="a mission file `quadsitl fly --mission` flies (.plan, waypoint CSV, "
                    "QGC WPL 110; the spec's folder is its base)"),
    "state": spec(None, choices=STATES),
}  # fmt: skip
LIMIT_SPEC = spec(low=0, low_open=True)


@dataclass(frozen=True)
class SweepSpec:
    """A validated spec. ``vary`` maps each varied name (:data:`PARAMETERS`) to its distribution; ``trials`` is
    the number asked for (a multiple of :attr:`grid_size`)."""

    name: str
    preset: Preset
    controller: str
    task: str
    duration: float
    seed: int
    trials: int
    keep: tuple[int, ...]
    inadmissible: str
    limits: dict[str, float]
    vary: dict[str, Distribution]
    description: str = ""
    where: str = field(default="", compare=False)
    engine: str = "batch"  # ENGINES
    text: str = field(default="", compare=False, repr=False)  # the spec's TOML, as read
    preset_text: str = field(default="", compare=False, repr=False)  # its preset's TOML, as read
    trajectory: str | None = None  # what `quadsitl fly --trajectory` would fly (None: the task's reference)
    mission: Mission | None = None  # the mission file, read and checked
    state: str = "truth"  # STATES

    @property
    def fused(self) -> bool:
        """The batch engine flies its trials in one compiled loop (:func:`groundstation.sweep.engine.run_chunk`):
        the task's constant reference on the true state in calm air. Any other spec (a trajectory, a mission,
        sensors, wind) has each trial flown as ``quadsitl sim`` flies the trial's preset (:func:`trial_preset`),
        one after the other (:mod:`groundstation.sweep.run`); so is a controller of your own (``file.py:Name``)."""
        calm = self.preset.wind == WindParams() and not any(k.startswith(("wind.", "sensors.")) for k in self.vary)
        built_in = not is_plugin(self.controller)
        return self.trajectory is None and self.mission is None and self.state == "truth" and calm and built_in

    @property
    def period(self) -> float:
        return self.preset.sim.period

    @property
    def ticks(self) -> int:
        """Control ticks per trial (``quadsitl sim``'s count: round(duration / T))."""
        return round(self.duration / self.period)

    @property
    def grid(self) -> list[str]:
        """The grid's names, in sorted order (the first varies slowest)."""
        return sorted(k for k, d in self.vary.items() if d.kind == "grid")

    @property
    def grid_size(self) -> int:
        return math.prod(len(self.vary[k].values) for k in self.grid)

    @property
    def drawn(self) -> list[str]:
        """The names drawn from each trial's generator, in the order they are drawn."""
        return sorted(k for k, d in self.vary.items() if d.kind != "grid")

    def with_trials(self, trials: int) -> SweepSpec:
        """The spec with another number of trials (``--trials``), checked as the spec's own."""
        _check_trials(trials, self.grid_size, self.keep, f"{self.where}: --trials")
        return SweepSpec(**{**self.__dict__, "trials": trials})


def _check_trials(trials: int, grid: int, keep: tuple[int, ...], what: str) -> None:
    if not 1 <= trials <= MAX_TRIALS:
        raise ConfigError(f"{what} = {trials}: expected an integer in [1, {MAX_TRIALS}]")
    if trials % grid:
        raise ConfigError(f"{what} = {trials}: the grid has {grid} points; expected a multiple of {grid}")
    for k in keep:
        if k >= trials:
            raise ConfigError(f"{what} = {trials}: keep names trial {k}; expected trials above {max(keep)}")


def specs_folder() -> Path:
    return Path(str(resources.files("groundstation") / "sweep" / "specs"))


def available_specs() -> list[str]:
    """The example specs shipped with the package, by name."""
    return sorted(p.stem for p in specs_folder().glob("*.toml"))


def with_controller(text: str, controller: str) -> str:
    """The spec's TOML ``text`` with its top-level ``controller`` set to ``controller`` (``quadsitl sweep
    --controller``), so the spec a sweep writes says what it flew."""
    lines = text.splitlines()
    first_table = next((i for i, line in enumerate(lines) if line.lstrip().startswith("[")), len(lines))
    kept = [line for i, line in enumerate(lines) if i >= first_table or not re.match(r"\s*controller\s*=", line)]
    return f"controller = {json.dumps(controller)}  # quadsitl sweep --controller\n" + "\n".join(kept) + "\n"


def load_spec(name_or_path: str, controller: str | None = None) -> SweepSpec:
    """A shipped spec by name (``paper-mass-mismatch``) or any TOML file by path, validated; ``controller`` (the
    command's ``--controller``) in place of the spec's own."""
    path = Path(name_or_path)
    if name_or_path.endswith(".toml") or "/" in name_or_path or "\\" in name_or_path:
        if not path.is_file():
            raise ConfigError(f"sweep spec file {name_or_path!r} does not exist")
    else:
        names = available_specs()
        if name_or_path not in names:
            raise ConfigError(f"unknown sweep spec {name_or_path!r}; shipped specs: {', '.join(names)} (or a "
                              "path to a TOML file)")  # fmt: skip
        path = specs_folder() / f"{name_or_path}.toml"
    text = path.read_text(encoding="utf-8")
    return parse_spec(text if controller is None else with_controller(text, controller), path.stem, base=path.parent)


def _flatten(table: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    """[vary]'s nested tables (TOML's dotted keys) → {"group.name": value}; a table with ``dist`` is a leaf."""
    out: dict[str, Any] = {}
    for k, v in table.items():
        name = f"{prefix}{k}"
        if isinstance(v, dict) and "dist" not in v:
            out.update(_flatten(v, name + "."))
        else:
            out[name] = v
    return out


def parse_spec(
    text: str, name: str = "spec", base: Path | None = None, preset_text: str | None = None, preset_name: str = ""
) -> SweepSpec:
    """Parse and validate a spec from TOML text; a preset path in it is relative to ``base``. With
    ``preset_text``, that is the preset's TOML and ``preset_name`` its name (the key ``preset`` is then not
    read): how a sweep's folder, which keeps both texts, is read back (:func:`load_sweep`)."""
    where = f"sweep spec {name!r}"
    try:
        raw = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{where}: not valid TOML: {exc}") from None
    allowed = (*TOP, "keep", "limits", "vary")
    for key in raw:
        if key not in allowed:
            raise ConfigError(f"{where}: unknown key {key!r}; allowed: {', '.join(allowed)}")
    top: dict[str, Any] = {}
    for key, rule in TOP.items():
        if key in raw:
            top[key] = check_value(key, raw[key], rule, where)
        elif rule.required:
            raise ConfigError(f"{where}: missing key {key} ({rule.allowed})")
        else:
            top[key] = rule.default
    try:
        if preset_text is None:
            source = top["preset"]
            if base is not None and (source.endswith(".toml") or "/" in source):
                source = str((base / source) if not Path(source).is_absolute() else Path(source))
            preset_text, preset_name = read_preset(source)
        preset = parse_preset(preset_text, preset_name)
    except ConfigError as exc:
        raise ConfigError(f"{where}: preset = {top['preset']!r}: {exc}") from None
    controller = top["controller"] or preset.controller.type
    if is_plugin(controller):
        controller = _plugged(controller, base, preset, where)
    trajectory, mission, natural = _flown(top, base, preset, where)
    # What the autopilot flies on: the spec's state, else the preset's ([sensors] or not).
    top["state"] = top["state"] or ("sensors" if preset.sensors is not None else "truth")
    if top["state"] == "sensors" and preset.sensors is None:
        preset = replace(preset, sensors=SensorParams())
    elif top["state"] == "truth":
        preset = replace(preset, sensors=None)
    duration = top["duration"] or natural or preset.sim.duration

    limits = dict(DEFAULT_LIMITS)
    table = raw.get("limits", {})
    if not isinstance(table, dict):
        raise ConfigError(f"{where}: limits = {table!r}: expected a table [limits]")
    for key, value in table.items():
        if key not in LIMIT_NAMES:
            raise ConfigError(f"{where}: unknown key limits.{key}; allowed in [limits]: {', '.join(LIMIT_NAMES)}")
        limits[key] = check_value(f"limits.{key}", value, LIMIT_SPEC, where)

    table = raw.get("vary", {})
    if not isinstance(table, dict):
        raise ConfigError(f"{where}: vary = {table!r}: expected a table [vary]")
    vary: dict[str, Distribution] = {}
    for key, value in _flatten(table).items():
        check = _allowed(key)
        if check is None:
            raise ConfigError(f"{where}: unknown key vary.{key}; allowed: {', '.join(PARAMETERS)}")
        dist = parse_distribution(key, value, where)
        ok, what = check
        for v in dist.support():
            if not ok(v):
                bound = "its values include" if dist.kind in ("grid", "choice", "fixed") else "it can reach"
                raise ConfigError(f"{where}: vary.{key} = {value!r}: {bound} {v:g}; expected {what}"
                                  + (" (give a normal distribution bounds: low, high)"
                                     if dist.kind == "normal" and math.isinf(v) else ""))  # fmt: skip
        vary[key] = dist
    for key in vary:
        group, _, param = key.partition(".")
        if group == "model" and (f"mismatch.{param}" in vary or (param in ("ixx", "iyy", "izz")
                                                                    and "mismatch.inertia" in vary)):  # fmt: skip
            raise ConfigError(f"{where}: vary.{key} with vary.mismatch.{param}: the model's value is one or the "
                              "other (absolute, or a factor of the plant's)")  # fmt: skip
        if key in ("mismatch.ixx", "mismatch.iyy", "mismatch.izz") and "mismatch.inertia" in vary:
            raise ConfigError(f"{where}: vary.{key} with vary.mismatch.inertia: give one factor for all three, or "
                              "one per axis")  # fmt: skip
        if group == "gains" and is_plugin(controller):
            raise ConfigError(f"{where}: vary.{key}: gains.* are the built-in controllers'; {controller} is flown "
                              "with its parameters' defaults")  # fmt: skip
        pd_alt = param == "ki_alt" and controller == "pd"  # the PD's altitude channel has no integral
        if (
            group == "gains" and param not in INTEGRAL and (param in RATES) != (controller == "backstepping")
        ) or pd_alt:
            has = "k1..k8, ki_alt, ki_xy" if controller == "backstepping" else "kp1..kp4, kd1..kd4, ki_xy"
            raise ConfigError(f"{where}: vary.{key}: the {controller} controller has no such gain; its gains: {has}")

    keep_raw = raw.get("keep", [])
    if not isinstance(keep_raw, list) or not all(isinstance(k, int) and not isinstance(k, bool) and k >= 0
                                                 for k in keep_raw):  # fmt: skip
        raise ConfigError(f"{where}: keep = {keep_raw!r}: expected a list of trial numbers (integers >= 0)")
    keep = tuple(sorted(set(keep_raw)))
    for key in vary:
        if key.startswith("sensors.") and top["state"] != "sensors":
            raise ConfigError(f"{where}: vary.{key} with state = \"truth\": the autopilot flies on the true state; "
                              "set state = \"sensors\"")  # fmt: skip
    spec = SweepSpec(name, preset, controller, top["task"], duration, top["seed"], 1, keep, top["inadmissible"],
                     limits, vary, top["description"], where, top["engine"], text, preset_text, trajectory, mission,
                     top["state"])  # fmt: skip
    trials = top["trials"] or spec.grid_size
    _check_trials(trials, spec.grid_size, keep, f"{where}: trials")
    if round(duration / spec.period) < 1:
        raise ConfigError(f"{where}: duration = {duration!r}: shorter than one control period T = {spec.period:g} s")
    spec = check_engine(SweepSpec(**{**spec.__dict__, "trials": trials}))
    if controller == "backstepping":
        try:
            stability_interval(worst_poles(spec), spec.period)
        except GainError as exc:
            if spec.inadmissible == "refuse" or not any(k.startswith("gains.") for k in vary):
                varied = [k for k in vary if k.startswith("gains.")]
                which = f" (at the largest |λ| of {', '.join(varied)})" if varied else ""
                raise ConfigError(f"{where}: inadmissible gains{which}: {exc}; or set inadmissible = \"record\" "
                                  "to fly the others and record these") from None  # fmt: skip
    return spec


def _plugged(controller: str, base: Path | None, preset: Preset, where: str) -> str:
    """A controller of your own (``file.py:Name``: the spec's folder is its base; ``module:Name``), loaded, checked
    and probed on the preset's model as every trial would fly it; named by its absolute path."""
    from autopilot.factory import make_controller
    from autopilot.plugin import ControllerError

    controller = absolute(controller, base)
    try:
        make_controller(preset, controller, position_loop=False)
    except ControllerError as exc:
        raise ConfigError(f"{where}: {exc}") from None
    return controller


def _flown(top: dict[str, Any], base: Path | None, preset: Preset, where: str) -> tuple[str | None, Any, float | None]:
    """The spec's ``trajectory`` or ``mission``, checked as ``quadsitl fly`` checks them (a file's path relative to
    the spec's folder): (the trajectory, the mission, the duration they give: a position trajectory's own length, a
    mission's bound)."""
    from groundstation import trajectories
    from groundstation.mission_files import MISSION_DURATION
    from groundstation.mission_files import load as load_mission
    from quadsitl.cli_util import UsageError

    trajectory, mission_file = top.get("trajectory"), top.get("mission")
    if trajectory is not None and mission_file is not None:
        raise ConfigError(f"{where}: trajectory and mission: a trial flies one or the other")
    for key, value in (("trajectory", trajectory), ("mission", mission_file)):
        if value is not None and top["task"] != "step":
            raise ConfigError(f"{where}: {key} = {value!r} with task = {top['task']!r}: the {key} is what is flown; "
                              "leave task out")  # fmt: skip

    def located(name: str) -> str:
        path = Path(name)
        if base is not None and not path.is_absolute() and (base / path).is_file():
            return str(base / path)
        return name

    try:
        if trajectory is not None:
            if ":" not in trajectory and Path(located(trajectory)).is_file():
                trajectory = located(trajectory)
            path = trajectories.make(trajectory, preset.reference)
            natural = path.duration if isinstance(path, trajectories.PositionTrajectory) else None
            return trajectory, None, natural
        if mission_file is not None:
            return None, load_mission(located(mission_file)), MISSION_DURATION
    except UsageError as exc:
        key = "trajectory" if trajectory is not None else "mission"
        raise ConfigError(f"{where}: {key} = {top[key]!r}: {exc}") from None
    return None, None, None


def check_engine(spec: SweepSpec) -> SweepSpec:
    """The spec, or a ConfigError when its engine cannot fly it as asked: a trial the fused loop does not fly (a
    trajectory, a mission, sensors, wind) is a ``quadsitl sim`` of its preset, and the SITL engine's a ``quadsitl
    fly``; both check the default bounds. A ``quadsitl fly`` also starts on the ground at rest (its plant runs while
    the autopilot arms, before the flight begins, so an initial state elsewhere is not where the flight starts)."""
    if not spec.fused:
        for key, value in spec.limits.items():
            if value != DEFAULT_LIMITS[key]:
                what = ("trajectory" if spec.trajectory else "mission" if spec.mission else
                        "state = \"sensors\"" if spec.state == "sensors" else "wind")  # fmt: skip
                default = DEFAULT_LIMITS[key]
                raise ConfigError(f"{spec.where}: limits.{key} = {value!r} with {what}: each trial is a `quadsitl sim` "
                                  f"of its preset, which checks the default bounds ({key} = {default!r})")  # fmt: skip
    if spec.engine != "sitl":
        return spec
    p = spec.preset
    moving = [k for k in spec.vary if k.startswith("initial.")]
    if moving or spec.task == "hover" or dataclasses.astuple(p.initial) != dataclasses.astuple(InitialState()):
        what = f"vary.{moving[0]}" if moving else 'task = "hover"' if spec.task == "hover" else "its [initial]"
        raise ConfigError(f"{spec.where}: engine sitl with {what}: a `quadsitl fly` starts on the ground at rest (its "
                          "plant runs while the autopilot arms), so the trials' initial state cannot be flown; use the "
                          "batch engine")  # fmt: skip
    for key, value in spec.limits.items():
        if value != DEFAULT_LIMITS[key]:
            raise ConfigError(f"{spec.where}: engine sitl with limits.{key} = {value!r}: the plant process checks the "
                              f"default bounds ({key} = {DEFAULT_LIMITS[key]!r}); use the batch engine")  # fmt: skip
    return spec


def nominal_poles(spec: SweepSpec) -> tuple[float, ...]:
    """The preset's poles λ1..λ8."""
    return spec.preset.poles()


def worst_poles(spec: SweepSpec) -> tuple[float, ...]:
    """Each pole at the largest |λ| its gain can take: conditions (41)–(44) get only harder as any |λ| grows
    (ε > 4T²λ_i²/(1 − λ_i²) rises with |λ_i|, ε < 1 − T² − λ_(i+1)² falls with |λ_(i+1)|), so when these
    poles pass, every trial's do."""
    T = spec.period
    poles = list(nominal_poles(spec))
    for i, k in enumerate(RATES):
        d = spec.vary.get(f"gains.{k}")
        if d is not None:
            poles[i] = max((1.0 - T * v for v in d.support()), key=abs)
    return tuple(poles)


# ---- the trials' parameters -------------------------------------------------------------------------------


def draw(spec: SweepSpec, trials: np.ndarray) -> dict[str, np.ndarray]:
    """The varied parameters of the given trial numbers: {name: values}, one per trial, in the order given.
    Grid names take trial i's grid point (i mod G); the others come from trial i's own generator,
    SeedSequence(seed, spawn_key=(i,)), in sorted order: independent of which other trials are drawn with it."""
    trials = np.asarray(trials, dtype=np.int64)
    out = {k: np.empty(len(trials)) for k in spec.vary}
    grid = spec.grid
    sizes = [len(spec.vary[k].values) for k in grid]
    point = trials % max(spec.grid_size, 1)
    for k, n in zip(reversed(grid), reversed(sizes)):  # the last name varies fastest
        out[k][:] = np.asarray(spec.vary[k].values)[point % n]
        point = point // n
    drawn = spec.drawn
    if not drawn:
        return out
    fixed = [k for k in drawn if spec.vary[k].kind == "fixed"]
    for k in fixed:
        out[k][:] = spec.vary[k].values[0]
    random = [k for k in drawn if spec.vary[k].kind != "fixed"]
    if random:
        dists = [spec.vary[k] for k in random]
        columns = [out[k] for k in random]
        for row, i in enumerate(trials.tolist()):
            rng = np.random.Generator(np.random.PCG64(np.random.SeedSequence(spec.seed, spawn_key=(i,))))
            for col, d in zip(columns, dists):
                col[row] = d.draw(rng)
    return out


@dataclass
class TrialArrays:
    """The per-trial arrays the batch engine takes (:func:`groundstation.sweep.engine.run_chunk`), one row per
    trial: the initial state ``x0`` (12), the plant's vehicle ``v`` and actuators ``a``, the autopilot's model
    ``vm`` and control array ``c``, the reference ``r`` (4); ``admissible`` false where a trial's gains break
    (41)–(44) (``reason`` says how), which then is not flown."""

    x0: np.ndarray
    v: np.ndarray
    a: np.ndarray
    vm: np.ndarray
    c: np.ndarray
    r: np.ndarray
    admissible: np.ndarray
    reason: list[str]


def nominal(spec: SweepSpec) -> tuple[np.ndarray, ...]:
    """The unvaried trial, as ``quadsitl sim`` builds it (:func:`groundstation.offline.run_offline`): x0, v, a, vm,
    c, r."""
    p = spec.preset
    c = p.controller
    v = vehicle_array(p.vehicle)
    ctrl = control_array(nominal_poles(spec), p.sim.period, c.pd_kp, c.pd_kd, c.max_tilt, c.thrust_min,
                         c.thrust_max, p.position)  # fmt: skip
    x0 = np.array(initial_state(p), dtype=np.float64)
    r = np.array(p.reference, dtype=np.float64)
    if spec.task == "hover":  # at the reference altitude, level, at rest; asked to stay there
        x0[:] = 0.0
        x0[2] = -p.reference.altitude
        r[1:] = 0.0
    return x0, v, actuator_array(p.actuators), vehicle_array(p.autopilot_model), ctrl, r


def trial_arrays(spec: SweepSpec, params: dict[str, np.ndarray], n: int) -> TrialArrays:
    """The engine's arrays for ``n`` trials with the parameters ``params`` (from :func:`draw`)."""
    x0n, vn, an, vmn, cn, rn = nominal(spec)
    x0, v, a, c, r = (np.tile(arr, (n, 1)) for arr in (x0n, vn, an, cn, rn))
    for key, values in params.items():
        group, _, name = key.partition(".")
        if group == "plant":
            v[:, VEHICLE[name][0]] = values
        elif group == "initial":
            idx = INITIAL[name][0]
            x0[:, idx] = -values if name in ("altitude", "climb_rate") else values  # NED: z = −h, vz = −ḣ
        elif group == "reference":
            r[:, REFERENCE[name][0]] = values
    v[:, D_OVER_B] = v[:, D] / v[:, B]
    vm = v.copy()  # the model: the plant's values, the preset's [model] keys over them, then the spec's model.*
    for field_name, _ in spec.preset.model:  # and mismatch.* (a factor of the plant's value)
        cols = list(FIELD_COLUMNS[field_name])
        vm[:, cols] = vmn[cols]
    for key, values in params.items():
        group, _, name = key.partition(".")
        if group == "model":
            vm[:, VEHICLE[name][0]] = values
        elif group == "mismatch":
            for idx in (IXX, IYY, IZZ) if name == "inertia" else (VEHICLE[name][0],):
                vm[:, idx] = v[:, idx] * values
    vm[:, D_OVER_B] = vm[:, D] / vm[:, B]
    T = spec.period
    for i, k in enumerate(RATES):
        if f"gains.{k}" in params:
            c[:, POLES + i] = 1.0 - T * params[f"gains.{k}"]
    for k, index in zip(INTEGRAL, (KI_ALT, KI_XY)):
        if f"gains.{k}" in params:
            c[:, index] = params[f"gains.{k}"]
    for j in range(4):
        if f"gains.kp{j + 1}" in params:
            c[:, KP + j] = params[f"gains.kp{j + 1}"]
        if f"gains.kd{j + 1}" in params:
            c[:, KD + j] = params[f"gains.kd{j + 1}"]
    admissible = np.ones(n, dtype=bool)
    reason = [""] * n
    if spec.controller == "backstepping" and any(f"gains.{k}" in params for k in RATES):
        admissible, reason = admissibility(c[:, POLES : POLES + 8], T)
    return TrialArrays(x0, v, a, vm, c, r, admissible, reason)


def admissibility(poles: np.ndarray, period: float) -> tuple[np.ndarray, list[str]]:
    """Conditions (41)–(44) (:func:`autopilot.gains.stability_interval`) for each row of ``poles`` (n, 8: λ1..λ8)
    at the period T [s]: whether they hold for some ε > 0, and when not, the violated condition ("" when they
    hold). What :func:`trial_arrays` decides which trials fly with, and what the gain map draws."""
    n = len(poles)
    admissible = np.ones(n, dtype=bool)
    reason = [""] * n
    for i in range(n):
        try:
            stability_interval(tuple(poles[i]), period)
        except GainError as exc:
            admissible[i], reason[i] = False, str(exc)
    return admissible, reason


# ---- one trial as a preset ----------------------------------------------------------------------------------

DRAG_FIELDS = tuple(f"k{i + 1}" for i in range(6))


def trial_preset(spec: SweepSpec, trial: int) -> Preset:
    """Trial ``trial`` of the sweep as a preset of its own: the plant's vehicle in [vehicle], the autopilot's
    model in [model] (mismatches as the values they make), the gains, initial state and reference it flies, the
    spec's controller and duration. ``quadsitl sim`` on it flies what the batch engine flew for that trial, to
    the bit (the arrays of :func:`nominal` on it are that trial's :func:`trial_arrays` row), and ``quadsitl fly``
    on it flies the same trial through the whole SITL."""
    if not 0 <= trial < spec.trials:
        raise ConfigError(f"{spec.where}: trial {trial}: the sweep has {spec.trials} trials (0..{spec.trials - 1})")
    p = spec.preset
    params = {k: float(v[0]) for k, v in draw(spec, np.array([trial])).items()}

    def vehicle_fields(values: dict[str, float], base: Any) -> dict[str, Any]:
        """{VehicleParams field: value} for the spec's names (k1..k6 go into the drag tuple)."""
        out: dict[str, Any] = {}
        drag = list(base.drag)
        for name, value in values.items():
            if name in DRAG_FIELDS:
                drag[DRAG_FIELDS.index(name)] = value
                out["drag"] = tuple(drag)
            else:
                out[name] = value
        return out

    group = {g: {k.partition(".")[2]: v for k, v in params.items() if k.partition(".")[0] == g}
             for g in ("plant", "model", "mismatch", "gains", "initial", "reference", "wind", "sensors")}  # fmt: skip
    vehicle = replace(p.vehicle, **vehicle_fields(group["plant"], p.vehicle))
    # The model: the preset's [model] keys over the plant, then the spec's model.* and mismatch.* (× the plant's).
    model = replace(vehicle, **{k: getattr(p.autopilot_model, k) for k, _ in p.model})
    own = dict(group["model"])
    for name, factor in group["mismatch"].items():
        for k in ("ixx", "iyy", "izz") if name == "inertia" else (name,):
            plant_value = vehicle.drag[DRAG_FIELDS.index(k)] if k in DRAG_FIELDS else getattr(vehicle, k)
            own[k] = plant_value * factor
    model = replace(model, **vehicle_fields(own, model))
    fields = [f.name for f in dataclasses.fields(model)]
    overrides = tuple((k, getattr(model, k)) for k in fields if getattr(model, k) != getattr(vehicle, k))
    overrides = tuple(dict.fromkeys((*((k, getattr(model, k)) for k, _ in p.model), *overrides)).keys())
    # The initial state and reference (the hover task: at the reference altitude, level, at rest).
    initial, reference = p.initial, p.reference
    if spec.task == "hover":
        initial = InitialState(altitude=p.reference.altitude)
        reference = reference._replace(roll=0.0, pitch=0.0, yaw=0.0)
    initial = replace(initial, **group["initial"])
    reference = reference._replace(**group["reference"])
    # The gains: rates k stay rates (λ = 1 − T·k, as the engine's arrays make them), poles stay poles.
    c = replace(p.controller, type=spec.controller)
    rates = {int(k[1:]) - 1: v for k, v in group["gains"].items() if k in RATES}
    if rates and c.gains is not None:
        c = replace(c, gains=tuple(rates.get(i, k) for i, k in enumerate(c.gains)))
    elif rates:
        assert c.poles is not None
        c = replace(c, poles=tuple(1.0 - spec.period * rates[i] if i in rates else lam
                                   for i, lam in enumerate(c.poles)))  # fmt: skip
    kp = tuple(group["gains"].get(f"kp{j + 1}", x) for j, x in enumerate(c.pd_kp))
    kd = tuple(group["gains"].get(f"kd{j + 1}", x) for j, x in enumerate(c.pd_kd))
    c = replace(c, pd_kp=kp, pd_kd=kd)
    integral = tuple(group["gains"].get(k, x) for k, x in zip(INTEGRAL, p.position.integral))
    # The air and the sensors: the preset's, with the drawn values over them (a seed: the draw's integer part).
    wind = {WIND[k][0]: v for k, v in group["wind"].items()}
    if "turbulence" in wind:
        wind["turbulence"] = TURBULENCE_LEVELS[int(wind["turbulence"])]
    if "seed" in wind:
        wind["seed"] = int(wind["seed"])
    sensors = p.sensors
    if sensors is not None and group["sensors"]:
        scale = group["sensors"].get("noise", 1.0)
        sensors = replace(sensors, **{f: getattr(sensors, f) * scale for f in SENSOR_NOISE})
        if "seed" in group["sensors"]:
            sensors = replace(sensors, seed=int(group["sensors"]["seed"]))
    drawn = ", ".join(f"{k} = {v!r}" for k, v in params.items())
    return replace(
        p,
        name=f"{spec.name}-trial-{trial}",
        description=f"trial {trial} of sweep {spec.name!r} (seed {spec.seed})" + (f": {drawn}" if drawn else ""),
        vehicle=vehicle,
        model=overrides,
        sim=replace(p.sim, duration=spec.duration),
        controller=c,
        reference=reference,
        initial=initial,
        position=replace(p.position, integral=integral),
        wind=replace(p.wind, **wind),
        sensors=sensors,
    )


def load_sweep(folder: Path) -> SweepSpec:
    """The spec of the sweep written into ``folder`` (its ``spec.toml``, ``preset.toml`` and ``summary.json``'s
    number of trials), as it was flown: its trials can be flown again alone."""
    import json

    missing = [n for n in ("spec.toml", "preset.toml", "summary.json") if not (folder / n).is_file()]
    if missing:
        raise ConfigError(
            f"{folder}: not a sweep's folder (no {', '.join(missing)}; `quadsitl sweep --out` writes them)"
        )
    try:
        summary = json.loads((folder / "summary.json").read_text(encoding="utf-8"))
        trials, name, preset = int(summary["trials"]), str(summary["spec"]), str(summary["preset"])
    except (ValueError, KeyError, TypeError) as exc:
        raise ConfigError(f"{folder / 'summary.json'}: not a sweep's summary ({exc})") from None
    text = (folder / "spec.toml").read_text(encoding="utf-8")
    preset_text = (folder / "preset.toml").read_text(encoding="utf-8")
    spec = parse_spec(text, name, preset_text=preset_text, preset_name=preset)
    return spec.with_trials(trials) if trials != spec.trials else spec
