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

import numpy as np

from groundstation.metrics import outputs_from_columns, position_metrics, run_metrics, saturation_time
from groundstation.sweep import engine
from groundstation.telemetry_csv import COLUMNS, TRUTH_COLUMNS
from quadsitl.config import Preset

COL = {name: i for i, name in enumerate(COLUMNS)}
TRUTH = {name: len(COLUMNS) + i for i, name in enumerate(TRUTH_COLUMNS)}


def flight_rows(rows: np.ndarray, mission: bool) -> np.ndarray:
    """The rows the metrics are taken over: a mission's from its first thrust on."""
    if mission and len(rows):
        thrust = np.flatnonzero(rows[:, COL["u1"]] > 0.0)
        return rows[thrust[0] :] if thrust.size else rows[:0]
    return rows


def metrics_row(rows: np.ndarray, preset: Preset, period: float, diverged_at: float | None,
                mission: bool = False) -> np.ndarray:  # fmt: skip
    """The trial's metrics (engine.METRICS columns) from its telemetry ``rows``; ``diverged_at`` [s]: the time of
    the tick whose state left the bounds (None: it did not). ``mission``: the flight is a mission's."""
    rows = flight_rows(rows, mission)
    m = np.full(engine.METRICS_SIZE, math.nan)
    c, a = preset.controller, preset.actuators
    inputs = rows[:, COL["u1"] : COL["u4"] + 1]
    forces = rows[:, COL["f1"] : COL["f4"] + 1]
    m[engine.M_SATURATED] = saturation_time(inputs, forces, period, (c.thrust_min, c.thrust_max),
                                            (a.min_thrust, a.max_thrust))  # fmt: skip
    for j in range(len(engine.CHANNELS)):
        m[engine.PER_CHANNEL * j + engine.PEAK_U] = np.max(np.abs(inputs[:, j])) if len(rows) else 0.0
    m[engine.M_YAW_TURNS] = 0.0
    m[engine.M_TICKS] = len(rows)
    if diverged_at is not None:
        m[engine.M_DIVERGED], m[engine.M_DIVERGED_AT] = 1.0, diverged_at
        return m
    m[engine.M_DIVERGED] = 0.0
    truth = rows.shape[1] > len(COLUMNS)  # sensor mode: x..r are the estimate, the truth follows

    def col(name: str) -> np.ndarray:
        if name == "altitude":
            return -rows[:, TRUTH["z_true"]] if truth else rows[:, COL["altitude"]]
        return rows[:, TRUTH[f"{name}_true"]] if truth and f"{name}_true" in TRUTH else rows[:, COL[name]]

    x_ref, y_ref = rows[:, COL["x_ref"]], rows[:, COL["y_ref"]]
    tracked = position_metrics(col("x"), col("y"), x_ref, y_ref, col("altitude"), rows[:, COL["altitude_ref"]])
    if tracked["samples"]:
        for index, name in zip((engine.M_HORIZONTAL_RMS, engine.M_HORIZONTAL_MAX, engine.M_ALTITUDE_RMS),
                               engine.POSITION_METRICS):  # fmt: skip
            m[index] = tracked[name]
        return m
    t = rows[:, COL["t"]]
    y = outputs_from_columns(col("altitude"), col("roll"), col("pitch"), col("yaw"))
    ref = rows[:, COL["altitude_ref"] : COL["yaw_ref"] + 1]
    metrics = run_metrics(t, y, ref, inputs)
    for j, ch in enumerate(engine.CHANNELS):
        for q, name in enumerate(engine.STEP_METRICS):
            value = metrics[ch][name]
            m[engine.PER_CHANNEL * j + q] = math.nan if value is None else value
    return m
