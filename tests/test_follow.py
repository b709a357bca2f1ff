"""PX4's follow-me (FOLLOW_TARGET, autopilot.commander's FOLLOW): the receiver's reading of FOLLOW_TARGET, and the mode
flown in a closed loop of the compiled tick and the plant (tests/flight_loop.py): held until a target reports, then
FLW_TGT_DST from it on the side FLW_TGT_FA says at FLW_TGT_HT, moving with it and facing it, round to another side
when FLW_TGT_FA changes, and held where it stops when the target goes quiet."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from autopilot import records, setpoints
from autopilot import tick as kernel
from autopilot.commander import CommanderSettings
from autopilot.receiver import Receiver
from quadsitl import wire
from quadsitl.config import load_preset
from quadsitl.wire import Mode
from tests.flight_loop import Flight

X500 = load_preset("x500")
M = wire.mavlink
ORIGIN = (47.397742, 8.545594, 488.0)


def test_follow_target_is_read_as_px4_reads_it_and_a_bad_position_refused():
    got, counters = [], records.Counters()
    said = []
    outbox = type("Said", (), {"refuse": lambda self, topic, text: said.append(text)})()
    routes = records.Routes(*([got.append] * 12))
    frame = setpoints.Frame(ORIGIN, xy_vel_max=12.0, z_vel_up=3.0, z_vel_dn=1.5)
    rx = Receiver(1, 1, routes, outbox, counters, lambda: frame, lambda: 0.6, np.zeros(kernel.IO_SIZE, np.int64))
    north = round((ORIGIN[0] + 10.0 / 111_195.0) * 1e7)  # some 10 m north
    nan3 = [math.nan] * 3
    rx.on_message(M.MAVLink_follow_target_message(0, 3, north, round(ORIGIN[1] * 1e7), 490.0, [1.0, 2.0, 0.5],
                                                  nan3, [1, 0, 0, 0], nan3, nan3, 0), link=None)  # fmt: skip
    rx.on_message(M.MAVLink_follow_target_message(0, 1, north, round(ORIGIN[1] * 1e7), 490.0, nan3, nan3,
                                                  [1, 0, 0, 0], nan3, nan3, 0), link=None)  # fmt: skip
    rx.on_message(M.MAVLink_follow_target_message(0, 1, 95 * 10**7, 0, 490.0, nan3, nan3, [1, 0, 0, 0], nan3, nan3,
                                                  0), link=None)  # fmt: skip
    (a, b) = got
    assert isinstance(a, records.FollowTarget)
    assert a.x == pytest.approx(10.0, abs=0.05) and abs(a.y) < 0.01 and a.altitude == pytest.approx(2.0)
    assert (a.vx, a.vy, a.climb) == (1.0, 2.0, -0.5)  # NED's down is the climb's minus
    assert math.isnan(b.vx) and math.isnan(b.climb)  # no velocity: the change between reports is taken
    assert said == ["FOLLOW_TARGET refused: lat 95, lon 0 deg, alt 490 m; allowed: lat [-90, 90], lon [-180, 180], "
                    "a finite altitude"]  # fmt: skip


class Target:
    """A target walking north at 2 m/s from 30 m north of home, reported every 0.5 s of simulated time."""

    def __init__(self, f: Flight) -> None:
        self.f, self.start = f, f.time

    def position(self) -> tuple[float, float]:
        return 30.0 + 2.0 * (self.f.time - self.start), 0.0

    def fly(self, seconds: float, report: bool = True) -> None:
        for _ in range(round(seconds / 0.5)):
            if report:
                x, y = self.position()
                self.f.commander.on_follow_target(records.FollowTarget(x, y, 0.0, 2.0, 0.0, 0.0, wall=-math.inf))
            self.f.run(0.5)


@pytest.fixture(scope="module")
def followed() -> dict:
    f = Flight(X500, settings=CommanderSettings(takeoff_alt=8.0))
    c = f.commander
    assert c.arm() == (True, "") and c.takeoff()[0]
    f.run(8.0)
    assert c.set_mode(Mode.FOLLOW) == (True, "")
    f.run(1.0)
    seen = {"no_target": list(c.messages)}
    target = Target(f)
    target.fly(25.0)
    seen["behind"], seen["target_behind"] = f.state, target.position()
    c.settings = dataclasses.replace(c.settings, follow_angle=math.pi / 2)  # FLW_TGT_FA 90: its right
    target.fly(15.0)
    seen["right"], seen["target_right"] = f.state, target.position()
    target.fly(6.0, report=False)
    seen["lost"], seen["messages"] = f.state, list(c.messages)
    target.fly(1.0)
    seen["back"] = list(c.messages)
    return seen


def test_follow_me_holds_until_a_target_reports(followed):
    assert followed["no_target"][-1] == (4, "Follow me: no target yet (FOLLOW_TARGET); holding")


def test_follow_me_flies_behind_the_target_at_its_distance_and_height_facing_it(followed):
    s, (tx, ty) = followed["behind"], followed["target_behind"]
    assert s.x == pytest.approx(tx - 8.0, abs=0.3) and s.y == pytest.approx(ty, abs=0.3)  # FLW_TGT_DST behind
    assert s.altitude == pytest.approx(8.0, abs=0.1)  # FLW_TGT_HT above home
    assert s.vx == pytest.approx(2.0, abs=0.1) and abs(s.yaw) < 0.05  # with it, facing it (north)


def test_follow_me_goes_round_to_the_side_flw_tgt_fa_says(followed):
    s, (tx, ty) = followed["right"], followed["target_right"]
    assert s.x == pytest.approx(tx, abs=0.3) and s.y == pytest.approx(ty + 8.0, abs=0.3)  # on its right (east)
    assert abs(math.remainder(s.yaw - (-math.pi / 2), 2 * math.pi)) < 0.05  # facing it: west


def test_follow_me_holds_where_it_stops_when_the_target_goes_quiet_and_follows_it_again(followed):
    assert (4, "Follow target lost: no FOLLOW_TARGET for 1.5 s; holding") in followed["messages"]
    s = followed["lost"]
    assert math.hypot(s.vx, s.vy) < 0.1
    assert followed["back"][-1] == (6, "Follow target back; following")
