"""The mission executor (autopilot/mission_executor.py), flown against a kinematic point: it moves toward the
commanded point at the commanded speed (5 m/s by default), climbs and descends at 2 m/s and turns at 90°/s.
Enough to test the sequencing, acceptance radii, holds, events, yaw, speeds, takeoff, landing and pausing."""

from __future__ import annotations

import dataclasses
import math

import pytest

from autopilot import mission_protocol as mp
from autopilot.mission_executor import (
    Current,
    Finished,
    Goto,
    Hold,
    Land,
    MissionExecutor,
    Reached,
    ReturnToLaunch,
    Takeoff,
    VehicleNow,
)
from autopilot.mission_protocol import MissionItem, MissionProtocol
from quadsitl.frames import ned_to_geodetic

ORIGIN = (47.397742, 8.545594, 488.0)
NAN = math.nan
DT = 0.05


def item(seq: int, command: int = mp.NAV_WAYPOINT, north: float = 0.0, east: float = 0.0, z: float = 10.0, *,
         frame: int = mp.FRAME_GLOBAL_RELATIVE_ALT_INT, p1: float = 0.0, p2: float = 0.0, p4: float = NAN,
         here: bool = False) -> MissionItem:  # fmt: skip
    """An item at (north, east) [m] from the origin (``here``: latitude and longitude 0)."""
    lat, lon = ned_to_geodetic(north, east, ORIGIN[0], ORIGIN[1])
    x, y = (0, 0) if here else (round(lat * 1e7), round(lon * 1e7))
    return MissionItem(seq, frame, command, 0, 1, p1, p2, 0.0, p4, x, y, z)


def square(z: float = 10.0, **kw) -> list[MissionItem]:
    """Four waypoints: a 40 m square north and east of the origin."""
    corners = [(40.0, 0.0), (40.0, 40.0), (0.0, 40.0), (0.0, 0.0)]
    return [item(i, north=n, east=e, z=z, **kw) for i, (n, e) in enumerate(corners)]


class Point:
    """The kinematic vehicle; ``fly`` runs the executor in a loop and records what happened."""

    def __init__(self, home: tuple[float, float, float] = (0.0, 0.0, 0.0), cruise: float = 5.0) -> None:
        self.x, self.y, self.alt, self.yaw = home[0], home[1], home[2], 0.0
        self.home = home
        self.cruise = cruise
        self.landed = True
        self.t = 0.0
        self.goal: tuple[float, float, float] = (self.x, self.y, self.alt)
        self.goal_yaw = NAN
        self.speed = cruise
        self.mode = "hold"
        self.actions: list[tuple[float, object]] = []
        self.events: list[tuple[float, object, tuple[float, float, float, float]]] = []

    def now(self) -> VehicleNow:
        return VehicleNow(self.x, self.y, self.alt, yaw=self.yaw, landed=self.landed)

    def command(self, a: object) -> None:
        self.actions.append((self.t, a))
        if isinstance(a, Goto):
            self.mode, self.goal = "goto", (a.x, a.y, a.altitude)
            self.goal_yaw = a.yaw
            self.speed = self.cruise if math.isnan(a.speed) else a.speed
        elif isinstance(a, Takeoff):
            self.mode, self.goal, self.goal_yaw = "goto", (self.x, self.y, a.altitude), NAN
        elif isinstance(a, Hold):
            self.mode, self.goal, self.goal_yaw = "hold", (self.x, self.y, self.alt), NAN
        elif isinstance(a, Land):
            self.mode, self.goal = "land", (self.x, self.y, 0.0)
        elif isinstance(a, ReturnToLaunch):
            self.mode, self.speed = "rtl", self.cruise
            self.goal = (self.home[0], self.home[1], self.alt)

    def move(self) -> None:
        gx, gy, ga = self.goal
        dx, dy = gx - self.x, gy - self.y
        d = math.hypot(dx, dy)
        step = min(d, self.speed * DT)
        if d > 0.0:
            self.x += dx / d * step
            self.y += dy / d * step
        if self.mode == "rtl" and d == 0.0:
            self.mode, self.goal = "land", (self.x, self.y, 0.0)
        if self.mode != "land" or d == 0.0:
            self.alt += max(-2.0 * DT, min(2.0 * DT, ga - self.alt))
        if not math.isnan(self.goal_yaw):
            err = (self.goal_yaw - self.yaw + math.pi) % (2.0 * math.pi) - math.pi
            self.yaw += max(-math.pi / 2 * DT, min(math.pi / 2 * DT, err))
        self.landed = self.alt <= 0.0 and self.mode in ("land", "hold")
        if self.alt > 0.0:
            self.landed = False
        self.t += DT

    def fly(self, ex: MissionExecutor, seconds: float, until=None) -> None:
        last = ex.action
        for _ in range(round(seconds / DT)):
            a = ex.step(self.t, self.now())
            for e in ex.events:
                self.events.append((self.t, e, (self.x, self.y, self.alt, self.yaw)))
            ex.events.clear()
            if a is not last:
                self.command(a)
                last = a
            if until is not None and until(self, ex):
                return
            self.move()

    def start(self, ex: MissionExecutor) -> None:
        assert ex.start(self.t, self.now())
        for e in ex.events:
            self.events.append((self.t, e, (self.x, self.y, self.alt, self.yaw)))
        ex.events.clear()
        self.command(ex.action)

    def reached(self) -> list[int]:
        return [e.seq for _, e, _ in self.events if isinstance(e, Reached)]

    def reached_at(self, seq: int) -> tuple[float, tuple[float, float, float, float]]:
        return next((t, where) for t, e, where in self.events if e == Reached(seq))


def complete(p: Point, ex: MissionExecutor) -> bool:
    return ex.mission_state == mp.STATE_COMPLETE


def test_a_four_waypoint_mission_from_the_ground_takes_off_first_then_flies_each_in_order_and_holds_at_the_end():
    p = Point()
    ex = MissionExecutor(square(), ORIGIN)
    assert ex.mission_state == mp.STATE_NOT_STARTED
    p.start(ex)
    assert ex.mission_state == mp.STATE_ACTIVE and ex.current == 0
    assert isinstance(ex.action, Takeoff) and ex.action.altitude == pytest.approx(10.0)
    p.fly(ex, 120.0, until=complete)
    assert p.reached() == [0, 1, 2, 3]
    assert [e for _, e, _ in p.events if isinstance(e, Current)] == [
        Current(0, mp.STATE_ACTIVE), Current(1, mp.STATE_ACTIVE), Current(2, mp.STATE_ACTIVE),
        Current(3, mp.STATE_ACTIVE), Current(3, mp.STATE_COMPLETE),
    ]  # fmt: skip
    assert isinstance(p.events[-1][1], Finished)
    assert ex.current == 3 and isinstance(ex.action, Hold)
    # the climb ends within NAV_MC_ALT_RAD before the first leg starts; the goto's altitude is the item's
    gotos = [a for _, a in p.actions if isinstance(a, Goto)]
    assert len(gotos) == 4 and all(g.altitude == pytest.approx(10.0) for g in gotos)
    first_goto_t = next(t for t, a in p.actions if isinstance(a, Goto))
    assert p.alt >= 10.0 - 0.8 - 1e-9
    assert first_goto_t > 10.0 / 2.0 * 0.8 - DT
    # each waypoint reached within the default 2 m (and 0.8 m vertically); NaN yaw faces each leg
    for seq, (n, e) in enumerate([(40.0, 0.0), (40.0, 40.0), (0.0, 40.0), (0.0, 0.0)]):
        _, (x, y, alt, _) = p.reached_at(seq)
        assert math.hypot(x - n, y - e) <= 2.0 + 1e-6 and abs(alt - 10.0) <= 0.8
        assert math.hypot(x - n, y - e) > 2.0 - 5.0 * DT - 1e-6  # no sooner than the radius allows
    # (from where each leg starts: up to 2 m short of the last corner, so within 3°)
    for g, bearing in zip(gotos, (0.0, 90.0, 180.0, 270.0)):
        assert abs((math.degrees(g.yaw) - bearing + 180.0) % 360.0 - 180.0) < 3.0
    # nothing more happens afterwards
    n = len(p.events)
    p.fly(ex, 5.0)
    assert len(p.events) == n and isinstance(ex.action, Hold)


def test_the_takeoff_first_goes_to_mis_takeoff_alt_when_the_first_waypoint_is_lower():
    p = Point()
    ex = MissionExecutor(square(z=1.0), ORIGIN)
    p.start(ex)
    assert isinstance(ex.action, Takeoff) and ex.action.altitude == pytest.approx(2.5)
    ex2 = MissionExecutor(square(z=1.0), ORIGIN, takeoff_alt=4.0)
    ex2.start(0.0, Point().now())
    assert ex2.action.altitude == pytest.approx(4.0)  # type: ignore[union-attr]


def test_a_waypoint_s_own_acceptance_radius_and_the_default_one():
    p = Point()
    items = [item(0, north=30.0, p2=6.0), item(1, north=60.0)]
    ex = MissionExecutor(items, ORIGIN, acceptance_radius=3.0)
    p.landed, p.alt = False, 10.0
    p.start(ex)
    p.fly(ex, 60.0, until=complete)
    _, (x0, _, _, _) = p.reached_at(0)
    _, (x1, _, _, _) = p.reached_at(1)
    assert 24.0 - 0.02 <= x0 <= 24.0 + 5.0 * DT + 0.02  # (latitudes are stored to 1e-7°, about 1 cm)
    assert 57.0 - 0.02 <= x1 <= 57.0 + 5.0 * DT + 0.02


def test_the_vertical_acceptance_radius_is_0_8_m():
    p = Point()
    p.landed, p.alt = False, 10.0
    ex = MissionExecutor([item(0, north=0.0, z=20.0)], ORIGIN)
    p.start(ex)
    p.fly(ex, 20.0, until=complete)
    _, (_, _, alt, _) = p.reached_at(0)
    assert 19.2 - 2.0 * DT <= alt <= 19.2 + 1e-6


def test_a_hold_time_keeps_the_vehicle_at_the_waypoint_before_the_next_item():
    p = Point()
    p.landed, p.alt = False, 10.0
    items = [item(0, north=20.0, p1=3.0), item(1, north=20.0, east=20.0)]
    ex = MissionExecutor(items, ORIGIN)
    p.start(ex)
    arrived: list[float] = []
    p.fly(ex, 60.0, until=lambda p, ex: (arrived.append(p.t) if p.x >= 18.0 and not arrived else None) or False)
    t0, _ = p.reached_at(0)
    assert t0 - arrived[0] == pytest.approx(3.0, abs=2.5 * DT)
    t_second_goto = [t for t, a in p.actions if isinstance(a, Goto)][1]
    assert t_second_goto == pytest.approx(t0, abs=DT)


def test_loiter_time_and_delay_hold_for_their_time():
    p = Point()
    p.landed, p.alt = False, 10.0
    items = [item(0, mp.NAV_LOITER_TIME, north=10.0, p1=4.0), item(1, mp.NAV_DELAY, p1=2.0, frame=mp.FRAME_MISSION),
             item(2, north=30.0)]  # fmt: skip
    ex = MissionExecutor(items, ORIGIN)
    p.start(ex)
    p.fly(ex, 60.0, until=complete)
    t0, (x0, _, _, _) = p.reached_at(0)
    t1, _ = p.reached_at(1)
    assert x0 == pytest.approx(10.0, abs=0.02)  # held at the point during the 4 s
    assert t1 - t0 == pytest.approx(2.0, abs=1.5 * DT)
    assert any(isinstance(a, Hold) for _, a in p.actions)  # the delay holds
    assert p.reached() == [0, 1, 2]


def test_a_given_yaw_is_flown_and_waited_for_within_12_degrees():
    p = Point()
    p.landed, p.alt = False, 10.0
    # a short leg (1 m) toward north, facing west: the position is reached long before the heading
    ex = MissionExecutor([item(0, north=1.0, p4=-90.0), item(1, north=1.0, east=30.0)], ORIGIN)
    p.start(ex)
    assert isinstance(ex.action, Goto) and ex.action.yaw == pytest.approx(-math.pi / 2)
    p.fly(ex, 30.0, until=complete)
    t0, (_, _, _, yaw) = p.reached_at(0)
    assert abs(yaw + math.pi / 2) <= math.radians(12.0) + 1e-9
    assert t0 >= (math.pi / 2 - math.radians(12.0)) / (math.pi / 2) - 2 * DT


def test_change_speed_sets_the_following_legs_speed_and_completes_at_once():
    p = Point()
    p.landed, p.alt = False, 10.0
    items = [item(0, north=10.0), item(1, mp.DO_CHANGE_SPEED, p1=1.0, p2=2.0, frame=mp.FRAME_MISSION),
             item(2, north=20.0), item(3, mp.DO_CHANGE_SPEED, p1=1.0, p2=-1.0, frame=mp.FRAME_MISSION),
             item(4, north=30.0), item(5, mp.DO_CHANGE_SPEED, p1=1.0, p2=-2.0, frame=mp.FRAME_MISSION),
             item(6, north=40.0)]  # fmt: skip
    ex = MissionExecutor(items, ORIGIN)
    p.start(ex)
    p.fly(ex, 60.0, until=complete)
    assert p.reached() == list(range(7))
    gotos = [a for _, a in p.actions if isinstance(a, Goto)]
    assert [g.speed for g in gotos[1:]] == [2.0, 2.0, pytest.approx(NAN, nan_ok=True)]
    assert math.isnan(gotos[0].speed)
    assert p.reached_at(1)[0] == p.reached_at(0)[0]  # in the same step


def test_a_takeoff_item_from_the_ground_and_in_flight():
    p = Point()
    items = [item(0, mp.NAV_TAKEOFF, z=6.0), item(1, north=20.0, z=6.0), item(2, mp.NAV_TAKEOFF, z=12.0)]
    ex = MissionExecutor(items, ORIGIN)
    p.start(ex)
    assert isinstance(ex.action, Takeoff) and ex.action.altitude == pytest.approx(6.0)
    p.fly(ex, 60.0, until=complete)
    assert p.reached() == [0, 1, 2]
    _, (x, y, alt, _) = p.reached_at(2)
    last = [a for _, a in p.actions if isinstance(a, Goto)][-1]
    assert (last.x, last.y, last.altitude) == (pytest.approx(x, abs=2.0), pytest.approx(y, abs=2.0), 12.0)
    assert alt >= 12.0 - 0.8 - 1e-9
    low = MissionExecutor([item(0, mp.NAV_TAKEOFF, z=1.0)], ORIGIN)
    low.start(0.0, Point().now())
    assert low.action.altitude == pytest.approx(2.5)  # type: ignore[union-attr]


def test_a_mission_ending_with_return_finishes_when_landed():
    p = Point()
    ex = MissionExecutor([*square()[:2], item(2, mp.NAV_RETURN_TO_LAUNCH, frame=mp.FRAME_MISSION)], ORIGIN)
    p.start(ex)
    p.fly(ex, 120.0, until=lambda p, ex: complete(p, ex) and p.landed)
    assert isinstance(ex.action, ReturnToLaunch)
    _, (x, y, alt, _) = p.reached_at(2)
    assert math.hypot(x, y) < 1e-6 and alt <= 0.0
    assert isinstance(p.events[-1][1], Finished) and ex.mission_state == mp.STATE_COMPLETE


def test_a_land_item_flies_to_its_position_then_lands_and_finishes_on_the_ground():
    p = Point()
    ex = MissionExecutor([item(0, north=10.0), item(1, mp.NAV_LAND, north=10.0, east=20.0, z=0.0)], ORIGIN)
    p.start(ex)
    p.fly(ex, 120.0, until=lambda p, ex: complete(p, ex))
    kinds = [type(a).__name__ for _, a in p.actions]
    assert kinds == ["Takeoff", "Goto", "Goto", "Land"]
    goto = [a for _, a in p.actions if isinstance(a, Goto)][1]
    assert goto.altitude == pytest.approx(10.0, abs=0.8)  # flies there at its altitude, not the item's 0
    _, (x, y, alt, _) = p.reached_at(1)
    assert math.hypot(x - 10.0, y - 20.0) <= 2.0 and alt <= 0.0 and p.landed
    here = MissionExecutor([item(0, north=10.0), item(1, mp.NAV_LAND, here=True)], ORIGIN)
    q = Point()
    q.start(here)
    q.fly(here, 60.0, until=complete)
    assert [type(a).__name__ for _, a in q.actions] == ["Takeoff", "Goto", "Land"]


def test_pause_holds_mid_leg_and_resume_continues_the_same_item():
    p = Point()
    p.landed, p.alt = False, 10.0
    ex = MissionExecutor(square(), ORIGIN)
    p.start(ex)
    p.fly(ex, 60.0, until=lambda p, ex: ex.current == 1 and p.y > 15.0)
    p.command(ex.pause())  # the shell flies what pause() returns
    assert ex.mission_state == mp.STATE_PAUSED and ex.current == 1 and isinstance(ex.action, Hold)
    p.fly(ex, 5.0)
    where = (p.x, p.y)
    assert p.reached() == [0] and where[1] == pytest.approx(15.0 + 5.0 * DT, abs=5.0 * DT)
    assert ex.resume(p.t, p.now())
    assert ex.mission_state == mp.STATE_ACTIVE and ex.current == 1
    assert isinstance(ex.action, Goto) and (ex.action.x, ex.action.y) == (
        pytest.approx(40.0, abs=0.02),
        pytest.approx(40.0, abs=0.02),
    )
    p.command(ex.action)
    p.fly(ex, 120.0, until=complete)
    assert p.reached() == [0, 1, 2, 3]
    states = [e.mission_state for _, e, _ in p.events if isinstance(e, Current)]
    assert mp.STATE_PAUSED in states
    assert not ex.resume(p.t, p.now())  # only a paused mission resumes


def test_set_current_jumps_to_an_item():
    p = Point()
    p.landed, p.alt = False, 10.0
    ex = MissionExecutor(square(), ORIGIN)
    p.start(ex)
    p.fly(ex, 60.0, until=lambda p, ex: ex.current == 1 and p.y > 5.0)
    assert ex.set_current(3) and not ex.set_current(4) and not ex.set_current(-1)
    p.fly(ex, 60.0, until=complete)
    assert p.reached() == [0, 3]
    goto = [a for _, a in p.actions if isinstance(a, Goto)][-1]
    assert (goto.x, goto.y) == (pytest.approx(0.0, abs=1e-6), pytest.approx(0.0, abs=1e-6))
    # a complete mission: set_current pauses it there; start flies on from that item
    assert ex.set_current(2) and ex.mission_state == mp.STATE_PAUSED
    assert ex.start(p.t, p.now()) and ex.current == 2
    p.command(ex.action)
    p.fly(ex, 60.0, until=complete)
    assert p.reached() == [0, 3, 2, 3]


def test_starting_a_complete_mission_again_starts_from_the_first_item():
    p = Point()
    p.landed, p.alt = False, 10.0
    ex = MissionExecutor(square()[:2], ORIGIN)
    p.start(ex)
    p.fly(ex, 60.0, until=complete)
    p.start(ex)
    assert ex.current == 0 and ex.mission_state == mp.STATE_ACTIVE
    p.fly(ex, 60.0, until=complete)
    assert p.reached() == [0, 1, 0, 1]


def test_altitude_frames_amsl_and_relative_to_home():
    home = (5.0, -3.0, 3.0)
    amsl = item(0, north=10.0, z=498.0, frame=mp.FRAME_GLOBAL_INT)
    amsl_legacy = item(1, north=10.0, z=500.0, frame=mp.FRAME_GLOBAL)
    rel = item(2, north=10.0, east=5.0, z=10.0, frame=mp.FRAME_GLOBAL_RELATIVE_ALT_INT)
    rel_legacy = item(3, north=10.0, z=7.0, frame=mp.FRAME_GLOBAL_RELATIVE_ALT)
    ex = MissionExecutor([amsl, amsl_legacy, rel, rel_legacy], ORIGIN, home)
    assert [ex.altitude_of(i) for i in ex.items] == [pytest.approx(v) for v in (10.0, 12.0, 13.0, 10.0)]
    x, y, _ = ex.local(rel)
    assert (x, y) == (pytest.approx(10.0, abs=0.02), pytest.approx(5.0, abs=0.02))  # 1e-7° is about 1 cm
    # flown: the vehicle climbs to the AMSL item's local altitude
    p = Point(home)
    ex.start(0.0, p.now())
    assert isinstance(ex.action, Takeoff) and ex.action.altitude == pytest.approx(10.0)


def test_no_mission_cannot_start():
    ex = MissionExecutor([], ORIGIN)
    assert ex.mission_state == mp.STATE_NO_MISSION
    assert not ex.start(0.0, VehicleNow(0.0, 0.0, 0.0, landed=True))
    assert isinstance(ex.step(0.0, VehicleNow(0.0, 0.0, 0.0)), Hold)


def test_the_protocol_takes_the_executor_s_progress_and_says_so_on_change():
    proto = MissionProtocol()
    proto.items = tuple(square())
    out = proto.set_progress(1, mp.STATE_ACTIVE)
    assert [o.kind for o in out] == ["MISSION_CURRENT"]
    assert out[0].fields["seq"] == 1 and out[0].fields["mission_state"] == mp.STATE_ACTIVE
    assert proto.set_progress(1, mp.STATE_ACTIVE) == []
    reached = MissionProtocol.item_reached(2)
    assert reached.kind == "MISSION_ITEM_REACHED" and reached.kwargs() == {"seq": 2}


def test_step_returns_the_same_action_object_while_nothing_changes():
    ex = MissionExecutor(square(), ORIGIN)
    v = VehicleNow(0.0, 0.0, 10.0)
    ex.start(0.0, v)
    a = ex.step(0.1, v)
    assert a is ex.step(0.2, v) is ex.step(0.3, VehicleNow(1.0, 0.0, 10.0))


def test_closed_loop_a_mission_flown_by_the_compiled_tick_and_the_plant():
    """The executor's actions handed to the real commander (as the process will), the x500 flying: take off
    first, two waypoints, return and land."""
    from autopilot.commander import CommanderSettings
    from quadsitl.config import load_preset
    from quadsitl.wire import Mode
    from tests.flight_loop import Flight

    f = Flight(load_preset("x500"), settings=CommanderSettings())
    cmd = f.commander
    items = [item(0, north=15.0, z=5.0), item(1, north=15.0, east=15.0, z=5.0, p1=2.0),
             item(2, mp.NAV_RETURN_TO_LAUNCH, frame=mp.FRAME_MISSION)]  # fmt: skip
    ex = MissionExecutor(items, ORIGIN, cmd.home)

    def now() -> VehicleNow:
        s = f.state
        landed = s.altitude < 0.05 and abs(s.climb_rate) < 0.1
        return VehicleNow(s.x, s.y, s.altitude, s.vx, s.vy, s.climb_rate, s.yaw, landed, cmd.armed)

    def hand(a: object) -> None:
        if isinstance(a, Goto):
            assert cmd.reposition(a.x, a.y, a.altitude, a.yaw, a.speed, True)[0]
        elif isinstance(a, Takeoff):
            assert cmd.takeoff(a.altitude)[0]
        else:
            mode = {Hold: Mode.HOLD, Land: Mode.LAND, ReturnToLaunch: Mode.RTL}[type(a)]
            assert cmd.set_mode(mode)[0]

    assert cmd.arm()[0]
    assert ex.start(f.time, now())
    hand(ex.action)
    last, reached = ex.action, []
    while ex.mission_state != mp.STATE_COMPLETE or cmd.armed:
        assert f.time < 120.0, (f.state, cmd.mode, ex.current)
        f.step(10)  # the executor at 1/10 of the control rate
        a = ex.step(f.time, now())
        new = [e.seq for e in ex.events if isinstance(e, Reached)]
        ex.events.clear()
        if 0 in new:  # reached inside the 2 m radius (checked every 10 ticks: a few cm more)
            assert f.horizontal_error(15.0, 0.0) < 2.0 + 0.1
        reached += new
        if a is not last:
            hand(a)
            last = a
    assert reached == [0, 1, 2]
    assert f.horizontal_error(0.0, 0.0) < 0.5 and f.state.altitude < 0.1 and not cmd.armed


def test_the_plan_for_maps_places_each_item_as_it_is_flown_and_says_nothing_it_cannot_know():
    """Missions.plan (the ``quadsitl/<vehicle>/mission`` document): local x, y and altitude of each item as the
    executor reads them, home's x, y for a return, nothing for items without a place of their own."""
    from types import SimpleNamespace

    from autopilot.missions import Missions
    from quadsitl import telemetry

    home = (5.0, -3.0, 3.0)
    items = [item(0, mp.NAV_TAKEOFF, z=8.0, here=True), *square(z=10.0)[:2], item(3, mp.DO_CHANGE_SPEED),
             item(4, mp.NAV_LAND, north=20.0, east=-10.0), item(5, mp.NAV_LAND, here=True),
             item(6, mp.NAV_RETURN_TO_LAUNCH, here=True)]  # fmt: skip
    items = [MissionItem(k, *dataclasses.astuple(i)[1:]) for k, i in enumerate(items)]
    m = Missions(ORIGIN)
    m.protocol.items = tuple(items)
    vehicle = SimpleNamespace(home=home)
    plan = m.plan(vehicle)
    assert [p["seq"] for p in plan] == list(range(7)) and [p["command"] for p in plan] == [i.command for i in items]
    ex = MissionExecutor(items, ORIGIN, home)
    for p, i in zip(plan[1:3], items[1:3]):
        assert (p["x"], p["y"], p["altitude"]) == pytest.approx(ex.local(i))
    assert plan[1]["x"] == pytest.approx(40.0, abs=0.02) and plan[2]["y"] == pytest.approx(40.0, abs=0.02)
    assert plan[1]["altitude"] == pytest.approx(13.0)  # relative to home's 3 m
    assert math.isnan(plan[0]["x"]) and plan[0]["altitude"] == pytest.approx(11.0)  # takes off where it is
    assert all(math.isnan(plan[3][k]) for k in ("x", "y", "altitude"))  # a speed change has no place
    assert (plan[4]["x"], plan[4]["y"]) == pytest.approx((20.0, -10.0), abs=0.02) and math.isnan(plan[4]["altitude"])
    assert math.isnan(plan[5]["x"])  # lands where it is
    assert (plan[6]["x"], plan[6]["y"]) == (5.0, -3.0)  # returns home
    assert m.executor is None  # reading the plan changes nothing

    doc = telemetry.decode_mission(telemetry.encode_mission(7, 2, mp.STATE_ACTIVE, plan))
    assert (doc["version"], doc["current"], doc["state"], doc["total"]) == (7, 2, 3, 7)
    assert doc["items"][1]["x"] == pytest.approx(plan[1]["x"], abs=1e-3) and doc["items"][0]["x"] is None
    assert m.plan(SimpleNamespace(home=home)) == plan and Missions(ORIGIN).plan(vehicle) == []


def test_change_speed_types_2_and_3_set_the_climb_and_descent_speeds_not_the_horizontal_one():
    p = Point()
    p.landed, p.alt = False, 10.0
    items = [item(0, mp.DO_CHANGE_SPEED, p1=2.0, p2=0.5, frame=mp.FRAME_MISSION),
             item(1, mp.DO_CHANGE_SPEED, p1=3.0, p2=0.7, frame=mp.FRAME_MISSION),
             item(2, north=10.0, z=12.0),
             item(3, mp.DO_CHANGE_SPEED, p1=2.0, p2=-2.0, frame=mp.FRAME_MISSION), item(4, north=20.0)]  # fmt: skip
    ex = MissionExecutor(items, ORIGIN)
    p.start(ex)
    p.fly(ex, 60.0, until=complete)
    gotos = [a for _, a in p.actions if isinstance(a, Goto)]
    assert (gotos[0].climb, gotos[0].descent) == (0.5, 0.7) and math.isnan(gotos[0].speed)
    assert math.isnan(gotos[1].climb) and gotos[1].descent == 0.7  # −2: the climb back to its default


def test_an_item_with_autocontinue_0_is_reached_then_held_until_the_next_is_set_current():
    p = Point()
    p.landed, p.alt = False, 10.0
    items = [dataclasses.replace(item(0, north=10.0), autocontinue=0), item(1, north=20.0)]
    ex = MissionExecutor(items, ORIGIN)
    p.start(ex)
    p.fly(ex, 30.0)
    assert p.reached() == [0] and ex.current == 0 and ex.mission_state == mp.STATE_ACTIVE
    assert p.x == pytest.approx(10.0, abs=0.01)  # held at the item, as PX4 loiters there
    assert ex.set_current(1)
    p.fly(ex, 30.0, until=complete)
    assert p.reached() == [0, 1] and p.x == pytest.approx(20.0, abs=2.0)  # within its acceptance radius


def test_loiter_time_radius_is_its_acceptance_and_heading_required_faces_the_next_waypoint_before_leaving():
    p = Point()
    p.landed, p.alt = False, 10.0
    loiter = dataclasses.replace(item(0, mp.NAV_LOITER_TIME, north=10.0, p1=1.0, p2=1.0), p3=6.0)
    ex = MissionExecutor([loiter, item(1, north=10.0, east=30.0)], ORIGIN)
    p.start(ex)
    p.fly(ex, 30.0, until=lambda p, ex: p.reached() == [0])
    t0, where = p.reached_at(0)
    # Arrived 6 m short (its radius; 2 m would be at 1.6 s) at 0.8 s, held 1 s, then turned east at 90°/s: ~2.7 s.
    assert 2.5 < t0 < 3.0
    assert abs(where[3] - math.pi / 2) <= math.radians(12)  # facing the next waypoint before leaving


def test_a_waypoint_pass_radius_and_a_bad_loiter_heading_flag_are_refused_at_upload():
    def fields(command: int, p2: float, p3: float) -> dict:
        f = item(0, command).message_fields()
        return {**f, "param2": p2, "param3": p3}

    with pytest.raises(mp.ItemRefusedError, match="pass radius") as e:
        mp.parse_item(fields(mp.NAV_WAYPOINT, 0.0, 5.0))
    assert e.value.code == mp.INVALID_PARAM3
    with pytest.raises(mp.ItemRefusedError, match="heading required"):
        mp.parse_item(fields(mp.NAV_LOITER_TIME, 2.0, 0.0))
    assert mp.parse_item(fields(mp.NAV_WAYPOINT, 0.0, 0.0)).p3 == 0.0


def test_a_mission_from_the_ground_takes_off_at_mpc_tko_speed_as_takeoff_mode_does():
    """Through the autopilot's own glue (autopilot.missions) and the commander, the x500 flying: the climb before the
    first waypoint goes at MPC_TKO_SPEED (1.5 m/s), not at MPC_Z_VEL_MAX_UP (3 m/s)."""
    from autopilot import commander as cmd
    from autopilot.commander import CommanderSettings
    from autopilot.missions import Missions
    from quadsitl.config import load_preset
    from tests.flight_loop import Flight

    f = Flight(load_preset("x500"), settings=CommanderSettings())
    c = f.commander
    missions = Missions(ORIGIN)
    missions.protocol.items = [item(0, north=10.0, z=8.0)]
    assert c.arm()[0]
    ok, why, _ = missions.start(c, f.time)
    assert ok, why
    climbs = []
    while f.state.altitude < 7.0:
        assert f.time < 30.0
        f.step(10)
        missions.step(c, f.time)
        climbs.append(c.cm[cmd.REF_CLIMB])
    assert max(climbs) == pytest.approx(CommanderSettings().takeoff_speed, abs=1e-9)


def test_a_region_of_interest_is_faced_on_the_following_legs_until_cleared_and_camera_items_pass_at_once():
    p = Point()
    p.landed, p.alt = False, 10.0
    roi = dataclasses.replace(item(0, mp.DO_SET_ROI_LOCATION, north=0.0, east=50.0, z=0.0))
    camera = item(1, 2000, frame=mp.FRAME_MISSION)  # IMAGE_START_CAPTURE: no camera, done as it comes
    items = [roi, camera, item(2, north=30.0), item(3, mp.DO_SET_ROI_NONE, frame=mp.FRAME_MISSION),
             item(4, north=30.0, east=-30.0)]  # fmt: skip
    ex = MissionExecutor(items, ORIGIN)
    p.start(ex)
    p.fly(ex, 60.0, until=complete)
    assert p.reached() == [0, 1, 2, 3, 4] and p.reached_at(1)[0] == p.reached_at(0)[0]
    _, (x, y, _, yaw) = p.reached_at(2)
    assert abs(yaw - math.atan2(50.0 - y, 0.0 - x)) < math.radians(3)  # facing the ROI, not north along the leg
    gotos = [a for t, a in p.actions if isinstance(a, Goto) and t >= p.reached_at(3)[0]]
    _, (x, y, _, _) = p.reached_at(3)
    assert gotos[0].yaw == pytest.approx(math.atan2(-30.0 - y, 30.0 - x), abs=1e-3)  # cleared: the leg's bearing, west


def test_a_waypoint_without_an_altitude_is_flown_at_the_altitude_of_the_one_before():
    p = Point()
    p.landed, p.alt = False, 10.0
    items = [item(0, north=10.0, z=15.0), item(1, north=20.0, z=NAN)]
    ex = MissionExecutor(items, ORIGIN)
    p.start(ex)
    p.fly(ex, 60.0, until=complete)
    assert p.reached() == [0, 1] and p.alt == pytest.approx(15.0)
    assert mp.parse_item(items[1].message_fields()).z != mp.parse_item(items[1].message_fields()).z  # NaN kept
