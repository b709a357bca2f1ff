"""A real-time plant's work for one vehicle and one period, compiled: so that a fleet's clock spends its period
sleeping, not in Python (:func:`sitl.realtime.run_realtime`).

Each period the real-time clock sends every vehicle its state (:func:`send_tick`), sleeps until the period ends, and
then, vehicle by vehicle, takes what its autopilot answered and integrates (:func:`take_and_step`). In Python that was a
dozen calls and a socket exception per drained socket for each vehicle and period, besides the clock's own work: a large
fleet spent a good share of a core on its clock (docs/performance.md#the-fleets-period-in-one-call). The Python loop
(impaired links, whose queues release the datagrams; ``QUADSITL_COMPILED_LOOPS=0``) calls the two halves of
:func:`take_and_step`, :func:`apply` for each answer and :func:`end_period`, so the bookkeeping is written once, in
``rt``, the link's (:class:`sitl.plant_link.PlantLink`: its ``last_heard``, ``first_heard`` and ``lost`` read it):

- rt[ANSWERED], rt[LATE]: periods whose own answer (stamped with the period's tick) came within it, and periods
  since the autopilot's first answer whose answer did not (the vehicle flew the previous command);
- rt[FIRST_NS], rt[LAST_NS]: when an actuator message was first and last used (CLOCK_MONOTONIC [ns]; 0: never);
- rt[LOST]: 1 while the autopilot is lost (silent for longer than ``lost_after_ns``);
- rt[LENGTH]: the length of a datagram left in ``rx`` for Python (ANOTHER).
"""

from __future__ import annotations

import math

import numpy as np

from quadsitl import fastio
from quadsitl.codec import NOT_THIS_FRAME, decode_actuators
from quadsitl.jit import borrowed, copy_into, jit
from sitl import tick
from sitl.plant import W_AIR, W_COMMANDED, W_MOTORS, W_OUT, W_X, state_inside, step_work

ANSWERED, LATE, FIRST_NS, LAST_NS, LOST, LENGTH, RT_SIZE = range(7)
# take_and_step's result, flags: a datagram the compiled decoder does not take waits in rx (rt[LENGTH] bytes) for
# Python (pymavlink) to decode and apply, after which the call is made again (the period not stepped yet); the
# autopilot was found lost (silent for lost_after_ns) or is back: Python says so.
ANOTHER, LOST_NOW, BACK_NOW = 1, 2, 4
STILL_LOST = 8  # lost_clock's: the autopilot was lost already


@jit
def send_tick(fd: int, tx: np.ndarray, io: np.ndarray, x: np.ndarray, out: np.ndarray, air: np.ndarray,
              sens: tuple | None, k: int, period: float) -> bool:  # fmt: skip
    """The start of tick ``k``: False when the state ``x`` is not :func:`sitl.plant.state_inside` its bounds (nothing
    sent: the run ends), else its datagram (:func:`sitl.tick.encode_tick`) sent on the connected socket ``fd``. A
    refused send (no autopilot yet: an ICMP error) is not an error: the plant free-wheels."""
    if not state_inside(x):
        return False
    tick.encode_tick(tx, io, x, out, air, sens, k, period)
    fastio.send(fd, tx.ctypes.data, io[tick.TX_LEN], 0)
    return True


@jit
def apply(t: int, received: np.ndarray, io: np.ndarray, rt: np.ndarray, commanded: np.ndarray, now_ns: int) -> int:
    """An actuator message stamped ``t`` [us] (its forces in ``received``), heard at ``now_ns``: the command, unless
    it is older than the last used (counted as discarded: −1) → BACK_NOW when it ends a loss of the autopilot, else
    0. For every real-time loop, the Python ones (impaired links, the datagrams pymavlink reads) too."""
    if t <= io[tick.LAST_USEC]:
        io[tick.DISCARDED] += 1
        return -1
    io[tick.LAST_USEC] = t
    copy_into(commanded, received)
    return heard(rt, now_ns)


@jit
def heard(rt: np.ndarray, now_ns: int) -> int:
    """An actuator message was used at ``now_ns``: the autopilot is there (last heard then; first heard, if it is the
    first) → BACK_NOW when that ends a loss of the autopilot, else 0. For every loop, lockstep's too."""
    rt[LAST_NS] = now_ns
    if rt[FIRST_NS] == 0:
        rt[FIRST_NS] = now_ns
    if rt[LOST] != 0:
        rt[LOST] = 0
        return BACK_NOW
    return 0


@jit
def lost_clock(rt: np.ndarray, now_ns: int, lost_after_ns: int) -> int:
    """Whether the autopilot is lost at ``now_ns``: silent for longer than ``lost_after_ns`` since it was last heard
    → LOST_NOW when it is found lost now, STILL_LOST when it was already, 0 when it is not (or was never heard). For
    every loop, lockstep's too."""
    if rt[LAST_NS] == 0 or now_ns - rt[LAST_NS] <= lost_after_ns:
        return 0
    if rt[LOST] != 0:
        return STILL_LOST
    rt[LOST] = 1
    return LOST_NOW


@jit
def end_period(io: np.ndarray, rt: np.ndarray, commanded: np.ndarray, want: int, now_ns: int, lost_after_ns: int,
               zero_on_loss: bool, work: np.ndarray, params: np.ndarray, air_rng: np.ndarray, period: float,
               substeps: int, method: int) -> int:  # fmt: skip
    """The end of the period whose tick is stamped ``want`` [us], its answers taken: the period counted answered or
    late, the lost-autopilot clock at ``now_ns`` (zero thrust while lost with ``zero_on_loss``, else the last
    command), then one period integrated (:func:`sitl.plant.step_work` on ``work``, of which ``commanded`` is the
    command) → LOST_NOW when the autopilot is found lost now, else 0. For every real-time loop."""
    flags = 0
    if io[tick.LAST_USEC] == want:
        rt[ANSWERED] += 1
    elif rt[FIRST_NS] != 0:
        rt[LATE] += 1
    lost = lost_clock(rt, now_ns, lost_after_ns)
    if lost != 0:
        flags |= lost & LOST_NOW
        if zero_on_loss:
            commanded[:] = 0.0
    step_work(work, params, air_rng, period, substeps, method, math.nan)
    return flags


@jit
def take_and_step(fd: int, rx: np.ndarray, received: np.ndarray, max_thrust: float, io: np.ndarray, rt: np.ndarray,
                  commanded: np.ndarray, want: int, lost_after_ns: int, zero_on_loss: bool, work: np.ndarray,
                  params: np.ndarray, air_rng: np.ndarray, period: float, substeps: int, method: int
                  ) -> int:  # fmt: skip
    """The end of the period whose tick is stamped ``want`` [us], unimpaired: every actuator message waiting on
    socket ``fd`` (:func:`apply`: the newest stamp wins, older ones discarded as stale; corrupt ones counted), then
    :func:`end_period` → flags (ANOTHER: returned before the period ends, as soon as such a datagram is read)."""
    flags = 0
    while True:
        n = fastio.recvfrom(fd, rx.ctypes.data, rx.size, fastio.MSG_DONTWAIT, 0, 0)
        if n < 0:  # nothing waits (or an ICMP error, taken with the receive): the socket is drained
            break
        t = decode_actuators(rx, n, received, max_thrust)
        if t == NOT_THIS_FRAME:
            rt[LENGTH] = n
            return flags | ANOTHER
        if t < 0:
            io[tick.CORRUPT] += 1
            continue
        flags |= max(apply(t, received, io, rt, commanded, fastio.monotonic_ns()), 0)
    return flags | end_period(io, rt, commanded, want, fastio.monotonic_ns(), lost_after_ns, zero_on_loss, work,
                              params, air_rng, period, substeps, method)  # fmt: skip


# ---- a fleet's period: the functions above once per vehicle, in one call ---------------------------------------
# A fleet's arrays, one per field and a row per vehicle (sitl.realtime_fleet.RealtimeFleet stacks them, and each
# vehicle's objects keep their rows as their own arrays), so that one compiled call does every vehicle's part of the
# period, for any number of vehicles, where Python called two functions per vehicle
# (docs/performance.md#the-fleets-period-in-one-call).


@jit
def send_ticks(fds: np.ndarray, tx: np.ndarray, io: np.ndarray, work: np.ndarray, sens: tuple | None, k: int,
               period: float) -> int:  # fmt: skip
    """:func:`send_tick` for every vehicle: ``fds`` their connected sockets, the other arrays their rows (``work``:
    :class:`sitl.plant.Plant`'s work array; ``sens``: the six arrays of :attr:`sitl.sensors.Sensors.arrays`, or None
    on the true state) → −1, or the first vehicle whose state left its bounds (then no vehicle is sent tick ``k``: the
    run ends). The vehicles take turns at going first (:func:`send_order`)."""
    fds, tx, io, work = borrowed((fds, tx, io, work))  # quadsitl.jit.borrowed (not ``sens``: sitl.tick.take_and_step)
    for i in range(fds.size):
        if not state_inside(work[i, W_X:W_MOTORS]):
            return i
    for j in range(fds.size):
        i = send_order(j, k, fds.size)
        w = work[i]
        send_tick(fds[i], tx[i], io[i], w[W_X:W_MOTORS], w[W_OUT:W_AIR], w[W_AIR:], tick.sensors_of(sens, i), k,
                  period)  # fmt: skip
    return -1


@jit
def send_order(j: int, k: int, n: int) -> int:
    """The vehicle that tick ``k`` of a real-time fleet of ``n`` is sent to ``j``-th: each tick begins one vehicle
    further on (tick k with vehicle k mod n). The vehicle sent to last has the least of the period left to answer in,
    and its autopilot wakes behind the others on the cores: in a fixed order, the last vehicle missed more periods than
    the first (docs/performance.md#spreading-a-fleets-work-over-the-ticks). In turn, every vehicle gets the same."""
    return (k + j) % n


@jit
def take_and_step_all(fds: np.ndarray, rx: np.ndarray, received: np.ndarray, max_thrust: np.ndarray,
                      io: np.ndarray, rt: np.ndarray, work: np.ndarray, params: np.ndarray, air_rng: np.ndarray,
                      substeps: np.ndarray, method: np.ndarray, want: int, lost_after_ns: int, zero_on_loss: bool,
                      period: float, start: int, said: np.ndarray) -> int:  # fmt: skip
    """:func:`take_and_step` for vehicles ``start`` … N − 1, in order, the arrays their rows (``rx`` one buffer for
    all) → −1 once all are stepped, or the vehicle whose datagram waits in ``rx`` for Python (ANOTHER: rt[i,
    LENGTH] bytes), after which the call is made again from that vehicle. Each vehicle's LOST_NOW and BACK_NOW
    are added to ``said[i]``, for Python to say."""
    fds, rx, received, max_thrust, io, rt, work, params, air_rng, substeps, method, said = borrowed(
        (fds, rx, received, max_thrust, io, rt, work, params, air_rng, substeps, method, said)
    )  # quadsitl.jit.borrowed
    for i in range(start, fds.size):
        w = work[i]
        flags = take_and_step(
            fds[i],
            rx,
            received[i],
            max_thrust[i],
            io[i],
            rt[i],
            w[W_COMMANDED:W_OUT],
            want,
            lost_after_ns,
            zero_on_loss,
            w,
            params[i],
            air_rng[i],
            period,
            substeps[i],
            method[i],
        )
        said[i] |= flags & (LOST_NOW | BACK_NOW)
        if flags & ANOTHER:
            return i
    return -1
