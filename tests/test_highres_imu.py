"""HIGHRES_IMU on ``quadsitl up`` as MAVSDK-Python's ``highres_imu.py`` reads it: off until asked for (PX4's normal
link), then at the rate ``set_rate_imu`` asks; on sensors the measurements the estimator took, on the true state
the body rates, the Earth's field in the body frame and the barometer, without an accelerometer."""

from __future__ import annotations

import asyncio

import numpy as np
import pytest
from mavsdk.asyncio import ComponentType, Configuration, Mavsdk
from mavsdk.asyncio.plugins.telemetry import TelemetryAsync

from quadsitl import earth
from tests.mavclient import quadsitl_up
from tests.mavsdk_client import autopilot, first, healthy

pytestmark = pytest.mark.timeout(200)


async def imu_samples(port: int, n: int) -> list:
    async with Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION)) as m:
        system = await autopilot(m, port)
        tel = TelemetryAsync(system)
        await healthy(tel)
        await tel.set_rate_imu(50.0)  # highres_imu.py's call: SET_MESSAGE_INTERVAL for HIGHRES_IMU
        samples = [await first(tel.subscribe_imu())]
        async for imu in tel.subscribe_imu():
            samples.append(imu)
            if len(samples) == n:
                break
    return samples


@pytest.mark.parametrize("state", ["sensors", "truth"])
def test_mavsdk_reads_highres_imu_at_the_rate_it_asks(state):
    with quadsitl_up("--preset", "x500", "--state", state) as v:  # real time: the rate is in wall seconds
        samples = asyncio.run(asyncio.wait_for(imu_samples(v.api_port, 26), 120))
        assert v.proc.poll() is None
    stamps = [s.timestamp_us for s in samples[1:]]
    period = (stamps[-1] - stamps[0]) / (len(stamps) - 1)
    assert period == pytest.approx(20_000, rel=0.05)  # 50 Hz of the vehicle's clock
    # at rest on the ground, level, heading north: means over the samples (one sample's noise: 0.03 rad/s, 0.2 m/s²)
    mag = np.mean([(s.magnetic_field_frd.forward_gauss, s.magnetic_field_frd.right_gauss,
                    s.magnetic_field_frd.down_gauss) for s in samples], axis=0)  # fmt: skip
    assert np.linalg.norm(mag) == pytest.approx(earth.MAG_STRENGTH, abs=0.01)
    assert mag[2] > 0.4  # the field dips down at Zürich's 63°
    gyro = np.mean([(s.angular_velocity_frd.forward_rad_s, s.angular_velocity_frd.right_rad_s,
                     s.angular_velocity_frd.down_rad_s) for s in samples], axis=0)  # fmt: skip
    assert np.abs(gyro).max() < 0.02
    assert samples[-1].temperature_degc == pytest.approx(earth.isa_temperature(488.0) - 273.15, abs=0.2)
    acc = np.array([(s.acceleration_frd.forward_m_s2, s.acceleration_frd.right_m_s2, s.acceleration_frd.down_m_s2)
                    for s in samples])  # fmt: skip
    if state == "sensors":  # the accelerometer at rest, level: −g along down
        assert acc.mean(axis=0) == pytest.approx((0.0, 0.0, -9.81), abs=0.1)
        assert 0.1 < acc[:, 2].std() < 0.4  # the noise of PX4's IMU profile at 1 kHz
    else:  # the true state carries no acceleration: not given
        assert (acc == 0.0).all()
