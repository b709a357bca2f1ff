"""The autopilot's work for one control tick, compiled (:mod:`quadsitl.jit`): the control law, the
allocation, the answer to the plant and the telemetry records, in one call from the process's loop.

The process (:mod:`autopilot.process`) decodes the state (:func:`quadsitl.wire.decode_state`), asks the
commander for the reference, then calls :func:`control_tick`; everything else it does per tick is a
few comparisons. The arrays it passes:

- ``st``: the decoded state (:data:`quadsitl.wire.DECODED_SIZE`: the VehicleState fields, then p, q, r);
- ``mem``: the controller's memory and outputs (:mod:`autopilot.control_params`: MEM_*);
- ``v``, ``c``: the autopilot's vehicle model and control parameters (:mod:`quadsitl.param_arrays`,
  :mod:`autopilot.control_params`);
- ``tx``: the buffer the answer frame is written to; ``records``: the telemetry batch (:class:`Batch`).
"""

from __future__ import annotations

import numpy as np

from autopilot import commander
from autopilot.backstepping import Errors, backstepping
from autopilot.commander import (
    ARMED,
    EVENT_NONE,
    FAILSAFE,
    HOLD_ALT,
    MODE,
    OFFBOARD_TICK,
    REF_ALT,
    REF_PITCH,
    REF_ROLL,
    REF_YAW,
)
from autopilot.control_params import MEM_ERRORS, MEM_FORCES, MEM_OMEGA_R, MEM_SIZE, MEM_U, PD
from autopilot.pd import pd
from quadsitl import telemetry
from quadsitl.frames import altitude, climb_rate
from quadsitl.jit import jit
from quadsitl.mixer import allocate
from quadsitl.param_arrays import D_OVER_B
from quadsitl.state import Inputs
from quadsitl.wire import BODY_RATES, NOT_THIS_FRAME, decode_state, encode_actuators, tick_of

_ZERO_ERRORS = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)

# Telemetry record sizes [bytes] and where each stream's records start in a Batch row (quadsitl.telemetry).
STATE_SIZE, SETPOINT_SIZE, ACTUATORS_SIZE, STATUS_SIZE = (telemetry.STREAMS[s].size for s in telemetry.STREAMS)
assert tuple(telemetry.STREAMS) == ("state", "setpoint", "actuators", "status")


@jit
def control(kind: int, x: tuple, ref: tuple, last: tuple, v: np.ndarray, c: np.ndarray) -> tuple[Inputs, Errors, float]:
    """The law ``kind`` (BACKSTEPPING or PD): (u1..u4, e1..e8, Ωr); the PD has neither errors nor Ωr."""
    if kind == PD:
        return pd(x, ref, v, c), _ZERO_ERRORS, 0.0
    return backstepping(x, ref, last, v, c)


@jit
def _put(buf: np.ndarray, at: int, value: float) -> None:
    buf[at : at + 8].view(np.float64)[0] = value


@jit
def _put_int(buf: np.ndarray, at: int, value: int) -> None:
    buf[at : at + 8].view(np.int64)[0] = value


# The tick's integer bookkeeping (``io``, int64): the stamp of the last state flown, the answer's length, the
# plant link's sequence number, the telemetry rows batched and the batch's capacity, the first tick at which a
# telemetry message may be due, the last tick, the commander's event, and the autopilot's MAVLink ids.
LAST_USEC, TX_LEN, SEQ, ROWS, CAPACITY, NEXT_STREAM_TICK, TICK, EVENT, SYSTEM, COMPONENT, IO_SIZE = range(11)
# What autopilot_tick reports (bits): an answer is in tx; telemetry messages are due; the commander has an
# event (io[EVENT]); the batch is full; the datagram is no per-tick frame (pymavlink's to parse); it was
# corrupt or carried a state never to fly.
ANSWER, STREAM, EVENT_DUE, BATCH_FULL, NOT_MINE, REFUSED = 1, 2, 4, 8, 16, 32


@jit
def control_tick(kind: int, st: np.ndarray, cm: np.ndarray, mem: np.ndarray, v: np.ndarray, c: np.ndarray,
                 f_min: float, f_max: float, tx: np.ndarray, io: np.ndarray, time_usec: int, tick: int, now: float,
                 records: np.ndarray) -> None:  # fmt: skip
    """The tick once the state (``st``) is known: the commander (its event into io[EVENT]), when armed the law
    and the allocation into ``mem`` (disarmed: zero command and forces), the answer into ``tx``, and the four
    telemetry records into the batch's next row when io[CAPACITY] > 0 (``records``: :class:`Batch`)."""
    io[EVENT] = commander.update(cm, tick, now, altitude(st), climb_rate(st), st[8])
    armed = cm[ARMED] != 0.0
    if armed:
        x = (st[0], st[1], st[2], st[3], st[4], st[5], st[6], st[7], st[8], st[9], st[10], st[11])
        last = (mem[MEM_U], mem[MEM_U + 1], mem[MEM_U + 2], mem[MEM_U + 3])
        ref = (cm[REF_ALT], cm[REF_ROLL], cm[REF_PITCH], cm[REF_YAW])
        u, errors, omega_r = control(kind, x, ref, last, v, c)
        forces = allocate(u, v[D_OVER_B], f_min, f_max)
        for i in range(4):
            mem[MEM_U + i] = u[i]
            mem[MEM_FORCES + i] = forces[i]
        for i in range(8):
            mem[MEM_ERRORS + i] = errors[i]
        mem[MEM_OMEGA_R] = omega_r
    else:
        mem[MEM_U : MEM_FORCES + 4] = 0.0
        forces = (0.0, 0.0, 0.0, 0.0)
    io[SEQ] = (io[SEQ] + 1) & 0xFF
    io[TX_LEN] = encode_actuators(tx, io[SEQ], io[SYSTEM], io[COMPONENT], time_usec, forces, f_max, armed)
    capacity, row = io[CAPACITY], io[ROWS]
    if row >= capacity:  # no session (capacity 0), or a full batch not yet published: never past the end
        return
    at = row * STATE_SIZE
    _put_int(records, at, tick)
    _put(records, at + 8, now)
    for i in range(9):  # x, y, z, vx, vy, vz, roll, pitch, yaw
        _put(records, at + 16 + 8 * i, st[i])
    for i in range(3):  # body rates p, q, r
        _put(records, at + 88 + 8 * i, st[BODY_RATES + i])
    at = capacity * STATE_SIZE + row * SETPOINT_SIZE
    _put_int(records, at, tick)
    _put(records, at + 8, now)
    for i in range(4):  # the reference shown: the one flown, or the one held while disarmed
        _put(records, at + 16 + 8 * i, cm[REF_ALT + i] if armed else cm[HOLD_ALT + i])
    # x_ref, y_ref: wired to the commander's position reference by the position-control work
    _put(records, at + 48, np.nan)
    _put(records, at + 56, np.nan)
    at = capacity * (STATE_SIZE + SETPOINT_SIZE) + row * ACTUATORS_SIZE
    _put_int(records, at, tick)
    _put(records, at + 8, now)
    for i in range(8):  # u1..u4, f1..f4
        _put(records, at + 16 + 8 * i, mem[MEM_U + i])
    at = capacity * (STATE_SIZE + SETPOINT_SIZE + ACTUATORS_SIZE) + row * STATUS_SIZE
    _put_int(records, at, tick)
    _put(records, at + 8, now)
    records[at + 16], records[at + 17], records[at + 18] = armed, int(cm[MODE]), int(cm[FAILSAFE])
    _put_int(records, at + 19, int(cm[OFFBOARD_TICK]))
    io[ROWS] = row + 1


@jit
def autopilot_tick(rx: np.ndarray, length: int, scratch: np.ndarray, st: np.ndarray, period: float, kind: int,
                   cm: np.ndarray, mem: np.ndarray, v: np.ndarray, c: np.ndarray, f_min: float, f_max: float,
                   tx: np.ndarray, io: np.ndarray, records: np.ndarray) -> int:  # fmt: skip
    """A datagram from the plant (rx[:length]) → what to do (ANSWER | STREAM | ...). A new state becomes
    ``st`` and is flown (:func:`control_tick`); a re-sent one gets the same answer again; a stale one (older
    than the last, by less than 1 s: a jump back by more is a restarted plant) none."""
    t = decode_state(rx, length, scratch)
    if t < 0:
        return NOT_MINE if t == NOT_THIS_FRAME else REFUSED
    last = io[LAST_USEC]
    if t == last:
        return ANSWER
    if last - 1_000_000 < t < last:
        return 0
    if t < last:  # a restarted plant: its ticks start again
        io[NEXT_STREAM_TICK] = 0
    io[LAST_USEC] = t
    st[:] = scratch
    tick = tick_of(t, period)
    io[TICK] = tick
    control_tick(kind, st, cm, mem, v, c, f_min, f_max, tx, io, t, tick, tick * period, records)
    flags = ANSWER
    if tick >= io[NEXT_STREAM_TICK]:
        flags |= STREAM
    if io[EVENT] != EVENT_NONE:
        flags |= EVENT_DUE
    if io[CAPACITY] > 0 and io[ROWS] == io[CAPACITY]:
        flags |= BATCH_FULL
    return flags


class Batch:
    """Telemetry records of up to ``capacity`` ticks: one buffer, the streams' regions one after the other
    (telemetry.STREAMS' layouts); io[ROWS] counts the rows written."""

    def __init__(self, capacity: int) -> None:
        self.capacity = capacity
        self.records = np.zeros(capacity * sum(f.size for f in telemetry.STREAMS.values()), dtype=np.uint8)
        self.regions, at = {}, 0
        for stream, f in telemetry.STREAMS.items():
            self.regions[stream] = (at, f.size)
            at += capacity * f.size

    def payload(self, stream: str, rows: int) -> bytes:
        at, size = self.regions[stream]
        return self.records[at : at + rows * size].tobytes()


def warm_up() -> None:
    """Compile (or load from numba's cache) everything a tick calls, on made-up data, before the first tick."""
    from autopilot.commander import Commander
    from autopilot.control_params import BACKSTEPPING, control_array
    from quadsitl import wire
    from quadsitl.param_arrays import VEHICLE_SIZE

    frame = np.zeros(wire.FRAME_MAX, dtype=np.uint8)
    st = np.zeros(wire.DECODED_SIZE)
    v = np.ones(VEHICLE_SIZE)
    c = control_array((0.5,) * 8, 0.001)
    batch = Batch(2)
    for kind in (BACKSTEPPING, PD):
        for armed in (False, True):
            commander = Commander()
            if armed:
                commander.arm()
            io = np.zeros(IO_SIZE, dtype=np.int64)
            io[LAST_USEC], io[CAPACITY] = -1, batch.capacity
            n = wire.encode_state(frame, 0, 1, 1, 0, st)
            autopilot_tick(frame, n, st.copy(), st, 0.001, kind, commander.cm, np.zeros(MEM_SIZE), v, c, -1.0, 1.0,
                           frame, io, batch.records)  # fmt: skip
