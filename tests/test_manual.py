"""The sticks and PX4's manual modes (autopilot.manual, docs/manual.md): the sticks' math against PX4's formulas,
STABILIZED, ALTCTL and POSCTL flown in a closed loop of the compiled tick and the plant (tests/flight_loop.py), the
arming and mode checks, and the sticks' loss as PX4's failsafe (NAV_RCL_ACT, COM_RCL_EXCEPT, lost at arming)."""

from __future__ import annotations

import math

import pytest

from autopilot import commander as cmd
from autopilot import manual
from autopilot.commander import Commander, CommanderSettings
from quadsitl.config import load_preset
from quadsitl.state import VehicleState
from quadsitl.wire import Mode
from tests.flight_loop import Flight

X500 = load_preset("x500")
STICKS_EVERY = 20  # ticks between two MANUAL_CONTROL (20 ms at 1 kHz: a joystick's 50 Hz)


def test_expo_deadzone_is_pxs_formula():
    dz, e = 0.1, 0.6
    for v in (-1.5, -1.0, -0.5, -0.1, 0.0, 0.05, 0.3, 0.9, 1.0, 2.0):
        x = min(max(v, -1.0), 1.0)
        x = 0.0 if abs(x) <= dz else (x - math.copysign(dz, x)) / (1 - dz)
        assert manual.expo_deadzone(v, e, dz) == pytest.approx((1 - e) * x + e * x**3, abs=1e-15)
    assert manual.expo_deadzone(1.0, e, dz) == pytest.approx(1.0)  # full stick reaches the full value
    assert manual.expo_deadzone(0.1, e, dz) == 0.0


def test_the_sticks_math_tilts_forward_for_pitch_and_flies_relative_to_the_heading():
    roll, pitch = manual.tilt(0.0, 1.0, 0.5)
    assert (roll, pitch) == (0.0, -0.5)  # the pitch stick forward: nose down, PX4's
    roll, pitch = manual.tilt(1.0, 1.0, 0.5)
    assert math.hypot(roll, pitch) == pytest.approx(0.5)  # a diagonal tilts no more than one full stick
    assert manual.velocity(1.0, 0.0, 0.0, 10.0) == pytest.approx((10.0, 0.0))  # forward at heading north: north
    assert manual.velocity(0.0, 1.0, 0.0, 10.0) == pytest.approx((0.0, 10.0))  # right: east
    assert manual.velocity(1.0, 0.0, math.pi / 2, 10.0) == pytest.approx((0.0, 10.0), abs=1e-12)  # heading east
    assert manual.climb_rate(0.5, 3.0, 1.5) == 1.5 and manual.climb_rate(-1.0, 3.0, 1.5) == -1.5
    low, hover, high = 2.0, 20.0, 60.0
    assert [manual.throttle_curve(t, low, hover, high) for t in (-1.0, -0.5, 0.0, 0.5, 1.0)] == [
        2.0,
        11.0,
        20.0,
        40.0,
        60.0,
    ]


class Pilot:
    """A Flight with sticks sent every STICKS_EVERY ticks, as a joystick on MANUAL_CONTROL."""

    def __init__(self, **settings) -> None:
        self.f = Flight(X500, settings=CommanderSettings(takeoff_alt=5.0, **settings))
        self.c = self.f.commander

    def fly(self, seconds: float, pitch=0.0, roll=0.0, throttle=0.0, yaw=0.0) -> VehicleState:
        for _ in range(round(seconds / self.f.period / STICKS_EVERY)):
            self.c.on_sticks(pitch, roll, throttle, yaw)
            self.f.step(STICKS_EVERY)
        return self.f.state

    def airborne(self, mode: Mode) -> None:
        """Taken off to 5 m in TAKEOFF with the sticks centred, then ``mode``."""
        self.c.on_sticks(0.0, 0.0, 0.0, 0.0)
        assert self.c.arm() == (True, "") and self.c.takeoff()[0]
        self.fly(6.0)
        assert self.f.state.altitude == pytest.approx(5.0, abs=0.05)
        assert self.c.set_mode(mode) == (True, "")


@pytest.fixture(scope="module")
def posctl() -> dict:
    p = Pilot()
    p.airborne(Mode.POSCTL)
    seen = {"held": p.fly(3.0)}
    seen["forward"] = p.fly(6.0, pitch=1.0)
    seen["released"] = p.fly(8.0)
    seen["held_after"] = p.fly(3.0)
    seen["right"] = p.fly(4.0, roll=0.5)
    p.fly(5.0)
    p.fly(1.0, yaw=1.0)  # turn, then centred: the heading where it centred is held
    seen["turned"] = p.fly(3.0)
    seen["heading_forward"] = p.fly(3.0, pitch=1.0)
    seen["climb"] = p.fly(3.0, throttle=1.0)
    seen["climb_held"] = p.fly(3.0)
    seen["climb_held_after"] = p.fly(2.0)
    return seen


def test_posctl_centred_sticks_hold_the_position_and_full_forward_flies_mpc_vel_manual(posctl):
    held = posctl["held"]
    assert math.hypot(held.x, held.y) < 0.01 and held.altitude == pytest.approx(5.0, abs=0.02)
    fwd = posctl["forward"]
    assert fwd.vx == pytest.approx(10.0, abs=0.05) and abs(fwd.vy) < 0.05  # MPC_VEL_MANUAL, north at heading 0
    assert fwd.altitude == pytest.approx(5.0, abs=0.05)
    released, after = posctl["released"], posctl["held_after"]
    assert math.hypot(released.vx, released.vy) < 0.05  # braked at MPC_ACC_HOR and stopped
    assert math.hypot(after.x - released.x, after.y - released.y) < 0.05  # the position where it stopped, held


def test_posctl_right_stick_flies_east_and_forward_follows_the_heading(posctl):
    right = posctl["right"]
    speed = 10.0 * manual.expo_deadzone(0.5, 0.6, 0.1)  # the shaped stick × MPC_VEL_MANUAL
    assert right.vy == pytest.approx(speed, abs=0.05) and abs(right.vx) < 0.05
    turned, fwd = posctl["turned"], posctl["heading_forward"]
    assert abs(turned.yaw_dot) < 0.01  # the heading held after the turn
    assert math.hypot(fwd.vx, fwd.vy) > 5.0  # on its way to MPC_VEL_MANUAL, along the heading
    assert math.atan2(fwd.vy, fwd.vx) == pytest.approx(turned.yaw, abs=0.01)


def test_posctl_throttle_climbs_at_mpc_z_vel_max_up_and_centred_holds_the_altitude(posctl):
    assert posctl["climb"].climb_rate == pytest.approx(X500.position.z_vel_max_up, abs=0.02)
    held, after = posctl["climb_held"], posctl["climb_held_after"]
    assert abs(after.climb_rate) < 0.02 and after.altitude == pytest.approx(held.altitude, abs=0.03)


def test_altctl_tilts_as_the_stick_says_and_holds_the_altitude():
    p = Pilot()
    p.airborne(Mode.ALTCTL)
    s = p.fly(2.0, pitch=0.5)
    tilt = math.radians(35.0) * manual.expo_deadzone(0.5, 0.6, 0.1)
    assert s.pitch == pytest.approx(-tilt, abs=0.005) and s.vx > 1.0  # nose down, forward (north)
    assert s.altitude == pytest.approx(5.0, abs=0.1)  # the altitude held while tilted
    s = p.fly(3.0, throttle=-1.0)
    assert s.climb_rate == pytest.approx(-X500.position.z_vel_max_dn, abs=0.02)
    p.fly(10.0, throttle=-1.0)  # down to the ground, throttle low: landed, disarmed after COM_DISARM_LAND
    assert not p.c.armed and p.f.state.altitude < 0.05


def test_stabilized_flies_the_sticks_attitude_yaw_rate_and_thrust():
    p = Pilot()
    p.c.on_sticks(0.0, 0.0, -1.0, 0.0)
    assert p.c.set_mode(Mode.STABILIZED) == (True, "")
    assert p.c.arm() == (True, "")
    s = p.fly(2.0, throttle=-1.0)
    assert s.altitude < 0.01  # throttle low: idle on the ground
    s = p.fly(2.0, throttle=0.3)
    assert s.climb_rate > 1.0  # above the hover's thrust: up
    s = p.fly(1.0, roll=0.5, throttle=0.0)
    assert s.roll == pytest.approx(0.5 * math.radians(35.0), abs=0.005)  # no expo in stabilized, as PX4's
    s = p.fly(1.0, yaw=0.5, throttle=0.0)
    assert s.yaw_dot == pytest.approx(0.5 * math.radians(150.0), rel=0.02)  # MPC_MAN_Y_MAX at full stick


def at_rest(c: Commander, t: float, altitude: float = 10.0) -> None:
    c.update(round(t * 1000), t, VehicleState(z=-altitude))


def flying(mode: Mode, **settings) -> Commander:
    """A commander armed in HOLD with the sticks live, at 10 m, then in ``mode``."""
    c = Commander(CommanderSettings(**settings))
    c.on_sticks(0.0, 0.0, 0.0, 0.0)
    at_rest(c, 0.0)
    assert c.arm() == (True, "")
    assert c.set_mode(mode) == (True, "")
    at_rest(c, 0.1)
    c.on_sticks(0.0, 0.0, 0.0, 0.0)  # the newest at 0.1 s
    return c


@pytest.mark.parametrize(("action", "mode"), [(2, Mode.RTL), (3, Mode.LAND)])
def test_the_sticks_lost_in_posctl_hold_com_fail_act_t_then_fly_nav_rcl_acts_failsafe(action, mode):
    c = flying(Mode.POSCTL, rc_loss_action=action)
    at_rest(c, 0.6)
    assert c.mode == Mode.POSCTL  # within COM_RC_LOSS_T of the newest
    at_rest(c, 0.61)
    assert c.mode == Mode.HOLD and c.failsafe == cmd.FAILSAFE_MANUAL_CONTROL  # PX4's failsafe delay: hold first
    name = cmd.RC_LOSS_ACTIONS[action]
    assert c.messages[-1][1] == (f"Manual control lost: no MANUAL_CONTROL for 0.5 s; action: {name} in 5 s "
                                 f"(COM_FAIL_ACT_T), holding until then")  # fmt: skip
    at_rest(c, 5.6)
    assert c.mode == Mode.HOLD
    at_rest(c, 5.62)
    assert c.mode == mode and c.messages[-1][1] == f"Failsafe: manual control still lost; {name}"
    c.on_sticks(0.0, 0.0, 0.0, 0.0)
    at_rest(c, 5.63)
    assert "Manual control regained" in c.messages[-1][1] and c.mode == mode  # a return or landing goes on


@pytest.mark.parametrize("action", [1, 2])
def test_the_sticks_back_in_the_hold_of_their_loss_return_to_the_mode_it_left(action):
    c = flying(Mode.POSCTL, rc_loss_action=action)
    at_rest(c, 1.0)
    assert c.mode == Mode.HOLD
    c.on_sticks(0.0, 0.0, 0.0, 0.0)
    at_rest(c, 1.01)
    assert c.mode == Mode.POSCTL and c.failsafe == cmd.FAILSAFE_NONE
    assert c.messages[-1][1] == "Manual control regained; mode posctl"
    at_rest(c, 7.0)  # lost again: a new delay
    assert c.mode == Mode.HOLD


def test_com_fail_act_t_0_takes_the_action_at_once_and_a_mode_chosen_in_the_delay_stays():
    c = flying(Mode.POSCTL, fail_act_t=0.0)
    at_rest(c, 1.0)
    assert c.mode == Mode.RTL
    c = flying(Mode.POSCTL)
    at_rest(c, 1.0)
    assert c.set_mode(Mode.LAND) == (True, "")  # the pilot's choice in the delay: PX4 clears the failsafe
    at_rest(c, 7.0)
    assert c.mode == Mode.LAND


@pytest.mark.parametrize("action", [5, 6])
def test_the_sticks_lost_with_terminate_or_disarm_stop_the_motors(action):
    c = flying(Mode.POSCTL, rc_loss_action=action)
    at_rest(c, 1.0)
    assert not c.armed and c.failsafe == cmd.FAILSAFE_MANUAL_CONTROL


def test_the_sticks_loss_is_ignored_where_com_rcl_except_says_and_a_manual_mode_returns_when_no_action():
    c = flying(Mode.HOLD, rc_loss_except=cmd.RCL_EXCEPT_HOLD)
    at_rest(c, 1.0)
    assert c.mode == Mode.HOLD and c.failsafe == cmd.FAILSAFE_NONE
    assert c.messages[-1][1].endswith("action: none")
    c = flying(Mode.HOLD)  # not excepted: NAV_RCL_ACT's return
    at_rest(c, 1.0)
    at_rest(c, 6.1)
    assert c.mode == Mode.RTL
    c = flying(Mode.ALTCTL, rc_loss_action=0)  # no action taken, but ALTCTL cannot fly without sticks: PX4's return
    at_rest(c, 1.0)
    at_rest(c, 6.1)
    assert c.mode == Mode.RTL


def test_arming_without_sticks_makes_their_absence_no_failsafe_and_a_landing_goes_on():
    c = Commander(CommanderSettings())
    at_rest(c, 0.0)
    assert c.arm() == (True, "")  # in HOLD without sticks: PX4's "lost at arming"
    at_rest(c, 5.0)
    assert c.mode == Mode.HOLD and c.failsafe == cmd.FAILSAFE_NONE
    c.on_sticks(0.0, 0.0, 0.0, 0.0)  # they come: from now on their loss counts
    at_rest(c, 5.1)
    assert c.set_mode(Mode.LAND) == (True, "")
    at_rest(c, 6.0)
    assert c.mode == Mode.LAND and c.failsafe == cmd.FAILSAFE_NONE
    assert c.messages[-1][1].endswith("action: none, a landing or return goes on")


def test_manual_modes_need_live_sticks_and_a_safe_throttle_to_arm():
    c = Commander(CommanderSettings())
    at_rest(c, 0.0, altitude=0.0)
    ok, why = c.set_mode(Mode.POSCTL)
    assert not ok and "no manual control input" in why and c.mode == Mode.HOLD
    c.on_sticks(0.0, 0.0, 0.5, 0.0)
    assert c.set_mode(Mode.POSCTL) == (True, "")
    ok, why = c.arm()
    assert not ok and why.startswith("Arming denied: throttle above center")  # it would climb at once
    c.on_sticks(0.0, 0.0, 0.0, 0.0)
    assert c.set_mode(Mode.STABILIZED) == (True, "")
    ok, why = c.arm()
    assert not ok and why.startswith("Arming denied: high throttle")  # the throttle is the thrust
    c.on_sticks(0.0, 0.0, -1.0, 0.0)
    assert c.arm() == (True, "")


def test_com_rc_in_mode_0_or_4_takes_no_sticks():
    for mode in (0, 4):
        c = Commander(CommanderSettings(rc_in_mode=mode))
        c.on_sticks(0.0, 0.0, 0.0, 0.0)
        at_rest(c, 0.0, altitude=0.0)
        assert not c.sticks_fresh()
        assert not c.set_mode(Mode.POSCTL)[0]
