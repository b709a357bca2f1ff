"""``quadsitl sim``: the paper's experiment (or any preset) in one process, no network.

Builds the plant (``sitl``) and the controllers (``autopilot``) from a preset, runs the closed loop,
and writes telemetry CSV(s), ``metrics.json`` and the figures. A run whose state diverges
(:func:`sitl.simulate.simulate`) ends there: its CSV and metrics hold the ticks flown before it, and
``metrics.json`` says when (``diverged``, ``diverged_at``), as ``quadsitl fly`` does.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from autopilot.factory import make_controller
from groundstation.figures import write_figures
from groundstation.metrics import channel_outputs, run_metrics
from groundstation.telemetry_csv import rows_from_arrays, write_csv
from quadsitl.config import Preset
from quadsitl.mixer import allocate
from sitl.plant import Plant
from sitl.simulate import SimResult, simulate


@dataclass
class OfflineRun:
    """What ``quadsitl sim`` produced."""

    results: dict[str, SimResult]
    metrics: dict[str, dict]
    files: list[Path] = field(default_factory=list)


def run_offline(
    preset: Preset,
    controllers: Sequence[str],
    duration: float | None = None,
    integrator: str | None = None,
    substeps: int | None = None,
    rates: Sequence[float] | None = None,
    poles: Sequence[float] | None = None,
    progress: Callable[[float], None] | None = None,
) -> tuple[dict[str, SimResult], dict[str, dict]]:
    """Simulate each controller on a fresh plant. All controllers are built (and their gains checked)
    before any simulation starts, so inadmissible gains fail fast.

    ``progress``, when given, is called now and then with the simulated seconds done so far over all
    the runs: it reaches ``len(controllers) × duration`` at the end."""
    built = {kind: make_controller(preset, kind, rates=rates, poles=poles, position_loop=False) for kind in controllers}
    duration = duration or preset.sim.duration
    act = preset.actuators
    d_over_b = preset.autopilot_model.d_over_b

    def alloc(u: tuple[float, float, float, float]) -> tuple[float, float, float, float]:
        return allocate(u, d_over_b, act.min_thrust, act.max_thrust)

    results, metrics = {}, {}
    for i, (kind, controller) in enumerate(built.items()):
        plant = Plant(preset, integrator=integrator, substeps=substeps)
        done = None if progress is None else (lambda s, before=i * duration: progress(before + s))
        res = simulate(plant, controller, preset.reference, duration, alloc, progress=done)
        results[kind] = res
        flown = len(res.t) > 0  # a run that diverged at its first tick flew nothing: no metrics (None)
        metrics[kind] = run_metrics(res.t, channel_outputs(res.state), res.reference, res.inputs) if flown else None
    return results, metrics


def write_outputs(
    out: Path,
    preset: Preset,
    results: dict[str, SimResult],
    metrics: dict[str, dict],
    settings: dict,
    figures: bool = True,
) -> list[Path]:
    """telemetry.csv (first controller), telemetry_<other>.csv, metrics.json and fig2–fig4 PNGs.

    metrics.json's ``diverged`` and ``diverged_at`` [s] (null when it did not) are those of the run in
    telemetry.csv, as in ``quadsitl fly``'s; with more than one controller, ``diverged_at_by_controller`` has
    each run's."""
    out.mkdir(parents=True, exist_ok=True)
    files = []
    for i, (kind, res) in enumerate(results.items()):
        path = out / ("telemetry.csv" if i == 0 else f"telemetry_{kind}.csv")
        write_csv(path, rows_from_arrays(res.t, res.state, res.body_rates(), res.reference, res.inputs, res.forces))
        files.append(path)
    mpath = out / "metrics.json"
    first = next(iter(results.values()))
    diverged = {"diverged": first.diverged_at is not None, "diverged_at": first.diverged_at}
    if len(results) > 1:
        diverged["diverged_at_by_controller"] = {k: r.diverged_at for k, r in results.items()}
    mpath.write_text(json.dumps({"preset": preset.name, **settings, **diverged, "runs": metrics}, indent=2) + "\n")
    files.append(mpath)
    runs = {
        k: {"t": r.t, "outputs": channel_outputs(r.state), "reference": r.reference, "inputs": r.inputs}
        for k, r in results.items()
        if len(r.t)
    }
    if figures and runs:
        files += write_figures(runs, out, f"preset {preset.name}")
    return files
