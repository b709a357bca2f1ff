"""A geofence on ``quadsitl up`` as on PX4 SITL: MAVSDK-Python's ``geofence.py`` steps (an inclusion polygon 0.0001°
around home, uploaded), the fence downloaded back as uploaded, a malformed one refused with the stored one kept, and a
breach flown end to end: offboard north out of the fence, GF_ACTION's hold (PX4's default) stops the vehicle just
beyond it, and its return brings it home; a goto and an orbit beyond the fence are accepted and ignored, as PX4's
navigator ignores them. Rally points as MAVSDK's ``mission_import.py`` uploads them, and a return
that lands at the nearest."""

from __future__ import annotations

import asyncio
import json
import math
from pathlib import Path

import pytest
from mavsdk.asyncio import ComponentType, Configuration, Mavsdk
from mavsdk.asyncio.plugins.action import ActionAsync, OrbitYawBehavior
from mavsdk.asyncio.plugins.geofence import (
    FenceType,
    GeofenceAsync,
    GeofenceData,
    GeofenceError,
    Point,
    Polygon,
)
from mavsdk.asyncio.plugins.mission_raw import MissionRawAsync
from mavsdk.asyncio.plugins.offboard import OffboardAsync, VelocityNedYaw
from mavsdk.asyncio.plugins.param import ParamAsync
from mavsdk.asyncio.plugins.telemetry import FlightMode, TelemetryAsync

from tests.mavclient import quadsitl_up
from tests.mavsdk_client import autopilot, first, healthy, texts, until

pytestmark = pytest.mark.timeout(300)
DATA = Path(__file__).parent / "data"
FENCE_NORTH = 0.0001 * 111_320.0  # [m] the polygon's northern edge from home (0.0001° of latitude)


async def fence_and_breach(port: int, action: int) -> dict:
    seen: dict = {}
    said: list[str] = []
    async with Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION)) as m:
        system = await autopilot(m, port)
        tel, action_, fence = TelemetryAsync(system), ActionAsync(system), GeofenceAsync(system)
        off, param = OffboardAsync(system), ParamAsync(system)
        listener = asyncio.create_task(texts(system, said))
        await healthy(tel)
        home = await first(tel.subscribe_home())  # geofence.py: a polygon around home
        lat, lon = home.latitude_deg, home.longitude_deg
        corners = [Point(lat - 0.0001, lon - 0.0001), Point(lat + 0.0001, lon - 0.0001),
                   Point(lat + 0.0001, lon + 0.0001), Point(lat - 0.0001, lon + 0.0001)]  # fmt: skip
        await fence.upload_geofence(GeofenceData([Polygon(corners, FenceType.INCLUSION)], []))
        try:  # two vertices: no inside; PX4's ERROR, the fence kept
            await fence.upload_geofence(GeofenceData([Polygon(corners[:2], FenceType.INCLUSION)], []))
            seen["malformed"] = None
        except GeofenceError as exc:
            seen["malformed"] = exc.result
        back = await fence.download_geofence()
        seen["downloaded"] = [[(p.latitude_deg, p.longitude_deg) for p in poly.points] for poly in back.polygons]
        seen["corners"] = [(p.latitude_deg, p.longitude_deg) for p in corners]
        await param.set_param_int("GF_ACTION", action)
        await action_.set_takeoff_altitude(3.0)
        await action_.arm()
        await action_.takeoff()
        await until(tel.subscribe_position(), lambda p: p.relative_altitude_m > 2.9, 30)
        if action == 2:  # a goto and an orbit beyond the fence: accepted and ignored, as PX4's navigator does
            here = await first(tel.subscribe_position())
            await action_.goto_location(lat + 0.001, lon, here.absolute_altitude_m, 0.0)
            await action_.do_orbit(5.0, 2.0, OrbitYawBehavior.HOLD_FRONT_TO_CIRCLE_CENTER, lat + 0.001, lon,
                                   here.absolute_altitude_m)  # fmt: skip
            await asyncio.sleep(1.0)
            seen["after_goto"] = (await first(tel.subscribe_position_velocity_ned())).position
            seen["mode_after_goto"] = await first(tel.subscribe_flight_mode())
        await off.set_velocity_ned(VelocityNedYaw(2.0, 0.0, 0.0, 0.0))
        await off.start()
        wanted = FlightMode.HOLD if action == 2 else FlightMode.RETURN_TO_LAUNCH
        await until(tel.subscribe_flight_mode(), lambda mode: mode == wanted, 30)
        seen["north_at_breach"] = (await first(tel.subscribe_position_velocity_ned())).position.north_m
        if action == 2:
            await asyncio.sleep(3)
            seen["north_held"] = (await first(tel.subscribe_position_velocity_ned())).position.north_m
            await action_.land()
        await until(tel.subscribe_armed(), lambda a: not a, 90)
        seen["north_landed"] = (await first(tel.subscribe_position_velocity_ned())).position.north_m
        listener.cancel()
    seen["said"] = said
    return seen


@pytest.mark.parametrize("action", [2, 3])  # hold (PX4's default), return
def test_mavsdk_geofence_example_and_a_breach_flown_end_to_end(action):
    with quadsitl_up("--preset", "x500", "--speed", "3") as v:
        seen = asyncio.run(asyncio.wait_for(fence_and_breach(v.api_port, action), 240))
        assert v.proc.poll() is None
    assert seen["malformed"] is not None  # refused
    (polygon,) = seen["downloaded"]  # the first fence, kept
    assert len(polygon) == 4
    for got, sent in zip(polygon, seen["corners"], strict=True):
        assert got == pytest.approx(sent, abs=1e-7)
    what = {2: "hold", 3: "return"}[action]
    assert f"Geofence breached: outside the fence; action: {what}" in seen["said"], seen["said"]
    # The position the ground station holds when it sees the mode change may be the last one sent before the breach:
    # one LOCAL_POSITION_NED period (20 ms, 4 cm at 2 m/s) short of the fence at most.
    assert FENCE_NORTH - 0.05 < seen["north_at_breach"] < FENCE_NORTH + 2.0
    if action == 2:  # held where it stopped: at most its braking distance beyond the fence
        assert "Reposition is outside geofence" in seen["said"] and "Orbit is outside geofence" in seen["said"]
        assert math.hypot(seen["after_goto"].north_m, seen["after_goto"].east_m) < 0.5  # it stayed
        assert seen["mode_after_goto"] == FlightMode.HOLD  # not orbiting
        assert abs(seen["north_held"] - seen["north_at_breach"]) < 3.0
        assert seen["north_landed"] > FENCE_NORTH
    else:  # returned home and landed there
        assert abs(seen["north_landed"]) < 1.0


def north_east(lat0: float, lon0: float, north: float, east: float) -> tuple[float, float]:
    return lat0 + north / 111_320.0, lon0 + east / (111_320.0 * math.cos(math.radians(lat0)))


async def rally_and_return(port: int, plan: Path) -> dict:
    """mission_import.py's steps (a QGroundControl plan imported, its mission and rally points uploaded), then a
    flight north and a return, which goes to the rally point nearer than home."""
    seen: dict = {}
    async with Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION)) as m:
        system = await autopilot(m, port)
        tel, act, raw = TelemetryAsync(system), ActionAsync(system), MissionRawAsync(system)
        await healthy(tel)
        imported = await raw.import_qgroundcontrol_mission(str(plan))
        await raw.upload_mission(imported.mission_items)
        await raw.upload_rally_points(imported.rally_items)
        seen["rally_back"] = [(p.x, p.y, p.z) for p in await raw.download_rallypoints()]
        seen["rally_sent"] = [(p.x, p.y, p.z) for p in imported.rally_items]
        home = await first(tel.subscribe_home())
        await act.set_takeoff_altitude(5.0)
        await act.arm()
        await act.takeoff()
        await until(tel.subscribe_position(), lambda p: p.relative_altitude_m > 4.9, 30)
        lat, lon = north_east(home.latitude_deg, home.longitude_deg, 30.0, 0.0)
        await act.goto_location(lat, lon, home.absolute_altitude_m + 5.0, 0.0)
        await until(tel.subscribe_position_velocity_ned(), lambda p: p.position.north_m > 29.0, 60)
        await act.return_to_launch()
        await until(tel.subscribe_armed(), lambda a: not a, 120)
        p = (await first(tel.subscribe_position_velocity_ned())).position
        seen["landed"] = (p.north_m, p.east_m)
    return seen


def test_mavsdk_mission_import_uploads_rally_points_and_a_return_lands_at_the_nearest(tmp_path):
    plan = json.loads((DATA / "square.plan").read_text())
    home = plan["mission"]["plannedHomePosition"]
    rally = north_east(home[0], home[1], 40.0, 10.0)  # nearer the vehicle at 30 m north than home is
    far = north_east(home[0], home[1], -80.0, 0.0)
    plan["rallyPoints"] = {"version": 2, "points": [[*far, 10.0], [*rally, 10.0]]}
    path = tmp_path / "rally.plan"
    path.write_text(json.dumps(plan))
    with quadsitl_up("--preset", "x500", "--speed", "4") as v:
        seen = asyncio.run(asyncio.wait_for(rally_and_return(v.api_port, path), 240))
        assert v.proc.poll() is None
    assert seen["rally_back"] == seen["rally_sent"] and len(seen["rally_sent"]) == 2
    north, east = seen["landed"]
    assert math.hypot(north - 40.0, east - 10.0) < 1.0, seen["landed"]  # at the rally point, not home
