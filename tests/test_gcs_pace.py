"""How often the ground station of `quadsitl fly` reads its link: every LOOP while the reference moves or a step is
near, every STEADY_SIM of the vehicle's time (within [LOOP, LOOP_STEADY] of wall time) while it holds still."""

from __future__ import annotations

import pytest

from groundstation import gcs, trajectories
from groundstation.gcs import LOOP, LOOP_STEADY, STEADY_LOOKAHEAD, STEADY_SIM, holds_still, read_interval
from quadsitl.state import Reference


def test_a_steady_reference_is_read_every_steady_sim_of_the_vehicles_time():
    assert read_interval(0.0) == LOOP  # the pace is not known yet
    assert read_interval(STEADY_SIM / 0.005) == pytest.approx(0.005)  # 30x real time: every 5 ms
    assert read_interval(1000.0) == LOOP  # never more often than a moving reference
    assert read_interval(1.0) == LOOP_STEADY  # real time: never less often than LOOP_STEADY (keep-alive, progress)
    assert LOOP_STEADY < 0.5 / 10  # 0.5 s: fly's --offboard-lockstep lead, at 10x real time


def test_the_step_is_steady_and_a_moving_or_coming_change_is_not():
    step = trajectories.make("step", Reference(5.0))
    assert holds_still(step, 0.0, step(0.0)) and holds_still(step, 100.0, step(100.0))
    assert not holds_still(step, 0.0, None)  # nothing sent yet
    ramp = trajectories.make("ramp", Reference(5.0))
    assert not holds_still(ramp, 0.5, ramp(0.5))  # still climbing a second ahead
    assert holds_still(ramp, 10.0, ramp(10.0))  # the ramp's plateau
    circle = trajectories.make("circle", Reference(2.0))
    assert not holds_still(circle, 5.0, circle(5.0))

    def later(t: float) -> Reference:  # a step at t = 3 s
        return Reference(5.0 if t < 3.0 else 7.0)

    assert holds_still(later, 1.0, later(1.0))
    assert not holds_still(later, 3.0 - STEADY_LOOKAHEAD / 2, later(1.0))  # read at LOOP's pace before the step


class _Logger:
    last_tick = 0


def test_the_pace_is_measured_over_a_window_of_batches():
    g = gcs.GroundStation.__new__(gcs.GroundStation)  # measure_pace alone: no link, no Zenoh session
    g.period, g.sim_ms, g.logger = 0.001, 0, _Logger()
    g._pace_mark, g.pace = (0.0, 0), 0.0
    assert g.measure_pace(100.0) == 0.0  # the first mark
    g.logger.last_tick = 600
    assert g.measure_pace(100.01) == 0.0  # within the window: a batch or none, not a pace
    g.logger.last_tick = 1500
    assert g.measure_pace(100.06) == pytest.approx(25.0)  # 1,500 ticks of 1 ms in 60 ms: 25x
    g.logger.last_tick = 2000
    assert g.measure_pace(100.07) == pytest.approx(25.0)  # kept until the next window ends
    g.sim_ms = 4000  # the ATTITUDE stream (MAVLink) ahead of the Zenoh batches
    assert g.measure_pace(100.16) == pytest.approx(2.5 / 0.1)
