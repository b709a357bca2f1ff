"""Per-call costs of the compiled equations, called from Python as the processes and ``quadsitl sim`` call
them: ``python -m benchmarks.costs`` prints them as JSON [µs]. ``quadsitl bench`` runs it twice, as it is and
with ``NUMBA_DISABLE_JIT=1`` (the same source as ordinary Python), and reports the two side by side."""

from __future__ import annotations

import json
import time
import timeit

import numpy as np

from autopilot.tick import ROWS, TX_LEN, autopilot_tick
from quadsitl.codec import usec_of
from quadsitl.jit import jit
from sitl import tick


def per_call(fn, number: int) -> float:
    """The best of five timings of ``number`` calls, after one to warm up [µs per call]."""
    fn()
    return min(timeit.repeat(fn, number=number, repeat=5)) / number * 1e6


def measure(number: int) -> dict[str, float]:
    from autopilot import backstepping, pd
    from autopilot.commander import Commander
    from autopilot.control_params import BACKSTEPPING, MEM_SIZE, control_array
    from autopilot.plugin import no_plug
    from autopilot.stream_frames import StreamFrames
    from autopilot.tick import CAPACITY, IO_SIZE, LAST_USEC, Batch
    from quadsitl import codec
    from quadsitl.config import SensorParams, load_preset
    from quadsitl.jit import specialized
    from quadsitl.param_arrays import actuator_array, vehicle_array
    from sitl import battery
    from sitl.plant import OUT_CURRENT, OUT_SIZE, Plant, step_work
    from sitl.sensors import Sensors
    from sitl.wind import air_arrays

    preset = load_preset("paper")
    T = preset.sim.period
    v, a = vehicle_array(preset.vehicle), actuator_array(preset.actuators)
    c = control_array(preset.poles(), T, preset.controller.pd_kp, preset.controller.pd_kd)
    x = np.array([0.0, 0.0, -1.0, 0.0, 0.0, -0.2, 0.1, -0.05, 0.3, 0.2, 0.1, 0.05])
    ref, mem = np.array([5.0, 1.0, 1.0, 1.0]), np.zeros(MEM_SIZE)
    motors, commanded, out = np.zeros(4), np.full(4, 5.0), np.zeros(OUT_SIZE)
    battery.start(out[OUT_CURRENT:], a)  # the paper's ideal supply: no battery to report
    air = air_arrays(preset.wind)  # calm: the preset's [wind]
    sens = Sensors(SensorParams(), T, preset.vehicle.gravity).arrays  # truth mode: passed, not touched
    # Called as the controllers and the Plant call them, every tick: their machine code without numba's dispatch
    # (quadsitl.jit.specialized); the plant's step also through the dispatch, to show what that costs.
    bs, pd_ = (specialized(m.step_arrays, x, ref, mem, v, c) for m in (backstepping, pd))
    figures = {
        "backstepping controller step": per_call(lambda: bs(x, ref, mem, v, c), number),
        "pd controller step": per_call(lambda: pd_(x, ref, mem, v, c), number),
    }
    for name in ("euler", "rk4"):
        plant = Plant(preset, integrator=name)
        plant.x[:], plant.commanded[:] = x, commanded
        args = (plant.work, plant.params, plant.air_rng, T, plant.substeps, plant.method, np.nan)
        plant_step = specialized(step_work, *args)
        figures[f"plant step ({name})"] = per_call(lambda f=plant_step, args=args: f(*args), number)
        if name == "euler":
            dispatched = per_call(lambda args=args: step_work(*args), number)
            figures["plant step (euler), through numba's dispatch"] = dispatched

    # The processes' whole ticks, frame in to frame out (no sockets).
    state_frame, answer = np.zeros(codec.FRAME_MAX, np.uint8), np.zeros(codec.FRAME_MAX, np.uint8)
    n_state = codec.encode_state(state_frame, 0, 1, 25, 1000, x)
    st, scratch = np.zeros(codec.DECODED_SIZE), np.zeros(codec.DECODED_SIZE)
    commander, batch = Commander(), Batch(64)
    frames = StreamFrames(2, (47.0, 8.0, 488.0), 4 * 1e4, False).out  # no stream due: as on most ticks
    commander.arm()
    io = np.zeros(IO_SIZE, dtype=np.int64)
    stamp = [0]

    def autopilot_side() -> None:
        io[LAST_USEC] = -1  # every call a new state
        autopilot_tick(state_frame, n_state, scratch, st, T, BACKSTEPPING, no_plug(), commander.cm, mem, v, c, -1e4,
                       1e4, answer, io, batch.records, frames)  # fmt: skip

    autopilot_side()
    n_answer = int(io[1])
    pio = np.zeros(tick.IO_SIZE, dtype=np.int64)
    received, xs = np.zeros(4), x.copy()

    def plant_side() -> None:
        pio[tick.LAST_USEC] = -1  # every call the answer to the tick
        tick.lockstep_tick(answer, n_answer, stamp[0], 1e4, received, commanded, xs, motors, out, v, a, *air, T, 1, 0,
                           state_frame, pio, sens, 0)  # fmt: skip

    stamp[0] = int(answer[10:18].view(np.uint64)[0])
    figures["autopilot tick: state frame in, answer out"] = per_call(autopilot_side, number)
    figures["plant tick: answer in, next state out (euler)"] = per_call(plant_side, number)

    # The two ticks in turn, each one's frame the other's input, in one compiled loop: the compiled work on every
    # round trip of a lockstep run, without the calls from Python above (or sockets). From 1 m up, taking off to 2 m
    # (the control law, the position loop and the telemetry records on every tick); the best of five runs of
    # ``ticks`` ticks, each from the same start.
    ticks = max(number // 25, 100)
    best = float("inf")
    for _ in range(6):  # the first compiles (or loads) and warms up
        commander = Commander()
        commander.arm()
        commander.takeoff(2.0)
        xs[:], mem[:], motors[:], out[:] = x, 0.0, 0.0, 0.0
        battery.start(out[OUT_CURRENT:], a)
        pio[:], io[:] = 0, 0
        pio[tick.LAST_USEC] = io[LAST_USEC] = -1
        io[CAPACITY] = batch.capacity  # the telemetry records written on every tick, as in the process
        targs = (scratch, st, T, BACKSTEPPING, no_plug(), commander.cm, mem, v, c, -1e4, 1e4, answer, io,
                 batch.records, frames)  # fmt: skip
        pargs = (xs, motors, out, v, a, *air, T, 1, 0, state_frame, pio, sens)
        start = time.perf_counter()
        pair_ticks(ticks, targs, pargs, received, commanded)
        best = min(best, (time.perf_counter() - start) / ticks * 1e6)
    figures["lockstep tick's compiled work: both ticks in turn, in one compiled loop"] = best
    return figures


@jit
def pair_ticks(n: int, targs: tuple, pargs: tuple, received: np.ndarray, commanded: np.ndarray) -> int:
    """``n`` lockstep ticks with no sockets: the plant's state frame to the autopilot's tick, its answer to the
    plant's tick, and again → the ticks stepped."""
    answer, io = targs[11], targs[12]
    state_frame, pio, period = pargs[10], pargs[11], pargs[7]
    tick.encode_tick(state_frame, pio, pargs[0], pargs[2], pargs[5], pargs[12], 0, period)
    stepped = 0
    for k in range(n):
        io[ROWS] = 0  # the telemetry batch never fills (the process publishes it)
        autopilot_tick(state_frame, pio[tick.TX_LEN], *targs)
        if (
            tick.lockstep_tick(answer, io[TX_LEN], usec_of(k, period), 1e4, received, commanded, *pargs, k)
            == tick.STEPPED
        ):
            stepped += 1
    return stepped


if __name__ == "__main__":
    from quadsitl.jit import DISABLED

    print(json.dumps(measure(2000 if DISABLED else 50000)))
