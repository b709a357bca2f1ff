"""The telemetry CSV: one row per control tick, the same columns for ``sim`` and ``fly``.

Columns: t [s]; x, y, z [m, NED]; altitude [m] (= −z); vx, vy, vz [m/s, NED]; roll, pitch, yaw [rad];
p, q, r [rad/s, body FRD]; altitude_ref [m]; roll_ref, pitch_ref, yaw_ref [rad]; x_ref, y_ref [m, NED]
(the horizontal position reference, NaN — written ``nan`` — while the horizontal position is not
controlled: attitude setpoints, ``quadsitl sim``); u1 [N], u2, u3 [N], u4 [N·m]; f1..f4 commanded motor
forces [N].

In sensor mode (``--state sensors``) x..r are the autopilot's estimate, what its controllers flew on, and the
plant's ground truth follows in :data:`TRUTH_COLUMNS` (x_true .. r_true, the same quantities and units), then what
the estimator took and how it was, :data:`SENSOR_COLUMNS` (the telemetry's sensors record: accel_x .. baro_alt,
estimator_flags .. pos_vert_accuracy, :mod:`quadsitl.telemetry`). A vehicle
with a battery has :data:`BATTERY_COLUMNS` last: what the autopilot knows of it (docs/battery.md), battery_v [V],
battery_a [A], battery_mah and battery_j (the charge and energy drawn [mAh, J]), battery_remaining (0..1).
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

from quadsitl import telemetry

COLUMNS = (
    "t", "x", "y", "z", "altitude", "vx", "vy", "vz", "roll", "pitch", "yaw", "p", "q", "r",
    "altitude_ref", "roll_ref", "pitch_ref", "yaw_ref", "x_ref", "y_ref", "u1", "u2", "u3", "u4",
    "f1", "f2", "f3", "f4",
)  # fmt: skip


TRUTH_COLUMNS = tuple(f"{c}_true" for c in ("x", "y", "z", "vx", "vy", "vz", "roll", "pitch", "yaw", "p", "q", "r"))
SENSOR_COLUMNS = telemetry.SENSORS_FIELDS[2:]  # the sensors record's fields, by their names
SENSING_COLUMNS = TRUTH_COLUMNS + SENSOR_COLUMNS  # sensor mode's
BATTERY_COLUMNS = telemetry.BATTERY_FIELDS  # the status record's battery fields, by their names


def names_of(width: int) -> tuple[str, ...]:
    """The columns of telemetry rows ``width`` wide: :data:`COLUMNS`, then :data:`SENSING_COLUMNS` (sensor mode) and
    :data:`BATTERY_COLUMNS` (a battery) where the width has room for them."""
    extra = width - len(COLUMNS)
    sensing = extra in (len(SENSING_COLUMNS), len(SENSING_COLUMNS) + len(BATTERY_COLUMNS))
    battery = extra in (len(BATTERY_COLUMNS), len(SENSING_COLUMNS) + len(BATTERY_COLUMNS))
    names = COLUMNS + (SENSING_COLUMNS if sensing else ()) + (BATTERY_COLUMNS if battery else ())
    if len(names) != width:
        raise ValueError(f"telemetry rows of {width} columns: expected {len(COLUMNS)}, sensor mode's "
                         f"{len(SENSING_COLUMNS)} and the battery's {len(BATTERY_COLUMNS)} after, or not")  # fmt: skip
    return names


def columns_from_arrays(
    t: np.ndarray,
    state: np.ndarray,
    body_rates: np.ndarray,
    reference: np.ndarray,
    inputs: np.ndarray,
    forces: np.ndarray,
    position_reference: np.ndarray | None = None,
) -> dict[str, np.ndarray]:
    """{column: values} for :data:`COLUMNS` (views of the arrays where they can be). ``reference``: (N, 4)
    altitude, roll, pitch, yaw references; ``position_reference``: (N, 2) x_ref, y_ref [m, NED], or None: not
    controlled (NaN)."""
    xy_ref = np.full((len(t), 2), np.nan) if position_reference is None else position_reference
    parts = [t, state[:, 0], state[:, 1], state[:, 2], -state[:, 2], *(state[:, i] for i in range(3, 9)),
             *body_rates.T, *reference.T, *xy_ref.T, *inputs.T, *forces.T]  # fmt: skip
    return dict(zip(COLUMNS, parts, strict=True))


def rows_from_arrays(*arrays: np.ndarray | None) -> np.ndarray:
    """(N, len(COLUMNS)) array in column order, from :func:`columns_from_arrays`' arguments."""
    return stacked(columns_from_arrays(*arrays))


def stacked(columns: dict[str, np.ndarray]) -> np.ndarray:
    """{column: values}, in the columns' order, as rows (:func:`columns_of`'s inverse)."""
    return np.column_stack(list(columns.values()))


def columns_of(rows: np.ndarray) -> dict[str, np.ndarray]:
    """{column: values} of telemetry rows (:func:`names_of` their width)."""
    names = names_of(rows.shape[1]) if rows.ndim == 2 else COLUMNS
    return {name: rows[:, i] for i, name in enumerate(names)}


def write_csv(path: Path, rows: np.ndarray) -> None:
    """Write rows (:func:`names_of` their width, in that order) with a header line."""
    columns = names_of(rows.shape[1]) if rows.ndim == 2 else COLUMNS
    np.savetxt(path, rows, delimiter=",", header=",".join(columns), comments="", fmt="%.12g")


def read_csv(path: Path) -> dict[str, np.ndarray]:
    """Read a telemetry CSV (as :func:`write_csv` writes it: a header line, then a row of numbers per tick) into
    {column: array}. ``np.loadtxt``: several times faster than ``np.genfromtxt`` (docs/performance.md#a-flights-files),
    and a fleet's report reads each vehicle's twice."""
    with open(path) as f:
        names = f.readline().strip().split(",")
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)  # a header alone: "input contained no data"
            data = np.loadtxt(f, delimiter=",", ndmin=2)
    columns = np.ascontiguousarray(data.T) if data.size else np.zeros((len(names), 0))
    return dict(zip(names, columns, strict=True))
