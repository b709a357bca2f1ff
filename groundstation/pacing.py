"""How the ground station of ``quadsitl gcs`` and ``quadsitl fly`` paces itself, pure (no link, no clock of its own):
when it reads its link, when it sends a setpoint, and with ``--setpoints-ahead`` how far ahead and which ones.

Setpoints are paced in simulated time: one per SETPOINT_MS (20 ms) of the vehicle's time seen (its ATTITUDE stream or
its Zenoh telemetry, whichever is newer), the same one again every KEEPALIVE_MS, and at least every KEEPALIVE_WALL of
wall time, so a sped-up lockstep run never starves the stream (:func:`setpoint_due`). Each is the trajectory at that
moment and is stamped with it (time_boot_ms). With ``--setpoints-ahead S`` (``quadsitl fly``'s 1.5 s, its autopilot on
``--offboard-lockstep 0``) the flight's setpoints are instead the trajectory at every moment of the grid of
:mod:`groundstation.setpoint_grid`, sent up to S ahead of the vehicle's clock (the horizon, on a grid of
AHEAD_KEEPALIVE: :func:`horizon`, :func:`ahead_setpoints`) and stamped with the tick each is for.

Reads: while the reference moves, when a datagram comes, at most every LOOP and at least every WAIT_MOVING of wall
time; while it holds still (:func:`holds_still`), every STEADY_SIM of the vehicle's time, between LOOP and LOOP_STEADY
of wall time (:func:`read_interval`), by the vehicle's pace (:func:`measured_pace`).

Times are wall-clock seconds [s] (time.monotonic) where named "wall", else the vehicle's simulated time: seconds,
milliseconds [ms] or ticks of the control period, as each name says.
"""

from __future__ import annotations

from collections.abc import Callable

from groundstation.setpoint_grid import SETPOINT_MS, next_moment, setpoint_step

LOOP = 0.002  # [s] wall: how often at most the ground station reads its socket and Zenoh channels, and may send
# Each wake-up takes one of the two cores from the lockstep processes for a moment
# (docs/performance.md#the-ground-station-in-lockstep). While the reference moves, a read finds something new only once
# the vehicle's time seen has moved, by the 50 Hz ATTITUDE (10 Hz with fly's --setpoints-ahead, where no setpoint waits
# for a read) or a Zenoh batch: the ground station reads when a datagram comes, at most every LOOP and at least every
# WAIT_MOVING of wall time (a vehicle that runs below 10x real time wakes it less often than LOOP's 500 times a second,
# and a changed setpoint goes as soon as the vehicle's time it is for is seen; WAIT_MOVING is longer than the 50 Hz
# ATTITUDE's period down to 0.4x real time, and short against KEEPALIVE_WALL).
# While the reference holds still (the paper's step, a hover), nothing it sends changes: it reads every STEADY_SIM of
# the vehicle's time instead, between LOOP and LOOP_STEADY of wall time. The keep-alive then goes every STEADY_SIM
# (not KEEPALIVE_MS), well within the vehicle's --offboard-lockstep lead (0.5 s) and setpoint timeout (1 s); the
# reference is looked at STEADY_LOOKAHEAD ahead, so a step is read for as a moving reference is.
LOOP_STEADY, STEADY_SIM, STEADY_LOOKAHEAD = 0.010, 0.15, 1.0  # [s] wall, simulated, simulated
WAIT_MOVING = 0.050  # [s] wall
# Setpoints: a changed one at most every SETPOINT_MS of the vehicle's time (50 Hz), the same one again every
# KEEPALIVE_MS (10 Hz; the vehicle's setpoint timeout is 1 s, its --offboard-lockstep lead 0.5 s), and at least
# every KEEPALIVE_WALL of wall time (a vehicle whose clock does not move still hears the stream). A constant
# reference (the paper's step) sent 50 times a simulated second cost both ends a share of their cores for nothing.
KEEPALIVE_MS, KEEPALIVE_WALL = 100, 0.1  # [ms] simulated, [s] wall
PACE_WINDOW = 0.05  # [s] wall: the vehicle's pace is measured over this long
# With --setpoints-ahead, each setpoint is made for its own tick of the trajectory's grid, so the vehicle's clock is
# read only to know how far ahead to send: ATTITUDE (which carries it) at AHEAD_CLOCK_READS per lead, at most every
# ATTITUDE_AHEAD_MAX_MS of the vehicle's time (10 Hz at fly's 1.5 s) and never more often than the 50 Hz default.
# Parsing and logging it at 50 Hz took most of the ground station's CPU in a lockstep flight, on the cores the two
# loops share (docs/performance.md#the-ground-station-in-lockstep).
AHEAD_CLOCK_READS, ATTITUDE_AHEAD_MAX_MS = 5, 100
# [s] simulated: with --setpoints-ahead, the horizon (the furthest setpoint sent) moves on a grid of this step, counted
# from the flight's start, and a constant reference goes again once per step: half the vehicle's 1 s setpoint timeout,
# on its own clock. The ground station reads once per step of the vehicle's clock (within LOOP and LOOP_STEADY of wall
# time); the clock stays the lead less one step short of the horizon (fly's 1.5 s lead: 1 s). A shorter lead with the
# horizon topped up at each read woke the ground station far more often, each time on a core the lockstep pair
# needed, and the clock still waited for it (docs/performance.md#the-ground-station-in-lockstep).
AHEAD_KEEPALIVE = 0.5


def attitude_interval_us(lead: float) -> int:
    """The ATTITUDE interval [µs] a ground station that sends setpoints ``lead`` [s] ahead asks for."""
    ms = min(ATTITUDE_AHEAD_MAX_MS, max(SETPOINT_MS, round(1000.0 * lead / AHEAD_CLOCK_READS)))
    return 1000 * ms


def holds_still(trajectory: Callable[[float], object], t: float, last_sent: object) -> bool:
    """True when the reference at flight time ``t`` [s] is the one last sent and is still that one STEADY_LOOKAHEAD
    later: the ground station may read less often (a step ahead is read at LOOP's pace, from a second before it)."""
    sp = trajectory(t)
    return sp == last_sent and trajectory(t + STEADY_LOOKAHEAD) == sp


def read_interval(pace: float, sim: float = STEADY_SIM) -> float:
    """The wall time [s] from one read to the next while the reference holds still (or, with --setpoints-ahead, in
    flight: ``sim`` is then the horizon's grid), for a vehicle whose clock runs ``pace`` simulated seconds per wall
    second (0: not known): ``sim`` [s] of its time, between LOOP and LOOP_STEADY."""
    return LOOP if pace <= 0.0 else min(LOOP_STEADY, max(LOOP, sim / pace))


def measured_pace(
    now: float, mark: tuple[float, int], newest: int, period: float, pace: float
) -> tuple[float, tuple[float, int]]:
    """The vehicle's pace [simulated s per wall s] measured over windows of PACE_WINDOW of wall time (its ticks arrive
    in batches: a shorter window would read 0 or a burst): at wall time ``now`` [s], the vehicle's newest tick seen
    ``newest`` (ticks of ``period`` [s]), the window's start ``mark`` (wall time [s], tick; wall time 0: none yet)
    and the pace measured so far ``pace`` → (the pace, the mark to measure on from). Within the window both are kept;
    the first window gives a mark and a pace of 0 (not known)."""
    since, tick = mark
    if now - since < PACE_WINDOW:
        return pace, mark
    return ((newest - tick) * period / (now - since) if since else 0.0), (now, newest)


def setpoint_due(since_ms: int, changed: bool, since_wall: float) -> bool:
    """Whether a ground station that does not send ahead sends a setpoint now: ``since_ms`` [ms] of the vehicle's time
    and ``since_wall`` [s] of wall time since the last went, ``changed`` whether the reference differs from it."""
    return (since_ms >= SETPOINT_MS and changed) or since_ms >= KEEPALIVE_MS or since_wall >= KEEPALIVE_WALL


def horizon_step(ahead: int, period: float) -> int:
    """With --setpoints-ahead ``ahead`` [ticks of ``period`` s]: the step [ticks] of the grid the horizon moves on,
    AHEAD_KEEPALIVE or half the lead if shorter, a whole number of :func:`setpoint_step`'s."""
    step = setpoint_step(period)
    return max(step, min(round(AHEAD_KEEPALIVE / period), ahead // 2) // step * step)


def horizon(start: int, newest: int, ahead: int, keep: int, end: int) -> int:
    """The furthest tick to send a setpoint for: the last moment of the grid of ``keep`` ticks (counted from the
    flight's first tick ``start``) within ``ahead`` ticks of the vehicle's ``newest`` tick seen, and never past two
    ticks after the flight's last, ``end`` (where the clock holds until the landing is asked for)."""
    return min(start + (newest + ahead - start) // keep * keep, end + 2)


def ahead_setpoints(
    trajectory: Callable[[float], object],
    period: float,
    start: int,
    end_ticks: int,
    keep: int,
    moment: int,
    furthest: int,
    last_sent: object,
) -> tuple[list[tuple[int, object]], int]:
    """With --setpoints-ahead: the setpoints to send now, each with the tick it is made for → (them in order, the
    next moment of the grid to make one for). The grid's moments from ``moment`` (−1: the flight's first tick,
    ``start``) up to the horizon ``furthest`` (:func:`horizon`) are walked, each the trajectory at its time of a
    flight of ``end_ticks`` ticks of ``period`` [s]; of those, the ones that change the reference (``last_sent``
    before them), each moment of the horizon's grid of ``keep`` ticks and the last go out: a constant reference goes
    once per ``keep`` ticks of the vehicle's time, and the furthest sent tells the vehicle's clock how far it may go
    (autopilot.offboard_lockstep holds each until its tick). Every setpoint up to the furthest goes before it, so
    what the vehicle flies does not depend on when this is called."""
    if moment < 0:
        moment = start
    step = setpoint_step(period)
    sends: list[tuple[int, object]] = []
    while moment <= furthest:
        g = moment
        sp = trajectory(min(g - start, end_ticks) * period)
        moment = start + next_moment(g - start, end_ticks, step)
        if sp != last_sent or (g - start) % keep == 0 or moment > furthest:
            sends.append((g, sp))
            last_sent = sp
    return sends, moment
