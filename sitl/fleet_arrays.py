"""A fleet's arrays, one per field and a row per vehicle, for the compiled loops that do every vehicle's part of a
tick in one call, whatever the number of vehicles: the real-time period (:class:`sitl.realtime_fleet.RealtimeFleet`)
and the lockstep clock (:func:`sitl.lockstep_loop.run`, one vehicle being a fleet of one).

:class:`FleetArrays` stacks each vehicle's arrays (its plant's work, parameters and turbulence stream, its sensors',
its link's) into one array per field, and gives every vehicle's objects their rows back as their own arrays: a row
is a view, so the plant, its sensors and its link read and write the fleet's arrays as before (``plant.x``,
``link.io``, ``Vehicle.answered``, the run's statistics), and the Python paths (a datagram only pymavlink reads, a
wind change) work on them unchanged. The vehicles' presets may differ (airframes, integrators, substeps); the
arrays' sizes do not.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from sitl.vehicle import Vehicle

PLANT_FIELDS = ("work", "params", "air_rng")  # sitl.plant.Plant's own arrays (the rest are views of work, params)
SENSOR_FIELDS = ("p", "rng", "bias", "clock", "queue", "out")  # sitl.sensors.Sensors.arrays, in that order
LINK_FIELDS = ("tx", "io", "rt", "received")  # sitl.plant_link.PlantLink's


def stacked(owners: Sequence[object], field: str) -> np.ndarray:
    """One array whose row i is ``owners[i]``'s array ``field``, which becomes that row (a view: the owner keeps
    reading and writing it as its own)."""
    rows = np.stack([getattr(owner, field) for owner in owners])
    for i, owner in enumerate(owners):
        setattr(owner, field, rows[i])
    return rows


class FleetArrays:
    """``vehicles``' arrays stacked (the module's docstring), and what the compiled loops take besides: each
    vehicle's connected socket (``fds``), largest rotor thrust [N], substeps and integration method; ``rx``, one
    receive buffer for all (a datagram for Python is copied to its link's); ``period`` [s], the fleet's one."""

    def __init__(self, vehicles: Sequence[Vehicle]) -> None:
        plants = [v.plant for v in vehicles]
        links = [v.link for v in vehicles]
        self.period = plants[0].period
        self.work, self.params, self.air_rng = (stacked(plants, f) for f in PLANT_FIELDS)
        for plant in plants:
            plant._views()  # x, commanded, out, ...: views of the plant's row of work
        # the sensors' arrays, if any vehicle flies on sensors (sitl.plant.Plant.sens; a vehicle on the truth in a
        # mixed fleet is told by its io[SENSING]): None compiles the loops without the sensors' path
        sensing = any(p.sensing for p in plants)
        self.sens = tuple(stacked([p.sensors for p in plants], f) for f in SENSOR_FIELDS) if sensing else None
        self.tx, self.io, self.rt, self.received = (stacked(links, f) for f in LINK_FIELDS)
        for link in links:
            link.tx_view = memoryview(link.tx)  # type: ignore[arg-type]
        self.fds = np.array([link.sock.fileno() for link in links], dtype=np.int64)
        self.rx = np.zeros(65535, dtype=np.uint8)
        self.max_thrust = np.array([link.max_thrust for link in links])
        self.substeps = np.array([p.substeps for p in plants], dtype=np.int64)
        self.method = np.array([p.method for p in plants], dtype=np.int64)
