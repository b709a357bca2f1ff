"""How often the ground station of `quadsitl fly` reads its link: when a datagram comes (at most every LOOP, at least
every WAIT_MOVING) while the reference moves or a step is near, every STEADY_SIM of the vehicle's time (within [LOOP,
LOOP_STEADY] of wall time) while it holds still; sending ahead (fly's --setpoints-ahead), once per step of the grid the
horizon moves on, and what it sends then."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from groundstation import pacing, station, trajectories
from groundstation.pacing import (
    LOOP,
    LOOP_STEADY,
    STEADY_LOOKAHEAD,
    STEADY_SIM,
    attitude_interval_us,
    holds_still,
    read_interval,
)
from groundstation.setpoint_grid import SETPOINT_MS
from quadsitl.state import Reference


def test_a_steady_reference_is_read_every_steady_sim_of_the_vehicles_time():
    assert read_interval(0.0) == LOOP  # the pace is not known yet
    assert read_interval(STEADY_SIM / 0.005) == pytest.approx(0.005)  # 30x real time: every 5 ms
    assert read_interval(1000.0) == LOOP  # never more often than a moving reference
    assert read_interval(1.0) == LOOP_STEADY  # real time: never less often than LOOP_STEADY (keep-alive, progress)
    assert LOOP_STEADY < pacing.AHEAD_KEEPALIVE / 10  # sent ahead, the horizon moves once per step: at 10x real time


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
    g = station.GroundStation.__new__(station.GroundStation)  # measure_pace alone: no link, no Zenoh session
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


class _Station:
    """A GroundStation's read loop alone (poll, _handle): a real UDP socket connected to a real sender, no Zenoh."""

    def __init__(self):
        import io
        import socket

        from quadsitl import wire

        self.vehicle = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.vehicle.bind(("127.0.0.1", 0))
        g = station.GroundStation.__new__(station.GroundStation)
        g.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        g.sock.bind(("127.0.0.1", 0))
        g.sock.connect(self.vehicle.getsockname())
        self.vehicle.connect(g.sock.getsockname())
        g.mav, g.tlog, g.sim_ms = wire.link(wire.GCS_SYSTEM_ID, wire.GCS_COMPONENT_ID), io.BytesIO(), 0
        g.last_read, g.interval, g.wait_data = time.monotonic(), LOOP, 0.0
        self.g, self._mav = g, wire.link(1, wire.AUTOPILOT_COMPONENT_ID)

    def attitude(self, ms: int) -> None:
        self.vehicle.send(self._mav.attitude_encode(ms, 0, 0, 0, 0, 0, 0).pack(self._mav))

    def poll(self) -> float:
        """Wall time [s] the read took, from its start."""
        t0 = time.monotonic()
        self.g.poll()
        return time.monotonic() - t0

    def close(self) -> None:
        self.g.sock.close()
        self.vehicle.close()


def test_a_moving_reference_is_read_when_a_datagram_comes_not_at_a_fixed_pace():
    s = _Station()
    try:
        # Reading for a moving reference: a datagram coming 0.2 s on ends the wait then, long before wait_data.
        # Timed from the timer's start, not the read's: on a loaded machine the read may begin a while after it.
        s.g.wait_data = 5.0
        began = time.monotonic()
        threading.Timer(0.2, s.attitude, (1234,)).start()
        s.poll()
        took = time.monotonic() - began
        assert 0.19 < took < 3.0 and s.g.sim_ms == 1234
        # Nothing comes: the read is wait_data after the last one (the keep-alive and the progress go on).
        s.g.wait_data = 0.15
        assert s.poll() > 0.14 and s.g.sim_ms == 1234
        # A datagram already waiting: still not before `interval` after the last read (LOOP's floor: a vehicle at
        # 25x real time sends its ATTITUDE every 0.8 ms, each read takes them all).
        s.g.interval, s.g.wait_data = 0.1, 5.0
        s.attitude(2000)
        s.g.last_read = time.monotonic()
        assert 0.09 < s.poll() < 3.0 and s.g.sim_ms == 2000
        # Holding still (wait_data 0): every `interval`, a datagram or not.
        s.g.interval, s.g.wait_data = 0.1, 0.0
        threading.Timer(0.01, s.attitude, (3000,)).start()
        assert s.poll() > 0.09 and s.g.sim_ms == 3000
    finally:
        s.close()


def test_a_ground_station_that_sends_ahead_reads_the_vehicle_clock_five_times_a_lead_between_10_and_50_hz():
    assert attitude_interval_us(0.5) == 100_000 == attitude_interval_us(1.5)  # fly's lead: 10 Hz
    assert attitude_interval_us(0.25) == 50_000
    assert attitude_interval_us(0.05) == 20_000  # never more often than the 50 Hz default
    assert attitude_interval_us(10.0) == 100_000  # never less often than 10 Hz


def _sending_ahead(lead: float, duration: float, trajectory) -> tuple[station.GroundStation, list]:
    """send_ahead alone: the flight's first tick 1000 (ticks of 1 ms), the vehicle's clock set by hand, the setpoints
    recorded as (tick made for, setpoint)."""
    g = station.GroundStation.__new__(station.GroundStation)
    g.period, g.sim_ms, g.logger, g.trajectory = 0.001, 0, _Logger(), trajectory
    g.logger.flight_start_tick = g.logger.last_tick = 1000
    g.ahead, g.end_ticks, g.next_moment = round(lead / g.period), round(duration / g.period), -1
    g.keep = pacing.horizon_step(g.ahead, g.period)
    sent: list = []
    g.send_setpoint = lambda sp, ms: sent.append((ms, sp))
    return g, sent


def test_sent_ahead_a_constant_reference_goes_once_per_step_of_the_grid_and_the_horizon_stays_ahead():
    step = trajectories.make("step", Reference(5.0))
    g, sent = _sending_ahead(1.5, 10.0, step)
    keep = round(pacing.AHEAD_KEEPALIVE * 1000)
    last = g.send_ahead(None)  # the flight's start: its first tick, and the grid up to the lead
    assert [ms for ms, _ in sent] == [1000, 1000 + keep, 1000 + 2 * keep, 1000 + 3 * keep]
    for tick in range(1000, 10_900, 37):  # the vehicle's clock as read, 37 ticks apart
        g.logger.last_tick = tick
        last = g.send_ahead(last)
        horizon = sent[-1][0]
        # the lead less one step (what a late ground station has in hand), or the tick after the flight's end
        assert horizon - tick >= min(1500 - keep, 11_002 - tick)
    g.logger.last_tick = 9000
    g.send_ahead(last)
    ticks = [ms for ms, _ in sent]
    assert set(np.diff(ticks[:-1])) == {keep} and ticks[-1] == 1000 + 10_000 + 2  # and the tick after the end
    assert {sp for _, sp in sent} == {step(0.0)}


def test_sent_ahead_a_late_read_sends_every_step_it_missed_and_a_moving_reference_every_setpoint_ms():
    step = trajectories.make("step", Reference(5.0))
    g, sent = _sending_ahead(1.5, 10.0, step)
    last = g.send_ahead(None)
    g.logger.last_tick = 2400  # read 1.4 s after the start: the clock stood at the horizon less 0.1 s
    g.send_ahead(last)
    assert [ms for ms, _ in sent][-2:] == [3000, 3500]  # both steps, none skipped: the stream never lapses
    ramp = trajectories.make("ramp", Reference(5.0))  # climbing for its first 2 s
    g, sent = _sending_ahead(1.5, 10.0, ramp)
    g.send_ahead(None)
    ticks = [ms for ms, _ in sent]
    assert ticks == list(range(1000, 2501, SETPOINT_MS))  # every moment of the 50 Hz grid up to the horizon
    assert [sp for _, sp in sent] == [ramp((tick - 1000) * 0.001) for tick in ticks]


def test_the_horizons_step_is_at_most_half_the_lead_and_a_whole_number_of_setpoint_steps():
    assert pacing.horizon_step(1500, 0.001) == 500  # fly's lead: AHEAD_KEEPALIVE
    assert pacing.horizon_step(500, 0.001) == 240  # half of 0.5 s, on the 20 ms grid
    assert pacing.horizon_step(10, 0.001) == 20  # never less than one step of the grid
    assert pacing.horizon_step(150, 0.01) == 50  # 10 ms ticks: AHEAD_KEEPALIVE is 50 of them
