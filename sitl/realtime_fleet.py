"""A real-time fleet's arrays, one per field and a row per vehicle, and its period in two compiled calls
(:func:`sitl.realtime_loop.send_ticks`, :func:`sitl.realtime_loop.take_and_step_all`), whatever the number of
vehicles.

:class:`RealtimeFleet` stacks each vehicle's arrays (its plant's work, parameters and turbulence stream, its
sensors', its link's) into one array per field, and gives every vehicle's objects their rows back as their own
arrays: a row is a view, so the plant, its sensors and its link read and write the fleet's arrays as before
(``plant.x``, ``link.io``, ``Vehicle.answered``, the run's statistics), and the Python paths (a datagram only
pymavlink reads, a wind change) work on them unchanged. The vehicles' presets may differ (airframes, integrators,
substeps); the arrays' sizes do not.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from quadsitl.jit import specialized
from sitl import realtime_loop

if TYPE_CHECKING:
    from sitl.process import Vehicle

PLANT_FIELDS = ("work", "params", "air_rng")  # sitl.plant.Plant's own arrays (the rest are views of work, params)
SENSOR_FIELDS = ("p", "rng", "bias", "clock", "queue", "out")  # sitl.sensors.Sensors.arrays, in that order
LINK_FIELDS = ("tx", "io", "rt", "received")  # sitl.process.PlantLink's


def stacked(owners: Sequence[object], field: str) -> np.ndarray:
    """One array whose row i is ``owners[i]``'s array ``field``, which becomes that row (a view: the owner keeps
    reading and writing it as its own)."""
    rows = np.stack([getattr(owner, field) for owner in owners])
    for i, owner in enumerate(owners):
        setattr(owner, field, rows[i])
    return rows


class RealtimeFleet:
    """The compiled real-time period of ``vehicles`` (unimpaired links; one control period for all): compiled for
    these arrays' types, or loaded from numba's cache, when made."""

    def __init__(self, vehicles: Sequence[Vehicle]) -> None:
        self.vehicles = list(vehicles)
        plants = [v.plant for v in self.vehicles]
        links = [v.link for v in self.vehicles]
        self.period = plants[0].period
        work, params, air_rng = (stacked(plants, f) for f in PLANT_FIELDS)
        for plant in plants:
            plant._views()  # x, commanded, out, ...: views of the plant's row of work
        sens = tuple(stacked([p.sensors for p in plants], f) for f in SENSOR_FIELDS)
        tx, io, rt, received = (stacked(links, f) for f in LINK_FIELDS)
        for link in links:
            link.tx_view = memoryview(link.tx)  # type: ignore[arg-type]
        fds = np.array([link.sock.fileno() for link in links], dtype=np.int64)
        self.rx = np.zeros(65535, dtype=np.uint8)  # every vehicle's answers, one after the other
        max_thrust = np.array([link.max_thrust for link in links])
        substeps = np.array([p.substeps for p in plants], dtype=np.int64)
        method = np.array([p.method for p in plants], dtype=np.int64)
        self.said = np.zeros(len(links), dtype=np.int64)  # LOST_NOW | BACK_NOW, by vehicle, for Python to say
        self.rt = rt
        self.send_args = (fds, tx, io, work, sens)
        self.take_args = (fds, self.rx, received, max_thrust, io, rt, work, params, air_rng, substeps, method)
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
