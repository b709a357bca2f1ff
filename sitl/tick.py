"""The plant's work for one lockstep tick, compiled (:mod:`quadsitl.jit`): take the autopilot's answer,
integrate one period, and encode the next state, in one call from the process's loop
(:func:`sitl.process.run_lockstep`)."""

from __future__ import annotations

import numpy as np

from quadsitl.jit import jit
from quadsitl.wire import NOT_THIS_FRAME, decode_actuators, encode_state, usec_of
from sitl.plant import DEFAULT_LIMITS, inside, step_arrays

# The tick's integer bookkeeping (``io``, int64): the link's sequence number, the length of the state frame
# in tx, the stamp of the newest actuator message used, and what was refused: stale or duplicate answers,
# corrupt frames or non-finite forces.
SEQ, TX_LEN, LAST_USEC, DISCARDED, CORRUPT, SYSTEM, COMPONENT, IO_SIZE = range(8)
# What lockstep_tick reports besides STEPPED: an answer from the future, or no actuator message for this
# tick in the datagram (NOTHING; ANOTHER_FRAME: not exactly one unsigned HIL_ACTUATOR_CONTROLS, for pymavlink).
# DIVERGED: stepped, and the new state is outside sitl.plant's DEFAULT_LIMITS (or not finite): not to be sent.
STEPPED, FUTURE, NOTHING, ANOTHER_FRAME, DIVERGED = 0, 1, 2, 3, 4


@jit
def encode_tick(tx: np.ndarray, io: np.ndarray, x: np.ndarray, tick: int, period: float) -> None:
    """The state ``x`` stamped with tick ``tick``'s simulated time, as ODOMETRY into ``tx``."""
    io[SEQ] = (io[SEQ] + 1) & 0xFF
    io[TX_LEN] = encode_state(tx, io[SEQ], io[SYSTEM], io[COMPONENT], usec_of(tick, period), x)


@jit
def take_and_step(t: int, want: int, commanded: np.ndarray, received: np.ndarray, x: np.ndarray,
                  motors: np.ndarray, out: np.ndarray, v: np.ndarray, a: np.ndarray, air: np.ndarray,
                  air_rng: np.ndarray, period: float, substeps: int, method: int, tx: np.ndarray, io: np.ndarray,
                  tick: int) -> int:  # fmt: skip
    """An actuator message stamped ``t`` (its forces in ``received``): when it answers tick ``tick``
    (``want``), make it the command, integrate one period in the tick's wind (:func:`sitl.plant.step_arrays`) and
    encode the state of tick + 1 (DIVERGED when that state is not :func:`sitl.plant.inside` the default
    bounds)."""
    if t < 0:
        return NOTHING
    if t <= io[LAST_USEC]:
        io[DISCARDED] += 1
        return NOTHING
    if t != want:
        io[DISCARDED] += 1
        return FUTURE
    io[LAST_USEC] = t
    commanded[:] = received
    step_arrays(x, motors, commanded, out, v, a, air, air_rng, period, substeps, method, np.nan)
    encode_tick(tx, io, x, tick + 1, period)
    s = (x[0], x[1], x[2], x[3], x[4], x[5], x[6], x[7], x[8], x[9], x[10], x[11])
    return STEPPED if inside(s, DEFAULT_LIMITS) else DIVERGED


@jit
def lockstep_tick(rx: np.ndarray, length: int, want: int, max_thrust: float, received: np.ndarray,
                  commanded: np.ndarray, x: np.ndarray, motors: np.ndarray, out: np.ndarray, v: np.ndarray,
                  a: np.ndarray, air: np.ndarray, air_rng: np.ndarray, period: float, substeps: int, method: int,
                  tx: np.ndarray, io: np.ndarray, tick: int) -> int:  # fmt: skip
    """A datagram from the autopilot (rx[:length]) during tick ``tick``: STEPPED (the next state is in tx),
    DIVERGED (it is, but outside its bounds), FUTURE, NOTHING or ANOTHER_FRAME."""
    t = decode_actuators(rx, length, received, max_thrust)
    if t == NOT_THIS_FRAME:
        return ANOTHER_FRAME
    if t < 0:
        io[CORRUPT] += 1  # a bad CRC, or a non-finite force: never integrated
        return NOTHING
    return take_and_step(t, want, commanded, received, x, motors, out, v, a, air, air_rng, period, substeps, method,
                         tx, io, tick)  # fmt: skip
