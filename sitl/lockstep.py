"""The plant's lockstep clock (:func:`run_lockstep`): the plant is the clock, one clock for every vehicle. For tick
k it sends each vehicle's datagram stamped with the simulated time, waits for every HIL_ACTUATOR_CONTROLS answering
tick k, then integrates one period. Until an answer comes (at start, or if an autopilot goes away) it free-wheels:
it sends the datagrams again every FREEWHEEL_PERIOD without advancing time. A pace cap (``--speed``) makes up a late
tick, but not time lost to a stall longer than PACE_SLACK (or to holding).

Unpaced, once the autopilots have answered, the ticks run in compiled code (:func:`sitl.lockstep_loop.run`) until
Python has something to do; this loop then goes on from where it stopped.
"""

from __future__ import annotations

import time
from collections.abc import Sequence

import numpy as np

from quadsitl import codec, fastio
from quadsitl.process_util import HOT_AFTER, PATIENCE, set_receive_timeout
from sitl import lockstep_loop, tick
from sitl.fleet_arrays import FleetArrays
from sitl.vehicle import DivergedError, Vehicle, check_state

FREEWHEEL_PERIOD = 0.05  # [s] state re-send pace while no answer comes
# [s] wall: a paced lockstep plant this far behind its pace (a stall of the machine) resumes the pace from where it
# is instead of running the lost ticks back to back; a shorter lateness (a late wake-up) is made up, so the pace holds
PACE_SLACK = 0.02
LOOP_RETURN_NS = 1_000_000  # [ns] wall: the compiled clock comes back to Python at least this often (signals, wind)


def run_lockstep(vehicles: Sequence[Vehicle], speed: float, max_ticks: int | None) -> int:
    """The plant as the clock, one clock for every vehicle: send tick k's datagram to each vehicle's autopilot,
    wait for every answer to it, integrate each vehicle, and only then go on to tick k + 1, until ``max_ticks``.
    A fleet therefore advances tick by tick together and is as deterministic as one vehicle.

    Each answer is decoded, taken and integrated and the vehicle's next datagram encoded by one compiled call
    (:func:`sitl.tick.lockstep_tick`). The answers are awaited in the vehicles' order: each vehicle's come on its
    own socket, so one that answered while another was awaited is waiting there, and the tick takes as long as the
    slowest answer, no longer. A vehicle that does not answer within FREEWHEEL_PERIOD is sent its datagram again
    (simulated time waits, for every vehicle), and so is every other vehicle its datagram of tick k (an answered one
    answers it again, and that answer is discarded as stale): an autopilot that heard nothing for a while would
    declare its plant lost and land. Wind changes are taken between two ticks."""
    period = vehicles[0].plant.period
    named = len(vehicles) > 1
    links = [v.link for v in vehicles]
    # Unpaced, once the autopilots have answered, the ticks run in compiled code (sitl.lockstep_loop) until Python has
    # something to do; the loop below then goes on from where it stopped. Its arrays are the fleet's (a row per
    # vehicle, the vehicles' own arrays views of them), stacked before anything below takes the vehicles' arrays.
    fast = speed <= 0 and fastio.compiled_loops() and all(link.impairment is None for link in links)
    fleet = FleetArrays(vehicles) if fast else None
    k = 0
    start = time.monotonic()
    waits = []
    for v in vehicles:
        check_state(v, 0, named)  # the initial state; the others are checked as they are made (tick.DIVERGED)
        v.link.encode(0, v.plant)
        # Unpaced, a late answer is polled for with patience (nothing else waits on this run's pace); paced, the
        # processes the pace serves get the core back after a budget (SpinThenBlock).
        v.link.wait.be_patient(PATIENCE if speed <= 0 else None)
        p, link = v.plant, v.link
        args = (p.x, p.motors, p.out, p.v, p.a, p.air, p.air_rng, period, p.substeps, p.method, link.tx, link.io,
                p.sens)  # fmt: skip
        waits.append((v, link, link.receive, link.rx_array, link.max_thrust, link.received, p.commanded, args))
    winds = [v for v in vehicles if v.wind is not None]
    monotonic, lockstep_tick, usec_of = time.monotonic, tick.lockstep_tick, codec.usec_of
    count = len(vehicles)
    stats = np.zeros((count, lockstep_loop.STATS_SIZE), dtype=np.int64)
    polling = np.zeros(count, dtype=np.bool_)
    budget_ns, patience_ns = np.zeros(count, dtype=np.int64), np.zeros(count, dtype=np.int64)
    sent_rows = np.zeros_like(fleet.tx) if fleet is not None else None  # tick k's datagrams, kept by the loop
    sent_len = np.zeros(count, dtype=np.int64)
    end = np.iinfo(np.int64).max if max_ticks is None else max_ticks
    while max_ticks is None or k < max_ticks:
        taken = None  # (length, result) of a datagram the compiled loop took for tick k, its answer not yet found
        sent = False
        first = 0  # the first vehicle whose answer to tick k is awaited (those before it stepped in compiled code)
        if fleet is not None and links[0].first_heard is not None:
            stats[:] = 0
            for i, link in enumerate(links):
                wait = link.wait
                if link.timeout != FREEWHEEL_PERIOD:  # the receive's own timeout: the free-wheel's
                    set_receive_timeout(link.sock, FREEWHEEL_PERIOD)
                    link.timeout = FREEWHEEL_PERIOD
                stats[i, lockstep_loop.SHORT] = wait.short
                polling[i] = wait.polling()
                budget_ns[i], patience_ns[i] = int(wait.budget * 1e9), int(wait.patience * 1e9)
            k0 = k
            status, k, first, nbytes, r = lockstep_loop.run(
                fleet.fds, fleet.rx, k, end, fleet.max_thrust, fleet.received, fleet.work, fleet.params,
                fleet.air_rng, fleet.sens, fleet.substeps, fleet.method, period, fleet.tx, fleet.io, sent_rows,
                sent_len, time.monotonic_ns() + LOOP_RETURN_NS, polling, budget_ns, patience_ns, HOT_AFTER, stats
            )  # fmt: skip
            for i, link in enumerate(links):
                link.wait.tally(int(stats[i, lockstep_loop.POLLED]), int(stats[i, lockstep_loop.LATE]),
                                status == lockstep_loop.QUIET and i == first, int(stats[i, lockstep_loop.BLOCKED]),
                                int(stats[i, lockstep_loop.SHORT]))  # fmt: skip
            if k > k0:
                now = monotonic()
                for link in links:
                    link.last_heard = now
                for v in vehicles:
                    for _ in range(k - k0):
                        v.plant.time += period
            if status in (lockstep_loop.DUE, lockstep_loop.END):
                for w in winds:
                    if w.wind.inbox:
                        w.wind.take(w.plant)
                continue
            sent = True
            if status == lockstep_loop.TAKEN:
                links[first].rx_array[:nbytes] = fleet.rx[:nbytes]  # (for pymavlink, if it is its to decode)
                taken = (nbytes, r)
            elif status == lockstep_loop.TIMED_OUT:
                taken = (-1, None)
        want = usec_of(k, period)
        if not sent:
            for link in links:
                link.send()
        if named:  # tick k's datagrams, to send again while any vehicle keeps the fleet waiting
            if sent:  # by the compiled loop, which kept them: the vehicles before `first` hold their next already
                sent_frames = [bytes(row[:n]) for row, n in zip(sent_rows, sent_len.tolist(), strict=True)]
            else:
                sent_frames = [bytes(link.tx_view[: link.io[tick.TX_LEN]]) for link in links]
        held = links[0].first_heard is None
        for v, link, receive, rx, max_thrust, received, commanded, args in waits[first:]:
            while True:
                if taken is not None:
                    (nbytes, r), taken = taken, None
                else:
                    nbytes, r = receive(FREEWHEEL_PERIOD), None
                if nbytes < 0:
                    held = True
                    link.check_lost("holding: simulated time stops until it answers")
                    if named:  # free-wheel the whole fleet: an autopilot that hears nothing declares its plant lost
                        for other, frame in zip(links, sent_frames, strict=True):
                            other.send(frame)
                    else:
                        link.send()  # free-wheel: no answer yet
                    continue
                if r is None:
                    r = lockstep_tick(rx, nbytes, want, max_thrust, received, commanded, *args, k)
                if r == tick.ANOTHER_FRAME:  # for pymavlink (several messages, signed)
                    r = tick.take_and_step(link.decode(nbytes), want, commanded, received, *args, k)
                if r == tick.STEPPED:
                    break
                if r == tick.HELD:  # the hold tick, the autopilot not yet armed: it is there, time waits
                    held = True
                    link.last_heard = monotonic()
                if r == tick.DIVERGED:  # x(k + 1), encoded but not sent
                    raise DivergedError(v, k + 1, named)
        if held:
            for link in links:
                link.heard()
            if speed > 0:  # the pace resumes from here: no burst to catch up with time spent holding
                start = monotonic() - k * period / speed
        else:
            now = monotonic()
            for link in links:
                link.last_heard = now
        for v in vehicles:
            v.plant.time += period
        k += 1
        for v in winds:
            if v.wind.inbox:
                v.wind.take(v.plant)
        if speed > 0:
            delay = start + k * period / speed - monotonic()
            if delay > 0:
                time.sleep(delay)
            elif delay < -PACE_SLACK:  # stalled: no burst at the machine's full speed to catch up, as after a hold
                start -= delay
    return k
