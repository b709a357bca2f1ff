"""Reference trajectories: functions of flight time t [s] → Reference (altitude [m], roll, pitch, yaw [rad]).

- ``step``: the paper's experiment, the preset's reference from t = 0.
- ``ramp``: from the ground and level to the preset's reference over ``ramp_time`` seconds.
- ``sine``: the preset's reference plus a sinusoid of 20 % of each channel's step, period 2 s.
- a CSV file with a header ``t, altitude, roll, pitch, yaw`` (SI, radians), linearly interpolated and
  held after its last row.
"""

from __future__ import annotations

import csv
import math
from collections.abc import Callable
from pathlib import Path

import numpy as np

from quadsitl.cli_util import UsageError
from quadsitl.state import Reference

Trajectory = Callable[[float], Reference]
COLUMNS = ("t", "altitude", "roll", "pitch", "yaw")


def step(ref: Reference) -> Trajectory:
    return lambda _t: ref


def ramp(ref: Reference, ramp_time: float = 2.0) -> Trajectory:
    def f(t: float) -> Reference:
        a = min(max(t / ramp_time, 0.0), 1.0)
        return Reference(*(a * v for v in ref))

    return f


def sine(ref: Reference, period: float = 2.0, fraction: float = 0.2) -> Trajectory:
    def f(t: float) -> Reference:
        s = fraction * math.sin(2.0 * math.pi * t / period)
        return Reference(*(v * (1.0 + s) for v in ref))

    return f


def from_csv(path: Path) -> Trajectory:
    """Load a CSV trajectory; refuses a missing column, a non-number, or non-increasing times."""
    with open(path, newline="", encoding="utf-8") as fh:
        reader = csv.DictReader(fh)
        header = [h.strip() for h in (reader.fieldnames or [])]
        missing = [c for c in COLUMNS if c not in header]
        if missing:
            raise UsageError(
                f"trajectory {path}: missing column(s) {', '.join(missing)}; expected {', '.join(COLUMNS)}"
            )
        rows = []
        for n, row in enumerate(reader, start=2):
            row = {k.strip(): v for k, v in row.items() if k}
            try:
                values = [float(row[c]) for c in COLUMNS]
            except (TypeError, ValueError):
                raise UsageError(f"trajectory {path}, line {n}: expected numbers in {', '.join(COLUMNS)}") from None
            if not all(math.isfinite(v) for v in values):
                raise UsageError(f"trajectory {path}, line {n}: values must be finite")
            if abs(values[2]) >= math.pi / 2 or abs(values[3]) >= math.pi / 2 or values[1] < 0:
                raise UsageError(f"trajectory {path}, line {n}: altitude must be >= 0 and |roll|, |pitch| < π/2")
            rows.append(values)
    if not rows:
        raise UsageError(f"trajectory {path}: no rows")
    data = np.array(rows)
    if np.any(np.diff(data[:, 0]) <= 0):
        raise UsageError(f"trajectory {path}: t must increase from row to row")
    t = data[:, 0]

    def f(time: float) -> Reference:
        return Reference(*(float(np.interp(time, t, data[:, i])) for i in range(1, 5)))

    return f


def make(name: str, ref: Reference) -> Trajectory:
    if name == "step":
        return step(ref)
    if name == "ramp":
        return ramp(ref)
    if name == "sine":
        return sine(ref)
    path = Path(name)
    if not path.is_file():
        raise UsageError(f"--trajectory {name!r}: expected step, ramp, sine or an existing CSV file")
    return from_csv(path)
