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

What can vary and what each may take: :mod:`groundstation.sweep.parameters`; the distributions:
:mod:`groundstation.sweep.distributions`; the trials' draws, arrays and presets: :mod:`groundstation.sweep.trials`.
Grids make a product, the names in sorted order, the first varying slowest; trial i flies grid point i mod G, and
the number of trials must be a multiple of G.

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

from autopilot.gains import GainError, stability_interval
from groundstation.sweep.distributions import Distribution, parse_distribution
from groundstation.sweep.parameters import INTEGRAL, PARAMETERS, RATES, vary_rule

# Re-exported: the tests and the benchmark took these from here before the trials had a module of their own.
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
    parse_preset,
    read_preset,
)
from quadsitl.controller_names import ALLOWED, absolute, is_controller_name, is_plugin
from quadsitl.keys import spec

if TYPE_CHECKING:
    from groundstation.mission_files import Mission

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - exercised on Python 3.10 only
    import tomli as tomllib

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
    def holds(self) -> bool:
        """The trajectory is a position hold (``hold[:...]``): one setpoint, sent again and again."""
        return self.trajectory is not None and self.trajectory.partition(":")[0] == "hold"

    @property
    def fused(self) -> bool:
        """The batch engine flies its trials in one compiled loop (:func:`groundstation.sweep.engine.run_chunk`):
        the task's constant reference, or a position hold, on the true state in calm air. Any other spec (a moving
        trajectory, a mission, sensors, wind) has each trial flown as ``quadsitl sim`` flies the trial's preset
        (:func:`trial_preset`), one after the other (:mod:`groundstation.sweep.run`); so is a controller of your own
        (``file.py:Name``)."""
        calm = self.preset.wind == WindParams() and not any(k.startswith(("wind.", "sensors.")) for k in self.vary)
        built_in = not is_plugin(self.controller)
        constant = self.trajectory is None or self.holds
        return constant and self.mission is None and self.state == "truth" and calm and built_in

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
        check = vary_rule(key)
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
            stability_interval(_worst_poles(spec), spec.period)
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


def _worst_poles(spec: SweepSpec) -> tuple[float, ...]:
    """:func:`groundstation.sweep.trials.worst_poles` (imported here: the trials module takes the spec's types)."""
    from groundstation.sweep.trials import worst_poles

    return worst_poles(spec)
