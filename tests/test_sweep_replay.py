"""A sweep's trial flown again alone: trial K as a preset of its own (``trial_preset``), whose arrays are the
batch engine's for that trial to the bit, and ``quadsitl sim --from-sweep DIR --trial K``, whose telemetry is the
sweep's kept trajectory of K byte for byte; ``quadsitl fly`` takes the same preset."""

import dataclasses
import json
import textwrap

import numpy as np
import pytest

from groundstation.sweep.spec import load_spec, parse_spec
from groundstation.sweep.trials import draw, nominal, trial_arrays, trial_preset
from quadsitl.config import ConfigError, parse_preset, preset_toml

pytestmark = [pytest.mark.timeout(180), pytest.mark.usefixtures("batch_engine")]  # the engine compiled first

EVERYTHING = """
    preset = "paper"
    controller = "backstepping"
    task = "{task}"
    duration = 0.5
    seed = 11
    trials = 8
    [vary]
    plant.mass = {{ dist = "uniform", low = 1.5, high = 2.5 }}
    plant.k2 = {{ dist = "uniform", low = 0.05, high = 0.2 }}
    model.k5 = {{ dist = "uniform", low = 0.0, high = 0.02 }}
    mismatch.inertia = {{ dist = "normal", mean = 1.0, std = 0.1, low = 0.7, high = 1.3 }}
    mismatch.thrust_factor = {{ dist = "uniform", low = 0.9, high = 1.1 }}
    gains.k3 = {{ dist = "grid", values = [8.0, 12.0] }}
    gains.k6 = {{ dist = "uniform", low = 5.0, high = 15.0 }}
    initial.altitude = {{ dist = "uniform", low = 0.0, high = 1.0 }}
    initial.roll_rate = {{ dist = "uniform", low = -0.5, high = 0.5 }}
    initial.climb_rate = 0.25
    reference.yaw = {{ dist = "choice", values = [-3.0, 0.5, 3.0] }}
"""


def engine_rows(spec, trials):
    a = trial_arrays(spec, draw(spec, np.asarray(trials)), len(trials))
    return a.x0, a.v, a.a, a.vm, a.c, a.r


@pytest.mark.parametrize("task", ["step", "hover"])
def test_a_trial_as_a_preset_is_the_engines_trial_to_the_bit(task):
    spec = parse_spec(textwrap.dedent(EVERYTHING.format(task=task)), "everything")
    rows = engine_rows(spec, list(range(spec.trials)))
    for k in range(spec.trials):
        p = trial_preset(spec, k)
        # through its TOML and back, as `fly --preset` and `sim --preset` read it
        p = parse_preset(preset_toml(p), p.name)
        alone = nominal(dataclasses.replace(spec, preset=p, vary={}, task="step"))
        for name, got, want in zip(("x0", "v", "a", "vm", "c", "r"), alone, rows):
            assert np.array_equal(got, want[k]), (k, name, got, want[k])
    # the model differs from the plant where the spec says so, and only there
    p = trial_preset(spec, 3)
    assert p.autopilot_model.thrust_factor != p.vehicle.thrust_factor and p.autopilot_model.mass == p.vehicle.mass
    assert p.controller.gains[2] in (8.0, 12.0) and p.initial.climb_rate == 0.25
    with pytest.raises(ConfigError, match=r"trial 8: the sweep has 8 trials \(0\.\.7\)"):
        trial_preset(spec, 8)


def test_sim_from_sweep_flies_a_trial_again_to_the_byte_and_fly_takes_its_preset(cli, tmp_path):
    out = tmp_path / "sweep"
    r = cli("sweep", "paper-mass-mismatch", "--trials", "12", "--keep-trial", "9", "--workers", "1", "--out", str(out),
            "--no-figures", "-q")  # fmt: skip
    assert r.returncode == 0, r.stderr
    assert (out / "spec.toml").read_text() == (load_spec("paper-mass-mismatch").text)
    again = tmp_path / "again"
    r = cli("sim", "--from-sweep", str(out), "--trial", "9", "--out", str(again), "--no-figures", "-q")
    assert r.returncode == 0, r.stderr
    assert (again / "telemetry.csv").read_bytes() == (out / "trajectories" / "trial_9.csv").read_bytes()
    # its metrics are the table's row
    header, *rows = (out / "trials.csv").read_text().splitlines()
    row = dict(zip(header.split(","), rows[9].split(",")))
    metrics = json.loads((again / "metrics.json").read_text())["runs"]["backstepping"]
    for ch in ("altitude", "roll", "pitch", "yaw"):
        assert metrics[ch]["settling_time"] == float(row[f"{ch}_settling_time"])
        assert metrics[ch]["steady_state_error"] == pytest.approx(float(row[f"{ch}_steady_state_error"]), abs=1e-15)
    # the trial's preset: the autopilot's model is the mismatched one
    p = parse_preset((again / "preset.toml").read_text(), "trial-9")
    assert p.autopilot_model.mass == p.vehicle.mass * float(row["mismatch.mass"])
    assert p.autopilot_model.ixx == p.vehicle.ixx * float(row["mismatch.inertia"])


REFUSALS = [
    (["--trial", "3"], "--trial goes with --from-sweep DIR"),
    (["--from-sweep", "{out}"], "--from-sweep needs --trial K"),
    (["--from-sweep", "{out}", "--trial", "3", "--preset", "x500"], "--preset does not go with --from-sweep"),
    (["--from-sweep", "{out}", "--trial", "3", "--gains", "1,1,1,1,1,1,1,1"], "--gains does not go with"),
    (["--from-sweep", "{out}", "--trial", "4"], "trial 4: the sweep has 4 trials (0..3)"),
    (["--from-sweep", "{tmp}", "--trial", "0"], "not a sweep's folder (no spec.toml, preset.toml, summary.json"),
]


def test_from_sweep_refusals_are_one_line(cli, tmp_path):
    out = tmp_path / "sweep"
    r = cli("sweep", "paper-mass-mismatch", "--trials", "4", "--workers", "1", "--out", str(out), "-q", "--no-figures")
    assert r.returncode == 0, r.stderr
    for args, message in REFUSALS:
        r = cli("sim", *[a.format(out=out, tmp=tmp_path) for a in args], "--out", str(tmp_path / "sim"))
        assert r.returncode == 2 and r.stderr.count("\n") == 1 and message in r.stderr, (args, r.stderr)
    assert not (tmp_path / "sim").exists()
