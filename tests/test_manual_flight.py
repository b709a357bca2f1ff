"""The sticks on ``quadsitl up`` as on PX4 SITL: MAVSDK-Python's ``manual_control.py`` steps (sticks set, arm, takeoff,
``start_position_control()``, then stick inputs at 10 Hz) fly POSCTL, and the sticks' loss flies PX4's failsafe end to
end (NAV_RCL_ACT 2, PX4's default: return, landed and disarmed at home)."""

from __future__ import annotations

import asyncio
import math

import pytest
from mavsdk.asyncio import ComponentType, Configuration, Mavsdk
from mavsdk.asyncio.plugins.action import ActionAsync
from mavsdk.asyncio.plugins.manual_control import ManualControlAsync, ManualControlError
from mavsdk.asyncio.plugins.param import ParamAsync
from mavsdk.asyncio.plugins.telemetry import FlightMode, TelemetryAsync

from tests.mavclient import quadsitl_up
from tests.mavsdk_client import autopilot, first, healthy, texts, until

pytestmark = pytest.mark.timeout(300)


class Joystick:
    """manual_control.py's loop in the background: the current sticks every 0.1 s (x = pitch, y = roll, z = throttle
    0..1, r = yaw), whatever the test waits for meanwhile, until it lets go."""

    def __init__(self, mc: ManualControlAsync) -> None:
        self.mc, self.sticks = mc, (0.0, 0.0, 0.5, 0.0)
        self.task = asyncio.create_task(self.send())

    async def send(self) -> None:
        while True:
            await self.mc.set_manual_control_input(*self.sticks)
            await asyncio.sleep(0.1)

    async def hold(self, seconds: float, pitch=0.0, roll=0.0, throttle=0.5, yaw=0.0) -> None:
        self.sticks = (pitch, roll, throttle, yaw)
        await asyncio.sleep(seconds)

    def let_go(self) -> None:
        self.task.cancel()


async def north_east(tel: TelemetryAsync) -> tuple[float, float]:
    p = (await first(tel.subscribe_position_velocity_ned())).position
    return p.north_m, p.east_m


async def manual_flight(port: int) -> dict:
    seen: dict = {}
    said: list[str] = []
    async with Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION)) as m:
        system = await autopilot(m, port)
        tel, act, mc = TelemetryAsync(system), ActionAsync(system), ManualControlAsync(system)
        listener = asyncio.create_task(texts(system, said))
        await healthy(tel)
        try:  # MAVSDK refuses this itself (INPUT_NOT_SET): no sticks given yet
            await mc.start_position_control()
            seen["without_input"] = None
        except ManualControlError as exc:
            seen["without_input"] = exc.result
        await ParamAsync(system).set_param_float("RTL_RETURN_ALT", 4.0)
        await mc.set_manual_control_input(0.0, 0.0, 0.5, 0.0)  # manual_control.py from here on, as written
        await act.arm()
        await act.takeoff()
        await asyncio.sleep(5)  # no sticks for 5 s: lost, held for COM_FAIL_ACT_T, and back before its end
        await mc.set_manual_control_input(0.0, 0.0, 0.5, 0.0)
        await mc.start_position_control()
        stick = Joystick(mc)  # the example's loop from here on
        seen["mode"] = await until(tel.subscribe_flight_mode(), lambda f: f == FlightMode.POSCTL, 10)
        await stick.hold(3.0)  # centred while the takeoff's climb stops
        start = await north_east(tel)
        await stick.hold(3.0, pitch=1.0)  # forward: north at heading 0
        seen["moved"] = [a - b for a, b in zip(await north_east(tel), start, strict=True)]
        await stick.hold(4.0)  # centred: brake, hold
        held = await north_east(tel)
        await stick.hold(2.0)
        seen["drift"] = math.dist(await north_east(tel), held)
        seen["heights"] = [(await first(tel.subscribe_position())).relative_altitude_m]
        await stick.hold(2.0)
        seen["heights"].append((await first(tel.subscribe_position())).relative_altitude_m)
        stick.let_go()
        # the sticks stop: lost after COM_RC_LOSS_T, NAV_RCL_ACT's return
        seen["lost_mode"] = await until(tel.subscribe_flight_mode(), lambda f: f == FlightMode.RETURN_TO_LAUNCH, 10)
        await until(tel.subscribe_armed(), lambda a: not a, 90)
        seen["landed"] = await north_east(tel)
        listener.cancel()
    seen["said"] = said
    return seen


def test_mavsdks_manual_control_flies_position_mode_and_the_sticks_loss_returns_home():
    with quadsitl_up("--preset", "x500", "--speed", "1") as v:  # real time: the example's sleeps are PX4 SITL's
        seen = asyncio.run(asyncio.wait_for(manual_flight(v.api_port), 240))
        assert v.proc.poll() is None
    assert seen["without_input"].name == "INPUT_NOT_SET"
    north, east = seen["moved"]
    assert north > 5.0 and abs(east) < 0.5  # forward stick at heading north
    assert seen["drift"] < 0.3  # centred sticks hold the position
    low, high = seen["heights"]
    assert low > 0.5 and high == pytest.approx(low, abs=0.05)  # z 0.5 holds it
    said = seen["said"]
    loss = (
        "Manual control lost: no MANUAL_CONTROL for 0.5 s; action: return in 5 s (COM_FAIL_ACT_T), holding until then"
    )
    assert said.count(loss) == 2, said  # in the example's sleep, and when the sticks stop for good
    # the sleep ended within the delay: the sticks back (in the mode flown then: POSCTL once the example's switch to
    # it came first, the takeoff's on a loaded machine whose simulated time lags the sleep), no return
    back = [i for i, text in enumerate(said) if text.startswith("Manual control regained; mode ")]
    assert back and back[0] < said.index(loss, said.index(loss) + 1), said
    assert "Failsafe: manual control still lost; return" in said
    assert math.hypot(*seen["landed"]) < 1.0  # home
