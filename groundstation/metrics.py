"""Step-response metrics per channel: rise time (10–90 %), 2 % settling time, overshoot, steady-state
error, peak |u| and RMS tracking error; for position trajectories, horizontal and altitude tracking errors
(:func:`position_metrics`)."""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np

CHANNELS = ("altitude", "roll", "pitch", "yaw")


def step_metrics(t: np.ndarray, y: np.ndarray, ref: np.ndarray, u: np.ndarray) -> dict[str, float | None]:
    """Metrics of output ``y`` following reference ``ref`` (same length as ``t``) under input ``u``.

    The step is from y[0] to the final reference. Rise and settling times are in seconds from t[0];
    ``None`` when the output never gets there within the run (or when there is no step).
    Overshoot is in percent of the step. Steady-state error = final reference − final output.
    """
    y0, r = float(y[0]), float(ref[-1])
    step = r - y0
    out: dict[str, float | None] = {
        "rise_time": None,
        "settling_time": None,
        "overshoot_pct": None,
        "steady_state_error": r - float(y[-1]),
        "peak_abs_u": float(np.max(np.abs(u))),
        "rms_error": float(np.sqrt(np.mean((ref - y) ** 2))),
    }
    if abs(step) < 1e-12:
        return out
    frac = (y - y0) / step
    i10 = np.flatnonzero(frac >= 0.1)
    i90 = np.flatnonzero(frac >= 0.9)
    if i10.size and i90.size:
        out["rise_time"] = float(t[i90[0]] - t[i10[0]])
    outside = np.flatnonzero(np.abs(y - r) > 0.02 * abs(step))
    if outside.size == 0:
        out["settling_time"] = 0.0
    elif outside[-1] + 1 < len(t):
        out["settling_time"] = float(t[outside[-1] + 1] - t[0])
    out["overshoot_pct"] = max(0.0, float(np.max(frac)) - 1.0) * 100.0
    return out


def saturation_time(
    inputs: np.ndarray,
    forces: np.ndarray,
    period: float,
    thrust_bounds: tuple[float, float],
    force_bounds: tuple[float, float],
) -> float:
    """Time [s] with the allocation saturated: T times the number of rows whose u1 [N] (``inputs[:, 0]``) is at a
    bound of the controller's thrust (thrust_min, thrust_max) or whose commanded motor forces (``forces``, (N, 4)
    [N]) reach a bound of the motors (F_min, F_max). The sweeps' batch engine counts the same rows on the fly."""
    if len(inputs) == 0:
        return 0.0
    u1 = inputs[:, 0]
    at_bound = (u1 <= thrust_bounds[0]) | (u1 >= thrust_bounds[1])
    at_bound |= (forces.min(axis=1) <= force_bounds[0]) | (forces.max(axis=1) >= force_bounds[1])
    return int(np.count_nonzero(at_bound)) * period


def outputs_from_columns(altitude, roll, pitch, yaw) -> np.ndarray:
    """(N, 4) outputs altitude, roll, pitch, yaw (unwrapped) from columns."""
    return np.column_stack([altitude, roll, pitch, np.unwrap(yaw)])


def channel_outputs(state: np.ndarray) -> np.ndarray:
    """(N, 4) outputs altitude, roll, pitch, yaw from (N, 12) VehicleState rows (yaw unwrapped)."""
    return outputs_from_columns(-state[:, 2], state[:, 6], state[:, 7], state[:, 8])


def run_metrics(t: np.ndarray, y: np.ndarray, reference: np.ndarray, inputs: np.ndarray) -> dict:
    """Metrics of all four channels of one run; ``y`` from :func:`channel_outputs`."""
    ref = reference.copy()
    # Yaw reference on the same branch as the unwrapped yaw.
    ref[:, 3] = y[:, 3] + np.angle(np.exp(1j * (reference[:, 3] - y[:, 3])))
    return {ch: step_metrics(t, y[:, i], ref[:, i], inputs[:, i]) for i, ch in enumerate(CHANNELS)}


def _name_width(metrics: dict) -> int:
    """The controller column's width: 13, or a loaded controller's name (path:Name) and two spaces."""
    return max([13] + [len(name) + 2 for name in metrics])


def format_table(metrics: dict[str, dict]) -> str:
    """A fixed-width table of {controller: {channel: metrics}} for the terminal and the docs (docs/results.md)."""

    def f(v: float | None, scale: float = 1.0, fmt: str = ".3f") -> str:
        return "—" if v is None or (isinstance(v, float) and math.isnan(v)) else format(v * scale, fmt)

    w = _name_width(metrics)
    header = (
        f"{'controller':<{w}}{'channel':<10}{'rise [s]':>10}{'settle [s]':>12}{'overshoot':>11}"
        f"{'ss error':>12}{'peak |u|':>11}"
    )
    lines = [header, "-" * len(header)]
    for ctrl, chans in metrics.items():
        for ch, m in chans.items():
            lines.append(
                f"{ctrl:<{w}}{ch:<10}{f(m['rise_time']):>10}{f(m['settling_time']):>12}"
                f"{f(m['overshoot_pct'], fmt='.2f') + ' %':>11}{f(m['steady_state_error'], fmt='.2e'):>12}"
                f"{f(m['peak_abs_u'], fmt='.1f'):>11}"
            )
    return "\n".join(lines)


def battery_use(columns: Mapping[str, np.ndarray]) -> dict | None:
    """What a flight drew from its battery, from its telemetry ``columns`` (telemetry_csv.BATTERY_COLUMNS, what the
    autopilot knew: docs/battery.md): ``energy_j`` and ``charge_mah`` drawn from the first row to the last,
    ``remaining_start`` and ``remaining_end`` (0..1), the lowest ``voltage_min_v`` and the highest ``current_max_a``;
    None for a flight without a battery."""
    if "battery_j" not in columns or not len(columns["battery_j"]):
        return None
    c = columns
    return {"energy_j": float(c["battery_j"][-1] - c["battery_j"][0]),
            "charge_mah": float(c["battery_mah"][-1] - c["battery_mah"][0]),
            "remaining_start": float(c["battery_remaining"][0]), "remaining_end": float(c["battery_remaining"][-1]),
            "voltage_min_v": float(np.min(c["battery_v"])), "current_max_a": float(np.max(c["battery_a"]))}  # fmt: skip


def position_metrics(
    x: np.ndarray, y: np.ndarray, x_ref: np.ndarray, y_ref: np.ndarray, altitude: np.ndarray, altitude_ref: np.ndarray
) -> dict[str, float | int | None]:
    """Position tracking over the samples where the horizontal position is controlled (x_ref and y_ref
    finite): ``horizontal_rms`` and ``horizontal_max`` of |(x, y) − (x_ref, y_ref)| [m] (NED, horizontal
    distance), ``altitude_rms`` of altitude_ref − altitude [m] over the same samples, and their number,
    ``samples``. The errors are ``None`` when there are no such samples."""
    controlled = np.isfinite(x_ref) & np.isfinite(y_ref)
    n = int(np.count_nonzero(controlled))
    if not n:
        return {"samples": 0, "horizontal_rms": None, "horizontal_max": None, "altitude_rms": None}
    e = np.hypot(x[controlled] - x_ref[controlled], y[controlled] - y_ref[controlled])
    ea = altitude_ref[controlled] - altitude[controlled]
    return {
        "samples": n,
        "horizontal_rms": float(np.sqrt(np.mean(e**2))),
        "horizontal_max": float(np.max(e)),
        "altitude_rms": float(np.sqrt(np.mean(ea**2))),
    }


def format_position_table(metrics: dict[str, dict]) -> str:
    """A fixed-width table of {controller: :func:`position_metrics`} for the terminal."""

    def f(v: float | None) -> str:
        return "—" if v is None else f"{v:.3f}"

    w = _name_width(metrics)
    header = (
        f"{'controller':<{w}}{'samples':>9}{'horizontal RMS [m]':>20}{'horizontal max [m]':>20}{'altitude RMS [m]':>18}"
    )
    lines = [header, "-" * len(header)]
    for ctrl, m in metrics.items():
        lines.append(
            f"{ctrl:<{w}}{m['samples']:>9}{f(m['horizontal_rms']):>20}{f(m['horizontal_max']):>20}"
            f"{f(m['altitude_rms']):>18}"
        )
    return "\n".join(lines)


def estimate_rms(estimate: dict, truth: dict) -> dict[str, float]:
    """The RMS of the estimate's error over a flight: horizontal position and altitude [m], roll, pitch and yaw
    [deg] (yaw wrapped to ±180°), from telemetry.csv's columns (``truth``: the x_true.. ones, renamed)."""

    def rms(e) -> float:
        return round(float(np.sqrt(np.mean(np.square(e)))), 6) if len(e) else float("nan")

    yaw = (estimate["yaw"] - truth["yaw"] + np.pi) % (2 * np.pi) - np.pi
    return {
        "horizontal_m": rms(np.hypot(estimate["x"] - truth["x"], estimate["y"] - truth["y"])),
        "altitude_m": rms(estimate["altitude"] - truth["altitude"]),
        "roll_deg": rms(np.degrees(estimate["roll"] - truth["roll"])),
        "pitch_deg": rms(np.degrees(estimate["pitch"] - truth["pitch"])),
        "yaw_deg": rms(np.degrees(yaw)),
    }
