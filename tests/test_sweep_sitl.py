"""``quadsitl sweep --engine sitl``: every trial a whole ``quadsitl fly`` (plant, autopilot and ground station as
processes, MAVLink over UDP, Zenoh telemetry), the same table as the batch engine's to the wire's float32
rounding, trial by trial."""

import math
import textwrap

import numpy as np
import pytest

from groundstation.telemetry_csv import read_csv
from tests.test_diverge import DIVERGING  # one trial stable, one whose roll PD is unstable

pytestmark = [pytest.mark.timeout(300), pytest.mark.usefixtures("batch_engine")]  # the engine compiled first

SPEC = """
    description = "both engines"
    preset = "paper"
    duration = 1.0
    trials = 3
    seed = 5
    keep = [2]
    [vary]
    mismatch.mass = { dist = "uniform", low = 0.8, high = 1.2 }
    mismatch.inertia = { dist = "uniform", low = 0.8, high = 1.2 }
    reference.yaw = { dist = "uniform", low = -1.0, high = 1.0 }
"""


def table(path):
    header, *rows = path.read_text().splitlines()
    names = header.split(",")
    return [dict(zip(names, (float(x) for x in row.split(",")))) for row in rows]


def test_the_sitl_engine_flies_each_trial_through_the_whole_sitl_and_agrees_with_the_batch_engine(cli, tmp_path):
    spec = tmp_path / "both.toml"
    spec.write_text(textwrap.dedent(SPEC))
    r = cli("sweep", str(spec), "--out", str(tmp_path / "batch"), "--workers", "1", "-q", "--no-figures")
    assert r.returncode == 0, r.stderr
    r = cli("sweep", str(spec), "--engine", "sitl", "--out", str(tmp_path / "sitl"), "-q", "--no-figures")
    assert r.returncode == 0, r.stderr
    batch, sitl = table(tmp_path / "batch" / "trials.csv"), table(tmp_path / "sitl" / "trials.csv")
    assert [row["trial"] for row in sitl] == [0, 1, 2]
    masses = [row["mismatch.mass"] for row in batch]
    assert min(masses) < 1.0 < max(masses)  # a model lighter and one heavier than the plant
    for b, s in zip(batch, sitl):
        assert b["mismatch.mass"] == s["mismatch.mass"] and s["diverged"] == 0 and s["ticks"] == 1000
        for ch in ("altitude", "roll", "pitch", "yaw"):
            # times: the same tick, or the next (a sample on the band's edge, in float32)
            for m in ("rise_time", "settling_time"):
                assert abs(b[f"{ch}_{m}"] - s[f"{ch}_{m}"]) <= 0.001 + 1e-12, (b["trial"], ch, m)
            assert s[f"{ch}_overshoot_pct"] == pytest.approx(b[f"{ch}_overshoot_pct"], abs=1e-3)
            assert s[f"{ch}_steady_state_error"] == pytest.approx(b[f"{ch}_steady_state_error"], abs=1e-5)
            assert s[f"{ch}_peak_abs_u"] == pytest.approx(b[f"{ch}_peak_abs_u"], rel=1e-6)
            assert s[f"{ch}_rms_error"] == pytest.approx(b[f"{ch}_rms_error"], rel=1e-4)
        assert s["saturation_time"] == b["saturation_time"]
        # the altitude settles where eq (59) says, through the whole SITL too
        assert math.copysign(1, s["altitude_steady_state_error"]) == math.copysign(1, 1.0 - b["mismatch.mass"])
    # the kept trial: the flight's own telemetry, within float32 of the batch engine's trajectory
    flown = read_csv(tmp_path / "sitl" / "trajectories" / "trial_2.csv")
    r = cli("sweep", str(spec), "--out", str(tmp_path / "kept"), "--workers", "1", "-q", "--no-figures")
    assert r.returncode == 0, r.stderr
    batch_kept = read_csv(tmp_path / "kept" / "trajectories" / "trial_2.csv")
    assert len(flown["t"]) == len(batch_kept["t"]) == 1000
    for column in ("altitude", "roll", "pitch", "yaw"):
        assert np.abs(flown[column] - batch_kept[column]).max() < 1e-3, column
    assert flown["altitude"][0] == 0.0 and flown["u1"][0] == pytest.approx(batch_kept["u1"][0], rel=1e-6)


def test_a_trial_that_diverges_ends_as_diverged_with_its_time_in_both_engines(cli, tmp_path):
    spec = tmp_path / "diverging.toml"
    spec.write_text(textwrap.dedent(DIVERGING))
    for engine in ("batch", "sitl"):
        r = cli("sweep", str(spec), "--engine", engine, "--workers", "1", "--out", str(tmp_path / engine), "-q",
                "--no-figures")  # fmt: skip
        assert r.returncode == 0, r.stderr
    batch, sitl = table(tmp_path / "batch" / "trials.csv"), table(tmp_path / "sitl" / "trials.csv")
    assert [row["diverged"] for row in batch] == [row["diverged"] for row in sitl] == [0, 1]
    assert math.isnan(sitl[0]["diverged_at"]) and sitl[0]["ticks"] == 500
    assert 0.0 < batch[1]["diverged_at"] < 0.1
    assert sitl[1]["diverged_at"] == batch[1]["diverged_at"]  # the same tick (tests/test_diverge.py)
    assert sitl[1]["ticks"] == round(sitl[1]["diverged_at"] / 0.001)
    assert math.isnan(sitl[1]["roll_settling_time"])
