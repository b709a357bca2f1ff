"""The plant's lockstep clock run by compiled code: send tick k's datagram, take the answer, integrate, and on to
tick k + 1, without coming back to Python between two ticks (:func:`run`).

:func:`sitl.process.run_lockstep` is the clock; for one vehicle, once its autopilot has answered, it hands the
ticks to :func:`run` and takes over again whenever something is not the plain case: a datagram whose answer is not
the one awaited (:func:`sitl.tick.lockstep_tick` says other than STEPPED: stale, from the future, for pymavlink,
the hold tick, a diverged state), a wait that finds nothing, the wall-clock moment ``deadline_ns`` (signals, wind
changes, the "autopilot lost" clock are Python's), or the last tick. Each tick does what the Python loop does, in
the same order, through the same compiled tick, so runs are the same to the bit (tested:
:mod:`tests.test_plant_loop`). The wait is :class:`quadsitl.process_util.SpinThenBlock`'s, as in
:mod:`autopilot.plant_loop`.
"""

from __future__ import annotations

import numpy as np

from quadsitl import fastio
from quadsitl.codec import usec_of
from quadsitl.jit import jit
from sitl import tick

# What run() returns with: at a tick boundary, tick k's datagram not sent yet (DUE, END); or tick k's datagram sent
# and its answer still awaited: a datagram taken with another result than STEPPED (TAKEN), no datagram within the
# polling budget (QUIET) or the socket's receive timeout (TIMED_OUT).
DUE, END, TAKEN, QUIET, TIMED_OUT = range(5)
# stats (int64): ticks stepped here, then the waits (quadsitl.fastio.receive's counts).
STEPPED, STATS_SIZE = 0, 5
POLLED, LATE, BLOCKED, SHORT = fastio.POLLED, fastio.LATE, fastio.BLOCKED, fastio.SHORT


@jit
def run(fd: int, rx: np.ndarray, k: int, max_k: int, max_thrust: float, received: np.ndarray,
        commanded: np.ndarray, targs: tuple, deadline_ns: int, polling: bool, budget_ns: int, patience_ns: int,
        hot_after: int, stats: np.ndarray) -> tuple:  # fmt: skip
    """Run the clock from tick ``k`` (its datagram encoded, not sent) on the connected socket ``fd`` until Python has
    something to do (the module's docstring) → (status, the tick, the datagram's length, lockstep_tick's result).
    ``targs``: :func:`sitl.tick.lockstep_tick`'s arguments from ``x`` to ``sens`` (``tx`` and ``io`` among them).

    ``polling``: each wait polls for up to ``patience_ns`` [ns]; else it blocks in the receive (the socket's own
    timeout ends it: TIMED_OUT), and once ``hot_after`` consecutive waits were each shorter than the budget the
    clock goes back to Python (DUE), which then polls. ``deadline_ns``: CLOCK_MONOTONIC [ns]."""
    period, tx, io = targs[7], targs[10], targs[11]
    sender, length = np.zeros(fastio.SOCKADDR_IN, dtype=np.uint8), np.zeros(1, dtype=np.int32)  # (connected: the peer)
    while k < max_k:
        want = usec_of(k, period)
        fastio.send(fd, tx.ctypes.data, io[tick.TX_LEN], 0)
        n = fastio.receive(fd, rx, sender, length, polling, budget_ns, patience_ns, stats)  # tick k's answer
        if n == fastio.RAN_OUT:
            return QUIET, k, -1, 0
        if n < 0:
            return TIMED_OUT, k, -1, 0
        r = tick.lockstep_tick(rx, n, want, max_thrust, received, commanded, *targs, k)
        if r != tick.STEPPED:
            return TAKEN, k, n, r
        stats[STEPPED] += 1
        k += 1
        if fastio.monotonic_ns() >= deadline_ns or (not polling and stats[SHORT] == hot_after):
            return DUE, k, -1, 0
    return END, k, -1, 0
