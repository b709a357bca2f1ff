"""The Python API (groundstation/api.py through ``import quadsitl``): docs/python.md's code runs as written, sim's
DataFrame is the command's telemetry.csv, a refusal is the command's one line, and the vehicle to step refuses
garbage."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import quadsitl

ROOT = Path(__file__).resolve().parent.parent
PAGE = ROOT / "docs" / "python.md"


def blocks() -> list[str]:
    return re.findall(r"```python\n(.*?)```", PAGE.read_text(encoding="utf-8"), flags=re.S)


@pytest.mark.parametrize("index", range(len(blocks())))
def test_the_pages_code_runs_as_written(index, capsys):
    exec(compile(blocks()[index], f"{PAGE.name}[{index}]", "exec"), {})
    assert capsys.readouterr().out.strip()  # each example prints what it shows


def test_sim_gives_the_commands_telemetry_csv(tmp_path):
    flight = quadsitl.sim("paper", duration=0.5, compare=True)
    r = subprocess.run([sys.executable, "-m", "groundstation.cli", "sim", "--preset", "paper", "--duration", "0.5",
                        "--compare", "--no-figures", "-q", "--out", str(tmp_path)], capture_output=True, text=True,
                       timeout=300)  # fmt: skip
    assert r.returncode == 0, r.stderr
    assert set(flight.runs) == {"backstepping", "pd", "px4"}
    csv = pd.read_csv(tmp_path / "telemetry.csv")
    pd.testing.assert_frame_equal(flight.telemetry, csv)
    pd.testing.assert_frame_equal(flight.runs["px4"], pd.read_csv(tmp_path / "telemetry_px4.csv"))
    assert len(csv) == 500 and flight.metrics["runs"]["backstepping"]["altitude"]["peak_abs_u"] > 0


def test_refusals_are_the_commands_one_line():
    with pytest.raises(ValueError, match=r"^quadsitl sim: .*--duration 0.0") as err:
        quadsitl.sim("paper", duration=0.0)
    assert "\n" not in str(err.value)
    with pytest.raises(ValueError, match=r"invalid choice: 'gale'"):
        quadsitl.sim("x500", turbulence="gale")
    with pytest.raises(TypeError):
        quadsitl.sim("x500", speed=2)  # not an option of sim: Python's own refusal


def test_the_vehicle_to_step_refuses_a_command_that_is_not_four_finite_numbers():
    vehicle = quadsitl.Vehicle("x500")
    x0 = vehicle.reset()
    for bad in ((1.0, 0.0, 0.0), (np.nan, 0.0, 0.0, 0.0), (1.0, np.inf, 0.0, 0.0)):
        with pytest.raises(ValueError, match="expected 4 finite numbers"):
            vehicle.step(bad)
    assert np.array_equal(vehicle.plant.x, x0) and vehicle.t == 0.0  # nothing flown
    hover = vehicle.preset.vehicle.mass * vehicle.preset.vehicle.gravity
    for _ in range(200):  # the motors spin up (their lag), then it climbs
        x = vehicle.step((1.5 * hover, 0.0, 0.0, 0.0))
    assert vehicle.t == pytest.approx(200 * vehicle.preset.sim.period) and x[5] < -0.1  # climbing (NED: v_down < 0)
    assert all(0.0 <= f <= vehicle.preset.actuators.max_thrust for f in vehicle.forces)


def test_import_quadsitl_loads_nothing_until_used():
    code = "import sys, quadsitl; print('groundstation.api' in sys.modules, 'numba' in sys.modules)"
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert r.stdout.split() == ["False", "False"], r.stdout + r.stderr
