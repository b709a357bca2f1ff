"""MAVSDK-Python's ``calibration.py`` on ``quadsitl up`` as on PX4 SITL: the gyro calibrates (its progress reported, its
offsets saved as CAL_GYRO0_*OFF); the accelerometer's finds the vehicle on its "down" side, measures it and fails,
as PX4's does when the vehicle is never turned over ("timeout: no motion"), and the example stops there. With the 4.x
API the rest are called too: the magnetometer's fails for want of rotation, the level calibration saves the board
offsets; a calibration armed is refused, and one running is cancelled (``cancel()``)."""

from __future__ import annotations

import asyncio

import pytest
from mavsdk.asyncio import ComponentType, Configuration, Mavsdk
from mavsdk.asyncio.plugins.action import ActionAsync
from mavsdk.asyncio.plugins.calibration import CalibrationAsync, CalibrationError, CalibrationResult
from mavsdk.asyncio.plugins.param import ParamAsync
from mavsdk.asyncio.plugins.telemetry import TelemetryAsync

from tests.mavclient import quadsitl_up
from tests.mavsdk_client import autopilot, healthy, texts, until

pytestmark = pytest.mark.timeout(300)


async def run(calibrate) -> tuple[str, list]:
    """The example's loop over one calibration's progress → (how it ended, the progress data seen)."""
    seen = []
    try:
        async for result, progress in calibrate():
            seen.append(progress)
            if result == CalibrationResult.SUCCESS:
                return "SUCCESS", seen
    except CalibrationError as exc:
        return exc.result.name, seen
    return "ended", seen


async def heard(said: list[str], text: str, timeout: float = 5.0) -> None:
    """Until ``text`` is among the status texts (their subscription may trail the calibration's report)."""
    for _ in range(int(timeout / 0.05)):
        if text in said:
            return
        await asyncio.sleep(0.05)


async def calibrations(port: int, sensors: bool) -> dict:
    seen: dict = {}
    said: list[str] = []
    async with Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION)) as m:
        system = await autopilot(m, port)
        tel, cal, par, act = TelemetryAsync(system), CalibrationAsync(system), ParamAsync(system), ActionAsync(system)
        listener = asyncio.create_task(texts(system, said))
        await healthy(tel, 60)
        seen["gyro"] = await run(cal.calibrate_gyro)
        seen["gyro_offsets"] = [await par.get_param_float(f"CAL_GYRO0_{a}OFF") for a in "XYZ"]
        seen["accel"] = await run(cal.calibrate_accelerometer)
        await heard(said, "[cal] calibration failed: accel")
        if sensors:
            seen["said_accel"] = list(said)
            seen["mag"] = await run(cal.calibrate_magnetometer)
            await heard(said, "[cal] calibration failed: mag")
            seen["level"] = await run(cal.calibrate_level_horizon)
            seen["board"] = [await par.get_param_float(f"SENS_BOARD_{a}_OFF") for a in "XY"]
            gyro = asyncio.create_task(run(cal.calibrate_gyro))  # cancelled while it runs
            await asyncio.sleep(0.05)
            await cal.cancel()
            seen["cancelled"] = await asyncio.wait_for(gyro, 10)
            await heard(said, "[cal] calibration cancelled")
            await act.arm()
            seen["armed"] = await run(cal.calibrate_gyro)
            await act.disarm()
            await until(tel.subscribe_armed(), lambda a: not a, 10)
        listener.cancel()
    seen["said"] = said
    return seen


def test_mavsdks_calibration_example_calibrates_the_gyro_and_stops_at_the_accelerometer():
    """calibration.py's steps on x500 (truth mode: ideal sensors at rest), up to where it stops on PX4 SITL."""
    with quadsitl_up("--preset", "x500", "--speed", "4") as v:
        seen = asyncio.run(asyncio.wait_for(calibrations(v.api_port, sensors=False), 120))
        assert v.proc.poll() is None
    result, progress = seen["gyro"]
    assert result == "SUCCESS"
    fractions = [p.progress for p in progress if p.has_progress]
    assert fractions == sorted(fractions) and fractions[-1] == pytest.approx(1.0), fractions
    assert seen["gyro_offsets"] == [0.0, 0.0, 0.0]  # ideal sensors at rest: no offset
    result, progress = seen["accel"]
    assert result == "FAILED"
    instructions = [p.status_text for p in progress if p.has_status_text]
    assert "down orientation detected" in instructions
    said = seen["said"]
    assert "[cal] calibration failed: timeout: no motion" in said
    assert said.count("[cal] down side already completed") == 5  # PX4's five tries before it gives up


def test_mavsdk_calibrates_in_sensor_mode_saves_what_it_measures_and_refuses_armed():
    """Sensor mode (PX4's IMU profile: no turn-on bias): the gyro offsets measured are the noise's mean, small and
    not zero, and saved; the level calibration saves the attitude the estimate shows at rest; the magnetometer's
    fails without rotation (at 4× real time: its 35 s deadline in about 9 s); cancelled, and refused armed."""
    with quadsitl_up("--preset", "x500", "--state", "sensors", "--speed", "4") as v:
        seen = asyncio.run(asyncio.wait_for(calibrations(v.api_port, sensors=True), 200))
        assert v.proc.poll() is None
    assert seen["gyro"][0] == "SUCCESS"
    assert all(0.0 < abs(o) < 2e-3 for o in seen["gyro_offsets"]), seen["gyro_offsets"]
    assert seen["accel"][0] == "FAILED"
    assert seen["mag"][0] == "FAILED"
    assert "Failed: This calibration requires rotation." in seen["said"]
    assert seen["level"][0] == "SUCCESS"
    assert all(0.0 < abs(b) < 2.0 for b in seen["board"]), seen["board"]  # [deg]
    assert seen["cancelled"][0] == "CANCELLED"
    assert "[cal] calibration cancelled" in seen["said"]
    assert seen["armed"][0] == "COMMAND_DENIED"  # MAVSDK reports TEMPORARILY_REJECTED so
