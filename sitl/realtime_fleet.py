"""A real-time fleet's period in two compiled calls (:func:`sitl.realtime_loop.send_ticks`,
:func:`sitl.realtime_loop.take_and_step_all`), whatever the number of vehicles, on the fleet's arrays stacked a row
per vehicle (:class:`sitl.fleet_arrays.FleetArrays`).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from quadsitl.jit import specialized
from sitl import realtime_loop
from sitl.fleet_arrays import FleetArrays

if TYPE_CHECKING:
    from sitl.vehicle import Vehicle


class RealtimeFleet:
    """The compiled real-time period of ``vehicles`` (unimpaired links; one control period for all): compiled for
    these arrays' types, or loaded from numba's cache, when made."""

    def __init__(self, vehicles: Sequence[Vehicle]) -> None:
        self.vehicles = list(vehicles)
        a = FleetArrays(self.vehicles)
        self.period, self.rx = a.period, a.rx
        self.said = np.zeros(len(self.vehicles), dtype=np.int64)  # LOST_NOW | BACK_NOW, by vehicle, for Python to say
        self.rt = a.rt
        self.send_args = (a.fds, a.tx, a.io, a.work, a.sens)
        self.take_args = (a.fds, a.rx, a.received, a.max_thrust, a.io, a.rt, a.work, a.params, a.air_rng, a.substeps,
                          a.method)  # fmt: skip
        self._send = specialized(realtime_loop.send_ticks, *self.send_args, 0, self.period)
        self._take = specialized(realtime_loop.take_and_step_all, *self.take_args, 0, 0, True, self.period, 0,
                                 self.said)  # fmt: skip

    def send(self, k: int) -> int:
        """Tick ``k``'s datagrams sent, the vehicles taking turns at going first → −1, or the first vehicle whose
        state left its bounds (then none is sent: :func:`sitl.realtime_loop.send_ticks`)."""
        return self._send(*self.send_args, k, self.period)

    def take_and_step(self, want: int, lost_after_ns: int, zero_on_loss: bool, action: str) -> None:
        """The end of the period whose tick is stamped ``want`` [us]: every vehicle's answers taken and counted, the
        lost-autopilot clock, one step each (:func:`sitl.realtime_loop.take_and_step_all`); a datagram for pymavlink
        decoded here on the way; a loss or a return said."""
        start = 0
        while True:
            i = self._take(*self.take_args, want, lost_after_ns, zero_on_loss, self.period, start, self.said)
            if i < 0:
                break
            v = self.vehicles[i]
            n = int(self.rt[i, realtime_loop.LENGTH])
            v.link.rx_array[:n] = self.rx[:n]
            v.link.apply(v.plant, v.link.decode(n))  # (pymavlink decodes it)
            start = i  # on with this vehicle's answers, then the next vehicles'
        if self.said.any():
            for v, said in zip(self.vehicles, self.said.tolist(), strict=True):
                if said & realtime_loop.BACK_NOW:
                    v.link.say_back()
                if said & realtime_loop.LOST_NOW:
                    v.link.say_lost(action)
            self.said[:] = 0
        for v in self.vehicles:
            v.plant.time += self.period
