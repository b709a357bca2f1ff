"""Reference trajectories, functions of flight time t [s] (t = 0 at the switch to offboard).

Attitude trajectories → :class:`~quadsitl.state.Reference` (altitude [m], roll, pitch, yaw [rad]), flown as
SET_ATTITUDE_TARGET + a z-only SET_POSITION_TARGET_LOCAL_NED (the paper's experiment):

- ``step``: the paper's experiment, the preset's reference from t = 0.
- ``ramp``: from the ground and level to the preset's reference over ``ramp_time`` seconds.
- ``sine``: the preset's reference plus a sinusoid of 20 % of each channel's step, period 2 s.
- a CSV file with a header ``t, altitude, roll, pitch, yaw`` (SI, radians), linearly interpolated and
  held after its last row.

Position trajectories → :class:`PositionSetpoint` (x north, y east [m] in local NED, altitude up [m], yaw
[rad], and the velocity feed-forward: the trajectory's derivative), flown as SET_POSITION_TARGET_LOCAL_NED
in MAV_FRAME_LOCAL_NED with type_mask 2496 (position, velocity and yaw; z = −altitude). Each starts with a
``hold`` at its start point (climb from the ground and settle there), then moves:

- ``circle[:radius=M][,period=S][,altitude=M][,hold=S][,yaw=RAD|travel]``: a circle through home, flown
  clockwise seen from above (north, then east), centre ``radius`` east of home. Defaults: radius 5 m,
  period 20 s, altitude the preset's reference altitude, hold 5 s, yaw ``travel``.
- ``figure8[:size=M][,period=S][,altitude=M][,hold=S][,yaw=RAD|travel]``: the lemniscate of Gerono through
  home, x = size·sin θ, y = (size/2)·sin 2θ (10 m north–south and 5 m east–west at the default size 5 m),
  first to the north-east. Same defaults as the circle.
- ``hold[:altitude=M][,duration=S][,yaw=RAD]``: climb to ``altitude`` above home (default: the preset's reference
  altitude) and hold there, heading ``yaw`` (default 0), for ``duration`` (default 20 s).
- a CSV file with a header ``t, x, y, altitude, yaw``: linearly interpolated, held after its last row (and
  at its first row before it); the velocity feed-forward is each segment's slope.

A shape's angle θ starts at rest: its rate grows linearly from 0 to 2π/period over the first quarter period
(:func:`spin_up`), so the velocity reference is continuous, and one lap takes ``period`` after that.
``yaw=travel`` points the nose along the path (its tangent, also defined while the vehicle is at rest); a
number fixes the heading [rad]. Yaw goes out wrapped to [−π, π]. No position trajectory asks for more than
``MAX_HORIZONTAL_SPEED`` (PX4's MPC_XY_VEL_MAX default) or more than PX4's default vertical speed limits.
"""

from __future__ import annotations

import csv
import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

import numpy as np

from quadsitl.cli_util import UsageError
from quadsitl.config import PositionParams
from quadsitl.state import Reference

Trajectory = Callable[[float], Reference]
COLUMNS = ("t", "altitude", "roll", "pitch", "yaw")  # an attitude CSV's header
POSITION_COLUMNS = ("t", "x", "y", "altitude", "yaw")  # a position CSV's header
MAX_HORIZONTAL_SPEED = PositionParams.xy_vel_max  # [m/s] PX4's MPC_XY_VEL_MAX default, the preset key's
MAX_CLIMB, MAX_DESCENT = PositionParams.z_vel_max_up, PositionParams.z_vel_max_dn  # [m/s] MPC_Z_VEL_MAX_UP, _DN's


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
    """An attitude CSV (header ``t, altitude, roll, pitch, yaw``: t [s] increasing, altitude [m] ≥ 0, angles
    [rad], |roll|, |pitch| < π/2) → its trajectory, linearly interpolated and held after its last row. Refused,
    with the file, line and column named: a missing column or value, a non-number, a value not finite or out
    of range, t not increasing."""
    half_pi = math.pi / 2
    data, _lines = _read_table(path, COLUMNS, {
        "altitude": (lambda v: v >= 0, "a number ≥ 0 [m]"),
        "roll": (lambda v: abs(v) < half_pi, "|roll| < π/2 [rad]"),
        "pitch": (lambda v: abs(v) < half_pi, "|pitch| < π/2 [rad]"),
    })  # fmt: skip
    t = data[:, 0]

    def f(time: float) -> Reference:
        return Reference(*(float(np.interp(time, t, data[:, i])) for i in range(1, 5)))

    return f


Bounds = dict[str, tuple[Callable[[float], bool], str]]  # column → (value allowed?, what is allowed)


def _read_table(path: Path, columns: tuple[str, ...], bounds: Bounds) -> tuple[np.ndarray, list[int]]:
    """A trajectory CSV's rows (values in ``columns`` order; other columns ignored, blank lines skipped) and
    their line numbers. Every value must be a finite number within ``bounds``, and t must increase; else a
    UsageError naming the file, the line and the column."""
    rows, lines = [], []
    with open(path, newline="", encoding="utf-8") as fh:
        reader = csv.reader(fh)
        header = [h.strip() for h in next(reader, [])]
        missing = [c for c in columns if c not in header]
        if missing:
            raise UsageError(
                f"trajectory {path}: missing column(s) {', '.join(missing)}; expected {', '.join(columns)}"
            )
        index = [header.index(c) for c in columns]
        for row in reader:
            if not any(cell.strip() for cell in row):
                continue
            n = reader.line_num
            values = []
            for c, i in zip(columns, index):
                text = row[i].strip() if i < len(row) else ""
                where = f"trajectory {path}, line {n}, column {c}"
                if not text:
                    raise UsageError(f"{where}: no value; expected a number")
                try:
                    v = float(text)
                except ValueError:
                    raise UsageError(f"{where}: {text!r} is not a number") from None
                if not math.isfinite(v):
                    raise UsageError(f"{where}: {text!r}; expected a finite number")
                allowed, what = bounds.get(c, (None, ""))
                if allowed is not None and not allowed(v):
                    raise UsageError(f"{where}: {text}; expected {what}")
                if c == "t" and rows and v <= rows[-1][0]:
                    raise UsageError(f"{where}: {text} is not after the previous row's {rows[-1][0]:g}; t must "
                                     "increase from row to row")  # fmt: skip
                values.append(v)
            rows.append(values)
            lines.append(n)
    if not rows:
        raise UsageError(f"trajectory {path}: no rows after the header {', '.join(columns)}")
    return np.array(rows), lines


# ---- position trajectories ------------------------------------------------------------------------------


class PositionSetpoint(NamedTuple):
    """One offboard position setpoint: x north, y east [m] (local NED, home at the origin), altitude [m, up]
    (z = −altitude), yaw [rad]; the velocity feed-forward vx north, vy east [m/s] and climb [m/s, up]
    (vz = −climb)."""

    x: float
    y: float
    altitude: float
    yaw: float
    vx: float = 0.0
    vy: float = 0.0
    climb: float = 0.0


@dataclass(frozen=True)
class PositionTrajectory:
    """A trajectory flown as offboard position setpoints: ``setpoint(t)`` for flight time t [s]."""

    setpoint: Callable[[float], PositionSetpoint]
    duration: float  # [s] its natural length: hold, spin-up and one lap; a CSV: its last row's t
    description: str  # for messages and metrics.json

    def __call__(self, t: float) -> PositionSetpoint:
        return self.setpoint(t)


def spin_up(tau: float, period: float) -> tuple[float, float]:
    """A shape's angle θ [rad] and its rate θ̇ [rad/s] at τ [s] after its hold: at rest for τ ≤ 0, the
    rate growing linearly to ω = 2π/period over the first period/4 (θ = ω·τ²/(2·S), S = period/4), then
    constant (θ = ω·(τ − S/2))."""
    omega, ramp = 2.0 * math.pi / period, period / 4.0
    if tau <= 0.0:
        return 0.0, 0.0
    if tau < ramp:
        return omega * tau * tau / (2.0 * ramp), omega * tau / ramp
    return omega * (tau - ramp / 2.0), omega


def shape_duration(period: float, hold: float) -> float:
    """[s] from t = 0 to the end of the first lap: the hold, the spin-up (θ lags ω·τ by ω·S/2), one lap."""
    return hold + period + period / 8.0


def circle(
    t: float, radius: float = 5.0, period: float = 20.0, altitude: float = 5.0, hold: float = 5.0,
    yaw: float | None = None,
) -> PositionSetpoint:  # fmt: skip
    """The circle through home at flight time t [s]: centre (0, radius) [m, NED], p = (R·sin θ, R·(1 − cos θ)),
    clockwise seen from above, θ from :func:`spin_up` after ``hold`` seconds at home. ``yaw`` [rad], or
    None: along the path (ψ = θ, the tangent's heading)."""
    theta, rate = spin_up(t - hold, period)
    s, c = math.sin(theta), math.cos(theta)
    heading = _wrap(theta) if yaw is None else yaw
    return PositionSetpoint(radius * s, radius * (1.0 - c), altitude, heading, radius * c * rate, radius * s * rate)


def figure8(
    t: float, size: float = 5.0, period: float = 20.0, altitude: float = 5.0, hold: float = 5.0,
    yaw: float | None = None,
) -> PositionSetpoint:  # fmt: skip
    """The figure eight (lemniscate of Gerono) through home at flight time t [s]: p = (a·sin θ, a·sin θ·cos θ)
    [m, NED] with a = ``size``, θ from :func:`spin_up` after ``hold`` seconds at home. ``yaw`` [rad], or
    None: along the path (the heading of dp/dθ = (cos θ, cos 2θ), defined everywhere)."""
    theta, rate = spin_up(t - hold, period)
    s, c, c2 = math.sin(theta), math.cos(theta), math.cos(2.0 * theta)
    heading = math.atan2(c2, c) if yaw is None else yaw
    return PositionSetpoint(size * s, 0.5 * size * math.sin(2.0 * theta), altitude, heading, size * c * rate,
                            size * c2 * rate)  # fmt: skip


def _wrap(angle: float) -> float:
    """An angle [rad] in [−π, π]."""
    return math.remainder(angle, 2.0 * math.pi)


SHAPES: dict[str, tuple[Callable[..., PositionSetpoint], str]] = {"circle": (circle, "radius"),
                                                                  "figure8": (figure8, "size")}  # fmt: skip
# Each numeric shape parameter: default (None: the preset's reference altitude), allowed interval and unit.
# The interval is (lo, hi], or [lo, hi] where lo_closed.
_PARAMETERS: dict[str, tuple[float | None, float, float, bool, str]] = {
    "radius": (5.0, 0.0, 1000.0, False, "m"),
    "size": (5.0, 0.0, 1000.0, False, "m"),
    "period": (20.0, 1.0, 3600.0, False, "s"),
    "altitude": (None, 0.0, 10000.0, False, "m"),
    "hold": (5.0, 0.0, 3600.0, True, "s"),
}


def shape_usage(name: str) -> str:
    """The syntax of a shape's --trajectory value."""
    return f"{name}[:{SHAPES[name][1]}=M][,period=S][,altitude=M][,hold=S][,yaw=RAD|travel]"


def _check(spec: str, key: str, value: float, given: str) -> None:
    _default, lo, hi, lo_closed, unit = _PARAMETERS[key]
    if not ((lo <= value if lo_closed else lo < value) and value <= hi):
        bounds = f"{'[' if lo_closed else '('}{lo:g}, {hi:g}]"
        raise UsageError(f"--trajectory {spec!r}: {key} {given}: expected a number in {bounds} {unit}")


def parse_shape(spec: str, default_altitude: float) -> PositionTrajectory:
    """``circle`` or ``figure8`` with optional ``:key=value,...`` (syntax: :func:`shape_usage`; the module
    docstring) → its trajectory; ``default_altitude`` [m]: the preset's reference altitude. Raises
    UsageError naming --trajectory, the value and what is allowed."""
    name, _, rest = spec.partition(":")
    func, size_key = SHAPES[name]
    keys = (size_key, "period", "altitude", "hold")
    values = {k: _PARAMETERS[k][0] for k in keys}
    values["altitude"] = default_altitude
    yaw: float | None = None  # along the path
    usage = shape_usage(name)
    for item in (i.strip() for i in rest.split(",") if i.strip()):
        key, eq, text = (p.strip() for p in item.partition("="))
        if not eq or key not in (*keys, "yaw"):
            raise UsageError(f"--trajectory {spec!r}: unknown parameter {item!r}; expected {usage}")
        if key == "yaw" and text == "travel":
            yaw = None
            continue
        try:
            value = float(text)
        except ValueError:
            value = math.nan
        if not math.isfinite(value):
            what = "a number [rad] or travel" if key == "yaw" else "a number"
            raise UsageError(f"--trajectory {spec!r}: {key}={text!r} is not {what}; expected {usage}")
        if key == "yaw":
            yaw = value
        else:
            _check(spec, key, value, f"= {text}")
            values[key] = value
    _check(spec, "altitude", values["altitude"], f"{values['altitude']:g} (the preset's reference; give altitude=M)")
    size, period, altitude, hold = (float(values[k]) for k in keys)  # type: ignore[arg-type]
    # Peak speed: the circle's 2πR/P; the figure eight's √2·2πa/P, at home, where |dp/dθ| = a·√2.
    peak = 2.0 * math.pi * size / period * (1.0 if name == "circle" else math.sqrt(2.0))
    if peak > MAX_HORIZONTAL_SPEED:
        raise UsageError(
            f"--trajectory {spec!r}: a peak speed of {peak:.3g} m/s exceeds {MAX_HORIZONTAL_SPEED:g} m/s (PX4's "
            f"MPC_XY_VEL_MAX default); make period longer or {size_key} smaller"
        )

    def setpoint(t: float) -> PositionSetpoint:
        return func(t, size, period, altitude, hold, yaw)

    return PositionTrajectory(setpoint, shape_duration(period, hold), spec)


HOLD_USAGE = "hold[:altitude=M][,duration=S][,yaw=RAD]"


def parse_hold(spec: str, default_altitude: float) -> PositionTrajectory:
    """``hold`` with optional ``:altitude=M,duration=S,yaw=RAD``: climb from the ground to ``altitude`` above home
    (default: the preset's reference altitude) and hold there, heading ``yaw`` [rad] (default 0), for ``duration``
    [s] (default 20): the position hold a wind or sensor sweep measures. Raises UsageError naming --trajectory."""
    values = {"altitude": default_altitude, "duration": 20.0, "yaw": 0.0}
    bounds = {"altitude": (0.0, 10000.0, "m"), "duration": (0.0, 3600.0, "s"), "yaw": (-math.pi, math.pi, "rad")}
    for item in (i.strip() for i in spec.partition(":")[2].split(",") if i.strip()):
        key, eq, text = (p.strip() for p in item.partition("="))
        if not eq or key not in values:
            raise UsageError(f"--trajectory {spec!r}: unknown parameter {item!r}; expected {HOLD_USAGE}")
        try:
            values[key] = float(text)
        except ValueError:
            values[key] = math.nan
    for key, (lo, hi, unit) in bounds.items():
        v = values[key]
        if not (lo <= v <= hi if key == "yaw" else lo < v <= hi):
            what = f"[{lo:g}, {hi:g}]" if key == "yaw" else f"({lo:g}, {hi:g}]"
            raise UsageError(f"--trajectory {spec!r}: {key} = {v:g}: expected a number in {what} {unit}")
    point = PositionSetpoint(0.0, 0.0, values["altitude"], values["yaw"])
    return PositionTrajectory(lambda _t: point, values["duration"], spec)


def position_from_csv(path: Path) -> PositionTrajectory:
    """A CSV with the header ``t, x, y, altitude, yaw`` (t [s] ≥ 0 increasing; x north, y east [m, NED];
    altitude [m] ≥ 0; yaw [rad], interpolated as written: 0 → 6.283 is a full turn) → its trajectory:
    linear interpolation, the first row before its t and the last row after it; velocity feed-forward is
    each segment's slope (0 while held). Refused, with the file, line and column named: a missing column or
    value, a non-number, a value not finite, a negative altitude or t, t not increasing, or a segment
    faster than MAX_HORIZONTAL_SPEED, MAX_CLIMB or MAX_DESCENT."""
    data, lines = _read_table(path, POSITION_COLUMNS, {
        "t": (lambda v: v >= 0, "a number ≥ 0 [s]"),
        "altitude": (lambda v: v >= 0, "a number ≥ 0 [m]"),
    })  # fmt: skip
    t = data[:, 0]
    for i in range(1, len(t)):
        dt = t[i] - t[i - 1]
        horizontal = math.hypot(data[i, 1] - data[i - 1, 1], data[i, 2] - data[i - 1, 2]) / dt
        climb = (data[i, 3] - data[i - 1, 3]) / dt
        if horizontal > MAX_HORIZONTAL_SPEED:
            raise UsageError(f"trajectory {path}, line {lines[i]}, columns x, y: {horizontal:.3g} m/s from the "
                             f"previous row exceeds {MAX_HORIZONTAL_SPEED:g} m/s (PX4's MPC_XY_VEL_MAX "
                             "default)")  # fmt: skip
        if climb > MAX_CLIMB or -climb > MAX_DESCENT:
            raise UsageError(f"trajectory {path}, line {lines[i]}, column altitude: {climb:.3g} m/s from the "
                             f"previous row; allowed −{MAX_DESCENT:g} to {MAX_CLIMB:g} m/s (PX4's MPC_Z_VEL_MAX_DN "
                             "and _UP defaults)")  # fmt: skip
    slopes = np.diff(data[:, 1:4], axis=0) / np.diff(t)[:, None] if len(t) > 1 else np.zeros((0, 3))

    def setpoint(time: float) -> PositionSetpoint:
        x, y, alt, yaw = (float(np.interp(time, t, data[:, i])) for i in range(1, 5))
        k = int(np.searchsorted(t, time, side="right")) - 1  # the segment [t_k, t_k+1) holding time
        vx, vy, climb = slopes[k] if 0 <= k < len(slopes) else (0.0, 0.0, 0.0)
        return PositionSetpoint(x, y, alt, _wrap(yaw), float(vx), float(vy), float(climb))

    return PositionTrajectory(setpoint, float(t[-1]), str(path))


def csv_kind(path: Path) -> str:
    """'position' or 'attitude' by a CSV's header; UsageError naming the file when it is neither."""
    try:
        with open(path, newline="", encoding="utf-8") as fh:
            header = {h.strip() for h in next(csv.reader(fh), [])}
    except (OSError, UnicodeDecodeError) as exc:
        raise UsageError(f"trajectory {path}: cannot read it as a CSV file: {exc}") from None
    position, attitude = set(POSITION_COLUMNS) <= header, set(COLUMNS) <= header
    if position and attitude:
        raise UsageError(f"trajectory {path}: its header has both an attitude trajectory's columns "
                         f"({', '.join(COLUMNS)}) and a position trajectory's ({', '.join(POSITION_COLUMNS)}); "
                         "keep one set")  # fmt: skip
    if position:
        return "position"
    if attitude or not {"x", "y"} & header:
        return "attitude"  # from_csv names what is missing
    missing = [c for c in POSITION_COLUMNS if c not in header]
    raise UsageError(f"trajectory {path}: missing column(s) {', '.join(missing)}; a position trajectory has the "
                     f"columns {', '.join(POSITION_COLUMNS)}")  # fmt: skip


EXPECTED = "step, ramp, sine, circle[:...], figure8[:...], hold[:...] or an existing CSV file"


def make(name: str, ref: Reference) -> Trajectory | PositionTrajectory:
    """``--trajectory`` → an attitude trajectory (a function of t → Reference) or a PositionTrajectory.
    ``ref``: the preset's reference (the attitude trajectories' target, the shapes' default altitude)."""
    if name == "step":
        return step(ref)
    if name == "ramp":
        return ramp(ref)
    if name == "sine":
        return sine(ref)
    if name.partition(":")[0] in SHAPES:
        return parse_shape(name, ref.altitude)
    if name.partition(":")[0] == "hold":
        return parse_hold(name, ref.altitude)
    path = Path(name)
    if not path.is_file():
        raise UsageError(f"--trajectory {name!r}: expected {EXPECTED}")
    if csv_kind(path) == "position":
        return position_from_csv(path)
    return from_csv(path)
