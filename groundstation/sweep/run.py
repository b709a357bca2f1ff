"""Running a sweep: its trials in chunks, in this process or in worker processes, then the table
(``trials.csv``, ``trials.parquet``), ``summary.json`` and the trajectories of the trials kept.

A chunk is a list of trial numbers. The worker that gets it draws their parameters
(:func:`groundstation.sweep.trials.draw`: each trial from its own seed), builds the engine's arrays and flies them
all in one compiled call (:func:`groundstation.sweep.engine.run_chunk`). A trial's row depends on the spec and
its number only, so the table is the same however the trials are split into chunks and over workers.
"""

from __future__ import annotations

import csv
import json
import math
import os
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from multiprocessing import get_context
from pathlib import Path

import numpy as np

from autopilot import setpoints
from autopilot.control_params import BACKSTEPPING, KINDS, PD
from groundstation import trajectories
from groundstation.setpoint_grid import grid_setpoints
from groundstation.sweep import engine
from groundstation.sweep.spec import SweepSpec
from groundstation.sweep.trial_row import metrics_row
from groundstation.sweep.trials import draw, trial_arrays, trial_preset
from groundstation.vehicle import Setpoints, commander_for, frame_of
from quadsitl.config import PositionParams
from quadsitl.frames import PX4_HOME
from quadsitl.state import Reference
from sitl.integrators import EULER, INTEGRATORS

FLOWN_METRICS = engine.METRICS[: engine.M_TICKS + 1] + engine.POSITION_METRICS + ("energy_j",)
"""The metrics columns of the table (:data:`groundstation.sweep.engine.METRICS` less the engine's bookkeeping)."""
PERCENTILES = (5, 25, 50, 75, 95)
WORST = 10  # trials listed in summary.json's "worst"
MAX_CHUNK = 2000  # trials per chunk at most: a progress update every second or so per worker


@dataclass
class ChunkResult:
    """What one chunk gives back: its trial numbers, their drawn parameters, metrics (engine.METRICS columns,
    NaN for trials not flown), admissibility and why not, and the kept trajectories: the batch engine's
    {trial: (ticks, KEEP_SIZE)}, or the SITL engine's telemetry rows {trial: (ticks, telemetry_csv.COLUMNS)}."""

    trials: np.ndarray
    params: dict[str, np.ndarray]
    metrics: np.ndarray
    admissible: np.ndarray
    reason: list[str]
    kept: dict[int, np.ndarray] = field(default_factory=dict)
    rows: dict[int, np.ndarray] = field(default_factory=dict)


def _method(spec: SweepSpec) -> int:
    return INTEGRATORS[spec.preset.sim.integrator]


def fly(spec: SweepSpec, trials: Sequence[int] | np.ndarray) -> ChunkResult:
    """Draw, build and fly the given trials in one call of the batch engine, or one ``quadsitl fly`` after the other
    with ``spec.engine`` "sitl" (also what a worker runs)."""
    trials = np.asarray(trials, dtype=np.int64)
    if spec.engine == "sitl":
        from groundstation.sweep.sitl_engine import fly_trials

        params, metrics, arrays, rows = fly_trials(spec, trials)
        return ChunkResult(trials, params, metrics, arrays.admissible, arrays.reason, rows=rows)
    params = draw(spec, trials)
    arrays = trial_arrays(spec, params, len(trials))
    if not spec.fused:
        metrics, kept = fly_as_sim(spec, trials, arrays.admissible)
        return ChunkResult(trials, params, metrics, arrays.admissible, arrays.reason, kept)
    n = len(trials)
    metrics = np.full((n, engine.METRICS_SIZE), math.nan)
    go = np.flatnonzero(arrays.admissible)
    keep_rows = [i for i in go.tolist() if int(trials[i]) in spec.keep]
    slots = np.full(len(go), -1, dtype=np.int64)
    for slot, row in enumerate(keep_rows):
        slots[np.searchsorted(go, row)] = slot
    keep = np.zeros((max(len(keep_rows), 1), spec.ticks if keep_rows else 1, engine.KEEP_SIZE))
    limits = np.array([spec.limits[k] for k in ("position", "speed", "tilt", "rate")], dtype=np.float64)
    sub = [np.ascontiguousarray(x[go]) for x in (arrays.x0, arrays.v, arrays.a, arrays.vm, arrays.c, arrays.r)]
    sub.append(np.tile(hold_setpoint(spec), (len(go), 1)) if spec.holds else setpoint_rows(sub[5]))
    turns = np.zeros(len(go))
    out = np.empty((len(go), engine.METRICS_SIZE))
    kind = KINDS[spec.controller]
    ticks, T, substeps = spec.ticks, spec.period, spec.preset.sim.substeps
    ctx = context(spec.preset.position, spec.ticks, spec.period)
    engine.run_chunk(*sub, kind, ticks, T, substeps, _method(spec), turns, spec.holds, limits, out, slots, keep, ctx)
    # The rare trial that ended with its yaw on another branch than it flew on: again, on its own (module doc).
    again = np.flatnonzero(out[:, engine.M_YAW_TURNS] != turns)
    if again.size:
        turns2 = out[again, engine.M_YAW_TURNS].copy()
        out2 = np.empty((again.size, engine.METRICS_SIZE))
        engine.run_chunk(*(np.ascontiguousarray(x[again]) for x in sub), kind, ticks, T, substeps, _method(spec),
                         turns2, spec.holds, limits, out2, np.ascontiguousarray(slots[again]), keep, ctx)  # fmt: skip
        out[again] = out2
    metrics[go] = out
    kept = {int(trials[row]): keep[slot].copy() for slot, row in enumerate(keep_rows)}
    return ChunkResult(trials, params, metrics, arrays.admissible, arrays.reason, kept)


def fly_as_sim(spec: SweepSpec, trials: np.ndarray, admissible: np.ndarray) -> tuple[np.ndarray, dict]:
    """Trials the fused loop does not fly (a moving trajectory, a mission, sensors, wind: :attr:`SweepSpec.fused`),
    each as
    ``quadsitl sim`` flies the trial's preset (:func:`groundstation.sweep.trials.trial_preset`), its row from its
    telemetry by the metrics' one definition (:mod:`groundstation.sweep.trial_row`), as the SITL engine's: (the
    metrics, engine.METRICS columns; the kept trajectories, engine.KEEP_SIZE columns)."""
    from groundstation.offline import rows_of, run_offline, telemetry_columns

    metrics = np.full((len(trials), engine.METRICS_SIZE), math.nan)
    kept: dict[int, np.ndarray] = {}
    for i, k in enumerate(trials.tolist()):
        if not admissible[i]:
            continue
        preset = trial_preset(spec, k)
        results, _ = run_offline(preset, [spec.controller], spec.duration, trajectory=spec.trajectory or "step",
                                 mission=spec.mission, metrics=False)  # fmt: skip
        res = results[spec.controller]
        if res.mission is not None and res.mission.where:
            raise SweepError(f"sweep {spec.name!r}, trial {k}: {res.mission.where}")
        metrics[i] = metrics_row(
            telemetry_columns(res, rates=False), preset, spec.period, res.diverged_at, spec.mission is not None
        )
        if k in spec.keep:
            kept[k] = rows_of(res)
    return metrics, kept


def hold_setpoint(spec: SweepSpec) -> np.ndarray:
    """The offboard setpoint of the spec's position hold (the commander's fields), as ``quadsitl sim`` parses it for
    the spec's preset (:func:`groundstation.offline.grid_of`: the frame of a vehicle not yet flown, yaw 0)."""
    path = trajectories.make(spec.trajectory, spec.preset.reference)
    frame = frame_of(spec.preset, PX4_HOME, commander_for(spec.preset.position), 0.0)
    return Setpoints.of([(0, path(0.0))], frame).values[0]


def setpoint_rows(r: np.ndarray) -> np.ndarray:
    """Each trial's offboard setpoint (the commander's fields, :class:`groundstation.vehicle.Setpoints`) for its
    reference r[i] (altitude, roll, pitch, yaw), as ``quadsitl fly``'s ground station sends it and ``quadsitl sim``
    gives it."""
    frame = setpoints.Frame(PX4_HOME)
    return Setpoints.of(((0, Reference(*row)) for row in r.tolist()), frame).values


def context(position: PositionParams, ticks: int, period: float) -> tuple:
    """The engine's arrays for a chunk of trials of ``ticks`` ticks of ``period`` [s]
    (:func:`groundstation.sweep.engine.context`): the commander as the preset's ``position`` settings start it,
    the setpoint sent at every moment of ``quadsitl fly``'s grid."""
    moments = [g for g, _ in grid_setpoints(lambda t: None, period, ticks)]
    return engine.context(commander_for(position).cm, np.array(moments, dtype=np.int64))


VERSIONS = ((BACKSTEPPING, 1, EULER), (PD, 1, EULER))
"""(controller, substeps, integrator) of each compiled version of the engine: the paper's and the general one."""


def warm_up(spec: SweepSpec | None = None) -> None:
    """Compile the batch engine (or load it from numba's cache) on made-up data, before workers start: they then
    load it instead of compiling it each; the version ``spec`` flies (:func:`groundstation.sweep.engine.run_chunk`),
    or every version. For the SITL engine, the processes' equations."""
    if spec is not None and spec.engine == "sitl":
        from groundstation.launcher import compile_once

        compile_once(None)
        return
    if spec is not None and not spec.fused:  # each trial a `quadsitl sim`: its loop, on the first trial's preset
        from groundstation.offline import run_offline

        run_offline(trial_preset(spec, 0), [spec.controller], spec.period, trajectory=spec.trajectory or "step",
                    mission=spec.mission)  # fmt: skip
        return
    versions = VERSIONS if spec is None else [(KINDS[spec.controller], spec.preset.sim.substeps, _method(spec))]
    for kind, substeps, method in versions:
        warm_version(kind, substeps, method)


def warm_version(kind: int, substeps: int, method: int) -> None:
    """Compile (or load) the engine's version that flies controller ``kind`` with ``substeps`` steps of integrator
    ``method`` per tick (the paper's configuration has a version of its own; every other shares one)."""
    from autopilot.control_params import SIZE
    from quadsitl.param_arrays import ACTUATOR_SIZE, VEHICLE_SIZE

    one = np.ones((1, 12))
    r = np.array([[1.0, 0.0, 0.0, 0.0]])
    engine.run_chunk(one, np.ones((1, VEHICLE_SIZE)), np.ones((1, ACTUATOR_SIZE)), np.ones((1, VEHICLE_SIZE)),
                     np.full((1, SIZE), 0.5), r, setpoint_rows(r), kind, 1, 0.001, substeps, method, np.zeros(1),
                     False, np.array(engine.DEFAULT_LIMITS), np.empty((1, engine.METRICS_SIZE)), np.zeros(1, np.int64),
                     np.zeros((1, 1, engine.KEEP_SIZE)), context(PositionParams(), 1, 0.001))  # fmt: skip


def chunks(trials: int, workers: int, chunk: int | None = None) -> list[np.ndarray]:
    """Trial numbers 0..trials−1 in consecutive chunks: ``chunk`` each, or by default about four per worker (at
    most MAX_CHUNK)."""
    size = chunk or max(1, min(MAX_CHUNK, math.ceil(trials / (4 * workers))))
    return [np.arange(start, min(start + size, trials)) for start in range(0, trials, size)]


@dataclass
class SweepResult:
    """The table (one row per trial, in trial order: {column: values}), the kept trajectories, how long the
    flights took (wall time [s], from the first chunk's start: the engine already compiled), how many ticks, and
    where they ran (summary.json's ``cluster``: the scheduler's address or None, and ``workers``)."""

    spec: SweepSpec
    table: dict[str, np.ndarray]
    reasons: list[str]
    kept: dict[int, np.ndarray]
    wall_s: float
    ticks_flown: int
    rows: dict[int, np.ndarray] = field(default_factory=dict)  # the SITL engine's kept telemetry rows
    where: dict[str, str | int | None] = field(default_factory=dict)


class SweepError(RuntimeError):
    """A sweep that did not complete: the chunks did not give back every trial exactly once, or the cluster
    failed (:class:`groundstation.sweep.cluster.ClusterError`). One line; nothing is written."""


def _worker_pid(seconds: float) -> int:
    """A worker's process id, after ``seconds`` (so that one worker does not take every such task at once)."""
    time.sleep(seconds)
    return os.getpid()


def run_sweep(
    spec: SweepSpec,
    workers: int = 1,
    chunk: int | None = None,
    progress: Callable[[float], None] | None = None,
) -> SweepResult:
    """Fly every trial of ``spec``: in this process (``workers`` = 1) or in ``workers`` processes, by chunks.
    ``progress``, when given, is called with the simulated vehicle-seconds done after each chunk.
    (:func:`groundstation.sweep.cluster.run_on_cluster` flies the same chunks on a Dask cluster.)"""
    parts = chunks(spec.trials, workers, chunk)
    warm_up(spec)
    start = time.monotonic()  # the flights only: not the first compilation, nor the workers' start
    results: list[ChunkResult] = []
    done = 0.0
    processes = 1 if workers <= 1 or len(parts) == 1 else min(workers, len(parts))
    if processes == 1:
        for part in parts:
            results.append(fly(spec, part))
            done += len(part) * spec.duration
            if progress is not None:
                progress(done)
        wall = time.monotonic() - start
    else:
        with ProcessPoolExecutor(max_workers=processes, mp_context=get_context("spawn"), initializer=warm_up,
                                 initargs=(spec,)) as pool:  # fmt: skip
            ready: set[int] = set()  # every worker started and warm (a worker runs tasks once its warm-up is done)
            while len(ready) < processes:
                ready.update(f.result() for f in [pool.submit(_worker_pid, 0.05) for _ in range(processes)])
            start = time.monotonic()
            futures = [pool.submit(fly, spec, part) for part in parts]
            for fut, part in zip(futures, parts):
                results.append(fut.result())
                done += len(part) * spec.duration
                if progress is not None:
                    progress(done)
            wall = time.monotonic() - start  # the flights: not the workers' shutdown on leaving the pool
    return assemble(spec, results, wall, {"cluster": None, "workers": processes})


def assemble(
    spec: SweepSpec, results: list[ChunkResult], wall: float, where: dict[str, str | int | None]
) -> SweepResult:
    """The table in trial order from the chunks' results, in any order; ``wall`` [s] and ``where`` as
    :class:`SweepResult` has them. A :class:`SweepError` unless every trial 0..N−1 came back exactly once."""
    trials = np.concatenate([r.trials for r in results]) if results else np.zeros(0, dtype=np.int64)
    check_every_trial_once(spec, trials)
    order = np.argsort(trials, kind="stable")
    metrics = np.concatenate([r.metrics for r in results])[order]
    admissible = np.concatenate([r.admissible for r in results])[order]
    reasons = [x for r in results for x in r.reason]
    reasons = [reasons[i] for i in order]
    table: dict[str, np.ndarray] = {"trial": trials[order]}
    for name in spec.vary:
        table[name] = np.concatenate([r.params[name] for r in results])[order]
    table["admissible"] = admissible
    for name in FLOWN_METRICS:
        table[name] = metrics[:, engine.METRICS.index(name)]
    table["diverged"] = metrics[:, engine.M_DIVERGED] == 1.0
    kept = {k: v for r in results for k, v in r.kept.items()}
    rows = {k: v for r in results for k, v in r.rows.items()}
    ticks = int(np.nansum(metrics[:, engine.M_TICKS]))
    return SweepResult(spec, table, reasons, kept, wall, ticks, rows, dict(where))


def check_every_trial_once(spec: SweepSpec, trials: np.ndarray) -> None:
    """A :class:`SweepError` naming the first trials missing or come back more than once, unless ``trials``
    holds every number 0..spec.trials−1 exactly once (in any order)."""
    counts = np.bincount(trials[(trials >= 0) & (trials < spec.trials)], minlength=spec.trials)
    stray = trials[(trials < 0) | (trials >= spec.trials)]
    missing, twice = np.flatnonzero(counts == 0), np.flatnonzero(counts > 1)
    if missing.size or twice.size or stray.size:

        def some(xs: np.ndarray) -> str:
            return ", ".join(str(int(x)) for x in xs[:5]) + (f" and {xs.size - 5} more" if xs.size > 5 else "")

        what = [f"{what}: {some(xs)}" for what, xs in (("missing", missing), ("more than once", twice),
                                                       ("not in the sweep", stray)) if xs.size]  # fmt: skip
        raise SweepError(f"sweep {spec.name!r}: the chunks did not give back every trial 0..{spec.trials - 1} "
                         f"exactly once: {'; '.join(what)}")  # fmt: skip


# ---- the summary ------------------------------------------------------------------------------------------


def _num(x: float) -> float | None:
    return None if not math.isfinite(x) else float(x)


def _badness(table: dict[str, np.ndarray], i: int) -> tuple:
    """Sort key, worst first: diverged (earliest first), then, for a position trajectory or a mission, the largest
    horizontal error; else the longest settling time over the channels with a step (one that never settled counts
    as infinite), then the largest overshoot (settling times are whole ticks: many trials share one)."""
    if table["diverged"][i]:
        return (0, table["diverged_at"][i], 0.0)
    if math.isfinite(table["horizontal_max"][i]):
        return (1, -table["horizontal_max"][i], -table["horizontal_rms"][i])
    worst, overshoot = -math.inf, 0.0
    for ch in engine.CHANNELS:
        if math.isfinite(table[f"{ch}_overshoot_pct"][i]):  # the channel had a step
            settle = table[f"{ch}_settling_time"][i]
            worst = max(worst, settle if math.isfinite(settle) else math.inf)
            overshoot = max(overshoot, table[f"{ch}_overshoot_pct"][i])
    return (1, -worst, -overshoot)


def summarize(result: SweepResult) -> dict:
    """summary.json: the sweep's settings, counts, percentiles of every metric over the trials flown that did
    not diverge, and the worst trials with their parameters."""
    spec, table = result.spec, result.table
    n = len(table["trial"])
    flown = table["admissible"]
    diverged = table["diverged"] & flown
    ok = flown & ~diverged
    metrics = {}
    for name in (*FLOWN_METRICS[: 4 * engine.PER_CHANNEL], "saturation_time", *engine.POSITION_METRICS, "energy_j"):
        col = table[name][ok]
        finite = col[np.isfinite(col)]
        entry: dict[str, float | int | None] = {"undefined": int(col.size - finite.size)}
        if finite.size:
            entry.update({f"p{p}": float(v) for p, v in zip(PERCENTILES, np.percentile(finite, PERCENTILES))})
            entry.update(min=float(finite.min()), max=float(finite.max()), mean=float(finite.mean()))
        metrics[name] = entry
    rows = sorted(np.flatnonzero(flown).tolist(), key=lambda i: _badness(table, i))[:WORST]
    params = list(spec.vary)
    worst = []
    for i in rows:
        worst.append({
            "trial": int(table["trial"][i]),
            "parameters": {k: float(table[k][i]) for k in params},
            "diverged": bool(table["diverged"][i]),
            "diverged_at": _num(table["diverged_at"][i]),
            "settling_time": {ch: _num(table[f"{ch}_settling_time"][i]) for ch in engine.CHANNELS},
            "overshoot_pct": {ch: _num(table[f"{ch}_overshoot_pct"][i]) for ch in engine.CHANNELS},
            "steady_state_error": {ch: _num(table[f"{ch}_steady_state_error"][i]) for ch in engine.CHANNELS},
            **{name: _num(table[name][i]) for name in engine.POSITION_METRICS},
        })  # fmt: skip
    n_flown = int(flown.sum())
    return {
        "spec": spec.name,
        "description": spec.description,
        "preset": spec.preset.name,
        "controller": spec.controller,
        "engine": spec.engine,
        "task": spec.task,
        "trajectory": spec.trajectory,
        "mission": None if spec.mission is None else str(spec.mission.path),
        "state": spec.state,
        "duration": spec.duration,
        "period": spec.period,
        "seed": spec.seed,
        "trials": n,
        "varied": {k: d.describe() for k, d in spec.vary.items()},
        "flown": n_flown,
        "inadmissible": n - n_flown,
        "diverged": int(diverged.sum()),
        "failure_rate": float(diverged.sum() / n_flown) if n_flown else None,
        **{k: result.where[k] for k in ("cluster", "workers") if k in result.where},
        "wall_s": result.wall_s,
        "vehicle_steps": result.ticks_flown,
        "vehicle_steps_per_s": result.ticks_flown / result.wall_s if result.wall_s > 0 else None,
        "percentiles": list(PERCENTILES),
        "metrics": metrics,
        "worst": worst,
    }


# ---- the files --------------------------------------------------------------------------------------------


def write_table(out: Path, result: SweepResult) -> list[Path]:
    """trials.csv and trials.parquet: one row per trial, its parameters and metrics (NaN: not defined, or not
    flown); with ``inadmissible = "record"`` also the violated condition."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    table = dict(result.table)
    if result.spec.inadmissible == "record":
        table["inadmissible_reason"] = np.array(result.reasons, dtype=object)
    csv_path, parquet_path = out / "trials.csv", out / "trials.parquet"
    columns = list(table)
    with open(csv_path, "w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(columns)
        cells = [_csv_cells(table[c]) for c in columns]
        w.writerows(zip(*cells))
    pq.write_table(pa.table({c: pa.array(table[c].tolist() if table[c].dtype == object else table[c])
                             for c in columns}), parquet_path)  # fmt: skip
    return [csv_path, parquet_path]


def _csv_cells(col: np.ndarray) -> list[str]:
    if col.dtype == bool:
        return ["1" if v else "0" for v in col.tolist()]
    if col.dtype.kind in "iu":
        return [str(v) for v in col.tolist()]
    if col.dtype == object:
        return [str(v) for v in col.tolist()]
    return [repr(v) if math.isfinite(v) else "nan" for v in col.tolist()]


def write_kept(out: Path, result: SweepResult) -> list[Path]:
    """Each kept trial's trajectory as ``trajectories/trial_<k>.csv``, the telemetry CSV of ``quadsitl sim``."""
    from groundstation.telemetry_csv import rows_from_arrays, write_csv
    from quadsitl.compiled_frames import euler_rates_to_body_rates

    files = []
    if result.kept or result.rows:
        (out / "trajectories").mkdir(parents=True, exist_ok=True)
    for trial, rows in sorted(result.rows.items()):  # the SITL engine's: the flight's telemetry.csv as it was
        path = out / "trajectories" / f"trial_{trial}.csv"
        write_csv(path, rows)
        files.append(path)
    T = result.spec.period
    for trial, k in sorted(result.kept.items()):
        i = np.flatnonzero(result.table["trial"] == trial)[0]
        n = int(result.table["ticks"][i]) if math.isfinite(result.table["ticks"][i]) else k.shape[0]
        k = k[:n]
        s = k[:, engine.K_STATE : engine.K_STATE + 12]
        rates = np.array([euler_rates_to_body_rates(r[6], r[7], r[9], r[10], r[11]) for r in s]).reshape(-1, 3)
        path = out / "trajectories" / f"trial_{trial}.csv"
        write_csv(path, rows_from_arrays(np.arange(n) * T, s, rates, k[:, engine.K_REF : engine.K_REF + 4],
                                         k[:, engine.K_INPUTS : engine.K_INPUTS + 4],
                                         k[:, engine.K_FORCES : engine.K_FORCES + 4]))  # fmt: skip
        files.append(path)
    return files


def write_outputs(out: Path, result: SweepResult, summary: dict) -> list[Path]:
    """The table, summary.json, the spec and its preset as read (``spec.toml``, ``preset.toml``: what
    ``quadsitl sim --from-sweep`` flies a trial again from) and the kept trajectories into ``out``."""
    out.mkdir(parents=True, exist_ok=True)
    files = write_table(out, result)
    path = out / "summary.json"
    path.write_text(json.dumps(summary, indent=2) + "\n")
    files.append(path)
    for name, text in (("spec.toml", result.spec.text), ("preset.toml", result.spec.preset_text)):
        (out / name).write_text(text, encoding="utf-8")
        files.append(out / name)
    return files + write_kept(out, result)
