"""``quadsitl sim`` as a user runs it: files, columns, metrics, figures, and one-line errors."""

import json
import math

import numpy as np
import pytest

from groundstation.telemetry_csv import read_csv

REQUIRED = [
    "t", "x", "y", "z", "altitude", "vx", "vy", "vz", "roll", "pitch", "yaw", "p", "q", "r",
    "altitude_ref", "roll_ref", "pitch_ref", "yaw_ref", "u1", "u2", "u3", "u4",
]  # fmt: skip


def test_sim_compare_writes_telemetry_metrics_and_figures(cli, tmp_path):
    out = tmp_path / "run"
    r = cli("sim", "--preset", "paper", "--compare", "--duration", "1.5", "--out", str(out))
    assert r.returncode == 0, r.stderr
    assert "backstepping" in r.stdout and "pd" in r.stdout
    data = read_csv(out / "telemetry.csv")
    assert set(REQUIRED) <= set(data)
    n = len(data["t"])
    assert n == 1500  # one row per control tick
    assert np.allclose(np.diff(data["t"]), 0.001)
    assert np.array_equal(data["altitude"], -data["z"])
    assert data["altitude"][-1] == pytest.approx(5.0, abs=0.01)
    assert data["altitude_ref"][0] == 5.0 and data["roll_ref"][0] == pytest.approx(math.pi / 3)
    # Body rates follow eq (1): at the end everything is at rest.
    assert abs(data["p"][-1]) < 1e-3
    assert len(read_csv(out / "telemetry_pd.csv")["t"]) == 1500
    metrics = json.loads((out / "metrics.json").read_text())
    assert set(metrics["runs"]) == {"backstepping", "pd", "px4"}  # and PX4's cascade, the baseline
    assert len(read_csv(out / "telemetry_px4.csv")["t"]) == 1500
    for name, run in metrics["runs"].items():
        assert set(run) == {"altitude", "roll", "pitch", "yaw"}
        for m in run.values():
            assert {"rise_time", "settling_time", "overshoot_pct", "steady_state_error", "peak_abs_u"} <= set(m)
            if name != "px4":  # the paper's designs: the same rates; PX4's its own (docs/controllers.md)
                assert 0.2 < m["rise_time"] < 0.5
    for fig in ("fig2_outputs.png", "fig3_errors.png", "fig4_inputs.png"):
        assert (out / fig).stat().st_size > 10_000


def test_sim_gains_override_slows_the_altitude(cli, tmp_path):
    r = cli("sim", "--gains", "5,5,10,10,10,10,10,10", "--duration", "2", "--no-figures", "--out", str(tmp_path))
    assert r.returncode == 0, r.stderr
    m = json.loads((tmp_path / "metrics.json").read_text())
    assert m["poles"][0] == pytest.approx(0.995)
    assert m["runs"]["backstepping"]["altitude"]["rise_time"] > 0.6  # half the rate: twice as slow
    assert m["runs"]["backstepping"]["roll"]["rise_time"] < 0.4


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (("--poles", "1.5,0.99,0.99,0.99,0.99,0.99,0.99,0.99"), r"condition (41)"),
        (("--poles", "-10,-10,-10,-10,-10,-10,-10,-10"), r"λ1 = -10"),
        (("--gains", "10,10"), "--gains '10,10': expected 8 comma-separated finite numbers"),
        (("--preset", "nope"), "unknown preset 'nope'; available presets: paper, x500"),
        (("--duration", "-1"), "--duration -1.0: expected a number in (0, 3600]"),
    ],
)
def test_sim_refuses_bad_input_before_simulating(cli, tmp_path, args, message):
    out = tmp_path / "never"
    r = cli("sim", *args, "--out", str(out))
    assert r.returncode == 2
    assert message in r.stderr
    assert "Traceback" not in r.stderr and len(r.stderr.strip().splitlines()) == 1
    assert not out.exists()  # nothing simulated, nothing written


@pytest.mark.parametrize(
    ("module", "prog"),
    [("sitl", "quadsitl plant"), ("autopilot", "quadsitl autopilot"), ("groundstation", "quadsitl gcs")],
)
def test_every_package_runs_as_a_module(cli, module, prog):
    r = cli("--help", module=module)
    assert r.returncode == 0 and f"usage: {prog}" in r.stdout and "examples:" in r.stdout


def test_gains_and_presets_commands(cli):
    r = cli("gains", "--poles", "-10,-10,-10,-10,-10,-10,-10,-10")
    assert r.returncode == 2 and "condition (41)" in r.stderr
    r = cli("gains")
    assert r.returncode == 0 and "conditions (41)–(44) hold for 0.000197005 < ε < 0.019899" in r.stdout
    r = cli("presets")
    assert r.returncode == 0 and "paper" in r.stdout and "x500" in r.stdout
    r = cli("presets", "x500")
    assert r.returncode == 0 and "57.4 % of F_max" in r.stdout
