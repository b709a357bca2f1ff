"""autopilot.offboard_lockstep alone (the pure rule of when the clock waits for a ground station), and the
autopilot's ``--offboard-lockstep`` option refused with one line. The processes are in test_fly.py's circle
flight: its ground station is stopped again and again, and the reference flown never lags the plan by more than
the lead."""

import subprocess
import sys

import pytest

from autopilot.offboard_lockstep import HOLD_AHEAD, HOLD_MAX, NO_WAIT, OffboardLockstep

PERIOD = 0.001


def pace(lead: float = 0.5) -> OffboardLockstep:
    return OffboardLockstep(lead, PERIOD)


def test_the_clock_runs_while_the_newest_setpoint_is_recent_and_waits_beyond_the_lead():
    p = pace()
    p.stamp(1000)  # made for t = 1 s: tick 1000, so every setpoint for the ticks up to 999 is in
    assert not p.must_wait(1000, True, wall=0.0)
    assert not p.must_wait(1498, True, wall=0.0)  # tick 1499 flown next: the lead past the ticks complete
    assert p.must_wait(1499, True, wall=0.0)  # one tick beyond
    assert p.must_wait(1499, True, wall=0.1)  # still, while no newer setpoint comes
    p.stamp(1100)  # a newer one, made for 1.1 s
    assert not p.must_wait(1499, True, wall=0.12)
    assert p.waits == 1 and p.waited == pytest.approx(0.12) and p.gave_up_count == 0


def test_no_wait_unless_flying_offboard_or_before_any_stamped_setpoint():
    p = pace()
    assert not p.must_wait(10_000, True, wall=0.0)  # nothing stamped yet
    p.stamp(0)
    assert not p.must_wait(10_000, False, wall=0.0)  # disarmed, or in another mode
    assert p.must_wait(10_000, True, wall=0.0)
    assert not p.must_wait(10_000, False, wall=0.05)  # a mode change ends the wait
    assert p.waits == 1


def test_a_stamp_never_goes_back_and_one_from_the_future_never_waits():
    p = pace()
    p.stamp(5000)
    p.stamp(1000)  # an older one, reordered on the way: the newest stays
    assert p.newest == 5000 and not p.must_wait(5498, True, wall=0.0)
    p.stamp(9_000_000)  # a foreign clock ahead of the vehicle's: never a wait
    assert not p.must_wait(6000, True, wall=0.0)


def test_a_wait_runs_out_after_hold_max_and_is_not_repeated_for_the_same_setpoint():
    """A ground station that has gone: the clock waits HOLD_MAX once, then runs (the setpoint-loss failsafe's
    business); a newer setpoint that is again too old may be waited for again."""
    p = pace()
    p.stamp(0)
    assert p.must_wait(600, True, wall=10.0)
    assert p.must_wait(600, True, wall=10.0 + HOLD_MAX * 0.99)
    assert not p.must_wait(600, True, wall=10.0 + HOLD_MAX)
    assert not p.must_wait(5000, True, wall=11.0)  # the same setpoint, much older now: no second wait
    assert p.gave_up_count == 1 and p.waited == pytest.approx(HOLD_MAX)
    p.stamp(4000)
    assert p.must_wait(5000, True, wall=12.0)  # a newer setpoint, 1 s old: waited for
    assert p.waits == 2


def test_the_clock_waits_as_long_as_the_ground_station_is_heard():
    """A ground station descheduled (or stopped) for seconds: the clock waits while it was heard within hold_max (the
    autopilot's datalink timeout), however long that is; it runs on hold_max after the last time it was heard."""
    p = OffboardLockstep(0.0, 0.001, hold_max=10.0)
    p.stamp(0)
    assert p.must_wait(600, True, wall=100.0, heard=99.5)
    assert p.must_wait(600, True, wall=108.0, heard=99.5)  # 8 s stopped, heard 8.5 s ago: still waiting
    assert p.must_wait(600, True, wall=115.0, heard=106.0)  # heard again (a heartbeat between two stops)
    assert not p.must_wait(600, True, wall=116.0, heard=106.0)  # silent for 10 s: gone, the failsafes' business
    assert p.gave_up_count == 1 and p.waited == pytest.approx(16.0)


def test_free_until_is_the_last_tick_answered_without_a_wait():
    """What a compiled loop may answer alone (autopilot.plant_loop): every tick up to it, must_wait agrees."""
    p = pace()
    assert p.free_until(True) == NO_WAIT  # nothing stamped yet
    p.stamp(1000)
    assert p.free_until(False) == NO_WAIT  # not flying offboard
    last = p.free_until(True)
    assert last == 1498 and not p.must_wait(last, True, wall=0.0) and p.must_wait(last + 1, True, wall=0.0)
    assert p.free_until(True) == -1  # a wait under way: every tick is Python's
    assert not p.must_wait(last + 1, True, wall=HOLD_MAX)  # it runs out for this setpoint
    assert p.free_until(True) == NO_WAIT


def test_the_lead_is_counted_in_ticks_of_the_period():
    p = OffboardLockstep(0.05, 0.004)  # 12.5 ticks, rounded
    p.stamp(400)  # tick 100
    assert not p.must_wait(110, True, wall=0.0) and p.must_wait(111, True, wall=0.0)


@pytest.mark.parametrize("value", ["-0.001", "-1", "nan", "inf", "100"])
def test_a_bad_lead_is_refused_with_one_line(value):
    r = subprocess.run([sys.executable, "-m", "groundstation.cli", "autopilot", "--no-zenoh",
                        f"--offboard-lockstep={value}"], capture_output=True, text=True, timeout=60)  # fmt: skip
    assert r.returncode == 2 and "Traceback" not in r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and f"--offboard-lockstep {float(value)!r}: expected a number in [0, 60]" in lines[0]


def test_a_ground_station_ahead_of_the_clock_has_each_setpoint_flown_from_its_tick_and_leads_the_clock():
    """Lead 0, setpoints sent ahead (quadsitl fly: gcs --setpoints-ahead): each made for a later tick than the next is
    held and flown from that tick, in the order made (an attitude pair for one moment stays a pair); the clock answers
    tick k only once a setpoint for k + 2 or later is in; one made for too far ahead, or for now, is flown at once."""
    p = OffboardLockstep(0.0, PERIOD)
    for tick, name in ((1000, "a"), (1020, "b1"), (1020, "b2"), (1040, "c")):
        p.stamp(tick)
        assert p.hold(tick, 1000 - 2, name) == (tick > 999)  # after tick 998: 999 is next; 1000 is held
    assert p.next_due() == 1000 and p.due(999) == [] and p.due(1000) == ["a"]
    assert p.next_due() == 1020 and p.due(1030) == ["b1", "b2"] and p.due(2000) == ["c"] and p.next_due() == NO_WAIT
    assert not p.must_wait(1038, True, wall=0.0) and p.must_wait(1039, True, wall=0.0)  # 1040 is the newest
    assert p.free_until(True) == -1  # that wait is under way
    assert not p.hold(1001, 1000, "now")  # for the next tick: flown at once, as it comes
    assert not p.hold(1000 + round(HOLD_AHEAD / PERIOD) + 1, 999, "foreign")  # a foreign clock's stamp: at once
    p2 = OffboardLockstep(0.0, PERIOD)
    p2.stamp(1040)
    assert p2.free_until(True) == 1038 and not p2.must_wait(1038, True, wall=0.0) and p2.must_wait(1039, True, 0.0)
