"""Monte-Carlo sweeps: the batch engine against ``quadsitl sim``, the steady-state offset of a mass mismatch, the
table whatever the chunking, the spec's refusals, and ``quadsitl sweep`` end to end."""

import json
import math
import textwrap

import numpy as np
import pytest

from groundstation.metrics import channel_outputs, run_metrics, saturation_time
from groundstation.offline import run_offline
from groundstation.sweep import engine
from groundstation.sweep.run import fly, run_sweep
from groundstation.sweep.spec import load_spec, parse_spec
from groundstation.sweep.trials import draw
from quadsitl.config import ConfigError

pytestmark = [pytest.mark.timeout(180), pytest.mark.usefixtures("batch_engine")]  # the engine compiled first


def spec_of(body: str, name: str = "test"):
    return parse_spec(textwrap.dedent(body), name)


def kept_run(kept: np.ndarray, period: float) -> dict:
    """A kept trajectory (engine.KEEP_SIZE columns) as run_metrics' inputs."""
    state = kept[:, engine.K_STATE : engine.K_STATE + 12]
    t = np.arange(len(kept)) * period
    return {"t": t, "state": state, "ref": kept[:, engine.K_REF : engine.K_REF + 4],
            "inputs": kept[:, engine.K_INPUTS : engine.K_INPUTS + 4],
            "forces": kept[:, engine.K_FORCES : engine.K_FORCES + 4]}  # fmt: skip


def assert_metrics_agree(row: np.ndarray, expected: dict) -> None:
    """The engine's on-the-fly metrics (one row of engine.METRICS) equal groundstation.metrics' on the same rows:
    rise and settling times exactly (they are tick counts × T), the others to round-off."""
    for j, ch in enumerate(engine.CHANNELS):
        for q, name in enumerate(engine.STEP_METRICS):
            got, want = row[engine.PER_CHANNEL * j + q], expected[ch][name]
            if want is None:
                assert math.isnan(got), (ch, name, got)
            elif name in ("rise_time", "settling_time"):
                assert got == want, (ch, name, got, want)
            else:
                assert got == pytest.approx(want, rel=1e-9, abs=1e-12), (ch, name)


@pytest.mark.parametrize("controller", ["backstepping", "pd"])
def test_a_trial_with_nothing_varied_is_quadsitl_sims_flight(controller):
    spec = spec_of(f"""
        preset = "paper"
        controller = "{controller}"
        keep = [0]
    """)
    res = fly(spec, [0])
    sims, metrics = run_offline(spec.preset, [controller], spec.duration)
    sim = sims[controller]
    k = kept_run(res.kept[0], spec.period)
    assert k["state"].shape == sim.state.shape == (5000, 12)
    for name, ours, theirs in (("state", k["state"], sim.state), ("reference", k["ref"], sim.reference),
                               ("inputs", k["inputs"], sim.inputs), ("forces", k["forces"], sim.forces)):  # fmt: skip
        worst = np.max(np.abs(ours - theirs) / np.maximum(1.0, np.abs(theirs)))
        assert worst <= 1e-12, f"{name} differs from quadsitl sim by {worst:.3g}"
    assert np.ptp(sim.state[:, 2]) > 4.0  # the paper's step was flown
    assert_metrics_agree(res.metrics[0], metrics[controller])
    assert res.metrics[0, engine.M_DIVERGED] == 0.0 and res.metrics[0, engine.M_TICKS] == 5000


def test_an_x500_trials_energy_is_its_sim_flights_and_the_papers_is_undefined():
    """The battery's energy over a trial (engine.M_ENERGY, from the autopilot's report as the rows have it) equals
    the one :mod:`groundstation.sweep.trial_row` takes from ``quadsitl sim``'s telemetry of the same flight; the
    paper's ideal supply has none."""
    from groundstation.offline import telemetry_columns
    from groundstation.sweep.trial_row import metrics_row

    spec = spec_of("""
        preset = "x500"
        keep = [0]
    """)
    res = fly(spec, [0])
    sims, _ = run_offline(spec.preset, ["backstepping"], spec.duration)
    sim = sims["backstepping"]
    assert np.array_equal(res.kept[0][:, -5:], sim.battery)  # the rows' battery: the autopilot's report, tick by tick
    want = metrics_row(telemetry_columns(sim), spec.preset, spec.period, None)[engine.M_ENERGY]
    energy = res.metrics[0, engine.M_ENERGY]
    assert energy == want
    assert 200.0 * spec.duration < energy < 500.0 * spec.duration  # a 2 kg quadrotor flies on some 300 W
    paper = fly(spec_of('preset = "paper"'), [0])
    assert math.isnan(paper.metrics[0, engine.M_ENERGY])


def test_the_paper_configurations_own_compiled_version_flies_as_the_general_one_to_the_bit(monkeypatch):
    """run_chunk flies the backstepping with one plant step per tick on a version compiled for it (run_trial_paper);
    the general version (run_trial, the controller and step count at run time) flies the same trials to the bit:
    metrics and kept trajectories, with the model mismatched and a trial that diverges."""
    spec = spec_of("""
        preset = "paper"
        trials = 6
        keep = [0, 5]
        [vary]
        mismatch.mass = { dist = "uniform", low = 0.8, high = 1.2 }
        mismatch.inertia = { dist = "choice", values = [0.9, 1.1, 0.02] }
    """)
    calls = []
    monkeypatch.setattr(engine, "_chunk_paper", _counting(engine._chunk_paper, calls))
    paper = fly(spec, range(6))
    assert calls, "the paper's configuration did not run its own version"

    def general_only(x0, v, a, vm, c, r, sp, kind, ticks, period, substeps, method, *rest):
        engine._chunk(x0, v, a, vm, c, r, sp, kind, ticks, period, substeps, method, *rest)

    monkeypatch.setattr(engine, "run_chunk", general_only)
    general = fly(spec, range(6))
    assert np.array_equal(paper.metrics, general.metrics, equal_nan=True)
    assert np.nansum(paper.metrics[:, engine.M_DIVERGED]) >= 1  # a 2 % inertia model: the loop breaks
    for trial in (0, 5):
        assert np.array_equal(paper.kept[trial], general.kept[trial], equal_nan=True)


def _counting(fn, calls: list):
    def counted(*args):
        calls.append(1)
        return fn(*args)

    return counted


def test_on_the_fly_metrics_equal_the_post_processed_ones_with_overshoot_yaw_across_pi_and_saturation():
    """Hover at yaw −3.0 from yaw 3.0 (the short way crosses ±π: numpy.unwrap's branch, flown a second time on it),
    a slow PD (overshoot), realistic motors (saturation)."""
    spec = spec_of("""
        preset = "x500"
        controller = "pd"
        task = "hover"
        duration = 4.0
        keep = [0, 1, 2]
        trials = 3
        [vary]
        initial.yaw = 3.0
        reference.yaw = -3.0
        initial.altitude = { dist = "uniform", low = 0.0, high = 1.0 }
        initial.roll = { dist = "uniform", low = -0.6, high = 0.6 }
        gains.kd1 = { dist = "uniform", low = 1.0, high = 2.0 }
    """)
    res = fly(spec, [0, 1, 2])
    for i in range(3):
        k = kept_run(res.kept[i], spec.period)
        y = channel_outputs(k["state"])
        assert y[-1, 3] > math.pi  # the unwrapped yaw went past π
        expected = run_metrics(k["t"], y, k["ref"], k["inputs"])
        assert_metrics_agree(res.metrics[i], expected)
        assert expected["altitude"]["overshoot_pct"] > 1.0
        assert res.metrics[i, engine.M_YAW_TURNS] == 1.0
        f = k["forces"]
        saturated = np.count_nonzero((f.min(axis=1) <= 0.0) | (f.max(axis=1) >= spec.preset.actuators.max_thrust))
        assert saturated > 0 and res.metrics[i, engine.M_SATURATED] == pytest.approx(saturated * spec.period)
        # the post-processed definition the SITL engine uses counts the same ticks
        c, a = spec.preset.controller, spec.preset.actuators
        bounds = ((c.thrust_min, c.thrust_max), (a.min_thrust, a.max_thrust))
        assert saturation_time(k["inputs"], f, spec.period, *bounds) == res.metrics[i, engine.M_SATURATED]


def test_a_mass_mismatch_without_integral_action_leaves_the_altitude_off_by_eq_59():
    """The autopilot's model mass m̂ against the plant's m: the hover settles e1 = (m̂ − m)·g/(m̂·k1·k2) above its
    reference (docs/position.md, eq (59); paper preset: no integral action), trial by trial."""
    spec = spec_of("""
        preset = "paper"
        trials = 8
        seed = 7
        [vary]
        mismatch.mass = { dist = "uniform", low = 0.8, high = 1.2 }
        mismatch.inertia = { dist = "uniform", low = 0.8, high = 1.2 }
    """)
    result = run_sweep(spec)
    t = result.table
    p = spec.preset
    m, g = p.vehicle.mass, p.vehicle.gravity
    k1, k2 = p.controller.gains[0], p.controller.gains[1]
    m_hat = m * t["mismatch.mass"]
    assert np.ptp(m_hat) > 0.2  # the draws spread
    e1 = (m_hat - m) * g / (m_hat * k1 * k2)
    # steady-state error = reference − output = −e1
    assert np.allclose(t["altitude_steady_state_error"], -e1, rtol=0, atol=1e-9)
    assert np.max(np.abs(e1)) > 0.015  # centimetres: not round-off
    for ch in ("roll", "pitch", "yaw"):  # a wrong inertia leaves no offset
        assert np.all(np.abs(t[f"{ch}_steady_state_error"]) < 1e-9)


def test_the_table_is_the_same_however_the_trials_are_chunked_and_over_how_many_workers():
    spec = spec_of("""
        preset = "paper"
        duration = 0.3
        trials = 24
        seed = 11
        [vary]
        plant.mass = { dist = "normal", mean = 2.0, std = 0.2, low = 1.5, high = 2.5 }
        plant.k3 = { dist = "choice", values = [0.0, 0.1, 0.5] }
        mismatch.izz = { dist = "uniform", low = 0.9, high = 1.1 }
        gains.k1 = { dist = "grid", values = [5.0, 10.0, 20.0] }
        initial.pitch = { dist = "uniform", low = -0.2, high = 0.2 }
    """)
    one = run_sweep(spec, workers=1, chunk=24).table
    for workers, chunk in ((1, 5), (2, 7)):
        other = run_sweep(spec, workers=workers, chunk=chunk).table
        assert list(other) == list(one)
        for name in one:
            assert np.array_equal(one[name], other[name], equal_nan=one[name].dtype.kind == "f"), name
    assert np.array_equal(one["trial"], np.arange(24))
    assert np.array_equal(one["gains.k1"][:6], [5.0, 10.0, 20.0, 5.0, 10.0, 20.0])  # trial i: grid point i mod 3
    assert len(np.unique(one["plant.mass"])) == 24 and np.all(np.abs(one["plant.mass"] - 2.0) <= 0.5)


def test_a_trials_draws_depend_on_the_seed_and_its_number_only():
    spec = spec_of("""
        preset = "paper"
        trials = 40
        seed = 3
        [vary]
        mismatch.mass = { dist = "uniform", low = 0.8, high = 1.2 }
        initial.roll = { dist = "normal", mean = 0.0, std = 0.1, low = -0.3, high = 0.3 }
    """)
    together = draw(spec, np.arange(40))
    for i in (0, 17, 39):
        alone = draw(spec, [i])
        assert all(alone[k][0] == together[k][i] for k in together)
    backwards = draw(spec, np.arange(40)[::-1])
    assert all(np.array_equal(backwards[k][::-1], together[k]) for k in together)
    other = draw(
        parse_spec(
            textwrap.dedent("""
        preset = "paper"
        seed = 4
        [vary]
        mismatch.mass = { dist = "uniform", low = 0.8, high = 1.2 }
        initial.roll = { dist = "normal", mean = 0.0, std = 0.1, low = -0.3, high = 0.3 }
    """)
        ),
        np.arange(40),
    )
    assert not np.any(other["mismatch.mass"] == together["mismatch.mass"])


def test_a_trial_that_leaves_its_bounds_ends_there_as_diverged():
    """limits.tilt = 0.5 rad on the paper's step to π/3: the trial ends at the first tick whose roll is past 0.5."""
    spec = spec_of("""
        preset = "paper"
        duration = 1.0
        keep = [0]
        [limits]
        tilt = 0.5
    """)
    res = fly(spec, [0])
    sims, _ = run_offline(spec.preset, ["backstepping"], 1.0)
    first = int(np.flatnonzero(np.abs(sims["backstepping"].state[:, 6]) >= 0.5)[0])
    m = res.metrics[0]
    assert m[engine.M_DIVERGED] == 1.0 and m[engine.M_DIVERGED_AT] == pytest.approx(first * spec.period)
    assert m[engine.M_TICKS] == first and 50 < first < 1000
    assert math.isnan(m[engine.SETTLE]) and m[engine.PEAK_U] > 0


def test_gains_that_break_41_44_are_recorded_and_not_flown_when_the_spec_says_so():
    spec = spec_of("""
        preset = "paper"
        duration = 0.2
        inadmissible = "record"
        [vary]
        gains.k1 = { dist = "grid", values = [10.0, 2100.0] }
    """)
    t = run_sweep(spec).table
    assert list(t["admissible"]) == [True, False]
    assert not math.isnan(t["altitude_peak_abs_u"][0]) and math.isnan(t["altitude_peak_abs_u"][1])
    with pytest.raises(ConfigError, match=r"inadmissible gains .*gains\.k1.*condition \(41\).*λ1 = -1\.1"):
        spec_of("""
            preset = "paper"
            [vary]
            gains.k1 = { dist = "uniform", low = 10.0, high = 2100.0 }
        """)


@pytest.mark.parametrize(
    ("body", "message"),
    [
        ('preset = "paper"\ntrails = 3', "unknown key 'trails'; allowed: preset, controller"),
        ('preset = "paper"\n[vary]\nplant.mas = 2.0', "unknown key vary.plant.mas; allowed: plant.mass"),
        (
            'preset = "paper"\n[vary]\nplant.mass = { dist = "uniform", low = 2.5, high = 1.5 }',
            "vary.plant.mass.high = 1.5: expected a number above low = 2.5",
        ),
        (
            'preset = "paper"\n[vary]\nplant.mass = { dist = "uniform", low = -0.5, high = 1.5 }',
            "vary.plant.mass = {'dist': 'uniform', 'low': -0.5, 'high': 1.5}: it can reach -0.5; expected a number > 0",
        ),
        (
            'preset = "paper"\n[vary]\nplant.mass = { dist = "normal", mean = 2.0, std = 0.1 }',
            "it can reach -inf; expected a number > 0 (give a normal distribution bounds: low, high)",
        ),
        (
            'preset = "paper"\n[vary]\nplant.mass = { dist = "gauss", mean = 2.0 }',
            "vary.plant.mass.dist = 'gauss': expected one of fixed, uniform, normal, grid, choice",
        ),
        ('preset = "paper"\n[vary]\nmismatch.mass = 1.1\nmodel.mass = 2.0', "vary.model.mass with vary.mismatch.mass"),
        ('preset = "paper"\n[vary]\ngains.kp1 = 5.0', "vary.gains.kp1: the backstepping controller has no such gain"),
        (
            'preset = "paper"\ntrials = 5\n[vary]\ngains.k1 = { dist = "grid", values = [5.0, 10.0] }',
            "trials = 5: the grid has 2 points; expected a multiple of 2",
        ),
        (
            'preset = "paper"\n[vary]\ninitial.roll = { dist = "choice", values = [0.1, 2.0] }',
            "its values include 2; expected a number in (−π/2, π/2) [rad]",
        ),
        ('preset = "nope"', "preset = 'nope': unknown preset 'nope'; available presets: paper, x500"),
        ('preset = "paper"\n[limits]\ntilt = -1.0', "limits.tilt = -1.0: expected a finite number > 0"),
    ],
)
def test_bad_spec_input_is_refused_in_one_line_naming_key_value_and_what_is_allowed(body, message):
    with pytest.raises(ConfigError) as info:
        parse_spec(body, "bad")
    text = str(info.value)
    assert text.startswith("sweep spec 'bad': ") and message in text and "\n" not in text, text


def test_shipped_specs_load_and_the_readmes_is_among_them():
    spec = load_spec("paper-mass-mismatch")
    assert spec.trials >= 1000 and spec.duration == 5.0 and set(spec.vary) == {"mismatch.mass", "mismatch.inertia"}
    grid = load_spec("paper-gain-grid")
    assert grid.grid_size == grid.trials == 144 and grid.inadmissible == "record"


def test_quadsitl_sweep_end_to_end(cli, tmp_path):
    import pyarrow.parquet as pq

    spec = tmp_path / "tiny.toml"
    spec.write_text(
        textwrap.dedent("""
        description = "tiny"
        preset = "paper"
        duration = 0.4
        trials = 6
        seed = 5
        [vary]
        mismatch.mass = { dist = "uniform", low = 0.9, high = 1.1 }
    """)
    )
    out = tmp_path / "out"
    r = cli("sweep", str(spec), "--out", str(out), "--workers", "1", "--keep", "2", "--json", "--no-figures")
    assert r.returncode == 0, r.stderr
    summary = json.loads(r.stdout)
    assert summary == json.loads((out / "summary.json").read_text())
    assert summary["trials"] == summary["flown"] == 6 and summary["diverged"] == 0 and summary["failure_rate"] == 0
    assert summary["varied"] == {"mismatch.mass": {"dist": "uniform", "low": 0.9, "high": 1.1}}
    assert len(summary["worst"]) == 6 and set(summary["worst"][0]["parameters"]) == {"mismatch.mass"}
    med = summary["metrics"]["altitude_rise_time"]
    assert med["p5"] <= med["p50"] <= med["p95"] and 0.2 < med["p50"] < 0.4
    table = pq.read_table(out / "trials.parquet").to_pydict()
    assert table["trial"] == list(range(6))
    rows = (out / "trials.csv").read_text().splitlines()
    assert rows[0].split(",")[:3] == ["trial", "mismatch.mass", "admissible"] and len(rows) == 7
    assert [float(row.split(",")[1]) for row in rows[1:]] == table["mismatch.mass"]
    assert sorted(p.name for p in (out / "trajectories").iterdir()) == ["trial_0.csv", "trial_1.csv"]
    header = (out / "trajectories" / "trial_1.csv").read_text().splitlines()[0]
    assert header.startswith("t,x,y,z,altitude,")
    # by name, and refusals in one line
    r = cli("sweep", "paper-mass-mismatch", "--trials", "2", "--workers", "1", "--out", str(tmp_path / "b"), "-q")
    assert r.returncode == 0 and r.stdout == "", r.stderr
    assert len((tmp_path / "b" / "trials.csv").read_text().splitlines()) == 3
    r = cli("sweep", "no-such-spec", "--out", str(tmp_path / "c"))
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and "shipped specs: paper-gain-grid, paper-mass-mismatch" \
        in r.stderr, r.stderr  # fmt: skip


def test_the_table_is_assembled_only_from_every_trial_exactly_once():
    """The chunks' results come back in any order (a cluster's as they complete): the table is in trial order,
    and a chunk missing or come back twice (a lost worker's, flown again) is an error, never a table."""
    from groundstation.sweep.run import SweepError, assemble

    spec = spec_of("""
        preset = "paper"
        duration = 0.05
        trials = 5
        [vary]
        mismatch.mass = { dist = "uniform", low = 0.9, high = 1.1 }
    """)
    a, b = fly(spec, [0, 1, 2]), fly(spec, [3, 4])
    table = assemble(spec, [b, a], 1.0, {"cluster": None, "workers": 1}).table
    assert np.array_equal(table["trial"], np.arange(5))
    drawn = np.concatenate([a.params["mismatch.mass"], b.params["mismatch.mass"]])
    assert np.array_equal(table["mismatch.mass"], drawn)
    with pytest.raises(SweepError, match=r"every trial 0\.\.4 exactly once: missing: 3, 4$"):
        assemble(spec, [a], 1.0, {})
    with pytest.raises(SweepError, match=r"exactly once: more than once: 3, 4$"):
        assemble(spec, [b, a, b], 1.0, {})
    with pytest.raises(SweepError, match=r"exactly once: missing: 0, 1, 2; not in the sweep: 7$"):
        assemble(spec, [b, fly(spec, [7])], 1.0, {})
