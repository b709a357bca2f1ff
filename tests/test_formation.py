"""The formation manoeuvre's plan and its metrics (:mod:`groundstation.formation`), pure, and ``quadsitl fly
--vehicles N --formation KIND`` flown whole: an autopilot and a ground station per vehicle, one plant on one clock."""

from __future__ import annotations

import itertools
import json
import math
import subprocess
import sys

import numpy as np
import pytest

from groundstation import formation
from groundstation.fleet import plan_fleet
from groundstation.formation_flight import parse_formation
from groundstation.telemetry_csv import read_csv
from groundstation.trajectories import MAX_CLIMB, position_from_csv
from quadsitl.cli_util import UsageError


def starts(n: int, spacing: float = 3.0) -> list[tuple[float, float]]:
    return [v.offset for v in plan_fleet(n, preset="paper", spacing=spacing)]


@pytest.mark.parametrize("kind", formation.KINDS)
@pytest.mark.parametrize("n", [2, 3, 4, 7, 9])
def test_slots_are_centred_and_neighbours_are_spacing_apart(kind, n):
    s = formation.slots(kind, n, 2.5)
    assert s.shape == (n, 2)
    assert np.allclose(s.mean(axis=0), 0.0, atol=1e-12)
    d = np.linalg.norm(s[:, None] - s[None, :], axis=2) + np.eye(n) * 1e9
    assert d.min() == pytest.approx(2.5)  # nobody closer than the spacing, and neighbours at it


def test_the_assignment_is_the_cheapest_one():
    rng = np.random.default_rng(3)
    for n in range(1, 7):
        cost = rng.uniform(0, 10, (n, n))
        col = formation.assign(cost)
        assert sorted(col) == list(range(n))
        best = min(sum(cost[i, p[i]] for i in range(n)) for p in itertools.permutations(range(n)))
        assert sum(cost[i, col[i]] for i in range(n)) == pytest.approx(best)


@pytest.mark.parametrize("kind", formation.KINDS)
@pytest.mark.parametrize("n", [1, 2, 4, 6, 9, 16])
def test_the_plan_flies_each_phase_and_keeps_vehicles_apart(kind, n):
    p = formation.plan(kind, starts(n), 3.0, 5.0, 10.0)
    t = np.arange(0.0, p.duration + 1e-9, 0.01)
    pos, vel, psi, psi_dot = p.along(t)  # (n, len(t), 3) each, and the heading: the plan at every t at once ...
    for k in range(0, len(t), 97):  # ... is the plan at each t alone
        one = p.at(float(t[k]))
        close = dict(rtol=1e-12, atol=1e-12)  # (numpy's sin and cos may take another path for one element)
        assert np.allclose(one[0], pos[:, k], **close) and np.allclose(one[1], vel[:, k], **close)
        assert np.allclose((one[2], one[3]), (psi[k], psi_dot[k]), **close)
    t_climb, t_form, t_move, _t_turn, end = p.times[1:]
    # take off where each stands; formed up about the grid's centroid, facing north; moved north; turned 90°
    assert np.allclose(p.at(0.0)[0], np.column_stack([p.start, np.zeros(n)]))
    assert np.allclose(p.at(t_climb)[0][:, :2], p.start) and np.allclose(p.at(t_climb)[0][:, 2], 5.0)
    centre = p.start.mean(axis=0)
    assert np.allclose(p.at(t_form)[0][:, :2] - centre, p.slot)
    assert sorted(map(tuple, np.round(p.slot, 9))) == sorted(map(tuple, np.round(formation.slots(kind, n, 3.0), 9)))
    assert np.allclose(p.at(t_move)[0][:, :2] - centre - (10.0, 0.0), p.slot)
    turned = np.column_stack([-p.slot[:, 1], p.slot[:, 0]])  # 90° clockwise seen from above: forward → east
    assert np.allclose(p.at(end)[0][:, :2] - centre - (10.0, 0.0), turned)
    assert p.at(end)[2] == pytest.approx(math.pi / 2)
    # the rates are the positions' derivatives (the velocity feed-forward a vehicle gets), within the limits
    numeric = np.gradient(pos, t, axis=1)
    assert np.abs(numeric - vel)[:, 2:-2].max() < 2e-3
    assert np.hypot(vel[..., 0], vel[..., 1]).max() <= formation.CRUISE + 1e-9
    assert np.abs(vel[..., 2]).max() <= MAX_CLIMB / 2 + 1e-9
    if n > 1:  # straight paths of the least-squares assignment stay ≥ spacing/√2 apart (CAPT's bound)
        i, j = np.triu_indices(n, 1)
        assert np.linalg.norm(pos[i] - pos[j], axis=2).min() >= 3.0 / math.sqrt(2) - 1e-6


def test_each_vehicle_flies_its_part_in_its_own_frame(tmp_path):
    p = formation.plan("circle", starts(4), 3.0, 5.0, 10.0)
    for i in range(4):
        formation.write_vehicle_csv(tmp_path / f"v{i}.csv", p, i)
        traj = position_from_csv(tmp_path / f"v{i}.csv")  # the ground station's reader accepts it
        for tk in (0.0, 7.3, 15.0, p.duration):
            planned = p.at(tk)[0][i]
            sp = traj(tk)
            assert (sp.x + p.start[i, 0], sp.y + p.start[i, 1], sp.altitude) == pytest.approx(tuple(planned), abs=2e-3)


def test_metrics_of_a_perfect_a_shifted_and_a_wayward_flight():
    p = formation.plan("line", starts(4), 3.0, 5.0, 10.0)  # from the 2 × 2 grid: the middle two pass at 3/√2
    t = np.arange(0.0, p.duration, 0.01)
    planned = np.stack([p.at(float(tk))[0] for tk in t], axis=1)
    perfect = formation.fleet_metrics(p, t, planned)
    for ph in perfect["per_phase"].values():
        assert ph["formation_max_m"] < 1e-9 and ph["tracking_max_m"] < 1e-9
    assert perfect["min_separation"]["min_m"] == pytest.approx(3.0 / math.sqrt(2), abs=1e-3)
    shifted = formation.fleet_metrics(p, t, planned + np.array([0.5, -0.2, 0.1]))  # all off the plan: same shape
    assert shifted["per_phase"]["rotate"]["formation_max_m"] < 1e-9
    assert shifted["per_phase"]["rotate"]["tracking_rms_m"] == pytest.approx(math.sqrt(0.3), rel=1e-9)
    wayward = planned.copy()
    wayward[2, t >= p.times[3], 0] += 1.0  # vehicle 3 a metre north of its slot from the rotation on
    m = formation.fleet_metrics(p, t, wayward)
    assert m["per_phase"]["rotate"]["formation_max_m"] == pytest.approx(0.75)  # 1 − 1/4: the centroid moves too
    assert m["per_phase"]["translate"]["formation_max_m"] < 1e-9
    assert "minimum separation" in formation.format_table(m)


def test_the_common_track_takes_the_truth_in_sensor_mode_and_the_shared_ticks():
    p = formation.plan("line", starts(2), 3.0, 5.0)
    a = {"t": np.array([0.0, 0.001, 0.002]), "x": np.zeros(3), "y": np.zeros(3), "altitude": np.ones(3)}
    b = {"t": np.array([0.001, 0.002, 0.003]), "x": np.full(3, 9.0), "y": np.zeros(3), "altitude": np.zeros(3),
         "x_true": np.array([1.0, 2.0, 3.0]), "y_true": np.zeros(3), "z_true": np.full(3, -2.0)}  # fmt: skip
    t, track = formation.common_track(p, [a, b])
    assert t.tolist() == [0.001, 0.002]
    assert track[0, :, 2].tolist() == [1.0, 1.0]
    assert track[1, :, 0].tolist() == [1.0 + p.start[1, 0], 2.0 + p.start[1, 0]]  # the truth, not the estimate
    assert track[1, :, 1].tolist() == [p.start[1, 1]] * 2 and track[1, :, 2].tolist() == [2.0, 2.0]


def test_bad_formations_are_refused_naming_the_option():
    assert parse_formation("circle:altitude=8,distance=0") == ("circle", 8.0, 0.0)
    for text, expected in {
        "wedge": "expected line|grid|circle",
        "line:altitude=0": "altitude=0: expected metres in [1, 100]",
        "line:height=3": "unknown parameter 'height=3'",
        "grid:distance=x": "distance",
    }.items():
        with pytest.raises(UsageError, match="--formation") as e:
            parse_formation(text)
        assert expected in str(e.value), (text, e.value)


def _quadsitl(*argv: str, timeout: float = 240) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "groundstation.cli", *argv], capture_output=True, text=True,
                          timeout=timeout)  # fmt: skip


def test_fly_refuses_a_bad_fleet_flight_in_one_line(tmp_path):
    for argv, expected in {
        ("--vehicles", "0"): "--vehicles 0: expected an integer in 1..64",
        ("--vehicles", "2", "--formation", "wedge"): "--formation 'wedge'",
        ("--vehicles", "2", "--trajectory", "sine"): "each vehicle flies its part of --formation",
        ("--vehicles", "2", "--duration", "5"): "the plan's phases set the flight's length",
        ("--vehicles", "2", "--spacing", "0.1"): "--spacing 0.1",
    }.items():
        r = _quadsitl("fly", *argv, "--out", str(tmp_path / "x"), timeout=60)
        assert r.returncode == 2, (argv, r.stderr)
        assert expected in r.stderr and len(r.stderr.strip().splitlines()) == 1, (argv, r.stderr)
    assert not (tmp_path / "x").exists()


@pytest.mark.timeout(300)
def test_three_vehicles_fly_a_grid_formation_together(tmp_path):
    out = tmp_path / "fleet"
    r = _quadsitl("fly", "--vehicles", "3", "--formation", "grid:altitude=4,distance=6", "--spacing", "4", "--out",
                  str(out))  # fmt: skip
    assert r.returncode == 0, r.stderr
    assert "minimum separation" in r.stdout
    assert "lost" not in r.stderr, r.stderr  # the plant stopped first: no autopilot left it waiting at the end
    m = json.loads((out / "metrics.json").read_text())
    assert m["formation"] == "grid" and m["vehicles"] == 3 and m["spacing_m"] == 4.0
    runs = [read_csv(out / f"v{i}" / "telemetry.csv") for i in (1, 2, 3)]
    # one clock: every vehicle flew the same ticks, from the tick they all armed at
    assert all(np.array_equal(runs[0]["t"], run["t"]) for run in runs[1:])
    assert runs[0]["t"][0] == 0.0 and runs[0]["t"][-1] == pytest.approx(m["plan_s"], abs=0.01)
    # flown as planned: the shape held to a few decimetres while moving, and never closer than CAPT's bound allows
    for phase in ("form up", "translate", "rotate", "hold"):
        assert m["per_phase"][phase]["formation_max_m"] < 0.8, (phase, m["per_phase"][phase])
    assert m["per_phase"]["hold"]["formation_rms_m"] < 0.3
    assert 4.0 / math.sqrt(2) - 0.5 < m["min_separation"]["min_m"] <= 4.0 + 1e-3
    # each vehicle ends at its turned slot, in the common frame: its home's grid offset + its own x, y
    p = formation.plan("grid", starts(3, 4.0), 4.0, 4.0, 6.0)
    end = p.at(p.duration)[0]
    for i, run in enumerate(runs):
        at = (run["x"][-1] + p.start[i, 0], run["y"][-1] + p.start[i, 1], run["altitude"][-1])
        assert at == pytest.approx(tuple(end[i]), abs=0.4), (i, at, end[i])
    for i in (1, 2, 3):
        assert {"telemetry.csv", "flight.tlog", "metrics.json", "trajectory.csv"} <= {
            f.name for f in (out / f"v{i}").iterdir()}  # fmt: skip
    assert (out / "fig_formation.png").stat().st_size > 20_000
    series = np.genfromtxt(out / "formation.csv", delimiter=",", names=True)
    assert series["separation_min_m"].min() == pytest.approx(m["min_separation"]["min_m"], abs=1e-5)


@pytest.mark.timeout(300)
def test_a_stalled_ground_station_holds_the_fleets_clock_instead_of_lagging_its_vehicle(tmp_path):
    """v2's ground station stopped for 0.15 s of every 0.3 s of wall time, as a busy machine may deschedule it:
    v2's autopilot (--offboard-lockstep, as in single flights) holds the fleet's clock for its setpoints, so v2 flies
    the reference its ground station made for each tick. When formation flights did not hold the clock, on the
    development machine, v2 strayed 1.43 m from its plan (v1 0.30 m)."""
    from tests.test_fly import stall_child

    out = tmp_path / "fleet"
    argv = [sys.executable, "-m", "groundstation.cli", "fly", "--vehicles", "2", "--formation", "line", "--out",
            str(out)]  # fmt: skip
    with open(tmp_path / "stderr.txt", "w+") as err:
        proc = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=err, text=True)
        try:
            stalls = stall_child(proc, b"--target-system\x002\x00", 0.15, 0.3, timeout=240)
            assert proc.wait(timeout=30) == 0
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
        err.seek(0)
        said = err.read()
    assert stalls > 5, stalls
    assert "autopilot v2: --offboard-lockstep: the clock waited for a setpoint" in said, said
    v2 = json.loads((out / "metrics.json").read_text())["per_vehicle"]["v2"]["backstepping"]
    assert v2["horizontal_max"] < 1.2, v2
