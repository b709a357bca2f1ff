"""Mission files for ``quadsitl fly --mission``: QGroundControl .plan, waypoint CSV and QGC WPL 110, and what is
refused before anything starts (with the file, item or line, field and value)."""

import json
import math
from pathlib import Path

import pytest

from autopilot import mission_protocol as mp
from groundstation.mission_files import MissionFileError, load
from quadsitl.frames import geodetic_to_ned

DATA = Path(__file__).parent / "data"
HOME = (47.397742, 8.545594)


def test_the_hand_written_plan_follows_qgroundcontrols_format():
    """tests/data/square.plan, written by hand after QGroundControl's documented plan format: takeoff, a 10 m
    square at 5 m above home, return; plannedHomePosition is read but only informational."""
    m = load(DATA / "square.plan")
    assert m.kind == "plan" and m.lands and m.planned_home == (47.397742, 8.545594, 488.0)
    assert [i.command for i in m.items] == [22, 16, 16, 16, 20]
    assert [i.seq for i in m.items] == list(range(5))
    assert [i.frame for i in m.items] == [3, 3, 3, 3, 2]
    corners = [geodetic_to_ned(i.lat, i.lon, *HOME) for i in m.items[1:4]]
    for (n, e), (n0, e0) in zip(corners, [(10, 0), (10, 10), (0, 10)]):
        assert math.hypot(n - n0, e - e0) < 0.05
    assert all(i.z == 5.0 for i in m.items[:4])
    assert math.isnan(m.items[0].p4)  # QGroundControl writes NaN as null


def plan(tmp_path, items, **extra) -> Path:
    doc = {"fileType": "Plan", "groundStation": "QGroundControl", "version": 1,
           "mission": {"version": 2, "firmwareType": 12, "vehicleType": 2, "items": items}, **extra}  # fmt: skip
    p = tmp_path / "m.plan"
    p.write_text(json.dumps(doc))
    return p


def wp(command=16, frame=3, params=(0, 0, 0, None, 47.3978, 8.5456, 5)):
    return {"type": "SimpleItem", "command": command, "frame": frame, "params": list(params), "autoContinue": True}


@pytest.mark.parametrize(
    "items, expected",
    [
        ([wp(), {"type": "ComplexItem", "complexItemType": "StructureScan"}],
         "item 1, type: ComplexItem (StructureScan) has no saved items; allowed: SimpleItem, or a survey"),
        ([wp(command=17)], "item 0 (command 17), command: 17 is refused by the vehicle; allowed: one of 16 (NAV_WAYP"),
        ([wp(frame=1)], "item 0 (NAV_WAYPOINT), frame: 1 is refused by the vehicle; allowed: 0, 3, 5, 6"),
        ([wp(frame=2)], "item 0 (NAV_WAYPOINT), frame: 2 is refused"),
        ([wp(params=(-1, 0, 0, 0, 47.3, 8.5, 5))], "item 0 (NAV_WAYPOINT), param1: -1 is refused by the vehicle; "
         "allowed: hold time must be >= 0 s"),
        ([wp(params=(0, 0, 0, 0, 95, 8.5, 5))], "item 0 (NAV_WAYPOINT), latitude (param5): 95 is refused"),
        ([wp(command=22, params=(0, 0, 0, 0, 47, 8.5, None))],
         "item 0 (NAV_TAKEOFF), altitude (param7): NaN is refused"),
        ([wp(), wp(command=93, frame=2, params=(-1, 0, 0, 0, 0, 0, 0))], "item 1 (NAV_DELAY), param1: -1"),
        ([wp(params=(0, 0, 0))], "item 0, params: [0, 0, 0]; expected a list of 7 numbers (or null)"),
        ([wp(params=(0, 0, 0, "x", 47, 8, 5))], "item 0, params: 'x' is not a number (or null)"),
        ([], "no mission items"),
    ],
)  # fmt: skip
def test_plan_refusals_name_the_item_field_and_value(tmp_path, items, expected):
    with pytest.raises(MissionFileError, match=None) as e:
        load(plan(tmp_path, items))
    assert expected in str(e.value), str(e.value)
    assert str(e.value).startswith(f"mission {tmp_path / 'm.plan'}")
    assert "\n" not in str(e.value)


def test_plan_refuses_other_files(tmp_path):
    p = tmp_path / "x.plan"
    p.write_text('{"fileType": "Mission"}')
    with pytest.raises(MissionFileError, match="fileType: 'Mission'; expected 'Plan'"):
        load(p)
    p.write_text("{not json")
    with pytest.raises(MissionFileError, match="line 1: not valid JSON"):
        load(p)
    with pytest.raises(MissionFileError, match="cannot read it"):
        load(tmp_path / "missing.plan")


SQUARE = [[47.3976, 8.5454], [47.3979, 8.5454], [47.3979, 8.5458], [47.3976, 8.5458]]


def test_a_plans_geofence_and_rally_points_are_read_as_the_vehicle_stores_them(tmp_path):
    fence = {
        "version": 2,
        "polygons": [{"polygon": SQUARE, "inclusion": True, "version": 1}],
        "circles": [{"circle": {"center": [47.3977, 8.5456], "radius": 3.5}, "inclusion": False, "version": 1}],
    }
    m = load(plan(tmp_path, [wp()], geoFence=fence, rallyPoints={"version": 2, "points": [[47.3978, 8.5457, 12]]}))
    assert [(it.command, it.p1, it.lat, it.lon) for it in m.fence] == [
        *((mp.FENCE_POLYGON_INCLUSION, 4.0, pytest.approx(a), pytest.approx(b)) for a, b in SQUARE),
        (mp.FENCE_CIRCLE_EXCLUSION, 3.5, pytest.approx(47.3977), pytest.approx(8.5456))]  # fmt: skip
    assert [it.seq for it in m.fence] == list(range(5)) and {it.mission_type for it in m.fence} == {1}
    ((rally),) = m.rally
    assert (rally.command, rally.lat, rally.lon, rally.z, rally.mission_type) == (
        mp.RALLY_POINT, pytest.approx(47.3978), pytest.approx(8.5457), 12.0, 2)  # fmt: skip
    load(plan(tmp_path, [wp()], geoFence={"polygons": [], "circles": [], "version": 2}))  # empty: fine


@pytest.mark.parametrize(
    ("section", "expected"),
    [
        ({"geoFence": {"polygons": [{"polygon": [[1, 2]]}]}}, "geoFence.polygons[0].polygon[0]: a polygon has at "
         "least 3 vertices, not 1"),
        ({"geoFence": {"polygons": [{"polygon": [SQUARE[0], SQUARE[2], SQUARE[1], SQUARE[3]]}]}}, "crosses itself"),
        ({"geoFence": {"circles": [{"circle": {"center": [47.3, 8.5], "radius": 0}}]}}, "geoFence.circles[0]: a "
         "circle's radius must be a number > 0 m, not 0"),
        ({"geoFence": {"circles": [{"circle": {"center": [47.3], "radius": 5}}]}}, "circle.center: [47.3]; expected "
         "[latitude, longitude]"),
        ({"geoFence": {"polygons": "x"}}, "geoFence.polygons: 'x'; expected a list"),
        ({"rallyPoints": {"points": [[47.3, 8.5]]}}, "rallyPoints.points[0]: [47.3, 8.5]; expected [latitude, "
         "longitude, altitude]"),
        ({"rallyPoints": {"points": [[95.0, 8.5, 10]]}}, "rallyPoints.points[0]: latitude must be within [-90, 90]"),
    ],
)  # fmt: skip
def test_a_malformed_geofence_or_rally_point_is_refused_naming_where(tmp_path, section, expected):
    with pytest.raises(MissionFileError) as e:
        load(plan(tmp_path, [wp()], **section))
    assert expected in str(e.value), str(e.value)


def test_waypoint_csv_is_waypoints_at_relative_altitude(tmp_path):
    p = tmp_path / "w.csv"
    p.write_text("altitude, lat, lon, hold, radius, yaw\n5, 47.3978, 8.5456, 2, , 90\n\n6,47.3979,8.5457,,1.5,\n")
    m = load(p)
    assert m.kind == "csv" and not m.lands
    a, b = m.items
    assert (a.command, a.frame, a.seq, b.seq) == (16, 6, 0, 1)
    assert (a.z, a.p1, a.p4, a.x) == (5.0, 2.0, 90.0, 473978000)
    assert math.isnan(a.p2) and b.p1 == 0.0 and b.p2 == 1.5 and math.isnan(b.p4)


@pytest.mark.parametrize(
    "text, expected",
    [
        ("t,x,y\n0,1,2\n", "line 1: header 't,x,y' lacks lat, lon, altitude; expected a QGroundControl .plan"),
        ("lat,lon,altitude\n47.3,8.5,high\n", "line 2, column altitude: 'high' is not a number"),
        ("lat,lon,altitude\n47.3,8.5,5\n47.3,,5\n", "line 3, column lon: missing"),
        ("lat,lon,altitude\n47.3,8.5,-1\n", "line 2, column altitude: -1; allowed: >= 0 m above home"),
        ("lat,lon,altitude,hold\n47.3,8.5,5,-2\n", "line 2 (NAV_WAYPOINT), param1: -2 is refused by the vehicle"),
        ("lat,lon,altitude\n147.3,8.5,5\n", "line 2 (NAV_WAYPOINT), latitude (param5): 147.3 is refused"),
        ("lat,lon,altitude\n47.3,8.5,inf\n", "line 2, column altitude: 'inf' is not a finite number"),
        ("lat,lon,altitude\n", "no mission items"),
    ],
)  # fmt: skip
def test_csv_refusals_name_the_line_and_column(tmp_path, text, expected):
    p = tmp_path / "w.csv"
    p.write_text(text)
    with pytest.raises(MissionFileError) as e:
        load(p)
    assert expected in str(e.value), str(e.value)


def test_qgc_wpl_110(tmp_path):
    p = tmp_path / "m.waypoints"
    home = "0\t1\t0\t16\t0\t0\t0\t0\t47.397742\t8.545594\t488\t1\n"  # line 0: the planned home, AMSL
    p.write_text("QGC WPL 110\n" + home + "1\t0\t3\t22\t0\t0\t0\t0\t47.3977\t8.5456\t5\t1\n"
                 "2\t0\t3\t16\t0\t0\t0\t0\t47.3978\t8.5456\t5\t1\n3\t0\t2\t20\t0\t0\t0\t0\t0\t0\t0\t1\n")  # fmt: skip
    m = load(p)
    assert m.kind == "wpl" and m.lands and [i.command for i in m.items] == [22, 16, 20]
    assert [i.seq for i in m.items] == [0, 1, 2] and m.planned_home == (47.397742, 8.545594, 488.0)
    p.write_text("QGC WPL 110\n" + home + "2\t0\t3\t16\t0\t0\t0\t0\t47.3\t8.5\t5\t1\n")
    with pytest.raises(MissionFileError, match=r"line 3, index: 2; expected 1"):
        load(p)
    p.write_text("QGC WPL 110\n" + home + "1\t0\t3\t31\t0\t0\t0\t0\t47.3\t8.5\t5\t1\n")
    with pytest.raises(MissionFileError, match=r"line 3 \(item 1\) \(command 31\), command: 31 is refused"):
        load(p)
    p.write_text("QGC WPL 110\n" + home)
    with pytest.raises(MissionFileError, match=r"no mission items after the planned home"):
        load(p)


def test_every_supported_command_passes_and_the_vehicle_agrees(tmp_path):
    """The file check is the vehicle's own: what passes here, the vehicle's upload accepts."""
    items = [wp(22), wp(16), wp(19, params=(3, 0, 0, None, 47.3, 8.5, 5)), wp(178, 2, (1, 3, -1, 0, 0, 0, 0)),
             wp(93, 2, (1, 0, 0, 0, 0, 0, 0)), wp(21, params=(0, 0, 0, None, 0, 0, 0)), wp(20, 2, [0] * 7)]  # fmt: skip
    m = load(plan(tmp_path, items))
    for item in m.items:
        assert mp.parse_item({**item.message_fields()}) == item


def test_qgroundcontrols_older_items_with_a_coordinate_and_four_params_and_a_surveys_saved_items(tmp_path):
    old = {"type": "SimpleItem", "command": 16, "frame": 3, "params": [0, 0, 0, None],
           "coordinate": [47.3978, 8.5456, 5], "autoContinue": True}  # fmt: skip
    mount = {"type": "SimpleItem", "command": 205, "frame": 2, "params": [0, 0, 0, 0], "coordinate": [0, 0, 2],
             "autoContinue": True}  # fmt: skip
    survey = {"type": "ComplexItem", "complexItemType": "survey", "TransectStyleComplexItem": {"Items": [wp(), wp()]}}
    m = load(plan(tmp_path, [old, mount, survey, wp()]))
    assert [i.command for i in m.items] == [16, 205, 16, 16, 16] and [i.seq for i in m.items] == [0, 1, 2, 3, 4]
    assert m.items[0].z == 5.0 and m.items[0].x == 473978000
