"""The geofence as PX4 checks it (autopilot.geofence): inside at least one inclusion, outside every exclusion, within
GF_MAX_HOR_DIST and GF_MAX_VER_DIST of home; and the commander's GF_ACTION on a breach, once per breach."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from autopilot import geofence
from autopilot.commander import (
    FAILSAFE,
    FAILSAFE_GEOFENCE,
    GF_BREACH,
    RTL_TO,
    RTL_X,
    RTL_Y,
    Commander,
    CommanderSettings,
)
from quadsitl.state import VehicleState
from quadsitl.wire import Mode

PI, PE, CI, CE = (geofence.POLYGON_INCLUSION, geofence.POLYGON_EXCLUSION, geofence.CIRCLE_INCLUSION,
                  geofence.CIRCLE_EXCLUSION)  # fmt: skip


def polygon(kind: int, *vertices: tuple[float, float]) -> list[float]:
    return [v for x, y in vertices for v in (kind, len(vertices), x, y)]


def circle(kind: int, x: float, y: float, radius: float) -> list[float]:
    return [kind, radius, x, y]


def fenced(*items: list[float]) -> np.ndarray:
    cm = Commander().cm
    geofence.set_fence(cm, np.array([v for item in items for v in item]))
    return cm


SQUARE = polygon(PI, (-10, -10), (10, -10), (10, 10), (-10, 10))
L_SHAPE = polygon(PI, (0, 0), (20, 0), (20, 5), (5, 5), (5, 20), (0, 20))  # a notch at (10..20, 5..20)


@pytest.mark.parametrize(
    ("items", "point", "breach"),
    [
        ([SQUARE], (0, 0), 0),
        ([SQUARE], (15, 0), geofence.BREACH_OUTSIDE),
        ([SQUARE], (0, -10.5), geofence.BREACH_OUTSIDE),
        ([L_SHAPE], (2, 2), 0),
        ([L_SHAPE], (12, 12), geofence.BREACH_OUTSIDE),  # in the notch: outside a concave polygon
        ([L_SHAPE], (2, 15), 0),
        ([SQUARE, circle(CI, 30, 0, 5)], (30, 2), 0),  # the union of the inclusions
        ([SQUARE, circle(CI, 30, 0, 5)], (20, 0), geofence.BREACH_OUTSIDE),
        ([SQUARE, circle(CE, 5, 5, 2)], (5, 6), geofence.BREACH_EXCLUDED),
        ([SQUARE, polygon(PE, (-2, -2), (2, -2), (0, 2))], (0, 0), geofence.BREACH_EXCLUDED),
        ([circle(CE, 5, 5, 2)], (50, 50), 0),  # only exclusions: everywhere else is allowed
        ([], (1e4, 1e4), 0),
    ],
)
def test_a_point_breaches_the_fence_as_px4_says(items, point, breach):
    assert geofence.fence_breach(fenced(*items), *point) == breach


def armed(action: int, *items: list[float], **settings) -> Commander:
    c = Commander(CommanderSettings(geofence_action=action, **settings))
    c.set_fence(np.array([v for item in items for v in item]))
    c.update(0, 0.0, VehicleState(z=-5.0))
    ok, why = c.arm()
    assert ok, why
    c.set_mode(Mode.HOLD)
    return c


def fly(c: Commander, tick: int, x: float, altitude: float = 5.0) -> None:
    c.messages.clear()
    c.update(tick, tick * 0.001, VehicleState(x=x, z=-altitude))


@pytest.mark.parametrize(("action", "mode"), [(1, Mode.HOLD), (2, Mode.HOLD), (3, Mode.RTL), (5, Mode.LAND)])
def test_a_breach_takes_gf_action_once_and_again_after_coming_back(action, mode):
    c = armed(action, SQUARE)
    c.set_mode(Mode.MISSION if action == 2 else Mode.HOLD)
    fly(c, 1, 5.0)
    assert c.messages == [] and c.cm[GF_BREACH] == 0
    fly(c, 2, 12.0)
    what = ("warning", "hold", "return", "terminate", "land")[action - 1]
    assert c.messages == [(2, f"Geofence breached: outside the fence; action: {what}")]
    assert c.mode == mode and c.armed
    assert c.cm[FAILSAFE] == (FAILSAFE_GEOFENCE if action != 1 else 0)
    fly(c, 3, 13.0)
    assert c.messages == []  # once per breach
    c.set_mode(Mode.HOLD)
    fly(c, 4, 5.0)
    assert c.cm[GF_BREACH] == 0
    fly(c, 5, 12.0)
    assert c.messages and c.messages[0][1].startswith("Geofence breached")


def test_terminate_turns_the_motors_off_and_none_checks_nothing():
    c = armed(4, SQUARE)
    fly(c, 1, 12.0)
    assert not c.armed and c.messages[0] == (2, "Geofence breached: outside the fence; action: terminate")
    c = armed(0, SQUARE)
    fly(c, 1, 12.0)
    assert c.armed and c.messages == [] and c.cm[GF_BREACH] == 0


def test_a_point_is_checked_as_the_vehicle_is_and_a_goto_outside_only_when_a_breach_is_acted_on():
    c = armed(2, SQUARE, max_distance=50.0, max_height=20.0)
    assert geofence.point_breach(c.cm, 5.0, 0.0, 5.0) == 0
    assert geofence.point_breach(c.cm, 12.0, 0.0, 5.0) == geofence.BREACH_OUTSIDE
    assert geofence.point_breach(c.cm, 5.0, 0.0, 30.0) == geofence.BREACH_HEIGHT  # home at 5 m
    assert c.outside_fence(12.0, 0.0, 5.0) and not c.outside_fence(5.0, math.nan, math.nan)
    warned = armed(1, SQUARE)  # GF_ACTION warning: PX4 lets a goto outside through
    assert not warned.outside_fence(12.0, 0.0, 5.0)


def test_the_distance_and_height_limits_are_breaches_too():
    c = armed(2, max_distance=20.0, max_height=30.0)
    fly(c, 1, 19.0, altitude=29.0)
    assert c.cm[GF_BREACH] == 0
    fly(c, 2, 21.0)
    assert c.messages == [(2, "Geofence breached: farther from home than GF_MAX_HOR_DIST; action: hold")]
    c = armed(3, max_height=30.0)  # home 5 m up (armed there)
    fly(c, 1, 0.0, altitude=34.0)
    assert c.cm[GF_BREACH] == 0
    fly(c, 2, 0.0, altitude=36.0)
    assert c.messages == [(2, "Geofence breached: higher above home than GF_MAX_VER_DIST; action: return")]
    assert c.mode == Mode.RTL


def test_a_landing_goes_on_through_a_breach_and_arming_outside_is_denied():
    c = armed(2, SQUARE)
    c.set_mode(Mode.LAND)
    fly(c, 1, 12.0)
    assert c.mode == Mode.LAND
    assert c.messages == [(2, "Geofence breached: outside the fence; action: hold, not taken: land goes on")]
    c = Commander(CommanderSettings(geofence_action=2))
    c.set_fence(np.array(SQUARE, dtype=float))
    c.update(0, 0.0, VehicleState(x=50.0))
    assert c.arm() == (False, "Arming denied: vehicle outside the geofence") and not c.armed


def test_a_return_goes_to_the_nearest_of_home_and_the_rally_points():
    c = armed(2)
    c.set_rally(np.array([50.0, 0.0, 5.0, -60.0, 10.0, 5.0]))  # rally points 1 (50 m north) and 2 (60 m south)
    for x, to, where in ((40.0, 1, (50.0, 0.0)), (-45.0, 2, (-60.0, 10.0)), (10.0, 0, (0.0, 0.0))):
        c.set_mode(Mode.HOLD)
        fly(c, 1, x)
        assert c.set_mode(Mode.RTL) == (True, "")
        assert c.cm[RTL_TO] == to and (c.cm[RTL_X], c.cm[RTL_Y]) == where, x


def test_rally_points_outside_the_stored_geofence_are_refused_by_the_vehicles_check():
    """Missions.rally_outside: the stored fence's polygons and circles, in the local frame, applied to each point."""
    from autopilot import mission_protocol as mp
    from autopilot.missions import Missions
    from quadsitl.frames import PX4_HOME, ned_to_geodetic

    def item(seq: int, command: int, north: float, east: float, p1: float, kind: int) -> mp.MissionItem:
        lat, lon = ned_to_geodetic(north, east, *PX4_HOME[:2])
        return mp.MissionItem(seq, mp.FRAME_GLOBAL_INT, command, 0, 0, p1, 0.0, 0.0, 0.0, round(lat * 1e7),
                              round(lon * 1e7), 10.0, kind)  # fmt: skip

    m = Missions(PX4_HOME)
    corners = ((-20, -20), (20, -20), (20, 20), (-20, 20))
    fence = [item(i, mp.FENCE_POLYGON_INCLUSION, n, e, 4.0, 1) for i, (n, e) in enumerate(corners)]
    fence.append(item(4, mp.FENCE_CIRCLE_EXCLUSION, 10, 10, 3.0, 1))
    assert m.protocol.store_other(mp.MISSION_TYPE_FENCE, tuple(fence)) == ""
    inside, outside, excluded = (item(0, mp.RALLY_POINT, 5, -5, 0, 2), item(1, mp.RALLY_POINT, 25, 0, 0, 2),
                                 item(1, mp.RALLY_POINT, 10, 11, 0, 2))  # fmt: skip
    assert m.rally_outside((inside,)) == ""
    assert m.rally_outside((inside, outside)) == "Rally point 1 is outside the geofence: refused"
    assert m.rally_outside((inside, excluded)) == "Rally point 1 is outside the geofence: refused"
    assert m.protocol.store_other(mp.MISSION_TYPE_RALLY, (inside, outside)) != "" and m.protocol.rally == ()
    assert m.protocol.store_other(mp.MISSION_TYPE_RALLY, (inside,)) == "" and len(m.protocol.rally) == 1


@pytest.mark.parametrize("action", [0, 1, 2])
def test_a_mission_with_a_place_outside_the_fence_is_refused_as_px4s_feasibility_check_does(action):
    """Missions.refusal names the first item (from 1) whose place is outside the fence, beyond GF_MAX_HOR_DIST or
    above GF_MAX_VER_DIST; a landing where the vehicle is has no place; GF_ACTION 0 checks nothing."""
    from autopilot import mission_protocol as mp
    from autopilot.missions import Missions
    from quadsitl.frames import PX4_HOME, ned_to_geodetic

    def item(seq: int, command: int, north: float, east: float, z: float = 10.0) -> mp.MissionItem:
        lat, lon = ned_to_geodetic(north, east, *PX4_HOME[:2])
        return mp.MissionItem(seq, mp.FRAME_GLOBAL_RELATIVE_ALT_INT, command, 0, 1, 0.0, 0.0, 0.0, math.nan,
                              round(lat * 1e7), round(lon * 1e7), z, 0)  # fmt: skip

    def refusal(*items: mp.MissionItem, **settings) -> str:
        m = Missions(PX4_HOME)
        square = [item(i, mp.FENCE_POLYGON_INCLUSION, n, e) for i, (n, e) in enumerate(
            ((-20, -20), (20, -20), (20, 20), (-20, 20)))]  # fmt: skip
        square = [dataclasses.replace(s, frame=mp.FRAME_GLOBAL_INT, p1=4.0, mission_type=1) for s in square]
        assert m.protocol.store_other(mp.MISSION_TYPE_FENCE, tuple(square)) == ""
        m.protocol.store(tuple(dataclasses.replace(it, seq=k) for k, it in enumerate(items)))
        c = Commander(CommanderSettings(geofence_action=action, **settings))
        m.sync(c)
        return m.refusal(c)

    checked = action != 0
    takeoff, inside = item(0, mp.NAV_TAKEOFF, 0, 0), item(1, mp.NAV_WAYPOINT, 10, 10)
    assert refusal(takeoff, inside, item(2, mp.NAV_LAND, 0, 0)) == ""
    far = refusal(takeoff, inside, item(2, mp.NAV_WAYPOINT, 25, 0), item(3, mp.NAV_LAND, 0, 0))
    assert far == ("Geofence violation for waypoint 3" if checked else "")
    assert refusal(takeoff, item(1, mp.NAV_LAND, 30, 0)) == ("Geofence violation for waypoint 2" if checked else "")
    here = dataclasses.replace(item(1, mp.NAV_LAND, 0, 0), x=0, y=0)  # lands where it is
    assert refusal(takeoff, inside, here) == ""
    high = refusal(item(0, mp.NAV_TAKEOFF, 0, 0, z=40.0), inside, max_height=30.0)
    assert high == ("Geofence violation for waypoint 1" if checked else "")
