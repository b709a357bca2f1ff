"""``quadsitl sim``: the paper's experiment (or any preset) in one process, no network.

Builds the plant (``sitl``) and the controllers (``autopilot``) from a preset, runs the closed loop,
and writes telemetry CSV(s), ``metrics.json`` and the figures. A run whose state diverges
(:func:`sitl.simulate.simulate`) ends there: its CSV and metrics hold the ticks flown before it, and
``metrics.json`` says when (``diverged``, ``diverged_at``), as ``quadsitl fly`` does.

A preset flown on sensors (its ``sensors``: ``--state sensors``) is flown as ``quadsitl fly`` flies it: the
plant's sensor datagram of each tick (the same compiled encoder), decoded and estimated by the autopilot's own
compiled functions (:class:`SensorObserver`), the controller on the estimate, after SENSOR_GROUND_S on the
ground. telemetry.csv then has the estimate in x..r and the truth in x_true..r_true.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from autopilot.estimator import Estimator
from autopilot.factory import make_controller
from groundstation.figures import write_figures
from groundstation.metrics import channel_outputs, estimate_rms, run_metrics
from groundstation.telemetry_csv import rows_from_arrays, write_csv
from quadsitl import codec, hil
from quadsitl.config import SENSOR_GROUND_S, Preset
from quadsitl.frames import PX4_HOME
from quadsitl.mixer import allocate
from quadsitl.state import VehicleState
from sitl import tick as plant_tick
from sitl.plant import Plant
from sitl.simulate import SimResult, simulate


class SensorObserver:
    """What the autopilot flies on in sensor mode, tick by tick, for ``simulate``: the plant's sensor datagram
    (:func:`sitl.tick.encode_tick`, as the plant process sends it), decoded (:func:`quadsitl.hil.decode_sensors`)
    and estimated (:class:`autopilot.estimator.Estimator`) as the autopilot process does, with the same compiled
    functions. ``home``: the local origin, the plant's and the autopilot's."""

    def __init__(self, plant: Plant, preset: Preset, home: tuple[float, float, float] = PX4_HOME) -> None:
        s = preset.sensors
        self.plant, self.home = plant, home
        self.estimator = Estimator.for_field(plant.period, preset.vehicle.gravity, s.mag_strength_gauss,
                                             s.mag_declination_deg, s.mag_inclination_deg)  # fmt: skip
        self.io = np.zeros(plant_tick.IO_SIZE, dtype=np.int64)
        self.io[plant_tick.SENSING] = 1
        self.datagram = np.zeros(hil.DATAGRAM_MAX, dtype=np.uint8)
        self.truth = np.zeros(codec.DECODED_SIZE)
        self.frame = np.zeros(codec.FRAME_MAX, dtype=np.uint8)

    def __call__(self, k: int) -> VehicleState:
        """The estimate at tick ``k`` (since the plant started) from the plant's state now."""
        p, est = self.plant, self.estimator
        plant_tick.encode_tick(self.datagram, self.io, p.x, p.out, p.air, p.sensors.arrays, k, p.period)
        _, flags, _ = hil.decode_sensors(self.datagram, int(self.io[plant_tick.TX_LEN]), self.home, est.z, self.truth,
                                         self.frame)  # fmt: skip
        est.tick(flags)
        return est.state


def ground_ticks(preset: Preset) -> int:
    """The ticks a flight on sensors spends on the ground first, motors off: ``quadsitl fly``'s plant holds its
    clock at SENSOR_GROUND_S until the vehicle arms, and that tick is answered disarmed; the flight's first tick
    is the one after."""
    return round(SENSOR_GROUND_S / preset.sim.period) + 1 if preset.sensors is not None else 0


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
        observe = SensorObserver(plant, preset) if preset.sensors is not None else None
        res = simulate(plant, controller, preset.reference, duration, alloc, progress=done, observe=observe,
                       ground_ticks=ground_ticks(preset))  # fmt: skip
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
        if res.estimate is None:
            rows = rows_from_arrays(res.t, res.state, res.body_rates(), res.reference, res.inputs, res.forces)
        else:  # sensor mode: the estimate flown in x..r, the truth after (telemetry_csv.TRUTH_COLUMNS)
            rows = rows_from_arrays(res.t, res.estimate, res.body_rates(res.estimate), res.reference, res.inputs,
                                    res.forces)  # fmt: skip
            rows = np.column_stack([rows, res.state[:, :9], res.body_rates()])
        write_csv(path, rows)
        files.append(path)
    mpath = out / "metrics.json"
    first = next(iter(results.values()))
    diverged = {"diverged": first.diverged_at is not None, "diverged_at": first.diverged_at}
    if len(results) > 1:
        diverged["diverged_at_by_controller"] = {k: r.diverged_at for k, r in results.items()}
    report = {"preset": preset.name, **settings, **diverged, "runs": metrics}
    if first.estimate is not None:  # as fly's: the sensors flown and the estimate's RMS error
        names = ("x", "y", "altitude", "roll", "pitch", "yaw")

        def columns(s: np.ndarray) -> dict[str, np.ndarray]:
            return dict(zip(names, (s[:, 0], s[:, 1], -s[:, 2], s[:, 6], s[:, 7], s[:, 8])))

        report.update(state="sensors", sensors=asdict(preset.sensors),
                      estimate_rms=estimate_rms(columns(first.estimate), columns(first.state)))  # fmt: skip
    mpath.write_text(json.dumps(report, indent=2) + "\n")
    files.append(mpath)
    runs = {
        k: {"t": r.t, "outputs": channel_outputs(r.state), "reference": r.reference, "inputs": r.inputs}
        for k, r in results.items()
        if len(r.t)
    }
    if figures and runs:
        files += write_figures(runs, out, f"preset {preset.name}")
    return files
