"""The grid a flight's offboard setpoints are made on, pure: the trajectory at every SETPOINT_MS of the flight, the
last made for two ticks past its end (the lockstep clock then holds at the tick after the end until the landing is
asked for). ``quadsitl fly``'s ground station sends these ahead of the vehicle's clock (:mod:`groundstation.gcs`,
``--setpoints-ahead``), each stamped with its tick; ``quadsitl sim`` gives the same ones to the commander at the same
ticks (:mod:`groundstation.offline`): so both fly the same reference, tick by tick.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator

# SET_POSITION_TARGET_LOCAL_NED's type_mask for a position trajectory's setpoints: x, y, z, vx, vy, vz and yaw used;
# acceleration (64, 128, 256) and yaw rate (2048) ignored: MAVSDK's position + velocity mask.
POSITION_VELOCITY_YAW = 2496
SETPOINT_MS = 20  # [ms] of the vehicle's time: a changed setpoint at most this often (50 Hz)
NONE_AFTER = 2**62  # next_moment: no moment follows


def setpoint_step(period: float) -> int:
    """SETPOINT_MS in ticks of ``period`` [s] (at least one): the step of the trajectory's grid."""
    return max(1, round(SETPOINT_MS / 1000.0 / period))


def next_moment(g: int, end: int, step: int) -> int:
    """The moment of the grid after ``g`` [ticks from the flight's first]: every ``step`` up to ``end`` (the flight's
    last tick), then ``end`` + 2, then none (NONE_AFTER)."""
    return g + step if g + step <= end else end + 2 if g < end + 2 else NONE_AFTER


def grid_setpoints(trajectory: Callable[[float], object], period: float, end: int) -> Iterator[tuple[int, object]]:
    """Every moment of the grid [ticks from the flight's first] with the trajectory's setpoint for it (sampled at
    the moment's time, at most the end's), for a flight whose last tick is ``end``."""
    g, step = 0, setpoint_step(period)
    while g <= end + 2:
        yield g, trajectory(min(g, end) * period)
        g = next_moment(g, end, step)
