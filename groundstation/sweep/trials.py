"""A sweep's trials: the parameters each draws (:func:`draw`), the arrays the batch engine flies them with
(:func:`trial_arrays`), whether their gains satisfy the paper's conditions (:func:`admissibility`,
:func:`worst_poles`), and one trial as a preset of its own (:func:`trial_preset`). Pure: no I/O, nothing compiled.

A trial's parameters depend on the sweep's seed and its number only: grid names take trial i's grid point
(i mod G), every other draw comes from trial i's own generator, ``numpy.random.SeedSequence(seed,
spawn_key=(i,))``, the names in sorted order, one value each; never on how the trials are split into chunks or
workers.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any

import numpy as np

from autopilot.control_params import KD, KI_ALT, KI_XY, KP, POLES, control_array
from autopilot.gains import GainError, stability_interval
from groundstation.sweep.parameters import (
    DRAG_FIELDS,
    INITIAL,
    INTEGRAL,
    RATES,
    REFERENCE,
    SENSOR_NOISE,
    TURBULENCE_LEVELS,
    VEHICLE,
    WIND,
)
from quadsitl.config import ConfigError, InitialState, Preset, initial_state
from quadsitl.param_arrays import D_OVER_B, FIELD_COLUMNS, IXX, IYY, IZZ, B, D, actuator_array, vehicle_array

if TYPE_CHECKING:
    from groundstation.sweep.spec import SweepSpec


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
    return x0, v, actuator_array(p.actuators, p.battery), vehicle_array(p.autopilot_model), ctrl, r


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
