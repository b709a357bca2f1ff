"""A plan made for another place: ``quadsitl fly --mission`` starts the vehicle at the plan's planned home
(QGroundControl's ``plannedHomePosition``) and flies it there; with ``--home`` elsewhere the autopilot refuses to start
it, as PX4 does (MIS_DIST_1WP), naming the distance."""

import json

from tests.conftest import run_cli

TOKYO = (35.681236, 139.767125, 40.0)


def plan(home: tuple[float, float, float]) -> dict:
    """A QGroundControl plan: take off to 10 m, a waypoint 20 m north of its planned home, return."""
    lat, lon, _ = home

    def simple(command: int, frame: int, params: list) -> dict:
        return {"type": "SimpleItem", "command": command, "frame": frame, "params": params, "autoContinue": True,
                "doJumpId": 1}  # fmt: skip

    items = [simple(22, 3, [0, 0, 0, None, lat, lon, 10]), simple(16, 3, [0, 0, 0, None, lat + 0.00018, lon, 10]),
             simple(20, 2, [0, 0, 0, 0, 0, 0, 0])]  # fmt: skip
    return {"fileType": "Plan", "version": 1, "groundStation": "QGroundControl",
            "mission": {"version": 2, "firmwareType": 12, "vehicleType": 2, "cruiseSpeed": 15, "hoverSpeed": 5,
                        "plannedHomePosition": list(home), "items": items},
            "geoFence": {"version": 2, "circles": [], "polygons": []},
            "rallyPoints": {"version": 2, "points": []}}  # fmt: skip


def test_a_plan_is_flown_at_its_planned_home_and_refused_from_a_home_9600_km_away(tmp_path):
    path = tmp_path / "tokyo.plan"
    path.write_text(json.dumps(plan(TOKYO)))
    out = tmp_path / "at-home"
    r = run_cli("fly", "--preset", "x500", "--mission", str(path), "--no-figures", "--quiet", "--out", str(out),
                timeout=300)  # fmt: skip
    assert r.returncode == 0, r.stderr
    doc = json.loads((out / "mission.json").read_text())
    assert doc["all_reached_in_order"], doc["reached"]
    far = run_cli("fly", "--preset", "x500", "--mission", str(path), "--home", "47.397742,8.545594,488",
                  "--no-figures", "--quiet", "--out", str(tmp_path / "far"), timeout=300)  # fmt: skip
    assert far.returncode != 0
    assert "First waypoint far away from home: 95" in far.stderr and "Correct mission loaded?" in far.stderr
