"""The plant's lockstep clock run by compiled code: send tick k's datagram to every vehicle, take each answer,
integrate, and on to tick k + 1, without coming back to Python between two ticks (:func:`run`).

:func:`sitl.lockstep.run_lockstep` is the clock; once the autopilots have answered, it hands the ticks to :func:`run`
and takes over again whenever something is not the plain case: a datagram whose answer is not the one awaited
(:func:`sitl.tick.lockstep_tick` says other than STEPPED: stale, from the future, for pymavlink, the hold tick, a
diverged state), a wait that finds nothing, the wall-clock moment ``deadline_ns`` (signals, wind changes, the
"autopilot lost" clock are Python's), or the last tick. Python then goes on from where the loop stopped, within the
tick if it stopped there. Each tick does what the Python loop does, in the same order (every datagram sent, then
the answers awaited in the vehicles' order), through the same compiled tick, so runs are the same to the bit
(tested: :mod:`tests.test_plant_loop`, :mod:`tests.test_fleet_plant`). One vehicle is a fleet of one: the arrays
are a fleet's, a row per vehicle (:class:`sitl.fleet_arrays.FleetArrays`). Each wait is
:class:`quadsitl.process_util.SpinThenBlock`'s, the vehicle's own, as in :mod:`autopilot.plant_loop`.

In Python, a fleet's clock made a call for each vehicle's receive, compiled tick and bookkeeping every tick: a fleet
of two flew far fewer ticks a second than one vehicle alone (docs/performance.md#the-fleets-period-in-one-call).
"""

from __future__ import annotations

import numpy as np

from quadsitl import fastio
from quadsitl.codec import usec_of
from quadsitl.jit import borrowed, copy_into, jit
from quadsitl.param_arrays import VEHICLE_SIZE
from sitl import tick
from sitl.plant import W_AIR, W_COMMANDED, W_MOTORS, W_OUT, W_X

# What run() returns with: at a tick boundary, tick k's datagrams not sent yet (DUE, END); or tick k's datagrams
# sent, the vehicles before the one returned with stepped, and that one's answer still awaited: a datagram taken with
# another result than STEPPED (TAKEN), no datagram within the polling budget (QUIET) or the socket's receive timeout
# (TIMED_OUT).
DUE, END, TAKEN, QUIET, TIMED_OUT = range(5)
# stats (int64, a row per vehicle): ticks stepped here, then the waits (quadsitl.fastio.receive's counts).
STEPPED, STATS_SIZE = 0, 5
POLLED, LATE, BLOCKED, SHORT = fastio.POLLED, fastio.LATE, fastio.BLOCKED, fastio.SHORT


@jit
def run(fds: np.ndarray, rx: np.ndarray, k: int, max_k: int, max_thrust: np.ndarray, received: np.ndarray,
        work: np.ndarray, params: np.ndarray, air_rng: np.ndarray, sens: tuple | None, substeps: np.ndarray,
        method: np.ndarray, period: float, tx: np.ndarray, io: np.ndarray, sent: np.ndarray, sent_len: np.ndarray,
        deadline_ns: int, polling: np.ndarray, budget_ns: np.ndarray, patience_ns: np.ndarray, hot_after: int,
        stats: np.ndarray) -> tuple:  # fmt: skip
    """Run the clock from tick ``k`` (every vehicle's datagram encoded, none sent) on the connected sockets ``fds``
    until Python has something to do (the module's docstring) → (status, the tick, the vehicle awaited, the
    datagram's length, lockstep_tick's result). The arrays are the fleet's, a row per vehicle
    (:class:`sitl.fleet_arrays.FleetArrays`); ``rx`` one receive buffer for all; ``sent``, ``sent_len`` (a row per
    vehicle, with more than one): each vehicle's datagram of the tick and its length, which Python sends again while
    another vehicle keeps the fleet waiting, once the vehicle's own ``tx`` holds its next.

    ``polling[i]``: vehicle i's wait polls for up to ``patience_ns[i]`` [ns]; else it blocks in the receive (the
    socket's own timeout ends it: TIMED_OUT), and once ``hot_after`` consecutive waits were each shorter than the
    budget the clock goes back to Python (DUE), which then polls. ``deadline_ns``: CLOCK_MONOTONIC [ns]."""
    fds, rx, max_thrust, received, work, params, air_rng, substeps, method, tx, io, sent, sent_len, polling, \
        budget_ns, patience_ns, stats = borrowed((fds, rx, max_thrust, received, work, params, air_rng, substeps,
                                                  method, tx, io, sent, sent_len, polling, budget_ns, patience_ns,
                                                  stats))  # quadsitl.jit.borrowed (not sens: sitl.tick)  # fmt: skip
    sender, length = np.zeros(fastio.SOCKADDR_IN, dtype=np.uint8), np.zeros(1, dtype=np.int32)  # (connected: the peer)
    fleet = fds.size
    while k < max_k:
        want = usec_of(k, period)
        for i in range(fleet):
            m = io[i, tick.TX_LEN]
            if fleet > 1:
                copy_into(sent[i], tx[i, :m])
                sent_len[i] = m
            fastio.send(fds[i], tx[i].ctypes.data, m, 0)
        for i in range(fleet):
            n = fastio.receive(fds[i], rx, sender, length, polling[i], budget_ns[i], patience_ns[i], stats[i])
            if n == fastio.RAN_OUT:
                return QUIET, k, i, -1, 0
            if n < 0:
                return TIMED_OUT, k, i, -1, 0
            w = work[i]
            r = tick.lockstep_tick(rx, n, want, max_thrust[i], received[i], w[W_COMMANDED:W_OUT], w[W_X:W_MOTORS],
                                   w[W_MOTORS:W_COMMANDED], w[W_OUT:W_AIR], params[i, :VEHICLE_SIZE],
                                   params[i, VEHICLE_SIZE:], w[W_AIR:], air_rng[i], period, substeps[i], method[i],
                                   tx[i], io[i], tick.sensors_of(sens, i), k)  # fmt: skip
            if r != tick.STEPPED:
                return TAKEN, k, i, n, r
            stats[i, STEPPED] += 1
        k += 1
        if fastio.monotonic_ns() >= deadline_ns:
            return DUE, k, 0, -1, 0
        for i in range(fleet):
            if not polling[i] and stats[i, SHORT] == hot_after:
                return DUE, k, 0, -1, 0
    return END, k, 0, -1, 0
