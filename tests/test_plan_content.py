"""What QGroundControl plans carry besides waypoints, flown by ``quadsitl fly --mission`` as PX4 flies them: a region of
interest the vehicle faces, camera items done as they come (no camera), a survey's saved waypoints, and a waypoint
whose altitude is null (the one before's)."""

import json
import math

import pandas as pd

from quadsitl.frames import geodetic_to_ned
from tests.conftest import run_cli

HOME = (47.397742, 8.545594, 488.0)
DLAT = 0.00009  # ≈ 10 m north
DLON = 0.000133  # ≈ 10 m east


def simple(command: int, frame: int, params: list) -> dict:
    return {"type": "SimpleItem", "command": command, "frame": frame, "params": params, "autoContinue": True,
            "doJumpId": 1}  # fmt: skip


def at(north: float, east: float, alt: float | None, command: int = 16) -> dict:
    lat, lon = HOME[0] + north / 10 * DLAT, HOME[1] + east / 10 * DLON
    return simple(command, 3, [0, 0, 0, None, lat, lon, alt])


def test_a_plan_with_roi_camera_items_a_survey_and_a_null_altitude_is_flown(tmp_path):
    saved = [simple(206, 2, [5, 0, 1, 0, 0, 0, 0]), at(20, 0, 8), at(20, 20, 8), simple(206, 2, [0, 0, 1, 0, 0, 0, 0])]
    survey = {"type": "ComplexItem", "complexItemType": "survey", "version": 5,
              "TransectStyleComplexItem": {"Items": saved}}  # fmt: skip
    items = [simple(22, 3, [0, 0, 0, None, HOME[0], HOME[1], 8]),
             at(10, 40, 0, command=195),  # look at a point 40 m east, 10 m north
             simple(2000, 2, [0, 0, 1, 0, 0, 0, 0]),  # IMAGE_START_CAPTURE
             survey, at(0, 20, None),  # null altitude: stays at 8 m
             simple(197, 2, [0, 0, 0, 0, 0, 0, 0]),
             simple(178, 2, [2, 0.8, 0, 0, 0, 0, 0]), at(0, 10, 14),  # climb at 0.8 m/s (speed type 2) to 14 m
             simple(20, 2, [0, 0, 0, 0, 0, 0, 0])]  # fmt: skip
    plan = {"fileType": "Plan", "version": 1, "groundStation": "QGroundControl",
            "mission": {"version": 2, "firmwareType": 12, "vehicleType": 2, "plannedHomePosition": list(HOME),
                        "items": items}, "geoFence": {"polygons": []}, "rallyPoints": {"points": []}}  # fmt: skip
    path = tmp_path / "content.plan"
    path.write_text(json.dumps(plan))
    out = tmp_path / "out"
    r = run_cli("fly", "--preset", "x500", "--mission", str(path), "--no-figures", "--out", str(out), timeout=300)
    assert r.returncode == 0, r.stderr
    doc = json.loads((out / "mission.json").read_text())
    assert doc["all_reached_in_order"] and len(doc["items"]) == 12, doc["reached"]
    assert "camera/gimbal items done as they come: no camera" in r.stderr  # said once, not silently skipped
    t = pd.read_csv(out / "telemetry.csv")
    reached = {e["seq"]: e["t"] for e in doc["reached"]}
    roi = geodetic_to_ned(HOME[0] + DLAT, HOME[1] + 4 * DLON, HOME[0], HOME[1])
    legs = t[(t.t > reached[4] + 3.0) & (t.t <= reached[5])]  # the survey's leg east, the turn to it done
    bearing = [math.atan2(roi[1] - y, roi[0] - x) for x, y in zip(legs.x, legs.y)]
    off = [abs((b - yaw + math.pi) % (2 * math.pi) - math.pi) for b, yaw in zip(bearing, legs.yaw)]
    assert max(off) < math.radians(5)  # facing the region of interest, not the leg (east)
    null = t[(t.t > reached[6]) & (t.t <= reached[7])]
    assert abs(null.altitude - 8.0).max() < 0.5  # the null altitude flown at the one before
    takeoff = t[t.t <= reached[0]]
    assert 1.4 < takeoff.vz.min() * -1 < 1.6  # the mission's takeoff at MPC_TKO_SPEED (NED: vz down)
    climb = t[(t.t > reached[9]) & (t.t <= reached[10])]
    assert 0.7 < -climb.vz.min() < 0.9 and climb.altitude.max() > 12.0  # DO_CHANGE_SPEED's climb speed, flown


async def mission_import(port: int, text: str) -> dict:
    """MAVSDK-Python's mission_import.py, as written but for the file (a string here): import a QGroundControl plan
    with mission_raw, upload it, arm, start; then wait for the mission to finish and the vehicle to disarm."""
    import asyncio

    from mavsdk.asyncio import ComponentType, Configuration, Mavsdk
    from mavsdk.asyncio.plugins.action import ActionAsync
    from mavsdk.asyncio.plugins.mission_raw import MissionRawAsync
    from mavsdk.asyncio.plugins.telemetry import TelemetryAsync

    from tests.mavsdk_client import autopilot, healthy, until

    seen: dict = {}
    async with Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION)) as m:
        system = await autopilot(m, port)
        raw, action, tel = MissionRawAsync(system), ActionAsync(system), TelemetryAsync(system)
        data = await raw.import_qgroundcontrol_mission_from_string(text)
        seen["imported"] = [i.command for i in data.mission_items]
        await raw.upload_mission(data.mission_items)
        await healthy(tel)
        await action.arm()
        await raw.start_mission()
        done = await until(raw.subscribe_mission_progress(), lambda p: p.current == p.total, 120)
        seen["progress"] = (done.current, done.total)
        seen["disarmed"] = await until(tel.subscribe_armed(), lambda a: not a, 60)
        await asyncio.sleep(0)
    return seen


def test_mavsdk_imports_a_plan_with_roi_camera_items_and_a_survey_uploads_and_flies_it():
    import asyncio

    from tests.mavclient import quadsitl_up

    saved = [simple(206, 2, [5, 0, 1, 0, 0, 0, 0]), at(20, 0, 8), at(20, 20, 8), simple(206, 2, [0, 0, 1, 0, 0, 0, 0])]
    items = [simple(22, 3, [0, 0, 0, None, HOME[0], HOME[1], 8]), at(10, 40, 0, command=195),
             simple(2000, 2, [0, 0, 1, 0, 0, 0, 0]),
             {"type": "ComplexItem", "complexItemType": "survey", "version": 5,
              "TransectStyleComplexItem": {"Items": saved}},
             simple(197, 2, [0, 0, 0, 0, 0, 0, 0]), simple(20, 2, [0, 0, 0, 0, 0, 0, 0])]  # fmt: skip
    plan = {"fileType": "Plan", "version": 1, "groundStation": "QGroundControl",
            "mission": {"version": 2, "firmwareType": 12, "vehicleType": 2, "plannedHomePosition": list(HOME),
                        "items": items}, "geoFence": {"version": 2, "polygons": [], "circles": []},
            "rallyPoints": {"version": 2, "points": []}}  # fmt: skip
    with quadsitl_up("--preset", "x500", "--speed", "4") as v:  # lockstep at 4× real time: the mission in ~20 s
        seen = asyncio.run(asyncio.wait_for(mission_import(v.api_port, json.dumps(plan)), 240))
        assert v.proc.poll() is None
    assert seen["imported"] == [22, 195, 2000, 206, 16, 16, 206, 197, 20]  # MAVSDK expands the survey too
    assert seen["progress"] == (9, 9) and seen["disarmed"] is False


def test_a_loiters_radius_and_heading_and_an_item_with_autocontinue_off_through_fly(tmp_path):
    """LOITER_TIME's p3 (its radius) and p2 = 1 (face the next waypoint before leaving), then a waypoint with
    autoContinue false: the vehicle holds there, the mission waiting on it, until --duration ends the run."""
    loiter = simple(19, 3, [1, 1, 6, None, HOME[0] + 2 * DLAT, HOME[1], 8])  # 20 m north, 1 s, heading, 6 m
    stop = {**at(20, 20, 8), "autoContinue": False}
    items = [simple(22, 3, [0, 0, 0, None, HOME[0], HOME[1], 8]), loiter, stop, at(0, 0, 8)]
    plan = {"fileType": "Plan", "version": 1, "groundStation": "QGroundControl",
            "mission": {"version": 2, "firmwareType": 12, "vehicleType": 2, "plannedHomePosition": list(HOME),
                        "items": items}}  # fmt: skip
    path = tmp_path / "stop.plan"
    path.write_text(json.dumps(plan))
    out = tmp_path / "out"
    r = run_cli("fly", "--preset", "x500", "--mission", str(path), "--duration", "60", "--no-figures", "--quiet",
                "--out", str(out), timeout=300)  # fmt: skip
    assert r.returncode != 0 and "current item 2 of 4, mission_state 3" in r.stderr  # still active, held on item 2
    doc = json.loads((out / "mission.json").read_text())
    reached = {e["seq"]: e["t"] for e in doc["reached"]}
    assert sorted(reached) == [0, 1, 2]  # item 3 never flown
    t = pd.read_csv(out / "telemetry.csv")
    point = t[t.t <= reached[1]].iloc[-1]  # (the reached time is the ground station's: telemetry comes in batches)
    gone = t[(t.t > reached[1] - 1.0) & (((t.x - point.x) ** 2 + (t.y - point.y) ** 2) > 2.0**2)].iloc[0]
    assert abs((gone.yaw - math.pi / 2 + math.pi) % (2 * math.pi) - math.pi) < math.radians(15)  # faced east first
    held = t[t.t > reached[2] + 2.0]
    assert len(held) > 10_000 and held.x.max() - held.x.min() < 0.3 and held.y.max() - held.y.min() < 0.3


def fenced_plan(tmp_path, far_north: float) -> str:
    """A plan: take off to 8 m, fly to 20 m north, then ``far_north`` metres north, return; a fence 30 m around
    home, a rally point 25 m north, 10 m east."""
    items = [simple(22, 3, [0, 0, 0, None, HOME[0], HOME[1], 8]), at(2 * 10 / 10, 0, 8), simple(16, 3, [0, 0, 0, None,
             HOME[0] + DLAT * far_north / 10, HOME[1], 8]), simple(20, 2, [0, 0, 0, 0, 0, 0, 0])]  # fmt: skip
    d = 30 / 10
    square = [[HOME[0] - d * DLAT, HOME[1] - d * DLON], [HOME[0] + d * DLAT, HOME[1] - d * DLON],
              [HOME[0] + d * DLAT, HOME[1] + d * DLON], [HOME[0] - d * DLAT, HOME[1] + d * DLON]]  # fmt: skip
    plan = {"fileType": "Plan", "version": 1, "groundStation": "QGroundControl",
            "mission": {"version": 2, "firmwareType": 12, "vehicleType": 2, "plannedHomePosition": list(HOME),
                        "items": items},
            "geoFence": {"version": 2, "polygons": [{"polygon": square, "inclusion": True, "version": 1}],
                         "circles": []},
            "rallyPoints": {"version": 2, "points": [[HOME[0] + 2.5 * DLAT, HOME[1] + DLON, 8]]}}  # fmt: skip
    path = tmp_path / f"fenced-{far_north:g}.plan"
    path.write_text(json.dumps(plan))
    return str(path)


def test_a_plans_geofence_and_rally_points_are_flown_by_fly_and_sim_alike(tmp_path):
    """The plan's rally point is nearer than home when its mission returns: fly (uploading the geofence and the rally
    points after the mission, as QGroundControl does) and sim both land there."""
    path = fenced_plan(tmp_path, 25)
    landed = {}
    for command in ("fly", "sim"):
        out = tmp_path / command
        r = run_cli(command, "--preset", "x500", "--mission", path, "--no-figures", "--quiet", "--out", str(out),
                    timeout=300)  # fmt: skip
        assert r.returncode == 0, r.stderr
        t = pd.read_csv(out / "telemetry.csv")
        landed[command] = (t.x.iloc[-1], t.y.iloc[-1])
    rally = geodetic_to_ned(HOME[0] + 2.5 * DLAT, HOME[1] + DLON, HOME[0], HOME[1])
    for command, (x, y) in landed.items():
        assert math.hypot(x - rally[0], y - rally[1]) < 0.5, (command, landed, rally)


def test_a_mission_with_a_waypoint_beyond_the_plans_geofence_is_not_flown(tmp_path):
    """As PX4's mission feasibility check refuses it ("Geofence violation for waypoint 3": its third item, 60 m north,
    is 30 m beyond the fence), whether the fence came before the mission or after it (fly uploads it after, as
    QGroundControl does): sim refuses the plan before it flies, and fly's vehicle never arms in AUTO.MISSION."""
    path = fenced_plan(tmp_path, 60)
    for command in ("sim", "fly"):
        out = tmp_path / command
        r = run_cli(command, "--preset", "x500", "--mission", path, "--duration", "60", "--no-figures", "--quiet",
                    "--out", str(out), timeout=300)  # fmt: skip
        assert r.returncode != 0 and "Geofence violation for waypoint 3" in r.stderr, (command, r.stderr)
        if (out / "telemetry.csv").exists():  # nothing flown: the vehicle stayed on the ground
            assert pd.read_csv(out / "telemetry.csv").altitude.max() < 0.5
