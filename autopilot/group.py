"""Several hosted vehicles flown by one thread (:mod:`autopilot.host`): one ``epoll_wait`` on their plant sockets and
each datagram served in compiled code (:func:`autopilot.plant_loop.serve_group`), instead of a thread woken and put
to sleep again for every vehicle's every tick (docs/performance.md#a-hosted-fleet-of-32-in-real-time).

Each vehicle is the same :class:`autopilot.process.Autopilot` with the same loop as a thread of its own runs
(:meth:`Autopilot.run`), cut at its turns: :meth:`Autopilot.begin`, then, each time the compiled loop gives that
vehicle back to Python, what :meth:`Autopilot.run` does after its compiled loop returns (:meth:`Autopilot.served`,
or the Python path's datagram) and :meth:`Autopilot.housekeeping`. A vehicle whose ticks go to Python (no plant
heard yet, a plant lost, a mission flying: :meth:`Autopilot.serving` False) has its datagrams read by Python, told
by the same ``epoll_wait``. Only that vehicle's Python ran in its turn, so only its row of the loop's arguments is made
again (:meth:`Group.prepare`). The vehicles are taken in turn, each turn starting after the last one served.

Not grouped (:func:`groupable`): a vehicle flown with ``--offboard-lockstep`` (its clock may wait for a setpoint in
Python, which would hold its group-mates) or whose plant link is not served by compiled code (IPv6, or
``QUADSITL_COMPILED_LOOPS=0``).
"""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Callable, Sequence

import numba
import numpy as np

from autopilot import plant_loop
from autopilot import tick as kernel
from autopilot.process import GCS_POLL, HOUSEKEEPING, Autopilot
from quadsitl import fastio
from quadsitl.process_util import PACED_BELOW, spin_budget


def group_threads() -> int:
    """How many groups a host flies its vehicles of one kind in: a thread for each core this process may run on but
    one, which the fleet's plant (one process, one thread) takes; at least one (docs/fleets.md#hosted-autopilots)."""
    return max(1, len(os.sched_getaffinity(0)) - 1)


QUIET_NS = 20_000_000  # [ns] the longest the loop waits without coming back to Python (the stop event's latency)


def groupable(ap: Autopilot) -> bool:
    """Whether ``ap`` can fly in a group (the module's docstring)."""
    return ap.pace is None and ap.plant.fast


def groups_of(aps: Sequence[Autopilot], threads: int | None = None) -> tuple[list[list[Autopilot]], list[Autopilot]]:
    """(the groups, the vehicles flown alone): ``aps`` that :func:`groupable` in ``threads`` groups (default
    :func:`group_threads`; fewer when there are fewer vehicles), each of vehicles whose loop arguments have the same
    types (one compiled loop: truth and sensors differ)."""
    kinds: dict[object, list[Autopilot]] = {}
    alone = []
    for ap in aps:
        if groupable(ap):
            kinds.setdefault(numba.typeof(_entry(ap)), []).append(ap)
        else:
            alone.append(ap)
    groups = []
    for same in kinds.values():
        count = min(len(same), group_threads() if threads is None else threads)  # as even as they come
        groups += [same[g::count] for g in range(count)]
    return groups, alone


def _entry(ap: Autopilot, targs: tuple | None = None) -> tuple:
    """``ap``'s part of :func:`plant_loop.serve_group`'s vehicles, with these tick arguments (default: its own now)."""
    targs = ap.tick_arguments() if targs is None else targs
    return ap.plant.group_entry(ap.io, targs, ap.destinations.out, ap.ground_fds)


def _same(a: tuple, b: tuple) -> bool:
    """Whether two tick-argument tuples hold the same things: the same arrays and tuples, equal numbers."""
    return len(a) == len(b) and all(
        x is y or (not isinstance(x, (np.ndarray, tuple)) and type(x) is type(y) and x == y)
        for x, y in zip(a, b, strict=True)
    )


class Group:
    """Vehicles flown by one thread (:meth:`run`), all of :func:`groups_of`'s kind."""

    def __init__(self, aps: Sequence[Autopilot]) -> None:
        self.aps = list(aps)
        k = len(self.aps)
        self.ctl = np.zeros((k, plant_loop.CTL_SIZE), dtype=np.int64)
        self.ready = fastio.ReadySet([ap.plant.sock for ap in self.aps])
        self.out = np.zeros(plant_loop.OUT_SIZE, dtype=np.int64)
        self.targs = [ap.tick_arguments() for ap in self.aps]
        self.peers = [ap.plant.address for ap in self.aps]
        self.entries = plant_loop.group_list([_entry(ap, t) for ap, t in zip(self.aps, self.targs, strict=True)])
        self.entries[0] = self.entries[0]  # numba compiles the list's item assignment now, not in the first turn
        # Each vehicle's plant pace, as a vehicle alone measures it (PaceGauge): the group polls before it blocks
        # (spin_ns) only while every one of them is unpaced (lockstep as fast as it goes), never in real time.
        self.unpaced = [False] * k
        self.budget_ns = int(spin_budget() * 1e9)
        self.spin_ns = 0

    def prepare(self, i: int) -> None:
        """Vehicle ``i``'s row of the loop's arguments, after its turn in Python (the only one whose Python ran)."""
        ap = self.aps[i]
        compiled = ap.serving()
        row = self.ctl[i]
        if compiled:
            deadline, limit = ap.serve_bounds()
            targs = ap.tick_arguments()
            if ap.plant.address is not self.peers[i] or not _same(targs, self.targs[i]):
                self.targs[i], self.peers[i] = targs, ap.plant.address
                self.entries[i] = _entry(ap, targs)
        else:
            deadline, limit = ap.next_chores, plant_loop.NO_LIMIT
        row[plant_loop.CTL_DEADLINE] = int(deadline * 1e9)
        row[plant_loop.CTL_LIMIT] = limit
        row[plant_loop.CTL_COMPILED] = compiled
        row[plant_loop.CTL_GROUND_EVERY] = int(GCS_POLL * 1e9)
        stats = ap.plant.stats
        stats[plant_loop.ANSWERED] = 0
        stats[plant_loop.NEXT_GROUND] = int(ap.next_poll * 1e9)

    def turn(self, i: int, status: int) -> None:
        """Vehicle ``i``'s turn in Python: what the loop gave back (``status``), then its housekeeping."""
        ap = self.aps[i]
        if status == plant_loop.READABLE:  # its datagrams are Python's: the one waiting, read at once
            ap.take_plant_datagram(lambda: ap.plant.sock.recvfrom_into(ap.plant.rx))
            status = -1
        elif status != plant_loop.QUIET:
            wall = ap.plant.after_loop(status)
            ap.next_poll = ap.plant.stats[plant_loop.NEXT_GROUND] * 1e-9
            ap.served(status, int(self.out[plant_loop.LENGTH]), int(self.out[plant_loop.FLAGS]), wall)
        ap.housekeeping(status)
        self.prepare(i)
        pace = ap.plant.pace.update(int(ap.io[kernel.TICK]), time.monotonic())
        if pace is not None:
            self.unpaced[i] = pace >= PACED_BELOW
            self.spin_ns = self.budget_ns if all(self.unpaced) else 0

    def run(self, stop: threading.Event, ready: Callable[[], None]) -> None:
        """Fly the group until ``stop`` is set; ``ready`` once for each vehicle, when its first heartbeat is out."""
        for i, ap in enumerate(self.aps):
            ap.begin(ready)
            ap.next_chores += HOUSEKEEPING * i / len(self.aps)  # the group's trips to Python spread over the period
            self.prepare(i)
        ready = self.ready
        try:
            while not stop.is_set():
                status = plant_loop.serve_group(self.entries, self.ctl, ready.fd, ready.events, ready.slot, self.out,
                                                QUIET_NS, self.spin_ns)  # fmt: skip
                i = int(self.out[plant_loop.VEHICLE])
                if i >= 0:
                    self.turn(i, status)
                else:  # nothing came for QUIET_NS: every vehicle's housekeeping (a plant gone silent)
                    for j in range(len(self.aps)):
                        self.turn(j, plant_loop.QUIET)
        finally:
            ready.close()
