"""The battery on ``quadsitl up`` as on PX4 SITL: MAVSDK-Python's ``telemetry.py`` reads it (a full 4-cell pack at
rest, the hover's current and the charge drawn in flight), SYS_STATUS carries it for pymavlink, and a low battery
flies PX4's failsafe end to end (COM_LOW_BAT_ACT 3: return at the critical level, landed and disarmed at home)."""

from __future__ import annotations

import asyncio
import dataclasses
import math

import pytest
from mavsdk.asyncio import ComponentType, Configuration, Mavsdk
from mavsdk.asyncio.plugins.action import ActionAsync
from mavsdk.asyncio.plugins.param import ParamAsync
from mavsdk.asyncio.plugins.telemetry import FlightMode, TelemetryAsync

from quadsitl.config import load_preset, preset_toml
from tests.mavclient import quadsitl_up
from tests.mavsdk_client import autopilot, first, healthy, texts, until

pytestmark = pytest.mark.timeout(300)


async def battery_in_flight(port: int) -> dict:
    seen: dict = {}
    async with Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION)) as m:
        system = await autopilot(m, port)
        tel, act = TelemetryAsync(system), ActionAsync(system)
        await healthy(tel)
        seen["rest"] = await first(tel.subscribe_battery())
        await act.set_takeoff_altitude(3.0)
        await act.arm()
        await act.takeoff()
        await until(tel.subscribe_position(), lambda p: p.relative_altitude_m > 2.9, 30)
        await asyncio.sleep(2.0)
        seen["hover"] = await first(tel.subscribe_battery())
        await act.land()
        await until(tel.subscribe_armed(), lambda a: not a, 60)
    return seen


def test_mavsdk_reads_the_x500s_battery_at_rest_and_in_flight():
    with quadsitl_up("--preset", "x500", "--speed", "3") as v:
        seen = asyncio.run(asyncio.wait_for(battery_in_flight(v.api_port), 200))
        assert v.proc.poll() is None
    rest, hover = seen["rest"], seen["hover"]
    assert rest.voltage_v == pytest.approx(4 * 4.2, abs=0.01)  # full, at rest: the open-circuit voltage
    assert rest.remaining_percent == 100.0
    assert 15.0 < hover.current_battery_a < 25.0  # some 300 W at 16 V
    assert hover.voltage_v < rest.voltage_v - 0.3  # the sag through the pack's resistance, and the charge drawn
    assert 0.0 < hover.capacity_consumed_ah < 0.1
    assert hover.remaining_percent >= 98.0


async def low_battery(port: int) -> dict:
    seen: dict = {}
    said: list[str] = []
    async with Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION)) as m:
        system = await autopilot(m, port)
        tel, act, param = TelemetryAsync(system), ActionAsync(system), ParamAsync(system)
        listener = asyncio.create_task(texts(system, said))
        await healthy(tel)
        await param.set_param_float("BAT_LOW_THR", 0.5)
        await param.set_param_float("BAT_CRIT_THR", 0.45)
        await param.set_param_int("COM_LOW_BAT_ACT", 3)
        await param.set_param_float("RTL_RETURN_ALT", 3.0)
        await act.set_takeoff_altitude(3.0)
        await act.arm()
        await act.takeoff()
        await until(tel.subscribe_position(), lambda p: p.relative_altitude_m > 2.9, 30)
        await act.goto_location(*seen.setdefault("target", await north_of(tel, 8.0)), 0.0)
        await until(tel.subscribe_flight_mode(), lambda mode: mode == FlightMode.RETURN_TO_LAUNCH, 60)
        seen["at_return"] = await first(tel.subscribe_battery())
        seen["north_at_return"] = (await first(tel.subscribe_position_velocity_ned())).position.north_m
        await until(tel.subscribe_armed(), lambda a: not a, 90)
        p = (await first(tel.subscribe_position_velocity_ned())).position
        seen["landed"] = (p.north_m, p.east_m)
        seen["after"] = await first(tel.subscribe_battery())
        listener.cancel()
    seen["said"] = said
    return seen


async def north_of(tel: TelemetryAsync, metres: float) -> tuple[float, float, float]:
    home = await first(tel.subscribe_home())
    return (home.latitude_deg + metres / 111_320.0, home.longitude_deg, home.absolute_altitude_m + 3.0)


def test_a_low_battery_returns_and_lands_at_home_as_com_low_bat_act_says(tmp_path):
    x500 = load_preset("x500")
    small = dataclasses.replace(x500.battery, capacity_mah=200.0, remaining=0.6)  # 30 mAh to the critical level
    preset = tmp_path / "small.toml"
    preset.write_text(preset_toml(dataclasses.replace(x500, battery=small)))
    with quadsitl_up("--preset", str(preset), "--speed", "3") as v:
        seen = asyncio.run(asyncio.wait_for(low_battery(v.api_port), 240))
        assert v.proc.poll() is None
    said = seen["said"]
    battery = [t for t in said if t.startswith("Battery")]
    # the battery reports whole percent (BATTERY_STATUS), as a smart battery does: 49 % is the first below 50 %
    assert battery == ["Battery low: 49% remaining", "Battery critical: 44% remaining; action: return"], said
    assert 30.0 < seen["at_return"].remaining_percent <= 44.0  # MAVSDK's next BATTERY_STATUS (0.5 Hz) after it
    assert seen["north_at_return"] > 1.0  # on its way north when the battery turned it back
    assert math.hypot(*seen["landed"]) < 1.0  # home
    assert seen["after"].remaining_percent < seen["at_return"].remaining_percent
