"""The plant's clock holds once a flight is over (``quadsitl plant --hold-when-landed``, what ``quadsitl fly``
runs): an answer saying disarmed, after one said armed, with the vehicle resting on the ground. The compiled tick
decides it (:func:`sitl.tick.take_and_step`); a vehicle disarmed in the air still falls, and arming again resumes."""

from __future__ import annotations

import numpy as np
import pytest

from quadsitl import codec
from quadsitl.config import load_preset
from sitl import tick
from sitl.plant import OUT_ON_GROUND, Plant


class Clock:
    """One vehicle's plant and the tick bookkeeping a lockstep link keeps, answered by hand."""

    def __init__(self, hold_when_landed: bool) -> None:
        preset = load_preset("paper")
        self.plant = Plant(preset)
        self.max_thrust = preset.actuators.max_thrust
        self.io = np.zeros(tick.IO_SIZE, dtype=np.int64)
        self.io[tick.LAST_USEC], self.io[tick.HOLD_TICK] = -1, -1
        self.io[tick.HOLD_LANDED] = int(hold_when_landed)
        self.tx = np.zeros(codec.FRAME_MAX, dtype=np.uint8)
        self.rx = np.zeros(codec.FRAME_MAX, dtype=np.uint8)
        self.received = np.zeros(4)
        self.k = 0

    def answer(self, armed: bool, thrust: float = 0.0) -> int:
        """The autopilot's answer to the current tick, each motor at ``thrust`` × F_max: the tick's result (the
        clock moves on when STEPPED)."""
        p = self.plant
        want = codec.usec_of(self.k, p.period)
        n = codec.encode_actuators(self.rx, 0, 1, 1, want, (thrust * self.max_thrust,) * 4, self.max_thrust, armed)
        r = tick.lockstep_tick(self.rx, n, want, self.max_thrust, self.received, p.commanded, p.x, p.motors, p.out,
                               p.v, p.a, p.air, p.air_rng, p.period, p.substeps, p.method, self.tx, self.io,
                               p.sensors.arrays, self.k)  # fmt: skip
        if r == tick.STEPPED:
            self.k += 1
        return r


def test_the_clock_holds_once_landed_and_disarmed_after_a_flight_and_resumes_on_arming():
    c = Clock(hold_when_landed=True)
    # Disarmed on the ground before any flight: the clock runs (the ground station has not armed it yet).
    assert [c.answer(armed=False) for _ in range(5)] == [tick.STEPPED] * 5 and c.io[tick.FLOWN] == 0
    assert [c.answer(armed=True) for _ in range(3)] == [tick.STEPPED] * 3 and c.io[tick.FLOWN] == 1
    x, stamp = c.plant.x.copy(), c.io[tick.LAST_USEC]
    # Landed (it never left the ground: zero thrust) and disarmed: held, and again for the same tick's re-answer.
    assert c.answer(armed=False) == tick.HELD and c.answer(armed=False) == tick.HELD and c.k == 8
    assert np.array_equal(c.plant.x, x) and c.io[tick.LAST_USEC] == stamp  # nothing taken, nothing integrated
    assert c.answer(armed=True) == tick.STEPPED and c.k == 9  # armed again: the clock goes on


def test_a_vehicle_disarmed_in_the_air_still_falls():
    c = Clock(hold_when_landed=True)
    assert c.answer(armed=True) == tick.STEPPED
    c.plant.x[2] = -3.0  # NED: 3 m up, at rest
    assert c.answer(armed=True) == tick.STEPPED and c.plant.out[OUT_ON_GROUND] == 0.0
    results = [c.answer(armed=False) for _ in range(20)]
    assert results == [tick.STEPPED] * 20 and c.plant.x[5] > 0.1  # disarmed up there: it falls (vz down)


def test_without_the_option_the_clock_runs_on_after_landing():
    c = Clock(hold_when_landed=False)
    assert c.answer(armed=True) == tick.STEPPED
    assert [c.answer(armed=False) for _ in range(5)] == [tick.STEPPED] * 5


@pytest.mark.parametrize(
    ("extra", "why"),
    [
        (["--mode", "realtime"], "here: realtime, 1 vehicle"),
        (["--autopilot", "127.0.0.1:14560", "--autopilot", "127.0.0.1:14561"], "here: lockstep, 2 vehicles"),
    ],
)
def test_hold_when_landed_is_refused_where_it_cannot_hold_one_clock(cli, extra, why):
    r = cli("plant", "--hold-when-landed", "--ticks", "1", *extra)
    assert r.returncode == 2 and r.stdout == ""
    assert r.stderr.strip().splitlines() == [
        f"quadsitl plant: error: --hold-when-landed: only in lockstep with one vehicle ({why}); a fleet's one clock "
        "would stop for all when the first one lands"
    ]
