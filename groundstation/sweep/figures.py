"""The figures of a sweep, drawn by ``quadsitl sweep`` into its folder after the table (``--no-figures`` skips
them). Each is drawn only when the sweep has what it shows:

- ``fig_sweep_envelopes.png``: for each channel with a step, the median and the 5–95 % band of the output over
  time across a sample of the trials (at most :data:`SAMPLE`, evenly spread over the trial numbers, flown again
  with their trajectories: the engine is deterministic), with the reference; below, the band about the median.
- ``fig_sweep_settling.png``: histograms of the settling time of each channel with a step, with how many trials
  did not settle within the run.
- ``fig_sweep_parameters.png``: the settling times and the steady-state errors that vary against each varied
  parameter, one panel per (metric, parameter), with the median in bins of the parameter; eq (59)'s offset over
  the altitude's steady-state error against ``mismatch.mass`` when it applies.
- ``fig_sweep_gain_map.png``: for a grid of two backstepping gains, the settling time and the overshoot over the
  grid, with the region where the paper's conditions (41)–(44) hold (computed on a finer grid of the same two
  gains by :func:`groundstation.sweep.trials.admissibility`, the check the trials are flown or refused by).

The data behind them are prepared by pure functions (:func:`choose_sample`, :func:`reflown`,
:func:`sample_outputs`, :func:`envelope`, :func:`tick_bins`, :func:`gain_map`, :func:`admissible_mask`),
testable without drawing. Headless: matplotlib's Agg backend, as :mod:`groundstation.figures`.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from matplotlib import colors, patheffects, ticker
from matplotlib.lines import Line2D
from matplotlib.patches import Patch, Rectangle

from autopilot.gains import poles_from_rates
from groundstation.figures import LABELS, plt
from groundstation.metrics import channel_outputs
from groundstation.sweep import engine
from groundstation.sweep.parameters import RATES
from groundstation.sweep.run import SweepResult, fly
from groundstation.sweep.spec import SweepSpec
from groundstation.sweep.trials import admissibility, nominal_poles

CHANNELS = engine.CHANNELS
UNITS = ("m", "rad", "rad", "rad")
SAMPLE = 200  # trials flown again for the envelopes, at most
POINTS = 400  # points kept of each re-flown output, at most (every s-th tick: decimate)
MAX_BATCH = 25  # trials flown again in one call of the engine, at most ...
KEEP_BYTES = 32 * 2**20  # ... and at most this much of kept trajectories at a time [bytes]
PERCENTILES = (5, 50, 95)
SCATTER = 20_000  # points per panel of the parameter figure, at most (evenly spread over the trials)
BINS = 20  # bins of a parameter for the median line ...
MEDIAN_POINTS = 200  # ... drawn when a panel has at least this many points
FINE_PER_CELL = 20  # points per grid cell and axis of the finer grid the (41)–(44) region is computed on
ANNOTATE = 16  # the gain map writes each cell's value when the grid has at most this many points per axis
SPREAD_FLOOR = 1e-6  # [m, rad] a spread below this is round-off: a steady-state error is drawn against the
# parameters when its 5–95 % spread is above it, and the envelopes' spread axes span at least ±it
MIN_SPAN = 20  # a histogram's axis spans at least this many ticks
DPI = 110

# ---- which trials, which channels --------------------------------------------------------------------------


def flown_ok(table: dict[str, np.ndarray]) -> np.ndarray:
    """Trials flown (admissible) that did not diverge: the ones with response metrics."""
    return np.asarray(table["admissible"], dtype=bool) & ~np.asarray(table["diverged"], dtype=bool)


def step_channels(table: dict[str, np.ndarray]) -> list[int]:
    """The channels (0 altitude, 1 roll, 2 pitch, 3 yaw) with a step in some trial flown to the end: those with an
    overshoot defined (it is NaN without a step)."""
    ok = flown_ok(table)
    return [j for j, ch in enumerate(CHANNELS) if np.isfinite(table[f"{ch}_overshoot_pct"][ok]).any()]


def spread(rows: np.ndarray, cap: int) -> np.ndarray:
    """``rows`` when there are at most ``cap``, else ``cap`` of them evenly spaced along it, the first and the last
    among them (distinct: the spacing is above 1)."""
    rows = np.asarray(rows)
    if len(rows) <= cap:
        return rows.copy()
    return rows[np.linspace(0, len(rows) - 1, cap).round().astype(np.int64)]


def choose_sample(table: dict[str, np.ndarray], cap: int = SAMPLE) -> np.ndarray:
    """The trial numbers flown again for the envelopes: among the trials flown that did not diverge, all of them
    when there are at most ``cap``, else ``cap`` evenly spread over them in trial order. Deterministic."""
    return spread(np.asarray(table["trial"])[flown_ok(table)], cap)


def decimate(ticks: int, points: int = POINTS) -> np.ndarray:
    """The ticks kept of a trajectory of ``ticks`` rows: every s-th from the first, at most ``points``; s is even when
    above 1, so that an oscillation at the period 2T (a pole near −1) is seen at one phase, not aliased into noise."""
    stride = max(1, math.ceil(ticks / points))
    if stride > 1 and stride % 2:
        stride += 1
    return np.arange(0, ticks, stride)


# ---- the sample, flown again -------------------------------------------------------------------------------


def reflown(spec: SweepSpec, trials: np.ndarray) -> Iterator[tuple[int, np.ndarray]]:
    """Fly the given trials again with their trajectories and yield (trial, its kept trajectory: (ticks,
    engine.KEEP_SIZE)) in the order given. In batches (at most :data:`MAX_BATCH` trials, :data:`KEEP_BYTES` of
    trajectories), the trials' numbers as ``keep``: :func:`groundstation.sweep.run.fly` draws each trial from its
    own number, so these are the sweep's own flights, to the bit. Always on the batch engine: a sweep flown with
    the SITL engine (``quadsitl fly`` a trial, seconds each) agrees with it to the wire's float32 rounding
    (docs/sweeps.md). The trials must be admissible."""
    per_trial = spec.ticks * engine.KEEP_SIZE * 8
    batch = max(1, min(MAX_BATCH, KEEP_BYTES // per_trial))
    trials = [int(k) for k in trials]
    for start in range(0, len(trials), batch):
        part = trials[start : start + batch]
        result = fly(dataclasses.replace(spec, keep=tuple(part), engine="batch"), part)
        for k in part:
            yield k, result.kept.pop(k)


@dataclass
class Sample:
    """The outputs of a sample of trials flown again: ``t`` [s] of the ticks kept (P), ``outputs`` (n, P, 4:
    altitude [m], roll, pitch, yaw [rad], yaw unwrapped), ``reference`` (n, 4), the yaw's on the branch of the
    trial's yaw at its end (as the metrics take it)."""

    trials: np.ndarray
    t: np.ndarray
    outputs: np.ndarray
    reference: np.ndarray


def sample_outputs(spec: SweepSpec, trials: np.ndarray, points: int = POINTS) -> Sample:
    """Fly ``trials`` again (:func:`reflown`) and keep only their four outputs at :func:`decimate`'s ticks."""
    ticks = decimate(spec.ticks, points)
    outputs = np.empty((len(trials), len(ticks), 4))
    reference = np.empty((len(trials), 4))
    for i, (_k, kept) in enumerate(reflown(spec, trials)):
        y = channel_outputs(kept[:, engine.K_STATE : engine.K_STATE + 12])
        outputs[i] = y[ticks]
        r = kept[-1, engine.K_REF : engine.K_REF + 4].copy()
        r[3] = y[-1, 3] + np.angle(np.exp(1j * (r[3] - y[-1, 3])))
        reference[i] = r
    return Sample(np.asarray(trials), ticks * spec.period, outputs, reference)


def envelope(y: np.ndarray, percentiles: tuple[float, ...] = PERCENTILES) -> np.ndarray:
    """The percentiles (numpy's linear interpolation) across trials of ``y`` (n trials, P times): (len(percentiles),
    P)."""
    return np.percentile(y, percentiles, axis=0)


# ---- histograms ---------------------------------------------------------------------------------------------


def tick_bins(values: np.ndarray, period: float, target: int = 40) -> np.ndarray:
    """Histogram edges for times that are whole ticks (k·T): each bin holds the same whole number of ticks, about
    ``target`` bins over the values' range, edges halfway between ticks (no bin gets two ticks' worth by
    aliasing)."""
    lo, hi = float(np.min(values)), float(np.max(values))
    width = period * max(1, math.ceil((hi - lo) / (target * period) - 1e-9))
    n = math.floor((hi - lo) / width + 1e-9) + 1
    return lo - period / 2 + width * np.arange(n + 1)


# ---- the gain map --------------------------------------------------------------------------------------------


def gain_axes(spec: SweepSpec) -> tuple[str, str] | None:
    """The two backstepping gains on the spec's grid (x first: the grid's order), or None when the grid has not
    exactly two gains with two values or more each."""
    if spec.controller != "backstepping":
        return None
    names = [k for k in spec.grid if k.startswith("gains.") and k[6:] in RATES and len(spec.vary[k].values) >= 2]
    return (names[0], names[1]) if len(names) == 2 else None


def gain_channels(names: tuple[str, ...]) -> list[int]:
    """The channels the gains act on: k1, k2 altitude; k3, k4 roll; k5, k6 pitch; k7, k8 yaw."""
    return sorted({RATES.index(name[6:]) // 2 for name in names})


def index_values(u: np.ndarray, values: np.ndarray) -> np.ndarray:
    """The gain at fractional positions ``u`` along a grid axis whose point i is ``values[i]`` (sorted; the map draws
    each grid point as a cell of the same size, at i): piecewise linear between grid points, in the logarithm when
    the values are all > 0 (rates: then the half cells beyond the ends stay > 0 too); beyond the ends, the end
    interval's slope."""
    v = np.asarray(values, dtype=np.float64)
    log = bool(v[0] > 0)
    w = np.log(v) if log else v
    i = np.arange(len(w))
    u = np.asarray(u, dtype=np.float64)
    out = np.interp(u, i, w)
    out = np.where(u < 0, w[0] + u * (w[1] - w[0]), out)
    out = np.where(u > i[-1], w[-1] + (u - i[-1]) * (w[-1] - w[-2]), out)
    return np.exp(out) if log else out


@dataclass
class GainMap:
    """A sweep's table over a grid of two gains [1/s]: ``x`` (nx), ``y`` (ny) the grid's values, sorted; per cell
    (ny, nx), over its trials flown to the end: the median settling time [s] of the gains' channels (the longest
    of them per trial; inf when not settled within the run, NaN when none of the cell's trials has one), the
    median overshoot [%]; ``flown`` any of its trials flown (admissible), ``diverged`` flown and all diverged."""

    x_name: str
    y_name: str
    x: np.ndarray
    y: np.ndarray
    channels: list[int]
    settling: np.ndarray
    overshoot: np.ndarray
    flown: np.ndarray
    diverged: np.ndarray


def _cell_medians(cell: np.ndarray, values: np.ndarray, cells: int) -> np.ndarray:
    """The median of ``values`` per cell number (NaN for a cell without values)."""
    out = np.full(cells, math.nan)
    order = np.argsort(cell, kind="stable")
    ids, starts = np.unique(cell[order], return_index=True)
    for c, part in zip(ids, np.split(values[order], starts[1:])):
        out[c] = np.median(part)
    return out


def gain_map(spec: SweepSpec, table: dict[str, np.ndarray], names: tuple[str, str]) -> GainMap:
    """The table over the grid of the gains ``names`` (:func:`gain_axes`); the trials of a cell are those at its
    grid point, across the grid's repeats and its other names."""
    xn, yn = names
    x, y = np.unique(table[xn]), np.unique(table[yn])
    cell = np.searchsorted(y, table[yn]) * len(x) + np.searchsorted(x, table[xn])
    cells, shape = len(x) * len(y), (len(y), len(x))
    chans = gain_channels(names)
    ok = flown_ok(table)
    settle = np.max([np.where(np.isnan(s), math.inf, s) for s in (table[f"{CHANNELS[j]}_settling_time"]
                                                                     for j in chans)], axis=0)  # fmt: skip
    overshoot = np.max([table[f"{CHANNELS[j]}_overshoot_pct"] for j in chans], axis=0)
    flown = np.bincount(cell, weights=table["admissible"].astype(float), minlength=cells) > 0
    finished = np.bincount(cell, weights=ok.astype(float), minlength=cells) > 0
    return GainMap(
        xn, yn, x, y, chans,
        _cell_medians(cell[ok], settle[ok], cells).reshape(shape),
        _cell_medians(cell[ok], overshoot[ok], cells).reshape(shape),
        flown.reshape(shape), (flown & ~finished).reshape(shape),
    )  # fmt: skip


def admissible_mask(spec: SweepSpec, names: tuple[str, str], x: np.ndarray, y: np.ndarray) -> np.ndarray | None:
    """Whether conditions (41)–(44) hold (:func:`groundstation.sweep.trials.admissibility`, the trials' own check) at
    each point (x_j, y_i) of the gains ``names`` [1/s]: (len(y), len(x)). The other gains at the spec's values (the
    preset's, or a fixed value under [vary]); None when another gain varies (the region then depends on it)."""
    poles = np.array(nominal_poles(spec), dtype=np.float64)
    for i, k in enumerate(RATES):
        d = spec.vary.get(f"gains.{k}")
        if d is None or f"gains.{k}" in names:
            continue
        if d.kind != "fixed":
            return None
        poles[i] = poles_from_rates(d.values, spec.period)[0]
    X, Y = np.meshgrid(np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64))
    grid = np.tile(poles, (X.size, 1))
    for name, values in zip(names, (X, Y)):
        grid[:, RATES.index(name[6:])] = poles_from_rates(values.ravel(), spec.period)
    ok, _reasons = admissibility(grid, spec.period)
    return ok.reshape(X.shape)


def fine_axis(n: int, points_per_cell: int = FINE_PER_CELL) -> np.ndarray:
    """Positions across the ``n`` cells of a grid axis, −0.5 to n − 0.5, ``points_per_cell`` a cell."""
    return np.linspace(-0.5, n - 0.5, n * points_per_cell + 1)


# ---- the eq (59) line ----------------------------------------------------------------------------------------


def eq59_steady_state_error(spec: SweepSpec, factor: np.ndarray) -> np.ndarray | None:
    """The altitude's steady-state error r − y [m] that eq (59) (docs/position.md) predicts for the model's mass
    m̂ = factor·m: −(m̂ − m)·g/(m̂·k1·k2) = −(factor − 1)·g/(factor·k1·k2); None where it does not apply (not the
    backstepping, an altitude integral, or k1, k2 varied)."""
    p = spec.preset
    if spec.controller != "backstepping" or p.position.integral[0] != 0.0:
        return None
    if any(f"gains.{k}" in spec.vary and spec.vary[f"gains.{k}"].kind != "fixed" for k in ("k1", "k2")):
        return None
    k = [spec.vary[f"gains.{n}"].values[0] if f"gains.{n}" in spec.vary else p.controller.gains[i]
         for i, n in enumerate(("k1", "k2"))]  # fmt: skip
    f = np.asarray(factor, dtype=np.float64)
    return -(f - 1.0) * p.vehicle.gravity / (f * k[0] * k[1])


# ---- drawing ---------------------------------------------------------------------------------------------------


def _title(spec: SweepSpec) -> str:
    return f"sweep {spec.name} ({spec.controller}, preset {spec.preset.name}, {spec.duration:g} s per trial)"


def _save(fig: plt.Figure, path: Path) -> Path:
    fig.savefig(path, dpi=DPI)
    plt.close(fig)
    return path


def write_envelopes(out: Path, spec: SweepSpec, table: dict[str, np.ndarray], cap: int = SAMPLE) -> Path | None:
    """``fig_sweep_envelopes.png``: per channel with a step, the 5–95 % band and the median of the output across a
    sample of trials flown again (:func:`choose_sample`), with the reference; below, the band about the median.
    None when no trial has a step to show."""
    chans = step_channels(table)
    trials = choose_sample(table, cap)
    if not chans or not len(trials):
        return None
    s = sample_outputs(spec, trials)
    n_ok = int(flown_ok(table).sum())
    fig, axes = plt.subplots(2, len(chans), figsize=(3.6 * len(chans) + 1, 6.4), sharex=True, squeeze=False,
                             gridspec_kw={"height_ratios": [2, 1]})  # fmt: skip
    for col, j in enumerate(chans):
        p5, p50, p95 = envelope(s.outputs[:, :, j])
        top, bottom = axes[0, col], axes[1, col]
        top.fill_between(s.t, p5, p95, color="C0", alpha=0.3, lw=0, label="5–95 %")
        top.plot(s.t, p50, color="C0", lw=1.4, label="median")
        ref = s.reference[:, j]
        if np.ptp(ref) == 0:
            top.axhline(ref[0], color="k", lw=0.9, ls=":", label="reference")
        else:  # the reference varies: its median, said in this panel's own legend
            top.axhline(np.median(ref), color="k", lw=0.9, ls=":", label="reference (median)")
            if col:
                top.legend(loc="best", fontsize=8)
        top.set_ylabel(LABELS[j])
        top.set_title(CHANNELS[j], fontsize=10)
        bottom.fill_between(s.t, p5 - p50, p95 - p50, color="C0", alpha=0.3, lw=0)
        bottom.axhline(0.0, color="C0", lw=1.0)
        bottom.set_ylabel(f"5–95 % − median [{UNITS[j]}]")
        bottom.set_xlabel("t [s]")
        bottom.ticklabel_format(axis="y", style="sci", scilimits=(-2, 3))
        lo, hi = bottom.get_ylim()
        bottom.set_ylim(min(lo, -SPREAD_FLOOR), max(hi, SPREAD_FLOOR))
        for ax in (top, bottom):
            ax.grid(True, alpha=0.3)
    axes[0, 0].legend(loc="best", fontsize=8)
    spread_of = "all of them" if len(trials) == n_ok else "evenly spread over the trial numbers"
    again = "on the batch engine (the SITL engine's flights agree with it to float32)" if spec.engine == "sitl" \
        else "with their trajectories"  # fmt: skip
    fig.suptitle(f"Response envelopes: {len(trials)} of the {n_ok} trials flown to the end ({spread_of}), flown "
                 f"again {again}\n{_title(spec)}", fontsize=10)  # fmt: skip
    fig.tight_layout()
    return _save(fig, out / "fig_sweep_envelopes.png")


def write_settling_histograms(out: Path, spec: SweepSpec, table: dict[str, np.ndarray]) -> Path | None:
    """``fig_sweep_settling.png``: the settling time's histogram per channel with a step, over the trials flown to
    the end, with the median and how many did not settle within the run. None when no channel has a step."""
    chans = step_channels(table)
    if not chans:
        return None
    ok = flown_ok(table)
    n_ok = int(ok.sum())
    cols = 2 if len(chans) > 2 else len(chans)
    rows = math.ceil(len(chans) / cols)
    fig, axes = plt.subplots(rows, cols, figsize=(5 * cols, 3.4 * rows), squeeze=False)
    for ax, j in zip(axes.flat, chans):
        st = table[f"{CHANNELS[j]}_settling_time"][ok]
        has_step = np.isfinite(table[f"{CHANNELS[j]}_overshoot_pct"][ok])
        settled = st[np.isfinite(st)]
        not_settled = int(np.count_nonzero(has_step & ~np.isfinite(st)))
        if settled.size:
            edges = tick_bins(settled, spec.period)
            ax.hist(settled, bins=edges, color="C0", alpha=0.8)
            pad = max(0.0, (MIN_SPAN * spec.period - (edges[-1] - edges[0])) / 2)
            ax.set_xlim(edges[0] - pad, edges[-1] + pad)
            ax.xaxis.set_major_locator(ticker.MaxNLocator(6))
            ax.axvline(np.median(settled), color="k", lw=1.0, ls="--", label=f"median {np.median(settled):.3f} s")
            ax.legend(loc="upper right", fontsize=8)
        ax.set_title(f"{CHANNELS[j]}: {settled.size} settled, {not_settled} not within {spec.duration:g} s",
                     fontsize=10)  # fmt: skip
        ax.set_xlabel("settling time into ±2 % of the step [s]")
        ax.set_ylabel("trials")
        ax.grid(True, alpha=0.3)
    for ax in axes.flat[len(chans) :]:
        ax.set_visible(False)
    n, flown = len(table["trial"]), np.asarray(table["admissible"], dtype=bool)
    others = f"; {n - int(flown.sum())} inadmissible, {int((flown & table['diverged']).sum())} diverged"
    fig.suptitle(f"Settling times over the {n_ok} of {n} trials flown to the end{others}\n{_title(spec)}", fontsize=10)
    fig.tight_layout()
    return _save(fig, out / "fig_sweep_settling.png")


def parameter_metrics(table: dict[str, np.ndarray]) -> list[tuple[str, str]]:
    """(column, label) of the metrics drawn against the parameters: a position trajectory's or a mission's tracking
    errors (horizontal RMS and largest, altitude RMS); otherwise each channel's settling time (channels with a
    step, when some trial settled), then each steady-state error whose 5–95 % spread over the trials flown to the
    end is above :data:`SPREAD_FLOOR`."""
    ok = flown_ok(table)
    if "horizontal_rms" in table and np.isfinite(table["horizontal_rms"][ok]).any():
        return [("horizontal_rms", "horizontal RMS error [m]"), ("horizontal_max", "largest horizontal error [m]"),
                ("altitude_rms", "altitude RMS error [m]")]  # fmt: skip
    settles = [j for j in step_channels(table) if np.isfinite(table[f"{CHANNELS[j]}_settling_time"][ok]).any()]
    out = [(f"{CHANNELS[j]}_settling_time", f"{CHANNELS[j]} settling time [s]") for j in settles]
    for j, ch in enumerate(CHANNELS):
        sse = table[f"{ch}_steady_state_error"][ok]
        sse = sse[np.isfinite(sse)]
        if sse.size and np.subtract(*np.percentile(sse, (95, 5))) > SPREAD_FLOOR:
            out.append((f"{ch}_steady_state_error", f"{ch} steady-state error r − y [{UNITS[j]}]"))
    return out


def varied_parameters(spec: SweepSpec, exclude: tuple[str, ...] = ()) -> list[str]:
    """The parameters that vary (not fixed), sorted, less ``exclude`` and the seeds (a seed draws a noise, it is not
    a quantity to draw a metric against)."""
    return sorted(k for k, d in spec.vary.items() if d.kind != "fixed" and k not in exclude
                  and not k.endswith(".seed"))  # fmt: skip


def _binned_median(x: np.ndarray, y: np.ndarray, bins: int = BINS) -> tuple[np.ndarray, np.ndarray]:
    """The median of ``y`` in ``bins`` equal bins of ``x`` (at the bins' centres; the bins without a point left out);
    for a few distinct x (a grid, a choice), at each of them."""
    values = np.unique(x)
    if len(values) <= bins:
        idx, centres = np.searchsorted(values, x), values
    else:
        edges = np.linspace(values[0], values[-1], bins + 1)
        idx, centres = np.clip(np.searchsorted(edges, x, side="right") - 1, 0, bins - 1), (edges[1:] + edges[:-1]) / 2
    med = np.array([np.median(y[idx == i]) if np.any(idx == i) else math.nan for i in range(len(centres))])
    keep = np.isfinite(med)
    return centres[keep], med[keep]


def write_parameter_figure(
    out: Path, spec: SweepSpec, table: dict[str, np.ndarray], exclude: tuple[str, ...] = (), cap: int = SCATTER
) -> Path | None:
    """``fig_sweep_parameters.png``: each metric of :func:`parameter_metrics` (rows) against each varied parameter
    (columns), over the trials flown to the end (at most ``cap`` points a panel, evenly spread over them), with the
    median in bins of the parameter; eq (59)'s line over the altitude's steady-state error against
    ``mismatch.mass`` when it applies. None when nothing varies or no metric is defined."""
    params = varied_parameters(spec, exclude)
    metrics = parameter_metrics(table)
    if not params or not metrics:
        return None
    ok_rows = np.flatnonzero(flown_ok(table))
    rows = spread(ok_rows, cap)
    panels = [(m, name) for m in metrics for name in params]
    ncols = len(params) if len(params) > 1 else min(3, len(metrics))  # one parameter: its panels side by side
    nrows = math.ceil(len(panels) / ncols)
    fig, axes = plt.subplots(nrows, ncols, figsize=(4.6 * ncols + 0.6, 2.6 * nrows + 1.2), squeeze=False)
    ms = 4.0 if len(rows) <= 200 else 3.0 if len(rows) <= 2000 else 1.2
    handles = {"trials": Line2D([], [], ls="none", marker=".", ms=6, color="C0", label="a trial")}
    for ax, ((column, label), name) in zip(axes.flat, panels):
        x, y = table[name][rows], table[column][rows]
        finite = np.isfinite(y)
        ax.plot(x[finite], y[finite], ls="none", marker=".", ms=ms, color="C0", alpha=0.5, rasterized=True)
        if np.count_nonzero(finite) >= MEDIAN_POINTS:
            bx, by = _binned_median(x[finite], y[finite])
            handles["median"] = ax.plot(bx, by, color="C1", lw=1.6, label=f"median in {BINS} bins of the parameter")[0]
        if column == "altitude_steady_state_error" and name == "mismatch.mass":
            xs = np.linspace(np.min(x), np.max(x), 50)
            line = eq59_steady_state_error(spec, xs)
            if line is not None:
                eq59 = r"eq (59): r − y = $-(\hat m - m)\,g\,/\,(\hat m\,k_1 k_2)$, $\hat m$ the model's mass"
                handles["eq59"] = ax.plot(xs, line, color="k", lw=1.0, ls="--", label=eq59)[0]
        if column.endswith("_settling_time"):  # NaN: not settled, or no step in that trial
            step = np.isfinite(table[column.replace("_settling_time", "_overshoot_pct")][rows])
            missing = int(np.count_nonzero(step & ~finite))
            if missing:
                ax.text(0.98, 0.95, f"{missing} not settled", transform=ax.transAxes, ha="right", va="top", fontsize=8)
        ax.set_ylabel(label, fontsize=9)
        ax.set_xlabel(_parameter_label(name), fontsize=9)
        ax.grid(True, alpha=0.3)
    for ax in axes.flat[len(panels) :]:
        ax.set_visible(False)
    fig.legend(handles=list(handles.values()), loc="lower center", ncol=len(handles), fontsize=8, frameon=False)
    shown = f"{len(rows):,} of the {len(ok_rows):,} trials flown to the end (evenly spread)"
    if len(rows) == len(ok_rows):
        shown = f"the {len(rows):,} trials flown to the end"
    fig.suptitle(f"Metrics against the varied parameters: {shown}\n{_title(spec)}", fontsize=10)
    fig.tight_layout(rect=(0, 0.5 / (2.6 * nrows + 1.2), 1, 1))
    return _save(fig, out / "fig_sweep_parameters.png")


def _parameter_label(name: str) -> str:
    """A varied parameter's axis label with its unit (docs/sweeps.md's table of what can vary)."""
    group, _, key = name.partition(".")
    if group == "mismatch":
        return f"{name} (model / plant) [–]"
    if group == "gains":
        return f"{name} [1/s²]" if key.startswith("kp") else f"{name} [1/s]"
    if group in ("initial", "reference"):
        unit = {"altitude": "m", "climb_rate": "m/s"}.get(key, "rad/s" if key.endswith("_rate") else "rad")
        return f"{name} [{unit}]"
    if group == "wind":
        unit = {"speed": "m/s", "gust": "m/s", "gust_start": "s", "gust_rise": "s",
                "turbulence": "0 none … 3 severe"}.get(key, "deg")  # fmt: skip
        return f"{name} [{unit}]"
    if group == "sensors":
        return f"{name} (× the preset's noise) [–]"
    unit = {"mass": "kg", "ixx": "kg·m²", "iyy": "kg·m²", "izz": "kg·m²", "arm_length": "m", "rotor_inertia": "kg·m²",
            "thrust_factor": "N·s²", "drag_factor": "N·m·s²"}.get(key, "SI")  # fmt: skip
    return f"{name} [{unit}]"


INADMISSIBLE_COLOR, NOT_SETTLED_COLOR, DIVERGED_COLOR = "0.85", "0.35", "k"


def write_gain_map(out: Path, spec: SweepSpec, table: dict[str, np.ndarray]) -> Path | None:
    """``fig_sweep_gain_map.png`` for a grid of two backstepping gains (:func:`gain_axes`): the median settling time
    (log colours when it spans more than a decade) and overshoot of the gains' channels per cell, each grid point a
    cell of the same size (the axes are labelled with the grid's values), the cells not flown (inadmissible),
    diverged or not settled in their own colours, the fastest cell outlined, and the contour of the region where
    (41)–(44) hold (:func:`admissible_mask` on a grid :data:`FINE_PER_CELL` times finer, the gains between grid
    points by :func:`index_values`). None without such a grid."""
    names = gain_axes(spec)
    if names is None:
        return None
    m = gain_map(spec, table, names)
    nx, ny = len(m.x), len(m.y)
    ux, uy = fine_axis(nx), fine_axis(ny)
    region = admissible_mask(spec, names, index_values(ux, m.x), index_values(uy, m.y))
    xe, ye = np.arange(nx + 1) - 0.5, np.arange(ny + 1) - 0.5
    chan = " and ".join(CHANNELS[j] for j in m.channels)
    finite = np.isfinite(m.settling)
    fastest = np.unravel_index(np.argmin(np.where(finite, m.settling, math.inf)), m.settling.shape) if finite.any() \
        else None  # fmt: skip
    status = np.full(m.settling.shape, math.nan)  # 0 not flown, 1 not settled (the settling panel), 2 diverged
    status[~m.flown] = 0
    status[m.diverged] = 2
    not_settled = np.where(m.flown & ~m.diverged & np.isinf(m.settling), 1.0, status)
    fig, axes = plt.subplots(1, 2, figsize=(14, 6.6))
    panels = (
        (m.settling, not_settled, f"{chan} settling time into ±2 % [s]", "viridis", "{:.3g}"),
        (m.overshoot, status, f"{chan} overshoot [%]", "YlOrRd", "{:.0f}"),
    )
    for ax, (z, cells, label, cmap, fmt) in zip(axes, panels):
        shown = np.ma.masked_invalid(z)
        if shown.count():
            lo, hi = float(shown.min()), float(shown.max())
            if z is m.overshoot:
                norm = colors.Normalize(vmin=0.0, vmax=max(hi, 1.0))
            elif lo > 0 and hi > 10 * lo:  # settling times over more than a decade: a log scale
                norm = colors.LogNorm(vmin=lo, vmax=hi)
            else:
                norm = colors.Normalize(vmin=lo, vmax=hi)
            bar = fig.colorbar(ax.pcolormesh(xe, ye, shown, norm=norm, cmap=cmap), ax=ax, label=label)
            if isinstance(norm, colors.LogNorm):
                bar.ax.yaxis.set_major_locator(ticker.LogLocator(subs=(1.0, 2.0, 5.0)))
            bar.ax.yaxis.set_major_formatter(ticker.FuncFormatter(lambda v, _pos: f"{v:g}"))
            bar.ax.yaxis.set_minor_formatter(ticker.NullFormatter())
        ax.pcolormesh(xe, ye, np.ma.masked_invalid(cells), vmin=-0.5, vmax=2.5,
                      cmap=colors.ListedColormap([INADMISSIBLE_COLOR, NOT_SETTLED_COLOR, DIVERGED_COLOR]))  # fmt: skip
        if nx <= ANNOTATE and ny <= ANNOTATE:
            _annotate(ax, np.where(np.isnan(cells), z, math.nan), fmt)
        if region is not None:
            ax.contour(ux, uy, region.astype(float), levels=[0.5], colors="C3", linewidths=2.0)
        if fastest is not None:
            i, j = fastest
            ax.add_patch(Rectangle((j - 0.5, i - 0.5), 1, 1, fill=False, ec="C0", lw=2.5))
        ax.set_xticks(np.arange(nx), [f"{v:g}" for v in m.x], rotation=45 if nx > 8 else 0)
        ax.set_yticks(np.arange(ny), [f"{v:g}" for v in m.y])
        ax.set_xlim(xe[0], xe[-1])
        ax.set_ylim(ye[0], ye[-1])
        ax.set_xlabel(f"{names[0]} [1/s] (grid points)")
        ax.set_ylabel(f"{names[1]} [1/s] (grid points)")
        ax.set_title(f"{label}, the median of each cell's trials flown to the end", fontsize=10)
    handles = [Patch(facecolor=INADMISSIBLE_COLOR, edgecolor="0.6", label="inadmissible: recorded, not flown")]
    if np.any(not_settled == 1):
        handles.append(Patch(facecolor=NOT_SETTLED_COLOR, label=f"not settled within {spec.duration:g} s"))
    if np.any(status == 2):
        handles.append(Patch(facecolor=DIVERGED_COLOR, label="diverged"))
    if region is not None:
        handles.append(Line2D([], [], color="C3", lw=2.0, label="(41)–(44) hold inside (other gains: the spec's)"))
    else:
        handles.append(Line2D([], [], color="none", label="(41)–(44) region not drawn: other gains vary"))
    if fastest is not None:
        i, j = fastest
        handles.append(Patch(facecolor="none", edgecolor="C0", lw=2.5, label=f"fastest settling: {names[0]} = "
                             f"{m.x[j]:g}, {names[1]} = {m.y[i]:g} 1/s, {m.settling[i, j]:.3g} s, overshoot "
                             f"{m.overshoot[i, j]:.1f} %"))  # fmt: skip
    fig.legend(handles=handles, loc="lower center", ncol=min(len(handles), 3), fontsize=8, frameon=False)
    trials = int(len(table["trial"]) / (nx * ny)) if len(table["trial"]) % (nx * ny) == 0 else None
    per = f", {trials} trials a cell" if trials and trials > 1 else ""
    fig.suptitle(f"The {chan} response over the {nx} × {ny} grid of {names[0]}, {names[1]}{per}\n{_title(spec)}",
                 fontsize=10)  # fmt: skip
    fig.tight_layout(rect=(0, 0.07, 1, 1))
    return _save(fig, out / "fig_sweep_gain_map.png")


def _annotate(ax: plt.Axes, z: np.ndarray, fmt: str) -> None:
    """Each cell's value (where it has one) written in it, dark on a light outline (readable on any colour)."""
    outline = [patheffects.withStroke(linewidth=1.8, foreground="w")]
    for i, j in zip(*np.nonzero(np.isfinite(z))):
        ax.text(j, i, fmt.format(z[i, j]), ha="center", va="center", fontsize=6.5, path_effects=outline)


def write_sweep_figures(out: Path, result: SweepResult) -> list[Path]:
    """Every figure the sweep has data for, into ``out``: the envelopes, the settling histograms, the metrics
    against the varied parameters (less the gain map's two gains), the gain map."""
    spec, table = result.spec, result.table
    names = gain_axes(spec)
    paths = (
        write_envelopes(out, spec, table),
        write_settling_histograms(out, spec, table),
        write_parameter_figure(out, spec, table, exclude=names or ()),
        write_gain_map(out, spec, table),
    )
    return [p for p in paths if p is not None]
