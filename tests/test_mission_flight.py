"""MAVSDK flies a mission on ``quadsitl up`` as its examples do: upload four waypoints with return-to-launch after
the mission, arm, start, pause in the middle and resume, watch the progress reach 4/4 and the mission finish,
and see the vehicle come home, land and disarm."""

import asyncio
import math

import pytest
from mavsdk.asyncio import ComponentType, Configuration, Mavsdk
from mavsdk.asyncio.plugins.action import ActionAsync
from mavsdk.asyncio.plugins.mission import MissionAsync, MissionItem, MissionPlan
from mavsdk.asyncio.plugins.telemetry import FlightMode, TelemetryAsync

from quadsitl.frames import ned_to_geodetic
from tests.mavclient import quadsitl_up
from tests.mavsdk_client import autopilot, first, healthy, until

ORIGIN = (47.397742, 8.545594)
POINTS = ((12.0, 0.0), (12.0, 12.0), (0.0, 12.0), (0.0, 0.0))  # north, east [m]


def plan() -> MissionPlan:
    items = []
    for north, east in POINTS:
        lat, lon = ned_to_geodetic(north, east, *ORIGIN)
        items.append(MissionItem(lat, lon, 5.0, 4.0, False, math.nan, math.nan, MissionItem.CameraAction.NONE, 0.5,
                                 math.nan, 1.0, math.nan, math.nan, MissionItem.VehicleAction.NONE))  # fmt: skip
    return MissionPlan(items)


async def fly(port: int) -> dict:
    seen: dict = {}
    async with Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION)) as m:
        system = await autopilot(m, port)
        tel, action, mission = TelemetryAsync(system), ActionAsync(system), MissionAsync(system)
        await healthy(tel)
        await mission.set_return_to_launch_after_mission(True)
        await mission.upload_mission(plan())
        seen["downloaded"] = len((await mission.download_mission()).mission_items)
        await action.arm()
        await mission.start_mission()
        seen["mode"] = await until(tel.subscribe_flight_mode(), lambda f: f == FlightMode.MISSION, 5)
        progress = await until(mission.subscribe_mission_progress(), lambda p: p.current == 2, 60)
        await mission.pause_mission()
        seen["paused"] = await until(tel.subscribe_flight_mode(), lambda f: f == FlightMode.HOLD, 5)
        await asyncio.sleep(1.0)
        p = (await first(tel.subscribe_position_velocity_ned())).position
        seen["held"] = (p.north_m, p.east_m)
        await asyncio.sleep(1.0)
        p = (await first(tel.subscribe_position_velocity_ned())).position
        seen["still_held"] = (p.north_m, p.east_m)
        await mission.start_mission()  # resume
        progress = await until(mission.subscribe_mission_progress(), lambda p: p.current == p.total, 60)
        seen["progress"] = (progress.current, progress.total)
        seen["finished"] = await until(_poll(mission.is_mission_finished), bool, 60)
        seen["disarmed"] = await until(tel.subscribe_armed(), lambda a: not a, 90)
        p = (await first(tel.subscribe_position_velocity_ned())).position
        seen["landed_at"] = (p.north_m, p.east_m, -p.down_m)
    return seen


async def _poll(call):
    while True:
        yield await call()
        await asyncio.sleep(0.2)


def test_mavsdk_flies_a_mission_with_pause_resume_and_return():
    with quadsitl_up("--speed", "4") as v:
        seen = asyncio.run(asyncio.wait_for(fly(v.api_port), 240))
        assert v.proc.poll() is None
    assert seen["downloaded"] == 4 and seen["mode"] == FlightMode.MISSION and seen["paused"] == FlightMode.HOLD
    assert math.dist(seen["held"], seen["still_held"]) < 0.2  # paused: holds where it stopped
    assert seen["progress"] == (4, 4) and seen["finished"] is True and seen["disarmed"] is False
    assert math.hypot(*seen["landed_at"][:2]) < 0.5 and seen["landed_at"][2] == pytest.approx(0.0, abs=0.1)
