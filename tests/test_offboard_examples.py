"""MAVSDK-Python's offboard examples, as written (``offboard_attitude.py``, ``offboard_velocity_ned.py``), flown
against ``quadsitl up --preset x500`` with the vehicle's track recorded: an attitude setpoint's thrust is flown (the
vehicle stays put on the ground at thrust 0 and climbs at 0.7), and the altitude holds through the velocity script's
yaw reversals."""

from __future__ import annotations

import asyncio
import math
import time

import pytest
from mavsdk.asyncio import ComponentType, Configuration, Mavsdk
from mavsdk.asyncio.plugins.action import ActionAsync
from mavsdk.asyncio.plugins.offboard import Attitude, OffboardAsync, VelocityNedYaw
from mavsdk.asyncio.plugins.telemetry import TelemetryAsync

from tests.mavclient import quadsitl_up
from tests.mavsdk_client import autopilot, healthy, until


class Track:
    """The vehicle's NED position as MAVSDK reports it, with the script's phase at each sample."""

    def __init__(self) -> None:
        self.phase = "start"
        # (phase, t [s], north, east, down [m], down speed [m/s])
        self.samples: list[tuple[str, float, float, float, float, float]] = []

    async def record(self, tel: TelemetryAsync) -> None:
        async for p in tel.subscribe_position_velocity_ned():
            n, e, d = p.position.north_m, p.position.east_m, p.position.down_m
            self.samples.append((self.phase, time.monotonic(), n, e, d, p.velocity.down_m_s))

    def of(self, phase: str) -> list[tuple[float, float, float]]:
        return [(n, e, d) for ph, _, n, e, d, _ in self.samples if ph == phase]

    def down_speeds(self, phase: str) -> list[float]:
        return [vd for ph, *_, vd in self.samples if ph == phase]


async def offboard_attitude(port: int) -> Track:
    """offboard_attitude.py's steps and timing, its track recorded."""
    track = Track()
    async with Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION)) as m:
        system = await autopilot(m, port)
        tel, action, off = TelemetryAsync(system), ActionAsync(system), OffboardAsync(system)
        await healthy(tel)
        recorder = asyncio.create_task(track.record(tel))
        await action.arm()
        await off.set_attitude(Attitude(0.0, 0.0, 0.0, 0.0))
        await off.start()
        track.phase = "rest"  # thrust 0: stays on the ground
        await asyncio.sleep(2)
        steps = (("up", Attitude(0.0, 0.0, 0.0, 0.7)), ("roll+", Attitude(30.0, 0.0, 0.0, 0.6)),
                 ("roll-", Attitude(-30.0, 0.0, 0.0, 0.6)), ("hover", Attitude(0.0, 0.0, 0.0, 0.6)))  # fmt: skip
        for phase, attitude in steps:
            track.phase = phase
            await off.set_attitude(attitude)
            await asyncio.sleep(2)
        track.phase = "stopped"
        await off.stop()
        await action.land()
        await until(tel.subscribe_armed(), lambda a: not a, 60)
        recorder.cancel()
    return track


async def offboard_velocity_ned(port: int) -> Track:
    """offboard_velocity_ned.py's steps and timing, its track recorded."""
    track = Track()
    async with Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION)) as m:
        system = await autopilot(m, port)
        tel, action, off = TelemetryAsync(system), ActionAsync(system), OffboardAsync(system)
        await healthy(tel)
        recorder = asyncio.create_task(track.record(tel))
        await action.arm()
        await off.set_velocity_ned(VelocityNedYaw(0.0, 0.0, 0.0, 0.0))
        await off.start()
        steps = (("up", (0.0, 0.0, -2.0, 0.0), 4), ("north", (2.0, 0.0, 0.0, 90.0), 4),
                 ("south", (-2.0, 0.0, 0.0, 270.0), 4), ("west", (0.0, -2.0, 0.0, 90.0), 4),
                 ("east", (0.0, 2.0, 0.0, 90.0), 4), ("turn", (0.0, 0.0, 0.0, 180.0), 2),
                 ("down", (0.0, 0.0, 1.0, 0.0), 4))  # fmt: skip
        for phase, setpoint, seconds in steps:
            track.phase = phase
            await off.set_velocity_ned(VelocityNedYaw(*setpoint))
            await asyncio.sleep(seconds)
        track.phase = "stopped"
        await off.stop()
        recorder.cancel()
    return track


def test_offboard_attitude_flies_the_thrust_and_rests_on_the_ground_at_zero():
    with quadsitl_up("--preset", "x500") as v:
        track = asyncio.run(asyncio.wait_for(offboard_attitude(v.api_port), 150))
        assert v.proc.poll() is None
    rest = track.of("rest")
    assert len(rest) > 10
    # Thrust 0 on the ground: the vehicle neither rises nor slides (it hovered along the ground at 9 m/s before).
    assert max(math.hypot(n, e) for n, e, _ in rest) < 0.01 and max(-d for _, _, d in rest) < 0.01
    up = track.of("up")
    # 0.7 of the x500's 34.2 N is 1.22 × its weight: about 2.2 m/s² up less the drag (a held altitude would be 0).
    # Climbed from rest, v² / 2h is that acceleration whatever the wall-clock sleep's length on a busy machine.
    height, speed = -up[-1][2], -track.down_speeds("up")[-1]
    assert height > 1.5 and 1.5 < speed**2 / (2 * height) < 2.3
    # ±30° roll at 0.6 thrust: it moves sideways (right wing down: east, then back), the height not held.
    roll = track.of("roll+")
    assert roll[-1][1] - roll[0][1] > 1.0
    assert track.of("roll-")[-1][1] - track.of("roll-")[0][1] > 0.0  # still east: the -30° only brakes the drift
    hover = track.of("hover")
    assert abs(hover[-1][2] - up[-1][2]) > 1.0


def test_offboard_velocity_ned_holds_the_altitude_through_yaw_reversals():
    with quadsitl_up("--preset", "x500") as v:
        track = asyncio.run(asyncio.wait_for(offboard_velocity_ned(v.api_port), 150))
        assert v.proc.poll() is None
    # The climb is flown at the commanded 2 m/s. The phases are the script's wall-clock sleeps, so the height
    # climbed in one depends on how busy the machine is; the speed reached does not.
    assert -track.down_speeds("up")[-1] == pytest.approx(2.0, abs=0.2)
    assert -track.of("up")[-1][2] > 4.0
    # The climb stops where the vehicle can stop, and that altitude is held through the turns and reversals.
    held = -track.of("north")[-1][2]
    level = [-d for phase in ("south", "west", "east", "turn") for _, _, d in track.of(phase)]
    worst = max(abs(h - held) for h in level)
    assert worst <= 0.2, f"the altitude strayed {worst:.2f} m from {held:.2f} m with no climb commanded"
    down = track.of("down")
    assert track.down_speeds("down")[-1] == pytest.approx(1.0, abs=0.1)  # then 1 m/s down
    assert down[0][2] < down[-1][2] - 2.0
