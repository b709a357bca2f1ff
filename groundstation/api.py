"""quadsitl in Python, for notebooks and scripts (docs/python.md): ``quadsitl.sim``, ``quadsitl.sweep`` and a vehicle
to step (``quadsitl.Vehicle``). ``import quadsitl`` loads none of this until one is used.

``sim`` and ``sweep`` are the commands: the same options (keyword arguments named as the command's options, ``-``
as ``_``), the same checks with the same one-line refusals (a :class:`ValueError`), the same flights, and their
outputs read back as pandas DataFrames: what ``telemetry.csv`` and ``trials.parquet`` hold, nothing converted.
"""

from __future__ import annotations

import contextlib
import io
import json
import math
import tempfile
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from quadsitl.state import VehicleState


@dataclass
class Flight:
    """A ``quadsitl sim`` run: ``telemetry`` (telemetry.csv: one row per control tick, its columns and units), the
    other controllers' with ``compare`` (``runs``, by name, the first included), and ``metrics`` (metrics.json)."""

    telemetry: pd.DataFrame
    runs: dict[str, pd.DataFrame]
    metrics: dict


def _argv(command: str, positional: list[str], options: dict[str, object]) -> list[str]:
    """The command line of ``options`` (None: not given; True: a flag; a tuple: comma-separated)."""
    argv = [command, *positional]
    for name, value in options.items():
        if value is None or value is False:
            continue
        flag = "--" + name.replace("_", "-")
        if value is True:
            argv.append(flag)
        elif isinstance(value, dict):  # repeated NAME=VALUE options
            argv += [f"{flag}={k}={v!r}" for k, v in value.items()]
        elif isinstance(value, (tuple, list)):
            argv.append(f"{flag}={','.join(repr(v) if isinstance(v, float) else str(v) for v in value)}")
        else:
            argv.append(f"{flag}={value}")
    return argv


def _run(argv: list[str]) -> None:
    """Run a quadsitl command in this process, quietly and without its signal handlers (a notebook keeps its own);
    its refusal (one line) as a ValueError."""
    from groundstation.cli import build_parser
    from quadsitl.cli_util import UsageError, attach_negative_values

    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        try:
            args = build_parser().parse_args(attach_negative_values(argv, ("--gains", "--poles")))
            status = args.func(args)
        except SystemExit as exc:  # argparse's refusals: its message is on stderr
            status = exc.code if isinstance(exc.code, int) else 2
        except UsageError as exc:
            raise ValueError(f"quadsitl {argv[0]}: {exc}") from None
    message = err.getvalue().strip().splitlines()
    if status in (1, 3):  # the flight failed (a mission unfinished, a controller's failsafe) or diverged: it is kept
        warnings.warn(" ".join(message) or f"quadsitl {argv[0]}: exit status {status}", RuntimeWarning, stacklevel=3)
    elif status != 0:
        raise ValueError(message[-1] if message else f"quadsitl {argv[0]}: exit status {status}")


def sim(preset: str = "paper", controller: str | None = None, *, trajectory: str | None = None,
        mission: str | None = None, home: tuple[float, float, float] | None = None, duration: float | None = None,
        compare: bool = False, state: str | None = None, sensor_seed: int | None = None,
        wind: tuple[float, float] | None = None, turbulence: str | None = None, gust: tuple[float, ...] | None = None,
        wind_seed: int | None = None, integrator: str | None = None, substeps: int | None = None,
        gains: tuple[float, ...] | None = None, poles: tuple[float, ...] | None = None,
        controller_params: dict[str, float] | None = None) -> Flight:  # fmt: skip
    """``quadsitl sim``: fly ``preset`` (a shipped name or a TOML file) with ``controller`` (default: the preset's;
    backstepping, pd, px4, or yours: ``path/to/file.py:Name``; ``controller_params`` its parameters by name) on
    ``trajectory`` or ``mission``; the options are the command's (docs/commands.md). Raises ValueError with the
    command's one-line refusal."""
    options = dict(preset=preset, controller=controller, trajectory=trajectory, mission=mission, home=home,
                   duration=duration, compare=compare, state=state, sensor_seed=sensor_seed, wind=wind,
                   turbulence=turbulence, gust=gust, wind_seed=wind_seed, integrator=integrator, substeps=substeps,
                   gains=gains, poles=poles, controller_param=controller_params)  # fmt: skip
    with tempfile.TemporaryDirectory(prefix="quadsitl-sim-") as tmp:
        _run(_argv("sim", [], {**options, "out": tmp, "no_figures": True, "quiet": True}))
        out = Path(tmp)
        metrics = json.loads((out / "metrics.json").read_text(encoding="utf-8"))
        names = list(metrics.get("runs") or metrics.get("position") or [controller or "run"])
        runs = {}
        for i, name in enumerate(names):
            path = out / ("telemetry.csv" if i == 0 else f"telemetry_{name}.csv")
            if path.is_file():
                runs[name] = pd.read_csv(path)
    return Flight(next(iter(runs.values())), runs, metrics)


def sweep(spec: str, *, controller: str | None = None, trials: int | None = None, workers: int | None = None,
          engine: str | None = None, keep: int | None = None) -> pd.DataFrame:  # fmt: skip
    """``quadsitl sweep``: the trials of ``spec`` (a shipped spec's name or a TOML file), one row each (trials.parquet:
    the drawn parameters and the metrics, docs/sweeps.md), flown with ``controller`` instead of the spec's when given.
    Raises ValueError with the command's one-line refusal."""
    with tempfile.TemporaryDirectory(prefix="quadsitl-sweep-") as tmp:
        _run(_argv("sweep", [spec], dict(controller=controller, trials=trials, workers=workers, engine=engine,
                                         keep=keep, out=tmp, no_figures=True, quiet=True)))  # fmt: skip
        return pd.read_parquet(Path(tmp) / "trials.parquet")


class Vehicle:
    """The plant of a preset to step yourself, one control period at a time, for control and learning loops: the
    command is (thrust [N] along the body's −z axis, torques [N·m] about the body's x, y, z axes, FRD), allocated to
    the four motors as the autopilot allocates its controllers' (within the motors' limits), then the plant steps
    (dynamics, motor lag, ground, wind). The state is the paper's 12 (VehicleState order: NED position [m] and
    velocity [m/s], roll, pitch, yaw [rad], their rates [rad/s])."""

    def __init__(self, preset: str = "x500") -> None:
        from quadsitl.config import load_preset

        self.preset = load_preset(preset)
        self.reset()

    def reset(self) -> np.ndarray:
        """Back to the preset's initial state, at t = 0: the state."""
        from sitl.plant import Plant

        self.plant = Plant(self.preset)
        return self.plant.x.copy()

    @property
    def t(self) -> float:
        """The time [s]."""
        return self.plant.time

    @property
    def state(self) -> VehicleState:
        return self.plant.state

    @property
    def forces(self) -> tuple[float, float, float, float]:
        """The motor forces [N] of the last step."""
        return self.plant.forces

    def step(self, command: tuple[float, float, float, float]) -> np.ndarray:
        """One control period under ``command`` = (thrust [N], roll, pitch, yaw torques [N·m]): the new state. A
        command that is not four finite numbers is refused (ValueError), never flown."""
        from quadsitl.mixer import allocate

        u = tuple(float(c) for c in command)
        if len(u) != 4 or not all(map(math.isfinite, u)):
            raise ValueError(f"command {tuple(command)!r}: expected 4 finite numbers (thrust [N], torques [N·m])")
        v, a = self.preset.vehicle, self.preset.actuators
        arm = v.arm_length
        forces = allocate((u[0], u[1] / arm, u[2] / arm, u[3]), v.d_over_b, a.min_thrust, a.max_thrust)
        self.plant.step(forces)
        return self.plant.x.copy()
