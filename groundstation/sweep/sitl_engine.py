"""The SITL engine of the sweeps (``quadsitl sweep --engine sitl``): every trial a whole ``quadsitl fly``.

A trial is written as a preset of its own (:func:`groundstation.sweep.trials.trial_preset`: the plant's vehicle, the
autopilot's model, the gains, initial state and reference) and flown by ``quadsitl fly`` in a process of its own:
the plant and autopilot processes in lockstep over MAVLink/UDP, the ground station sending the reference as
MAVLink setpoints and logging the telemetry from Zenoh. The trial's row comes from that flight's telemetry, with the
metrics' one definition (:func:`groundstation.metrics.run_metrics`, :func:`groundstation.metrics.saturation_time`),
so the table has the batch engine's columns and agrees with it to the wire's float32 rounding. A trial whose plant
diverged ends as the batch engine ends it: ``diverged`` with the time of the tick whose state left the bounds.

It is the multi-process SITL at scale, for the checks only the whole system can make (the wire's rounding, the
lockstep, the autopilot's commander and allocation as flown); the batch engine is for numbers of trials.
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from groundstation.launcher import FLY_DIVERGED
from groundstation.sweep import engine
from groundstation.sweep.spec import SweepSpec
from groundstation.sweep.trial_row import metrics_row
from groundstation.sweep.trials import draw, trial_arrays, trial_preset
from groundstation.telemetry_csv import COLUMNS
from quadsitl.config import preset_toml

COL = {name: i for i, name in enumerate(COLUMNS)}


def fly_command(preset: Path, duration: float, out: Path, spec: SweepSpec | None = None) -> list[str]:
    """The ``quadsitl fly`` a trial is: lockstep, as fast as possible, no figures, nothing printed on success; the
    spec's trajectory or mission."""
    flown = []
    if spec is not None and spec.trajectory is not None:
        flown = ["--trajectory", spec.trajectory]
    elif spec is not None and spec.mission is not None:
        flown = ["--mission", str(spec.mission.path)]
    return [sys.executable, "-m", "groundstation.cli", "fly", "--preset", str(preset), "--duration", repr(duration),
            "--out", str(out), "--no-figures", "--quiet", *flown]  # fmt: skip


def fly_trial(spec: SweepSpec, trial: int, folder: Path, timeout: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Fly trial ``trial`` through the whole SITL in ``folder``: (its metrics row, engine.METRICS columns; its
    telemetry rows, telemetry_csv.COLUMNS). Raises RuntimeError, with what ``fly`` said, when the flight fails."""
    folder.mkdir(parents=True, exist_ok=True)
    preset = trial_preset(spec, trial)
    path = folder / "preset.toml"
    path.write_text(preset_toml(preset), encoding="utf-8")
    out = folder / "flight"
    wall = timeout if timeout is not None else 120.0 + 60.0 * spec.duration
    r = subprocess.run(fly_command(path, spec.duration, out, spec), capture_output=True, text=True, timeout=wall)
    if r.returncode not in (0, FLY_DIVERGED):
        tail = " | ".join(r.stderr.strip().splitlines()[-3:])
        raise RuntimeError(f"trial {trial}: quadsitl fly exited with status {r.returncode}: {tail}")
    # The trial's ticks: a flight that diverged while landing, after them, kept its landing's rows too.
    rows = np.loadtxt(out / "telemetry.csv", delimiter=",", skiprows=1, ndmin=2)
    if spec.mission is None:
        rows = rows[: spec.ticks]
    # A flight that diverged before its end; one whose landing, after it, diverged was flown whole (the batch
    # engine flies the trial's duration only).
    diverged = r.returncode == FLY_DIVERGED and (spec.mission is not None or len(rows) < spec.ticks)
    diverged_at = json.loads((out / "metrics.json").read_text())["diverged_at"] if diverged else None
    return metrics_row(rows, preset, spec.period, diverged_at, spec.mission is not None), rows


def fly_trials(spec: SweepSpec, trials: np.ndarray) -> tuple[dict, np.ndarray, object, dict[int, np.ndarray]]:
    """Trials of a chunk, one ``quadsitl fly`` after the other: (their parameters, metrics, the trial arrays (for
    admissibility), the telemetry rows of the trials kept)."""
    params = draw(spec, trials)
    arrays = trial_arrays(spec, params, len(trials))
    metrics = np.full((len(trials), engine.METRICS_SIZE), math.nan)
    rows: dict[int, np.ndarray] = {}
    with tempfile.TemporaryDirectory(prefix="quadsitl-sweep-") as tmp:
        for i, k in enumerate(trials.tolist()):
            if not arrays.admissible[i]:
                continue
            metrics[i], telemetry = fly_trial(spec, k, Path(tmp) / f"trial_{k}")
            if k in spec.keep:
                rows[k] = telemetry
    return params, metrics, arrays, rows
