"""The plant's real-time clock (:func:`run_realtime`): every vehicle integrated on the wall clock at period T,
tick k due at t0 + k·T, each applying the latest actuator command it has (older ones, by ``time_usec``, discarded).
Where the compiled loops run and no link is impaired, a period is two compiled calls for the whole fleet
(:class:`sitl.realtime_fleet.RealtimeFleet`); otherwise the Python loop here does the same, vehicle by vehicle.
"""

from __future__ import annotations

import socket
import time
from collections.abc import Sequence

from quadsitl import codec, fastio
from quadsitl.process_util import readable_of
from sitl import realtime_loop
from sitl.plant_link import LOST_AFTER_NS
from sitl.realtime_fleet import RealtimeFleet
from sitl.vehicle import DivergedError, Vehicle, check_state


def receive_within(vehicles: Sequence[Vehicle], seconds: float, socks: dict[socket.socket, Vehicle]) -> None:
    """Real time with impaired links (``--impair``): apply every actuator message that arrives within ``seconds`` on
    any vehicle's link (``socks``: the vehicles by their sockets), and release the impaired datagrams that fall
    due; without impairment the plant sleeps through the period instead (:func:`run_realtime`)."""
    if len(vehicles) == 1:
        vehicles[0].link.receive_within(seconds, vehicles[0].plant)
        return
    impaired = [v for v in vehicles if v.link.impairment is not None]
    if impaired:
        seconds = min(seconds, max(0.0, min(v.link.next_event() for v in impaired) - time.monotonic()))
    arrived = {socks[s].name for s in readable_of(list(socks), seconds)}
    for v in vehicles:
        if v.name in arrived or v.link.impairment is not None:
            v.link.receive_within(0.0, v.plant)  # readable now (or its queues due): takes it without waiting


def sleep_until(deadline: float) -> None:
    """Sleep until ``deadline`` [s, time.monotonic's clock]; return at once when it has passed."""
    remaining = deadline - time.monotonic()
    if remaining > 0:
        time.sleep(remaining)


def run_realtime(
    vehicles: Sequence[Vehicle],
    max_ticks: int | None,
    starts: list[float] | None = None,
    on_loss: str = "zero",
    late: Sequence[list[int]] | None = None,
) -> int:
    """Integrate every vehicle on the wall clock, tick k due at t0 + k·T. ``starts`` (if given) receives each
    tick's actual start time [s, monotonic]; ``late`` (if given, a list per vehicle) the ticks whose answer did not
    come within their period, from the autopilot's first answer on (what ``rt[LATE]`` counts). Where the compiled
    loops run (:func:`quadsitl.fastio.compiled_loops`), but with impaired links, whose queues are Python's, the whole
    fleet's work of a period is two compiled calls (:class:`sitl.realtime_fleet.RealtimeFleet`); the Python loop does
    the same, vehicle by vehicle."""
    period = vehicles[0].plant.period
    named = len(vehicles) > 1
    socks = {v.link.sock: v for v in vehicles}
    impaired = any(v.link.impairment is not None for v in vehicles)  # their queues release datagrams on time
    fleet = RealtimeFleet(vehicles) if fastio.compiled_loops() and not impaired else None
    winds = [v for v in vehicles if v.wind is not None]
    zero = on_loss == "zero"
    action = f"applying {'zero thrust' if zero else 'the last command'}"
    k = 0
    next_time = time.monotonic()
    while max_ticks is None or k < max_ticks:
        if starts is not None:
            starts.append(time.monotonic())
        if fleet is not None:
            if (i := fleet.send(k)) >= 0:
                raise DivergedError(vehicles[i], k, named)
        else:
            for v in vehicles:
                check_state(v, k, named)
            for j in range(len(vehicles)):  # the vehicles take turns at going first, as the compiled period's do
                v = vehicles[realtime_loop.send_order(j, k, len(vehicles))]
                v.link.send_state(k, v.plant)
        if k == 0:  # the clock starts once the first states are out: a slow first send (page faults, a machine busy
            next_time = time.monotonic()  # starting a dashboard) would otherwise be caught up in a burst of late ticks
            if starts is not None:
                starts[0] = next_time
        next_time += period
        if impaired:
            while True:
                remaining = next_time - time.monotonic()
                if remaining <= 0:
                    break
                receive_within(vehicles, remaining, socks)
            receive_within(vehicles, 0.0, socks)
        else:
            # The answers are needed only when the period ends, so the plant sleeps until then and takes them all at
            # once: one wake-up per period, not one per answer, and an autopilot's answer wakes nobody (waking a
            # process on the other core costs the waker CPU)
            sleep_until(next_time)
            # Everything that came before the period ended, and only then: a plant whose own wake-up came late (the
            # scheduler ran something else) takes the answers that came in time, not the last command
            for v in vehicles if fleet is None else ():
                v.link.drain(v.plant)
        want = codec.usec_of(k, period)
        for v in winds:
            if v.wind.inbox:
                v.wind.take(v.plant)
        if fleet is not None:  # the drain above and the end of the period, for every vehicle in one compiled call
            fleet.take_and_step(want, LOST_AFTER_NS, zero, action)
        else:
            for v in vehicles:
                v.link.end_period(want, v.plant, zero, action)
        if late is not None:  # a period counts late at most once: the count grew by one for each vehicle late now
            for v, ticks in zip(vehicles, late, strict=True):
                if v.late > len(ticks):
                    ticks.append(k)
        k += 1
    return k
