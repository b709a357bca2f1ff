"""MAVSDK-Python's ``do_orbit.py`` on ``quadsitl up`` as on PX4 SITL: arm, take off, ``do_orbit`` (10 m around a point
54 m from home, 2 m/s, facing the centre, 10 m above home), the vehicle goes round it, then ``return_to_launch``; and
the orbits PX4 refuses: on the ground, and a radius below 1 m."""

from __future__ import annotations

import asyncio
import itertools
import math

import pytest
from mavsdk.asyncio import ComponentType, Configuration, Mavsdk
from mavsdk.asyncio.plugins.action import ActionAsync, ActionError, OrbitYawBehavior
from mavsdk.asyncio.plugins.telemetry import TelemetryAsync

from quadsitl.frames import geodetic_to_ned
from tests.mavclient import quadsitl_up
from tests.mavsdk_client import autopilot, first, healthy, until

pytestmark = pytest.mark.timeout(300)
CENTRE = (47.398036222362471, 8.5450146439425509)  # do_orbit.py's


async def do_orbit(port: int) -> dict:
    seen: dict = {}
    async with Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION)) as m:
        system = await autopilot(m, port)
        tel, act = TelemetryAsync(system), ActionAsync(system)
        await healthy(tel)
        position = await first(tel.subscribe_position())
        home = await first(tel.subscribe_home())
        orbit_height = position.absolute_altitude_m + 10
        behaviour = OrbitYawBehavior.HOLD_FRONT_TO_CIRCLE_CENTER
        try:  # on the ground: PX4's "Orbit command rejected"
            await act.do_orbit(10, 2, behaviour, *CENTRE, orbit_height)
        except ActionError as exc:
            seen["on_ground"] = exc.result.name
        await act.arm()
        await act.takeoff()
        await until(tel.subscribe_position(), lambda p: p.relative_altitude_m > 2.4, 30)
        try:
            await act.do_orbit(0.5, 2, behaviour, *CENTRE, orbit_height)
        except ActionError as exc:
            seen["small"] = exc.result.name
        await act.do_orbit(10, 2, behaviour, *CENTRE, orbit_height)
        north, east = geodetic_to_ned(*CENTRE, home.latitude_deg, home.longitude_deg)
        samples = []

        async def around() -> None:
            async for p in tel.subscribe_position_velocity_ned():
                dn, de = p.position.north_m - north, p.position.east_m - east
                samples.append((math.hypot(dn, de), -p.position.down_m, math.hypot(p.velocity.north_m_s,
                                                                                   p.velocity.east_m_s),
                                math.atan2(de, dn)))  # fmt: skip

        recorder = asyncio.create_task(around())
        await until(tel.subscribe_position_velocity_ned(),
                    lambda p: abs(math.hypot(p.position.north_m - north, p.position.east_m - east) - 10.0) < 1.0,
                    60)  # fmt: skip
        start = len(samples)
        await asyncio.sleep(13.0)  # some 39 s simulated at 3× real time: a turn at 2 m/s on 10 m
        recorder.cancel()
        seen["orbit"] = samples[start + (len(samples) - start) // 3 :]  # the approach's speed gone, the orbit's reached
        await act.return_to_launch()
        await until(tel.subscribe_armed(), lambda a: not a, 120)
        p = (await first(tel.subscribe_position_velocity_ned())).position
        seen["landed"] = (p.north_m, p.east_m)
    return seen


def test_mavsdks_do_orbit_circles_the_point_and_returns():
    with quadsitl_up("--preset", "x500", "--speed", "3") as v:
        seen = asyncio.run(asyncio.wait_for(do_orbit(v.api_port), 240))
        assert v.proc.poll() is None
    assert seen["on_ground"] == "COMMAND_DENIED"  # MAVSDK reports TEMPORARILY_REJECTED so
    assert seen["small"] == "COMMAND_DENIED"
    orbit = seen["orbit"]  # once on the circle at its speed
    assert len(orbit) > 50
    assert all(abs(r - 10.0) < 0.5 for r, _, _, _ in orbit)
    assert all(abs(h - 10.0) < 0.3 for _, h, _, _ in orbit), [round(h, 2) for _, h, _, _ in orbit]
    assert all(abs(v - 2.0) < 0.2 for _, _, v, _ in orbit), [round(v, 2) for _, _, v, _ in orbit]
    swept = sum(math.remainder(b[3] - a[3], 2 * math.pi) for a, b in itertools.pairwise(orbit))
    assert swept > 4.0  # most of a turn, clockwise (the bearing from the centre grows)
    assert math.hypot(*seen["landed"]) < 1.0
