"""A QGC WPL 110 file's line 0 is its planned home (QGroundControl's loader: "planned home position is already in
position 0"), not a waypoint: ``quadsitl sim --mission`` flies the lines after it, and the vehicle never goes down to
the home row's ground-level altitude between its waypoints."""

import json

import pandas as pd

from tests.conftest import run_cli

WPL = (
    "QGC WPL 110\n"
    "0\t1\t0\t16\t0\t0\t0\t0\t47.397742\t8.545594\t488.000000\t1\n"  # home, AMSL: on the ground
    "1\t0\t3\t22\t0\t0\t0\t0\t0\t0\t10.000000\t1\n"  # takeoff to 10 m
    "2\t0\t3\t16\t0\t0\t0\t0\t47.397922\t8.545594\t10.000000\t1\n"  # 20 m north
    "3\t0\t3\t16\t0\t0\t0\t0\t47.397922\t8.545860\t10.000000\t1\n"  # 20 m east of it
    "4\t0\t2\t20\t0\t0\t0\t0\t0\t0\t0\t1\n"  # return and land
)


def test_sim_flies_the_lines_after_the_planned_home_and_stays_up_between_waypoints(tmp_path):
    plan = tmp_path / "square.waypoints"
    plan.write_text(WPL)
    out = tmp_path / "out"
    r = run_cli("sim", "--preset", "x500", "--mission", str(plan), "--no-figures", "--quiet", "--out", str(out),
                timeout=300)  # fmt: skip
    assert r.returncode == 0, r.stderr
    doc = json.loads((out / "mission.json").read_text())
    assert [i["command"] for i in doc["items"]] == [22, 16, 16, 20]  # line 0 is not an item
    assert doc["all_reached_in_order"], doc["reached"]
    t = pd.read_csv(out / "telemetry.csv")
    north, east = (next(r["t"] for r in doc["reached"] if r["seq"] == s) for s in (1, 2))
    between = t[(t.t >= north) & (t.t <= east)]
    assert between.altitude.min() > 9.0  # it flew the waypoints at 10 m, never down to the home row
