"""Sweeps of the whole flight controller: specs that name a trajectory, a mission, sensors, wind and integral
gains, flown by the batch engine trial by trial as `quadsitl sim` flies each trial's preset, and by the SITL engine
as whole `quadsitl fly`s: the same table to float32. The two shipped specs, x500-wind-hold and
x500-mission-mismatch, and the spec's refusals of what the vehicle would not fly."""

import json
import textwrap

import numpy as np
import pytest

from groundstation.offline import run_offline
from groundstation.sweep import engine
from groundstation.sweep.run import fly
from groundstation.sweep.spec import load_spec, parse_spec
from groundstation.sweep.trial_row import metrics_row
from groundstation.sweep.trials import trial_preset
from groundstation.telemetry_csv import read_csv
from quadsitl.config import ConfigError

pytestmark = [pytest.mark.timeout(300), pytest.mark.usefixtures("sensor_sim")]  # x500-wind-hold flies sim on sensors

TRACKING = [engine.METRICS.index(n) for n in engine.POSITION_METRICS]


def spec_of(body: str, name: str = "test"):
    return parse_spec(textwrap.dedent(body), name)


@pytest.mark.parametrize("name", ["x500-wind-hold", "x500-mission-mismatch"])
def test_a_shipped_whole_vehicle_sweep_flies_each_trial_as_sim_flies_its_preset(name):
    """The batch engine's trial is `quadsitl sim` on the trial's preset, with the spec's trajectory or mission: its
    kept trajectory is sim's flight to the bit, and its row is the metrics' one definition on sim's telemetry."""
    spec = load_spec(name).with_trials(2)
    assert not spec.fused
    spec = type(spec)(**{**spec.__dict__, "keep": (1,)})
    res = fly(spec, [0, 1])
    preset = trial_preset(spec, 1)
    sims, _ = run_offline(preset, [spec.controller], spec.duration, trajectory=spec.trajectory or "step",
                          mission=spec.mission)  # fmt: skip
    sim = sims[spec.controller]
    assert np.array_equal(res.kept[1][:, engine.K_STATE : engine.K_STATE + 12], sim.state)
    from groundstation.offline import telemetry_rows

    want = metrics_row(telemetry_rows(sim, rates=False), preset, spec.period, sim.diverged_at, spec.mission is not None)
    assert np.array_equal(res.metrics[1], want, equal_nan=True)
    assert np.isfinite(res.metrics[:, TRACKING]).all()  # tracked: a hold, a mission
    assert np.isnan(res.metrics[:, engine.PER_CHANNEL * 0 + engine.SETTLE]).all()  # no step response here
    assert (res.metrics[:, engine.M_DIVERGED] == 0.0).all()
    # What was drawn was flown: the trials' presets differ as their draws do.
    a, b = trial_preset(spec, 0), trial_preset(spec, 1)
    if name == "x500-wind-hold":
        assert a.wind != b.wind and a.sensors.seed != b.sensors.seed and a.sensors is not None
    else:
        assert a.model != b.model


def test_wind_sensors_and_integral_gains_reach_the_trials_preset():
    spec = spec_of("""
        preset = "x500"
        state = "sensors"
        trajectory = "hold:altitude=3,duration=2"
        trials = 1
        [vary]
        wind.speed = 4.0
        wind.from = 90.0
        wind.turbulence = 2
        wind.gust = 1.5
        wind.seed = 7.9
        sensors.noise = 2.0
        sensors.seed = 11
        gains.ki_alt = 0.3
        gains.ki_xy = 0.2
    """)
    p = trial_preset(spec, 0)
    assert (p.wind.speed_m_s, p.wind.from_deg, p.wind.turbulence, p.wind.gust_m_s, p.wind.seed) == (
        4.0, 90.0, "moderate", 1.5, 7)  # fmt: skip
    base = load_spec("x500-wind-hold").preset.sensors
    assert (
        p.sensors.seed == 11
        and p.sensors.gyro_noise_density_rad_s_sqrt_hz == 2.0 * base.gyro_noise_density_rad_s_sqrt_hz
    )
    assert p.sensors.gps_xy_error_m == 2.0 * base.gps_xy_error_m and p.sensors.gps_rate_hz == base.gps_rate_hz
    assert p.position.integral == (0.3, 0.2)
    assert spec.duration == 2.0  # the hold's own length


def test_the_fused_loop_flies_integral_gains_as_sim_does():
    """A calm, true-state spec stays on the fused loop; its integral gains are flown there too."""
    spec = spec_of("""
        preset = "x500"
        duration = 3.0
        trials = 2
        keep = [1]
        [vary]
        gains.ki_alt = { dist = "choice", values = [0.0, 0.8] }
        mismatch.mass = 1.2
    """)
    assert spec.fused
    res = fly(spec, [0, 1])
    preset = trial_preset(spec, 1)
    sims, _ = run_offline(preset, [spec.controller], spec.duration)
    assert np.array_equal(res.kept[1][:, engine.K_STATE : engine.K_STATE + 12], sims[spec.controller].state)


def test_the_fused_loop_flies_a_position_hold_on_the_whole_vehicle_as_sim_does():
    """A position hold on the true state in calm air (the whole vehicle: the position loop, its limits and integral)
    is flown by the fused loop: each trial's kept trajectory is sim's flight to the bit, and its row the metrics'
    one definition on sim's telemetry (to 1e-12: the engine sums as it goes, numpy in pairs); a trial that leaves
    the bounds is marked as sim marks it."""
    spec = spec_of("""
        preset = "x500"
        trajectory = "hold:altitude=3,duration=4,yaw=0.5"
        trials = 4
        keep = [0, 1, 2, 3]
        [vary]
        gains.ki_xy = { dist = "grid", values = [0.0, 0.5] }
        mismatch.mass = { dist = "uniform", low = 0.8, high = 1.2 }
        initial.roll = { dist = "uniform", low = -0.2, high = 0.2 }
    """)
    assert spec.fused and spec.holds
    res = fly(spec, range(4))
    for k in range(4):
        preset = trial_preset(spec, k)
        sims, _ = run_offline(preset, [spec.controller], spec.duration, trajectory=spec.trajectory, metrics=False)
        sim = sims[spec.controller]
        from groundstation.offline import rows_of, telemetry_columns

        assert np.array_equal(res.kept[k], rows_of(sim), equal_nan=True)
        want = metrics_row(telemetry_columns(sim, rates=False), preset, spec.period, sim.diverged_at)
        assert np.allclose(res.metrics[k], want, rtol=1e-12, atol=0.0, equal_nan=True), k
        assert np.isfinite(res.metrics[k, TRACKING]).all()
        assert np.isnan(res.metrics[k, engine.PER_CHANNEL * 0 + engine.SETTLE])  # no step response here
        assert res.metrics[k, engine.M_YAW_TURNS] == 0.0 and res.metrics[k, engine.M_TICKS] == spec.ticks
    # the integral action is flown: the two grid points hold differently
    assert res.metrics[0, TRACKING[0]] != res.metrics[1, TRACKING[0]]


@pytest.mark.parametrize(
    ("body", "says"),
    [
        ("vary.wind.gustiness = 1.0", "unknown key vary.wind.gustiness; allowed:"),
        ("vary.sensors.noise = 2.0", 'vary.sensors.noise with state = "truth"'),
        ('trajectory = "spiral"', "trajectory = 'spiral'"),
        ('trajectory = "circle"\nmission = "m.plan"', "trajectory and mission"),
        ('task = "hover"\ntrajectory = "circle"', "with task = 'hover'"),
        ('mission = "nowhere.plan"', "mission = 'nowhere.plan'"),
        ('controller = "pd"\nvary.gains.ki_alt = 0.5', "vary.gains.ki_alt: the pd controller has no such gain"),
        ("vary.wind.turbulence = 4", "vary.wind.turbulence = 4: its values include 4; expected 0, 1, 2 or 3"),
        ('state = "estimate"', "state = 'estimate'"),
        (
            'trajectory = "circle"\n[limits]\ntilt = 1.0',
            "limits.tilt = 1.0 with trajectory: each trial is a `quadsitl sim`",
        ),
    ],
)
def test_the_spec_refuses_what_the_vehicle_would_not_fly_in_one_line(body, says):
    top, vary = [], []
    for line in body.splitlines():
        (vary if line.startswith("vary.") else top).append(line.removeprefix("vary."))
    text = 'preset = "x500"\n' + "\n".join(top) + "\n[vary]\n" + "\n".join(vary) + "\n"
    with pytest.raises(ConfigError) as exc:
        parse_spec(text, "bad")
    assert says in str(exc.value) and "\n" not in str(exc.value), str(exc.value)


@pytest.mark.parametrize("name", ["x500-mission-mismatch", "x500-wind-hold"])
def test_the_batch_engine_equals_the_sitl_engine_trial_by_trial_on_the_shipped_specs(cli, tmp_path, name):
    """Two trials of each shipped spec through both engines: the batch engine's (each a `quadsitl sim`) and the
    SITL engine's (each a whole `quadsitl fly`: processes, MAVLink, Zenoh). The tables agree to what the wire
    carries: float32 fields, and on sensors the truth in fly's telemetry from HIL_STATE_QUATERNION, whose latitude
    and longitude are integers of 1e-7 deg (about 1 cm; the estimate and the commands agree within 1e-7 m and 5e-5
    N when written); the flights are the same length."""
    tables = {}
    for engine_name in ("batch", "sitl"):
        out = tmp_path / engine_name
        r = cli("sweep", name, "--trials", "2", "--engine", engine_name, "--workers", "1", "--out", str(out), "-q",
                "--no-figures", timeout=280)  # fmt: skip
        assert r.returncode == 0, r.stderr
        tables[engine_name] = read_csv(out / "trials.csv")
        summary = json.loads((out / "summary.json").read_text())
        assert summary["metrics"]["horizontal_rms"]["p50"] is not None
    batch, sitl = tables["batch"], tables["sitl"]
    assert np.array_equal(batch["ticks"], sitl["ticks"])
    quantum = 0.012 if name == "x500-wind-hold" else 1e-4  # [m] (5 mm in horizontal_max when written)
    for column in engine.POSITION_METRICS:
        assert np.allclose(batch[column], sitl[column], rtol=0.0, atol=quantum), (column, batch[column], sitl[column])
    assert np.allclose(batch["saturation_time"], sitl["saturation_time"], atol=0.01)


def test_a_trials_row_is_the_same_from_the_telemetry_rows_and_from_its_columns():
    """The sweep takes a trial's row from its telemetry's columns (groundstation.offline.telemetry_columns), without
    stacking them into rows: the same row as from telemetry.csv's rows, on sensors, a step and a mission."""
    from groundstation.offline import telemetry_columns, telemetry_rows

    for name in ("x500-wind-hold", "x500-mission-mismatch", "paper-mass-mismatch"):
        spec = load_spec(name)
        preset = trial_preset(spec, 1)
        sims, _ = run_offline(preset, [spec.controller], 3.0 if spec.mission is None else None,
                              trajectory=spec.trajectory or "step", mission=spec.mission, metrics=False)  # fmt: skip
        sim = sims[spec.controller]
        mission = spec.mission is not None
        by_rows = metrics_row(telemetry_rows(sim, rates=False), preset, spec.period, sim.diverged_at, mission)
        by_columns = metrics_row(telemetry_columns(sim, rates=False), preset, spec.period, sim.diverged_at, mission)
        assert np.array_equal(by_rows, by_columns, equal_nan=True), name
        assert np.isfinite(by_columns[engine.M_HORIZONTAL_RMS]) == (spec.trajectory is not None or mission)
