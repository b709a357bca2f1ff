"""The ground station's pacing alone (groundstation.pacing, pure): the vehicle's pace, when a setpoint is due, the
horizon sent ahead and the setpoints that go out up to it. The ground station's use of it: tests/test_gcs_pace.py."""

from __future__ import annotations

import pytest

from groundstation.pacing import (
    KEEPALIVE_MS,
    KEEPALIVE_WALL,
    PACE_WINDOW,
    ahead_setpoints,
    horizon,
    horizon_step,
    measured_pace,
    setpoint_due,
)
from groundstation.setpoint_grid import SETPOINT_MS, grid_setpoints


def test_the_pace_is_measured_once_a_window_has_passed_and_kept_within_it():
    pace, mark = measured_pace(50.0, (0.0, 0), 700, 0.001, 0.0)
    assert (pace, mark) == (0.0, (50.0, 700))  # the first window: a mark, no pace yet
    assert measured_pace(50.0 + PACE_WINDOW / 2, mark, 5000, 0.001, pace) == (0.0, mark)  # within it: kept
    pace, mark = measured_pace(50.1, mark, 3200, 0.001, pace)
    assert pace == pytest.approx(2.5 / 0.1) and mark == (50.1, 3200)  # 2,500 ticks of 1 ms in 0.1 s
    assert measured_pace(50.1 + 2 * PACE_WINDOW, mark, 3200, 0.001, pace)[0] == 0.0  # a clock that stood still


@pytest.mark.parametrize(
    ("since_ms", "changed", "since_wall", "due"),
    [
        (SETPOINT_MS, True, 0.0, True),  # a change, once SETPOINT_MS of the vehicle's time passed
        (SETPOINT_MS - 1, True, 0.0, False),  # ... and not before
        (SETPOINT_MS, False, 0.0, False),  # the same one: not yet
        (KEEPALIVE_MS, False, 0.0, True),  # ... until the keep-alive
        (0, False, KEEPALIVE_WALL, True),  # a vehicle whose clock stands still still hears the stream
        (0, True, KEEPALIVE_WALL / 2, False),
    ],
)
def test_a_setpoint_is_due_on_a_change_or_a_keep_alive(since_ms, changed, since_wall, due):
    assert setpoint_due(since_ms, changed, since_wall) is due


def test_the_horizon_moves_on_its_grid_within_the_lead_and_stops_after_the_flights_end():
    keep = horizon_step(1500, 0.001)  # fly's lead at 1 ms: 500 ticks
    assert horizon(1000, 1000, 1500, keep, 11_000) == 2500
    assert horizon(1000, 1499, 1500, keep, 11_000) == 2500  # within a step: the same horizon
    assert horizon(1000, 1500, 1500, keep, 11_000) == 3000
    assert horizon(1000, 10_900, 1500, keep, 11_000) == 11_002  # two ticks past the last, no further


def _constant(t: float) -> str:
    return "hover"


def _ramp(t: float) -> float:
    return round(min(t, 0.1), 3)  # moves for 0.1 s, then holds


def test_sent_ahead_a_constant_reference_goes_once_per_step_and_the_last_moment():
    sends, moment = ahead_setpoints(_constant, 0.001, 1000, 2000, 500, -1, 2500, None)
    assert sends == [(1000, "hover"), (1500, "hover"), (2000, "hover"), (2500, "hover")]
    assert moment == 2520  # the grid's next moment (SETPOINT_MS on): where the next call starts
    sends, moment = ahead_setpoints(_constant, 0.001, 1000, 2000, 500, moment, 2760, "hover")
    assert sends == [(2760, "hover")]  # no step of the grid within: the furthest alone, for the vehicle's clock


def test_sent_ahead_every_change_goes_and_the_walk_is_the_grid_whatever_the_calls():
    """Walked in one call or in several, the moments visited are setpoint_grid's, each with the trajectory at its
    time, up to two ticks past the flight's last; a moving reference sends each of them."""
    start, end = 1000, 300
    whole, _ = ahead_setpoints(_ramp, 0.001, start, end, 100, -1, start + end + 2, None)
    grid = [(start + g, sp) for g, sp in grid_setpoints(_ramp, 0.001, end)]
    assert [g for g, _ in whole] == [g for g, sp in grid if g - start <= 100 or (g - start) % 100 == 0 or g == 1302]
    assert whole[:6] == grid[:6]  # moving: every moment of the grid
    pieces, moment, last = [], -1, None
    for furthest in (1040, 1100, 1150, 1302):
        sends, moment = ahead_setpoints(_ramp, 0.001, start, end, 100, moment, furthest, last)
        pieces += sends
        last = sends[-1][1] if sends else last
    assert {g for g, _ in whole} <= {g for g, _ in pieces}  # the same moments, and each call's furthest besides
    assert moment > start + end + 2  # the grid is over
