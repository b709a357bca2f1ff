"""MAVSDK-Python (from PyPI, as its users install it) against ``quadsitl up`` on the offboard-API link:
connect, see a PX4 vehicle, read and set parameters, arm, fly offboard attitude (and altitude) setpoints,
hold, land; and see it healthy and armable, with a GPS fix and a home, before takeoff."""

import asyncio
import time

import pytest
from mavsdk.asyncio import Autopilot, ComponentType, Configuration, Mavsdk
from mavsdk.asyncio.plugins.action import ActionAsync
from mavsdk.asyncio.plugins.offboard import Attitude, OffboardAsync, PositionNedYaw
from mavsdk.asyncio.plugins.param import ParamAsync, ParamError, ParamResult
from mavsdk.asyncio.plugins.telemetry import FixType, FlightMode, LandedState, TelemetryAsync

from tests.mavclient import quadsitl_up
from tests.mavsdk_client import autopilot, first, healthy, until


async def session(port: int) -> dict:
    seen: dict = {}
    config = Configuration.create_with_component_type(ComponentType.GROUND_STATION)
    async with Mavsdk(config) as m:
        system = await autopilot(m, port)
        seen["autopilot"] = await system.autopilot_type()
        param, tel = ParamAsync(system), TelemetryAsync(system)
        action, off = ActionAsync(system), OffboardAsync(system)

        seen["BS_K1"] = await param.get_param_float("BS_K1")
        await param.set_param_float("BS_K8", 12.0)
        seen["BS_K8"] = await param.get_param_float("BS_K8")
        for name, value in (("VM_MASS", -1.0), ("BS_K1", 5000.0), ("NO_SUCH_PARAM", 1.0)):  # range, (41), name
            began = time.monotonic()
            try:
                await param.set_param_float(name, value)
                seen[f"refused {name}"] = None
            except ParamError as exc:
                seen[f"refused {name}"] = (exc.result, time.monotonic() - began)
        seen["VM_MASS"] = await param.get_param_float("VM_MASS")
        seen["mode_before"] = await first(tel.subscribe_flight_mode())
        home = await first(tel.subscribe_home())
        seen["home"] = (home.latitude_deg, home.longitude_deg, home.absolute_altitude_m)

        await until(tel.subscribe_health(), lambda h: h.is_armable, 20)
        await action.arm()
        seen["armed"] = await until(tel.subscribe_armed(), bool, 5)
        await off.set_position_ned(PositionNedYaw(0.0, 0.0, -2.0, 0.0))  # climb to 2 m first
        await off.start()
        await until(tel.subscribe_position_velocity_ned(), lambda p: abs(p.position.down_m + 2.0) < 0.01, 10)
        # Degrees, and the thrust flown as PX4 flies it: normalised to the paper vehicle's 4 × 10 000 N motors,
        # 0.0005 is 20 N, 0.4 N above its weight: it climbs slowly from 2 m.
        await off.set_attitude(Attitude(5.0, -5.0, 30.0, 0.0005))
        seen["mode"] = await until(tel.subscribe_flight_mode(), lambda m: m == FlightMode.OFFBOARD, 5)
        seen["attitude"] = await until(
            tel.subscribe_attitude_euler(),
            lambda a: abs(a.roll_deg - 5) < 0.05 and abs(a.pitch_deg + 5) < 0.05 and abs(a.yaw_deg - 30) < 0.05,
            10,
        )
        seen["down"] = (await first(tel.subscribe_position_velocity_ned())).position.down_m
        seen["relative_alt"] = (await first(tel.subscribe_position())).relative_altitude_m
        seen["in_air"] = await first(tel.subscribe_landed_state())
        await off.stop()
        seen["hold"] = await until(tel.subscribe_flight_mode(), lambda m: m == FlightMode.HOLD, 5)
        await action.land()
        seen["disarmed"] = await until(tel.subscribe_armed(), lambda a: not a, 15)
        seen["landed"] = await until(tel.subscribe_landed_state(), lambda s: s == LandedState.ON_GROUND, 5)
    return seen


def test_mavsdk_connects_sets_parameters_arms_flies_offboard_attitude_and_lands():
    with quadsitl_up() as v:
        seen = asyncio.run(asyncio.wait_for(session(v.api_port), 120))
        assert v.proc.poll() is None
    assert seen["autopilot"] == Autopilot.PX4
    assert seen["BS_K1"] == 10.0 and seen["BS_K8"] == 12.0
    # Refusals reach MAVSDK as what they are (a PARAM_ERROR), at once: no resends, no TIMEOUT.
    out_of_range = ParamResult.VALUE_OUT_OF_RANGE
    assert seen["refused VM_MASS"][0] == out_of_range and seen["refused BS_K1"][0] == out_of_range
    assert seen["refused NO_SUCH_PARAM"][0] == ParamResult.DOES_NOT_EXIST
    assert max(seen[f"refused {n}"][1] for n in ("VM_MASS", "BS_K1", "NO_SUCH_PARAM")) < 1.0
    assert seen["VM_MASS"] == 2.0
    assert seen["mode_before"] == FlightMode.HOLD and seen["home"] == pytest.approx((47.397742, 8.545594, 488.0))
    assert seen["armed"] and seen["mode"] == FlightMode.OFFBOARD and seen["in_air"] == LandedState.IN_AIR
    assert seen["down"] < -2.0 and seen["relative_alt"] == pytest.approx(-seen["down"], abs=0.05)
    assert seen["hold"] == FlightMode.HOLD and seen["disarmed"] is False and seen["landed"] == LandedState.ON_GROUND


async def health_session(port: int) -> dict:
    seen: dict = {}
    config = Configuration.create_with_component_type(ComponentType.GROUND_STATION)
    async with Mavsdk(config) as m:
        system = await autopilot(m, port)
        tel, action = TelemetryAsync(system), ActionAsync(system)
        seen["health"] = await healthy(tel)  # as MAVSDK's examples wait before they arm
        seen["all_ok"] = await first(tel.subscribe_health_all_ok())
        seen["gps"] = await first(tel.subscribe_gps_info())
        seen["raw_gps"] = await first(tel.subscribe_raw_gps())
        seen["home"] = await first(tel.subscribe_home())
        seen["position"] = await first(tel.subscribe_position())
        seen["landed"] = await first(tel.subscribe_landed_state())
        await action.arm()  # armable means armable
        seen["armed"] = await until(tel.subscribe_armed(), bool, 5)
        await action.disarm()  # on the ground: no force needed
        seen["disarmed"] = await until(tel.subscribe_armed(), lambda a: not a, 5)
    return seen


def test_mavsdk_health_gps_and_home_before_takeoff():
    with quadsitl_up() as v:
        seen = asyncio.run(asyncio.wait_for(health_session(v.api_port), 90))
        assert v.proc.poll() is None
    h = seen["health"]
    assert h.is_gyrometer_calibration_ok and h.is_accelerometer_calibration_ok and h.is_magnetometer_calibration_ok
    assert h.is_local_position_ok and h.is_global_position_ok and h.is_home_position_ok and h.is_armable
    assert seen["all_ok"] is True
    assert seen["gps"].fix_type == FixType.FIX_3D and seen["gps"].num_satellites == 10
    home, pos, raw = seen["home"], seen["position"], seen["raw_gps"]
    assert (home.latitude_deg, home.longitude_deg, home.absolute_altitude_m) == pytest.approx(
        (47.397742, 8.545594, 488.0)
    )
    assert (home.local_north_m, home.local_east_m, home.local_down_m) == (0.0, 0.0, 0.0)
    # before takeoff the vehicle is at home: the same 1e-7 degrees
    assert (pos.latitude_deg, pos.longitude_deg) == (home.latitude_deg, home.longitude_deg)
    assert pos.absolute_altitude_m == pytest.approx(488.0) and pos.relative_altitude_m == pytest.approx(0.0)
    assert (raw.latitude_deg, raw.longitude_deg) == (home.latitude_deg, home.longitude_deg)
    assert raw.hdop == pytest.approx(1.0) and raw.velocity_m_s == 0.0
    assert seen["landed"] == LandedState.ON_GROUND and seen["armed"] and seen["disarmed"] is False
