"""MAVSDK-Python's ``follow_me_example.py`` on ``quadsitl up`` as on PX4 SITL: its config set (PX4's FLW_TGT_*
parameters), takeoff, ``follow_me.start()`` (AUTO.FOLLOW_TARGET), its three fake target locations, then ``stop()`` and
land. The example's target stands 8 m below home (480 m AMSL) and asks 8 m above it: PX4's safety altitude holds the
vehicle 1 m above the ground, 2 m ahead of the target."""

from __future__ import annotations

import asyncio
import math

import pytest
from mavsdk.asyncio import ComponentType, Configuration, Mavsdk
from mavsdk.asyncio.plugins.action import ActionAsync
from mavsdk.asyncio.plugins.follow_me import Config, FollowMeAsync, TargetLocation
from mavsdk.asyncio.plugins.param import ParamAsync
from mavsdk.asyncio.plugins.telemetry import FlightMode, TelemetryAsync

from quadsitl.frames import geodetic_to_ned
from tests.mavclient import quadsitl_up
from tests.mavsdk_client import autopilot, first, healthy, until

pytestmark = pytest.mark.timeout(300)
FAKE_LOCATION = [[47.398039859999997, 8.5455725400000002], [47.398036222362471, 8.5450146439425509],
                 [47.397825620791885, 8.5450092830163271]]  # fmt: skip


async def follow_me(port: int) -> dict:
    seen: dict = {}
    async with Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION)) as m:
        system = await autopilot(m, port)
        tel, act, follow = TelemetryAsync(system), ActionAsync(system), FollowMeAsync(system)
        await healthy(tel)
        home = await first(tel.subscribe_home())
        await act.arm()
        conf = Config(8.0, 2.0, 0.02, Config.FollowAltitudeMode.TARGET_GPS, 10, 0)  # the example's
        await follow.set_config(conf)
        seen["config"] = await follow.get_config()
        seen["params"] = [await ParamAsync(system).get_param_float(n) for n in ("FLW_TGT_DST", "FLW_TGT_RS")]
        await act.takeoff()
        await until(tel.subscribe_position(), lambda p: p.relative_altitude_m > 2.4, 30)
        await follow.start()
        seen["mode"] = await until(tel.subscribe_flight_mode(), lambda f: f == FlightMode.FOLLOW_ME, 10)
        for _ in range(20):  # MAVSDK's plugin learns the mode from the heartbeat in its own time
            seen["active"] = await follow.is_active()
            if seen["active"]:
                break
            await asyncio.sleep(0.1)
        target = TargetLocation(0, 0, 0, 0, 0, 0)
        for latitude, longitude in FAKE_LOCATION:
            target.latitude_deg, target.longitude_deg, target.absolute_altitude_m = latitude, longitude, 480.0
            target.velocity_x_m_s = target.velocity_y_m_s = target.velocity_z_m_s = 0
            await follow.set_target_location(target)
            await asyncio.sleep(2)
        await asyncio.sleep(6)  # MAVSDK keeps reporting the last location once a second
        p = await first(tel.subscribe_position_velocity_ned())
        seen["at"] = (p.position.north_m, p.position.east_m, -p.position.down_m)
        seen["target"] = geodetic_to_ned(*FAKE_LOCATION[-1], home.latitude_deg, home.longitude_deg)
        await follow.stop()
        seen["stopped"] = await until(tel.subscribe_flight_mode(), lambda f: f == FlightMode.HOLD, 10)
        await act.land()
        await until(tel.subscribe_armed(), lambda a: not a, 60)
    return seen


def test_mavsdks_follow_me_example_follows_the_target_and_stops():
    with quadsitl_up("--preset", "x500", "--speed", "2") as v:
        seen = asyncio.run(asyncio.wait_for(follow_me(v.api_port), 200))
        assert v.proc.poll() is None
    conf = seen["config"]
    assert (conf.follow_height_m, conf.follow_distance_m, conf.follow_angle_deg) == (8.0, 2.0, 0.0)
    assert seen["params"] == [2.0, pytest.approx(0.02)]
    assert seen["active"] is True
    north, east, up = seen["at"]
    tn, te = seen["target"]
    assert north == pytest.approx(tn + 2.0, abs=0.5) and east == pytest.approx(te, abs=0.5)  # 2 m ahead (north)
    assert up == pytest.approx(1.0, abs=0.2)  # the target's altitude + 8 m is the ground: PX4's 1 m safety altitude
    assert math.hypot(north - tn, east - te) > 1.0
