"""The sweep's figures: the data behind them (the envelopes' percentiles, the sample flown again, the histograms'
bins, the gain map and its (41)–(44) region) checked without drawing, and ``quadsitl sweep`` writing the PNGs."""

import dataclasses
import math
import struct
import textwrap

import numpy as np
import pytest

from autopilot.gains import GainError, stability_interval
from groundstation.sweep import engine
from groundstation.sweep import figures as figs
from groundstation.sweep.run import run_sweep
from groundstation.sweep.spec import load_spec, parse_spec
from groundstation.sweep.trials import draw, nominal_poles, trial_arrays

pytestmark = [pytest.mark.timeout(180), pytest.mark.usefixtures("batch_engine")]  # the engine compiled first


def spec_of(body: str, name: str = "test"):
    return parse_spec(textwrap.dedent(body), name)


def table_of(n: int, admissible=None, diverged=None) -> dict[str, np.ndarray]:
    """A made-up table of n trials: only what choose_sample reads."""
    return {
        "trial": np.arange(n),
        "admissible": np.ones(n, bool) if admissible is None else np.asarray(admissible),
        "diverged": np.zeros(n, bool) if diverged is None else np.asarray(diverged),
    }


def test_the_envelope_is_the_5_50_95_percentiles_across_trials_at_each_time():
    """101 trials y_i(t) = (i/100)·sin(t) + c, in shuffled order: at each t the p-th percentile is (p/100)·sin(t) + c
    (numpy's linear percentiles of 0, 0.01, …, 1 land on trials)."""
    t = np.linspace(0.1, 3.0, 50)
    y = np.arange(101)[:, None] / 100 * np.sin(t)[None, :] + 2.0
    y = y[np.random.default_rng(0).permutation(101)]
    p5, p50, p95 = figs.envelope(y)
    assert np.allclose(p5, 0.05 * np.sin(t) + 2.0, rtol=0, atol=1e-12)
    assert np.allclose(p50, 0.50 * np.sin(t) + 2.0, rtol=0, atol=1e-12)
    assert np.allclose(p95, 0.95 * np.sin(t) + 2.0, rtol=0, atol=1e-12)
    assert figs.envelope(y, (0, 100)).tolist() == [y.min(axis=0).tolist(), y.max(axis=0).tolist()]


def test_the_sample_is_deterministic_spread_capped_and_skips_trials_not_flown_to_the_end():
    n = 1000
    admissible = np.ones(n, bool)
    admissible[::7] = False
    diverged = np.zeros(n, bool)
    diverged[3::11] = True
    table = table_of(n, admissible, diverged)
    sample = figs.choose_sample(table, 200)
    assert np.array_equal(sample, figs.choose_sample(table, 200))  # deterministic
    assert len(sample) == len(np.unique(sample)) == 200  # capped, no trial twice
    assert np.all(admissible[sample]) and not np.any(diverged[sample])  # only trials flown to the end
    eligible = np.flatnonzero(admissible & ~diverged)
    assert sample[0] == eligible[0] and sample[-1] == eligible[-1]  # spread: from the first to the last
    gaps = np.diff(sample)
    assert gaps.max() <= 2 * n / 200 + 1  # evenly: no stretch of the trials left out
    assert np.array_equal(np.searchsorted(eligible, sample), np.linspace(0, len(eligible) - 1, 200).round())
    few = table_of(50, diverged=np.arange(50) % 2 == 1)
    assert figs.choose_sample(few, 200).tolist() == list(range(0, 50, 2))  # fewer than the cap: all of them
    assert figs.choose_sample(table_of(5, admissible=np.zeros(5, bool)), 200).size == 0


def test_decimation_keeps_evenly_spaced_ticks_at_an_even_stride():
    assert figs.decimate(300, 400).tolist() == list(range(300))  # fewer ticks than points: all
    for ticks in (5000, 3000, 4001, 60_000):
        kept = figs.decimate(ticks, 400)
        stride = np.diff(kept)
        assert len(kept) <= 400 and kept[0] == 0 and kept[-1] >= ticks - stride[0]
        assert np.all(stride == stride[0]) and stride[0] % 2 == 0


def test_histogram_bins_hold_whole_ticks():
    T = 0.001
    values = np.array([512, 513, 513, 520, 600, 655]) * T
    edges = figs.tick_bins(values, T, target=40)
    width = np.diff(edges)
    assert np.allclose(width, width[0]) and np.isclose(width[0] / T, round(width[0] / T))  # whole ticks a bin
    assert edges[0] < values.min() < edges[1] and edges[-2] < values.max() < edges[-1]
    # every tick falls inside a bin, not on an edge
    ticks = np.arange(512, 656) * T
    position = (ticks - edges[0]) / width[0]
    assert np.all(np.abs(position - np.round(position)) > 1e-6)
    one = figs.tick_bins(np.array([0.581, 0.581]), T)
    assert len(one) == 2 and one[0] < 0.581 < one[1]


def test_the_parameter_figure_draws_the_settling_times_that_exist_and_the_steady_state_errors_that_vary():
    """Made-up table of 300 trials: altitude and roll have a step (roll never settles), pitch and yaw none; the
    altitude's steady-state error spreads over centimetres, the others only by round-off."""
    n = 300
    rng = np.random.default_rng(1)
    table = table_of(n)
    nan = np.full(n, math.nan)
    table.update({
        "altitude_overshoot_pct": rng.uniform(0, 1, n), "altitude_settling_time": rng.uniform(0.5, 0.6, n),
        "roll_overshoot_pct": rng.uniform(0, 1, n), "roll_settling_time": nan,
        "pitch_overshoot_pct": nan, "pitch_settling_time": nan, "yaw_overshoot_pct": nan, "yaw_settling_time": nan,
        "altitude_steady_state_error": rng.uniform(-0.02, 0.02, n), "roll_steady_state_error": rng.normal(0, 1e-12, n),
        "pitch_steady_state_error": np.zeros(n), "yaw_steady_state_error": rng.normal(0, 1e-9, n),
    })  # fmt: skip
    assert figs.step_channels(table) == [0, 1]
    assert [c for c, _label in figs.parameter_metrics(table)] == [
        "altitude_settling_time",
        "altitude_steady_state_error",
    ]
    spec = load_spec("paper-mass-mismatch")
    assert figs.varied_parameters(spec) == ["mismatch.inertia", "mismatch.mass"]


@pytest.fixture(scope="module")
def gain_grid():
    """The shipped 12 × 12 grid of k1, k2 (inadmissible points recorded), flown for 0.3 s a trial."""
    spec = load_spec("paper-gain-grid")
    spec = dataclasses.replace(spec, duration=0.3)
    return spec, run_sweep(spec).table


def test_the_gain_maps_admissibility_is_the_specs_own_check_at_the_grids_points(gain_grid):
    spec, table = gain_grid
    names = figs.gain_axes(spec)
    assert names == ("gains.k1", "gains.k2")
    m = figs.gain_map(spec, table, names)
    assert m.x.tolist() == m.y.tolist() == list(spec.vary["gains.k1"].values)
    mask = figs.admissible_mask(spec, names, m.x, m.y)
    assert mask.shape == (12, 12)
    # the cells recorded inadmissible in the table are exactly those the mask refuses
    recorded = np.zeros((12, 12), bool)
    recorded[np.searchsorted(m.y, table["gains.k2"]), np.searchsorted(m.x, table["gains.k1"])] = table["admissible"]
    assert np.array_equal(mask, recorded) and np.array_equal(m.flown, recorded)
    assert 0 < np.count_nonzero(~mask) < 144  # both kinds are there
    # and the mask is stability_interval on the poles, the other gains at the preset's
    T = spec.period
    for i, k2 in enumerate(m.y):
        for j, k1 in enumerate(m.x):
            poles = (1 - T * k1, 1 - T * k2, *nominal_poles(spec)[2:])
            try:
                stability_interval(poles, T)
                ok = True
            except GainError:
                ok = False
            assert mask[i, j] == ok, (k1, k2)
    # the finer grid: the boundary of |λ1| < 1 (k1 < 2/T = 2000 1/s) falls between the grid points 1999 and 2100
    u = figs.fine_axis(12)
    gains = figs.index_values(u, m.x)
    assert gains[0] < 1.0 < 2100.0 < gains[-1] and np.all(np.diff(gains) > 0)
    assert np.allclose(figs.index_values(np.arange(12.0), m.x), m.x, rtol=1e-12)
    fine = figs.admissible_mask(spec, names, gains, np.array([10.0]))[0]
    assert np.all(fine[(gains > 1.0) & (gains < 1999.5)]) and not np.any(fine[gains > 2000.0])


def test_the_gain_map_cells_are_the_medians_of_their_trials(gain_grid):
    spec, table = gain_grid
    m = figs.gain_map(spec, table, ("gains.k1", "gains.k2"))
    for i, j in ((3, 3), (7, 2), (0, 0), (11, 4)):
        at = (table["gains.k1"] == m.x[j]) & (table["gains.k2"] == m.y[i])
        assert at.sum() == 1
        st, ov = table["altitude_settling_time"][at][0], table["altitude_overshoot_pct"][at][0]
        if not table["admissible"][at][0]:
            assert not m.flown[i, j] and math.isnan(m.settling[i, j]) and math.isnan(m.overshoot[i, j])
        else:
            assert m.settling[i, j] == (st if math.isfinite(st) else math.inf) and m.overshoot[i, j] == ov
    # repeats of the grid: medians over them (a draw varies across the repeats)
    rep = spec_of("""
        preset = "paper"
        duration = 0.2
        trials = 12
        [vary]
        gains.k1 = { dist = "grid", values = [10.0, 40.0] }
        gains.k2 = { dist = "grid", values = [10.0, 40.0] }
        mismatch.mass = { dist = "uniform", low = 0.8, high = 1.2 }
    """)
    t = run_sweep(rep).table
    m = figs.gain_map(rep, t, ("gains.k1", "gains.k2"))
    at = (t["gains.k1"] == 40.0) & (t["gains.k2"] == 10.0)
    assert at.sum() == 3
    assert m.overshoot[0, 1] == np.median(t["altitude_overshoot_pct"][at])
    assert figs.varied_parameters(rep, ("gains.k1", "gains.k2")) == ["mismatch.mass"]


def test_the_gain_map_needs_two_gains_on_the_grid_and_draws_no_region_when_another_gain_varies():
    one = spec_of('preset = "paper"\n[vary]\ngains.k1 = { dist = "grid", values = [5.0, 10.0] }')
    assert figs.gain_axes(one) is None
    other = spec_of("""
        preset = "paper"
        trials = 4
        [vary]
        gains.k3 = { dist = "grid", values = [5.0, 10.0] }
        gains.k4 = { dist = "grid", values = [5.0, 10.0] }
        gains.k1 = { dist = "uniform", low = 5.0, high = 20.0 }
    """)
    assert figs.gain_axes(other) == ("gains.k3", "gains.k4") and figs.gain_channels(("gains.k3", "gains.k4")) == [1]
    assert figs.admissible_mask(other, ("gains.k3", "gains.k4"), np.array([5.0]), np.array([5.0])) is None
    fixed = spec_of("""
        preset = "paper"
        inadmissible = "record"
        [vary]
        gains.k3 = { dist = "grid", values = [5.0, 10.0] }
        gains.k4 = { dist = "grid", values = [5.0, 10.0] }
        gains.k1 = 0.133
    """)
    # k1 = 0.133 1/s (λ1 = 0.999867) needs ε > 0.0150: k4 = 10 1/s allows ε < 0.0199, k4 = 5 1/s only ε < 0.00997.
    # The fixed k1 is the one checked (at the preset's k1 = 10 all four points pass), as the trials are.
    x = y = np.array([5.0, 10.0])
    mask = figs.admissible_mask(fixed, ("gains.k3", "gains.k4"), x, y)
    assert mask.tolist() == [[False, False], [True, True]]
    flown = trial_arrays(fixed, draw(fixed, np.arange(4)), 4).admissible  # k3 slowest: (5, 5), (5, 10), (10, 5), …
    assert flown.reshape(2, 2).T.tolist() == mask.tolist()


def test_the_sample_flown_again_is_the_sweeps_own_flights_to_the_bit():
    """The trials flown again in batches (reflown) give exactly the trajectories a sweep keeps with --keep."""
    spec = spec_of("""
        preset = "paper"
        duration = 0.4
        trials = 30
        seed = 9
        [vary]
        mismatch.mass = { dist = "uniform", low = 0.8, high = 1.2 }
        initial.roll = { dist = "uniform", low = -0.3, high = 0.3 }
    """)
    trials = np.array([0, 4, 5, 17, 29])
    kept = run_sweep(dataclasses.replace(spec, keep=tuple(trials.tolist())), chunk=7).kept
    again = dict(figs.reflown(spec, trials))
    assert sorted(again) == trials.tolist()
    for k in trials.tolist():
        assert again[k].shape == kept[k].shape == (spec.ticks, engine.KEEP_SIZE)
        assert np.array_equal(again[k], kept[k], equal_nan=True), k  # x_ref, y_ref: NaN (not controlled)
    # a sweep flown with the SITL engine has its sample flown again on the batch engine (not a `fly` a trial)
    sitl = dict(figs.reflown(dataclasses.replace(spec, engine="sitl"), trials[:2]))
    assert all(np.array_equal(sitl[k], kept[k], equal_nan=True) for k in trials[:2].tolist())
    s = figs.sample_outputs(spec, trials, points=50)
    ticks = figs.decimate(spec.ticks, 50)
    assert s.outputs.shape == (5, len(ticks), 4) and np.allclose(s.t, ticks * spec.period)
    assert np.array_equal(s.outputs[3, :, 0], -kept[17][ticks, 2])  # the altitude, −z
    assert np.array_equal(s.outputs[3, :, 1], kept[17][ticks, 6])  # the roll
    assert np.allclose(s.reference[:, 0], 5.0) and np.allclose(s.reference[:, 3], math.pi / 3)


def test_eq_59s_line_is_drawn_only_where_it_holds():
    spec = load_spec("paper-mass-mismatch")
    line = figs.eq59_steady_state_error(spec, np.array([0.8, 1.0, 1.2]))
    assert line == pytest.approx([0.2 * 9.8 / (0.8 * 100), 0.0, -0.2 * 9.8 / (1.2 * 100)])
    gains = spec_of('preset = "paper"\n[vary]\ngains.k1 = { dist = "uniform", low = 5.0, high = 20.0 }')
    assert figs.eq59_steady_state_error(gains, np.array([1.1])) is None
    pd = spec_of('preset = "paper"\ncontroller = "pd"')
    assert figs.eq59_steady_state_error(pd, np.array([1.1])) is None


def png_size(path) -> tuple[int, int]:
    """(width, height) from a PNG's header, which must be a PNG's."""
    head = path.read_bytes()[:24]
    assert head[:8] == b"\x89PNG\r\n\x1a\n" and head[12:16] == b"IHDR", path
    return struct.unpack(">II", head[16:24])


def test_quadsitl_sweep_writes_its_figures_and_no_figures_writes_none(cli, tmp_path):
    spec = tmp_path / "small.toml"
    spec.write_text(
        textwrap.dedent("""
        preset = "paper"
        duration = 0.8
        trials = 24
        seed = 1
        inadmissible = "record"
        [vary]
        gains.k1 = { dist = "grid", values = [5.0, 10.0, 2100.0] }
        gains.k2 = { dist = "grid", values = [10.0, 50.0] }
        mismatch.mass = { dist = "uniform", low = 0.8, high = 1.2 }
    """)
    )
    out = tmp_path / "out"
    r = cli("sweep", str(spec), "--out", str(out), "--workers", "1")
    assert r.returncode == 0, r.stderr
    names = ["fig_sweep_envelopes.png", "fig_sweep_settling.png", "fig_sweep_parameters.png", "fig_sweep_gain_map.png"]
    for name in names:
        w, h = png_size(out / name)
        assert 600 <= w <= 3000 and 400 <= h <= 3000, (name, w, h)
        assert (out / name).stat().st_size > 20_000, name
        assert name in r.stdout  # reported with the other files
    assert sorted(p.name for p in out.glob("*.png")) == sorted(names)
    wrote = r.stdout.splitlines()[-1]
    assert "spec.toml, preset.toml" in wrote and "trajector" not in wrote  # none kept: none counted
    bare = tmp_path / "bare"
    r = cli("sweep", str(spec), "--out", str(bare), "--workers", "1", "--no-figures")
    assert r.returncode == 0, r.stderr
    assert not list(bare.glob("*.png")) and (bare / "trials.csv").exists()
    assert "fig_" not in r.stdout
