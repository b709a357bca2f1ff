"""A trial's row of the sweep's table from its telemetry (one row per tick flown, :data:`groundstation.
telemetry_csv.COLUMNS`, the truth's columns after them in sensor mode): the metrics' one definition
(:func:`groundstation.metrics.run_metrics`, :func:`~groundstation.metrics.saturation_time`,
:func:`~groundstation.metrics.position_metrics`) for every trial not flown by the fused loop of the batch engine,
whichever runtime flew it: ``quadsitl sim``'s loop (the batch engine's trials with a trajectory, a mission, sensors
or wind) or a whole ``quadsitl fly`` (the SITL engine). Pure.

- What the vehicle did is the truth: in sensor mode the truth's columns, not the estimate the autopilot flew on.
- A mission's flight starts at its first thrust: ``quadsitl fly``'s mission starts some ticks after arming (its
  ground station's start command goes in wall time), ``quadsitl sim``'s at once.
- A position trajectory or a mission: the step response's metrics (rise and settling time, overshoot, steady-state
  error, RMS error) are not defined (NaN), the position tracking is; the task's attitude reference: the other way
  round.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np

from groundstation.metrics import battery_use, outputs_from_columns, position_metrics, run_metrics, saturation_time
from groundstation.sweep import engine
from groundstation.telemetry_csv import columns_of
from quadsitl.config import Preset


def flight_rows(table: Mapping[str, np.ndarray], mission: bool) -> Mapping[str, np.ndarray]:
    """The rows the metrics are taken over ({column: values}): a mission's from its first thrust on."""
    if mission and len(table["t"]):
        thrust = np.flatnonzero(table["u1"] > 0.0)
        first = thrust[0] if thrust.size else len(table["t"])
        return {name: values[first:] for name, values in table.items()}
    return table


def metrics_row(rows: np.ndarray | Mapping[str, np.ndarray], preset: Preset, period: float,
                diverged_at: float | None, mission: bool = False) -> np.ndarray:  # fmt: skip
    """The trial's metrics (engine.METRICS columns) from its telemetry: ``rows`` in telemetry.csv's columns, or
    {column: values} (:func:`groundstation.offline.telemetry_columns`); ``diverged_at`` [s]: the time of the tick
    whose state left the bounds (None: it did not). ``mission``: the flight is a mission's."""
    table = flight_rows(columns_of(rows) if isinstance(rows, np.ndarray) else rows, mission)
    n = len(table["t"])
    m = np.full(engine.METRICS_SIZE, math.nan)
    c, a = preset.controller, preset.actuators
    inputs = np.column_stack([table[f"u{i}"] for i in range(1, 5)])
    forces = np.column_stack([table[f"f{i}"] for i in range(1, 5)])
    m[engine.M_SATURATED] = saturation_time(inputs, forces, period, (c.thrust_min, c.thrust_max),
                                            (a.min_thrust, a.max_thrust))  # fmt: skip
    for j in range(len(engine.CHANNELS)):
        m[engine.PER_CHANNEL * j + engine.PEAK_U] = np.max(np.abs(inputs[:, j])) if n else 0.0
    m[engine.M_YAW_TURNS] = 0.0
    m[engine.M_TICKS] = n
    if (used := battery_use(table)) is not None:
        m[engine.M_ENERGY] = used["energy_j"]
    if diverged_at is not None:
        m[engine.M_DIVERGED], m[engine.M_DIVERGED_AT] = 1.0, diverged_at
        return m
    m[engine.M_DIVERGED] = 0.0
    truth = "z_true" in table  # sensor mode: x..r are the estimate, the truth follows

    def col(name: str) -> np.ndarray:
        if name == "altitude":
            return -table["z_true"] if truth else table["altitude"]
        return table.get(f"{name}_true", table[name]) if truth else table[name]

    tracked = position_metrics(col("x"), col("y"), table["x_ref"], table["y_ref"], col("altitude"),
                               table["altitude_ref"])  # fmt: skip
    if tracked["samples"]:
        for index, name in zip((engine.M_HORIZONTAL_RMS, engine.M_HORIZONTAL_MAX, engine.M_ALTITUDE_RMS),
                               engine.POSITION_METRICS):  # fmt: skip
            m[index] = tracked[name]
        return m
    y = outputs_from_columns(col("altitude"), col("roll"), col("pitch"), col("yaw"))
    ref = np.column_stack([table[f"{ch}_ref"] for ch in engine.CHANNELS])
    metrics = run_metrics(table["t"], y, ref, inputs)
    for j, ch in enumerate(engine.CHANNELS):
        for q, name in enumerate(engine.STEP_METRICS):
            value = metrics[ch][name]
            m[engine.PER_CHANNEL * j + q] = math.nan if value is None else value
    return m
