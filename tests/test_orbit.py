"""PX4's orbit (MAV_CMD_DO_ORBIT, autopilot.commander's ORBIT): the refusals PX4 gives and nothing changed by them, the
speed a radius allows, and the orbit flown in a closed loop of the compiled tick and the plant (tests/flight_loop.py):
to the circle, around it at its radius, altitude and speed, facing the centre or along the circle, the turns asked
for and then hold."""

from __future__ import annotations

import math

import numpy as np
import pytest

from autopilot import commander as cmd
from autopilot.commander import Commander, CommanderSettings
from quadsitl.config import load_preset
from quadsitl.state import VehicleState
from quadsitl.wire import Mode
from tests.flight_loop import Flight

X500 = load_preset("x500")
NAN = math.nan


def airborne_commander(**settings) -> Commander:
    c = Commander(CommanderSettings(**settings))
    c.update(0, 0.0, VehicleState(z=-10.0))
    assert c.arm() == (True, "")
    c.update(1, 0.001, VehicleState(z=-10.0))
    return c


@pytest.mark.parametrize(
    ("args", "why"),
    [
        ((0.5, NAN, NAN, NAN), "radius 0.5 m; allowed: [1, 1000] m (MC_ORBIT_RAD_MAX)"),
        ((-2000.0, NAN, NAN, NAN), "radius 2000 m"),
        ((10.0, NAN, 6.0, NAN), "yaw behaviour 6; allowed: 0..4"),
        ((10.0, NAN, 1.5, NAN), "yaw behaviour 1.5"),
        ((10.0, NAN, NAN, -1.0), "orbits -1"),
        ((10.0, math.inf, NAN, NAN), "speed inf"),
    ],
)
def test_a_bad_orbit_is_denied_naming_the_value_and_nothing_changes(args, why):
    c = airborne_commander()
    before = c.cm.copy()
    ok, reason = c.orbit(*args, 5.0, 5.0, 10.0)
    assert not ok and reason.startswith("Orbit denied: ") and why in reason
    assert c.mode == Mode.HOLD and np.array_equal(c.cm, before, equal_nan=True)


def test_an_orbit_on_the_ground_is_denied_and_one_too_fast_for_its_radius_is_slowed_and_said():
    c = Commander(CommanderSettings())
    c.update(0, 0.0, VehicleState())
    assert c.arm() == (True, "")
    assert c.orbit(10.0, 2.0, NAN, NAN, NAN, NAN, NAN) == (False, "Orbit denied: not flying (take off first)")
    c = airborne_commander()
    assert c.orbit(-2.0, 5.0, NAN, NAN, 0.0, 0.0, 10.0) == (True, "")
    assert c.cm[cmd.ORBIT_V] == pytest.approx(-2.0)  # √(2 m/s² · 2 m), counter-clockwise
    assert "Orbit speed 5 m/s reduced to 2.00 m/s" in c.messages[-2][1]
    assert cmd.orbit_speed(100.0, 30.0) == 10.0  # at most 10 m/s
    assert c.set_mode(Mode.ORBIT) == (True, "")  # already orbiting: as it is
    assert c.cm[cmd.ORBIT_R] == 2.0


def test_mc_orbit_rad_max_and_mc_orbit_yaw_mod_are_honoured():
    c = airborne_commander(orbit_radius_max=5.0, orbit_yaw_mode=3)
    assert c.orbit(10.0, NAN, NAN, NAN, NAN, NAN, NAN)[1].endswith("allowed: [1, 5] m (MC_ORBIT_RAD_MAX)")
    assert c.orbit(5.0, NAN, NAN, NAN, NAN, NAN, NAN) == (True, "")
    assert c.cm[cmd.ORBIT_YAW_MODE] == 3  # no heading given: MC_ORBIT_YAW_MOD
    assert c.orbit(NAN, NAN, 1.0, NAN, NAN, NAN, NAN) == (True, "") and c.cm[cmd.ORBIT_YAW_MODE] == 1
    assert c.orbit(NAN, NAN, 5.0, NAN, NAN, NAN, NAN) == (True, "") and c.cm[cmd.ORBIT_YAW_MODE] == 1  # unchanged


def fly_orbit(radius: float, speed: float, yaw_mode: int, turns: float) -> tuple[Flight, list, float]:
    """Taken off to 5 m, then an orbit around (20, 0) at 8 m; (the flight, its samples once on the circle, the
    simulated time the orbit took)."""
    f = Flight(X500, settings=CommanderSettings(takeoff_alt=5.0))
    c = f.commander
    assert c.arm() == (True, "") and c.takeoff()[0]
    f.run(6.0)
    assert c.orbit(radius, speed, yaw_mode, turns, 20.0, 0.0, 8.0) == (True, "")
    start = f.time
    on: list[tuple[float, VehicleState]] = []
    while c.mode == Mode.ORBIT:
        assert f.time - start < 120.0, "the orbit does not end"
        f.step(50)
        if c.cm[cmd.ORBIT_APPROACH] == 0.0 and c.cm[cmd.ORBIT_SPEED] == c.cm[cmd.ORBIT_V]:
            on.append((f.time, f.state))
    return f, on, f.time - start


@pytest.fixture(scope="module")
def facing_centre():
    return fly_orbit(10.0, 2.0, 0, 1.0)


def test_an_orbit_flies_its_circle_at_its_speed_and_altitude_facing_the_centre(facing_centre):
    _, on, _ = facing_centre
    assert len(on) > 100
    for _, s in on[20:]:  # after the settling from the approach
        dx, dy = s.x - 20.0, s.y
        assert math.hypot(dx, dy) == pytest.approx(10.0, abs=0.3)
        assert s.altitude == pytest.approx(8.0, abs=0.1)
        assert math.hypot(s.vx, s.vy) == pytest.approx(2.0, abs=0.1)
        assert dx * s.vy - dy * s.vx > 0.0  # clockwise seen from above (north to east)
        facing = math.atan2(-dy, -dx)
        assert abs(math.remainder(s.yaw - facing, 2 * math.pi)) < 0.05


def test_an_orbit_of_one_turn_holds_after_it_and_says_so(facing_centre):
    f, on, took = facing_centre
    assert f.commander.mode == Mode.HOLD
    assert f.commander.messages[-1] == (6, "Orbit done: 1 turns; holding")
    one_turn = 2 * math.pi * 10.0 / 2.0  # [s] at 2 m/s
    assert on[-1][0] - on[0][0] == pytest.approx(one_turn, abs=1.0)
    assert took < one_turn + 15.0  # the approach from the takeoff point: some 10 m at cruise speed


def test_a_counter_clockwise_orbit_faces_along_the_circle_with_yaw_behaviour_3():
    _, on, _ = fly_orbit(-6.0, 1.5, 3, 0.5)
    for _, s in on[80:]:  # after the quarter turn from facing the centre (the approach) at MPC_YAWRAUTO_MAX
        dx, dy = s.x - 20.0, s.y
        assert math.hypot(dx, dy) == pytest.approx(6.0, abs=0.3)
        assert dx * s.vy - dy * s.vx < 0.0  # counter-clockwise
        assert abs(math.remainder(s.yaw - math.atan2(s.vy, s.vx), 2 * math.pi)) < 0.08  # nose along the circle


def test_orbit_execution_status_says_the_circle_while_orbiting_and_nothing_otherwise():
    from autopilot.gcs_messages import Origin, orbit_execution_status
    from quadsitl.frames import geodetic_to_ned

    c = airborne_commander()
    home = Origin()
    assert orbit_execution_status(c, home, 0) is None
    assert c.orbit(-12.0, 1.0, NAN, NAN, 30.0, -40.0, 15.0) == (True, "")
    m = orbit_execution_status(c, home, 5_000)
    assert m.get_type() == "ORBIT_EXECUTION_STATUS" and m.time_usec == 5_000
    assert m.radius == -12.0 and m.frame == 0  # counter-clockwise; MAV_FRAME_GLOBAL
    north, east = geodetic_to_ned(m.x * 1e-7, m.y * 1e-7, home.lat, home.lon)
    assert (north, east) == (pytest.approx(30.0, abs=0.02), pytest.approx(-40.0, abs=0.02))
    assert m.z == pytest.approx(home.alt + 15.0)
