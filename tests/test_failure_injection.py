"""Failure injection as PX4 has it (SYS_FAILURE_EN, MAV_CMD_INJECT_FAILURE), flown end to end through ``quadsitl up
--preset x500 --state sensors``: MAVSDK's failure plugin as ``failure_injection.py`` uses it (the GPS off while the
vehicle holds 5 m: the failsafe within seconds, a landing, a disarm), each other failure through a raw pymavlink
ground station, and the plant's sensors failing physically (off: nothing sent; stuck: the last sample again; the
other sensors' noise unchanged)."""

from __future__ import annotations

import asyncio
import math
import time

import numpy as np
import pytest
from mavsdk.asyncio import ComponentType, Configuration, Mavsdk
from mavsdk.asyncio.plugins.action import ActionAsync
from mavsdk.asyncio.plugins.failure import FailureAsync, FailureType, FailureUnit
from mavsdk.asyncio.plugins.param import ParamAsync
from mavsdk.asyncio.plugins.telemetry import FlightMode, TelemetryAsync

from quadsitl import failures
from quadsitl.config import SensorParams
from quadsitl.hil import ACCEL_UPDATED, BARO_UPDATED, GYRO_UPDATED, MAG_UPDATED
from sitl import sensors as sn
from tests.mavclient import Client, M, armable_client, quadsitl_up
from tests.mavsdk_client import autopilot, first, healthy, until

pytestmark = pytest.mark.timeout(240)
SENSING = ("--preset", "x500", "--state", "sensors")


async def failure_injection(port: int) -> dict:
    """failure_injection.py's steps (enable, arm, take off, fly to a height, inject the GPS off, wait), at 5 m, with
    what the vehicle then does recorded."""
    seen: dict = {"texts": []}
    async with Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION)) as m:
        system = await autopilot(m, port)
        tel, action, param, failure = TelemetryAsync(system), ActionAsync(system), ParamAsync(system), \
            FailureAsync(system)  # fmt: skip

        async def texts():
            async for t in tel.subscribe_status_text():
                seen["texts"].append((time.monotonic(), t.text))

        reader = asyncio.create_task(texts())
        await healthy(tel)
        await param.set_param_int("SYS_FAILURE_EN", 1)
        await action.arm()
        await action.takeoff()
        await asyncio.sleep(5)
        home = await first(tel.subscribe_position())
        await action.goto_location(home.latitude_deg, home.longitude_deg,
                                   home.absolute_altitude_m - home.relative_altitude_m + 5.0, 0)  # fmt: skip
        await until(tel.subscribe_position(), lambda p: abs(p.relative_altitude_m - 5.0) < 0.3, 20)
        await asyncio.sleep(2)
        seen["held"] = (await first(tel.subscribe_position())).relative_altitude_m
        seen["injected"] = time.monotonic()
        await failure.inject(FailureUnit.SENSOR_GPS, FailureType.OFF, 0)
        await until(tel.subscribe_flight_mode(), lambda mode: mode == FlightMode.LAND, 10)
        seen["land"] = time.monotonic()
        await until(tel.subscribe_armed(), lambda a: not a, 30)
        seen["disarmed"] = time.monotonic()
        seen["landed_at"] = (await first(tel.subscribe_position())).relative_altitude_m
        await param.set_param_int("SYS_FAILURE_EN", 0)
        reader.cancel()
    return seen


def test_mavsdk_turns_the_gps_off_at_5_m_and_the_vehicle_lands_and_disarms():
    with quadsitl_up(*SENSING, "--speed", "2") as v:
        seen = asyncio.run(failure_injection(v.api_port))
    assert abs(seen["held"] - 5.0) < 0.3
    t0 = seen["injected"]
    said = {text: t - t0 for t, text in seen["texts"] if t >= t0}
    lost = next(t for text, t in said.items() if text.startswith("GPS lost"))
    assert lost < 1.0 and "Position estimate lost: no GPS; descending" in said  # the failsafe, within a second
    assert seen["land"] - t0 < 2.0 and seen["disarmed"] - t0 < 20.0
    assert abs(seen["landed_at"]) < 0.3


@pytest.fixture(scope="module")
def vehicle():
    with armable_client(*SENSING, "--speed", "2") as c:
        yield c


def armed(c: Client) -> bool:
    return bool(c.wait("HEARTBEAT", lambda m: m.autopilot == M.MAV_AUTOPILOT_PX4).base_mode
                & M.MAV_MODE_FLAG_SAFETY_ARMED)  # fmt: skip


def inject(c: Client, unit: int, kind: int, instance: int = 0):
    return c.command(M.MAV_CMD_INJECT_FAILURE, unit, kind, instance)


def take_off(c: Client) -> None:
    nan = math.nan
    c.texts.clear()
    c.wait_armable()
    assert c.command(M.MAV_CMD_NAV_TAKEOFF, nan, nan, nan, nan, nan, nan, nan).result == M.MAV_RESULT_ACCEPTED
    ack = c.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    assert ack.result == M.MAV_RESULT_ACCEPTED, c.texts
    c.text_containing("Takeoff complete", timeout=30)


def test_failure_injection_is_refused_unless_enabled_and_names_what_is_taken(vehicle):
    c = vehicle
    c.texts.clear()
    assert inject(c, failures.GPS, failures.OFF).result == M.MAV_RESULT_DENIED
    assert c.text_containing("Failure injection") == "Failure injection disabled: set SYS_FAILURE_EN to 1"
    assert c.param_set("SYS_FAILURE_EN", 1).param_value == 1
    for unit, kind, says in ((failures.GPS, 3, "GPS garbage not supported"), (105, 1, "MAVLink signal off not"),
                             (failures.MOTOR, failures.OFF, "motor 7 off: no such motor")):  # fmt: skip
        assert inject(c, unit, kind, 7 if unit == failures.MOTOR else 0).result == M.MAV_RESULT_UNSUPPORTED
        c.text_containing(says)
    assert "taken: gyro (0): ok, off, stuck" in c.text_containing("GPS garbage")


def test_barometer_and_compass_lost_and_back_in_flight_the_vehicle_holds(vehicle):
    """Baro off in a hold at 2.5 m: said, the altitude from the GPS (within its error); mag off: said, the heading
    from the gyro; each back with OK, said again; no failsafe, still armed."""
    c = vehicle
    assert c.param_set("SYS_FAILURE_EN", 1).param_value == 1
    take_off(c)
    for unit, lost, back in ((failures.BARO, "Barometer lost", "Barometer regained"),
                             (failures.MAG, "Compass lost", "Compass regained")):  # fmt: skip
        assert inject(c, unit, failures.OFF).result == M.MAV_RESULT_ACCEPTED
        c.text_containing(lost, timeout=5)
        c.pump(3.0)
        att, pos = c.wait("ATTITUDE"), c.wait("LOCAL_POSITION_NED")
        assert armed(c) and abs(-pos.z - 2.5) < 2.0 and abs(math.degrees(att.yaw)) < 10.0
        assert inject(c, unit, failures.OK).result == M.MAV_RESULT_ACCEPTED
        c.text_containing(back, timeout=5)
    assert armed(c) and not any("Failsafe" in t for t in c.texts), " | ".join(c.texts)
    c.command(M.MAV_CMD_NAV_LAND)
    c.text_containing("Landed, disarmed", timeout=30)


def test_the_imu_off_in_the_air_is_the_estimator_failsafe_a_landing():
    """A vehicle of its own: what an IMU loss leaves of the estimate is no start for the other tests."""
    with armable_client(*SENSING, "--speed", "2") as c:
        assert c.param_set("SYS_FAILURE_EN", 1).param_value == 1
        take_off(c)
        assert inject(c, failures.GYRO, failures.OFF).result == M.MAV_RESULT_ACCEPTED
        c.text_containing("IMU lost", timeout=5)
        assert "Attitude estimate lost: no IMU" in c.text_containing("Attitude estimate")
        c.text_containing("Failsafe: landing", timeout=5)
        assert inject(c, failures.GYRO, failures.OK).result == M.MAV_RESULT_ACCEPTED  # back: it lands all the same
        c.text_containing("Landed, disarmed", timeout=40)
        assert not armed(c)


def test_a_motor_off_in_the_air_is_com_act_fail_act_terminate_the_vehicle_falls(vehicle):
    """COM_ACT_FAIL_ACT 4 (terminate): motor 1 off in the air, said, the motors off, the vehicle falls to the ground;
    motor 1's force in the telemetry is 0 from the failure on."""
    c = vehicle
    assert c.param_set("SYS_FAILURE_EN", 1).param_value == 1
    assert c.param_set("COM_ACT_FAIL_ACT", 4).param_value == 4
    take_off(c)
    assert inject(c, failures.MOTOR, failures.OFF, 1).result == M.MAV_RESULT_ACCEPTED
    assert c.text_containing("Motor failure") == "Motor failure: motor 1 off; action: terminate"
    c.text_containing("Flight termination", timeout=5)
    assert not armed(c)
    c.wait("LOCAL_POSITION_NED", lambda m: m.z > -0.15, timeout=10)  # down
    assert inject(c, failures.MOTOR, failures.OK, 1).result == M.MAV_RESULT_ACCEPTED
    assert c.param_set("COM_ACT_FAIL_ACT", 0).param_value == 0


def test_a_sensor_failure_on_the_true_state_is_refused():
    with armable_client("--preset", "x500") as c:
        assert c.param_set("SYS_FAILURE_EN", 1).param_value == 1
        c.texts.clear()
        assert inject(c, failures.GPS, failures.OFF).result == M.MAV_RESULT_UNSUPPORTED
        assert "sensors fail with --state sensors" in c.text_containing("Failure GPS off")
        assert inject(c, failures.MOTOR, failures.OFF, 2).result == M.MAV_RESULT_ACCEPTED  # a motor fails either way


def test_the_plants_sensors_fail_physically_off_and_stuck_and_the_rest_is_untouched():
    """sitl.sensors: off sends nothing (its fields_updated bits clear, no fix delivered), stuck sends the last sample
    again, OK restores it; every sample is still drawn, so the other sensors' samples are those of a clean run."""
    period, g = 0.001, 9.8
    clean, failed = sn.Sensors(SensorParams(), period, g), sn.Sensors(SensorParams(), period, g)
    state = (0.0, 0.0, -1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.3, 0.0, 0.0, 0.0)
    assert sn.inject_failure(failed.clock, failures.GPS, failures.OFF)
    assert sn.inject_failure(failed.clock, failures.MAG, failures.STUCK)
    assert not sn.inject_failure(failed.clock, failures.GPS, failures.STUCK)  # not taken: nothing changed
    assert sn.inject_failure(failed.clock, failures.BARO, failures.OFF)
    fixes, mags, fields_seen = 0, set(), 0
    for k in range(3000):
        t = round(k * period * 1e6)
        a, b = clean.tick(t, state, (0.0, 0.0, 0.0)), failed.tick(t, state, (0.0, 0.0, 0.0))
        assert np.array_equal(clean.out[sn.OUT_GYRO : sn.OUT_GYRO + 3], failed.out[sn.OUT_GYRO : sn.OUT_GYRO + 3])
        assert b & (ACCEL_UPDATED | GYRO_UPDATED) == ACCEL_UPDATED | GYRO_UPDATED and not b & BARO_UPDATED
        fixes += clean.gps_new
        assert not failed.gps_new
        if b & MAG_UPDATED:
            mags.add(tuple(failed.out[sn.OUT_MAG : sn.OUT_MAG + 3]))
        fields_seen |= a
    assert fixes > 20 and len(mags) == 1 and fields_seen & BARO_UPDATED  # the magnetometer repeats one sample
    assert sn.inject_failure(failed.clock, failures.MAG, failures.OK)
    failed.tick(3_000_000 + 10_000, state, (0.0, 0.0, 0.0))
    assert tuple(failed.out[sn.OUT_MAG : sn.OUT_MAG + 3]) not in mags
