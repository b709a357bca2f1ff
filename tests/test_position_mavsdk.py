"""MAVSDK-Python (from PyPI) flies ``quadsitl up`` the way its examples fly PX4: wait for health, set the takeoff
altitude, arm, take off, go to a location, return to launch; then offboard position, velocity and body-velocity
setpoints, each checked against the telemetry."""

import asyncio
import math

import pytest
from mavsdk.asyncio import ComponentType, Configuration, Mavsdk
from mavsdk.asyncio.plugins.action import ActionAsync
from mavsdk.asyncio.plugins.offboard import OffboardAsync, PositionNedYaw, VelocityBodyYawspeed, VelocityNedYaw
from mavsdk.asyncio.plugins.param import ParamAsync
from mavsdk.asyncio.plugins.telemetry import FlightMode, LandedState, TelemetryAsync

from quadsitl.frames import ned_to_geodetic
from tests.mavclient import quadsitl_up
from tests.mavsdk_client import autopilot, first, healthy, until

SPEED = "4"  # lockstep at 4× real time: MAVSDK's 20 Hz setpoints still arrive many times per simulated second


async def connect(m: Mavsdk, port: int):
    system = await autopilot(m, port)
    tel = TelemetryAsync(system)
    await healthy(tel)
    return system, tel


async def takeoff_goto_return(port: int) -> dict:
    seen: dict = {}
    async with Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION)) as m:
        system, tel = await asyncio.wait_for(connect(m, port), 30)
        action, param = ActionAsync(system), ParamAsync(system)
        await action.set_takeoff_altitude(5.0)
        await param.set_param_float("RTL_RETURN_ALT", 10.0)  # a short climb before returning (PX4's default: 60 m)
        home = await first(tel.subscribe_home())
        await action.arm()
        await action.takeoff()
        seen["in_air"] = await until(tel.subscribe_landed_state(), lambda s: s == LandedState.IN_AIR, 10)
        seen["hold"] = await until(tel.subscribe_flight_mode(), lambda f: f == FlightMode.HOLD, 20)
        seen["altitude"] = (await first(tel.subscribe_position())).relative_altitude_m
        lat, lon = ned_to_geodetic(20.0, 0.0, home.latitude_deg, home.longitude_deg)
        await action.goto_location(lat, lon, home.absolute_altitude_m + 5.0, 0.0)

        def there(p) -> bool:
            return math.hypot(p.position.north_m - 20.0, p.position.east_m) < 0.5 and abs(p.velocity.north_m_s) < 0.05

        arrived = await until(tel.subscribe_position_velocity_ned(), there, 30)
        seen["arrived"] = (arrived.position.north_m, arrived.position.east_m, -arrived.position.down_m)
        await asyncio.sleep(1.0)  # it holds there
        p = (await first(tel.subscribe_position_velocity_ned())).position
        seen["held"] = (p.north_m, p.east_m, -p.down_m)
        seen["goto_mode"] = await first(tel.subscribe_flight_mode())
        await action.return_to_launch()
        seen["rtl"] = await until(tel.subscribe_flight_mode(), lambda f: f == FlightMode.RETURN_TO_LAUNCH, 5)
        seen["disarmed"] = await until(tel.subscribe_armed(), lambda a: not a, 60)
        p = (await first(tel.subscribe_position_velocity_ned())).position
        seen["landed_at"] = (p.north_m, p.east_m, -p.down_m)
        seen["landed"] = await until(tel.subscribe_landed_state(), lambda s: s == LandedState.ON_GROUND, 5)
    return seen


def test_mavsdk_takes_off_goes_to_a_location_and_returns_to_launch():
    with quadsitl_up("--speed", SPEED) as v:
        seen = asyncio.run(asyncio.wait_for(takeoff_goto_return(v.api_port), 150))
        assert v.proc.poll() is None
    assert seen["in_air"] == LandedState.IN_AIR and seen["hold"] == FlightMode.HOLD
    assert seen["altitude"] == pytest.approx(5.0, abs=0.2)
    assert seen["arrived"][:2] == pytest.approx((20.0, 0.0), abs=0.5)
    assert seen["held"] == pytest.approx((20.0, 0.0, 5.0), abs=0.1) and seen["goto_mode"] == FlightMode.HOLD
    assert seen["rtl"] == FlightMode.RETURN_TO_LAUNCH and seen["disarmed"] is False
    assert math.hypot(*seen["landed_at"][:2]) < 0.5 and seen["landed_at"][2] < 0.1
    assert seen["landed"] == LandedState.ON_GROUND


async def offboard(port: int) -> dict:
    seen: dict = {}
    async with Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION)) as m:
        system, tel = await asyncio.wait_for(connect(m, port), 30)
        action, off = ActionAsync(system), OffboardAsync(system)
        await action.arm()
        await off.set_position_ned(PositionNedYaw(3.0, -4.0, -6.0, 90.0))
        await off.start()

        def at_target(p) -> bool:
            return math.dist((p.position.north_m, p.position.east_m, p.position.down_m), (3.0, -4.0, -6.0)) < 0.05

        p = await until(tel.subscribe_position_velocity_ned(), at_target, 30)
        seen["position"] = (p.position.north_m, p.position.east_m, p.position.down_m)
        seen["heading"] = (await first(tel.subscribe_attitude_euler())).yaw_deg
        await off.set_velocity_ned(VelocityNedYaw(1.0, 0.5, -0.3, 90.0))
        await asyncio.sleep(2.0)
        seen["velocity"] = (await first(tel.subscribe_position_velocity_ned())).velocity
        await off.set_velocity_body(VelocityBodyYawspeed(1.5, 0.0, 0.0, 0.0))  # heading east: 1.5 m/s east
        await asyncio.sleep(2.0)
        seen["body"] = (await first(tel.subscribe_position_velocity_ned())).velocity
        await off.set_velocity_body(VelocityBodyYawspeed(0.0, 0.0, 0.0, 20.0))  # turn at 20°/s on the spot
        await asyncio.sleep(1.0)
        seen["yaw_rate"] = (await first(tel.subscribe_attitude_angular_velocity_body())).yaw_rad_s
        seen["mode"] = await first(tel.subscribe_flight_mode())
        await off.stop()
        seen["after"] = await until(tel.subscribe_flight_mode(), lambda f: f == FlightMode.HOLD, 5)
        await action.land()
        seen["disarmed"] = await until(tel.subscribe_armed(), lambda a: not a, 60)
    return seen


def test_mavsdk_offboard_position_velocity_and_body_velocity():
    with quadsitl_up("--speed", SPEED) as v:
        seen = asyncio.run(asyncio.wait_for(offboard(v.api_port), 150))
        assert v.proc.poll() is None
    assert seen["position"] == pytest.approx((3.0, -4.0, -6.0), abs=0.05) and seen["heading"] == pytest.approx(
        90, abs=1
    )
    vel = seen["velocity"]
    assert (vel.north_m_s, vel.east_m_s, vel.down_m_s) == pytest.approx((1.0, 0.5, -0.3), abs=0.05)
    body = seen["body"]
    assert (body.north_m_s, body.east_m_s, body.down_m_s) == pytest.approx((0.0, 1.5, 0.0), abs=0.05)
    assert seen["yaw_rate"] == pytest.approx(math.radians(20), abs=0.02) and seen["mode"] == FlightMode.OFFBOARD
    assert seen["after"] == FlightMode.HOLD and seen["disarmed"] is False
