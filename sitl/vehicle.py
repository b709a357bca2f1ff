"""One vehicle the plant process simulates (:class:`Vehicle`: its preset, plant, link to its autopilot and wind
changes), and the divergence check at the start of each tick (:func:`check_state`, :class:`DivergedError`) that
both clocks make (:mod:`sitl.lockstep`, :mod:`sitl.realtime`).
"""

from __future__ import annotations

from dataclasses import dataclass

from quadsitl.config import Preset
from sitl import realtime_loop
from sitl.plant import Plant, outside_what, state_inside
from sitl.plant_link import PlantLink
from sitl.wind_link import WindLink


@dataclass
class Vehicle:
    """One vehicle the plant process simulates: its name (Zenoh's ``quadsitl/<name>/…``, and in messages when the
    process simulates several), its preset (the state and wind options applied), its plant, its link to its
    autopilot, and its wind changes (None: no Zenoh)."""

    name: str
    preset: Preset
    plant: Plant
    link: PlantLink
    wind: WindLink | None = None

    @property
    def answered(self) -> int:
        """Real time: periods whose own answer (stamped with the period's tick) came within it ..."""
        return int(self.link.rt[realtime_loop.ANSWERED])

    @property
    def late(self) -> int:
        """... and periods since the autopilot's first answer whose answer did not: it flew a stale command."""
        return int(self.link.rt[realtime_loop.LATE])


class DivergedError(Exception):
    """The state of ``vehicle`` at the start of tick ``tick`` left its bounds (:func:`sitl.plant.inside`): the run
    ends, that state not sent. ``t`` is the plant's simulated time then [s], since the plant started. ``named``:
    the message names the vehicle (a fleet)."""

    def __init__(self, vehicle: Vehicle, tick: int, named: bool = False) -> None:
        self.vehicle, self.tick, self.t = vehicle, tick, tick * vehicle.plant.period
        self.what = outside_what(vehicle.plant.x)
        who = f"vehicle {vehicle.name} " if named else ""
        super().__init__(f"{who}diverged at t = {self.t:.3f} s (tick {tick} of the plant's clock): {self.what}")


def check_state(v: Vehicle, k: int, named: bool = False) -> None:
    """The start of tick ``k``: raise :class:`DivergedError` when the state is not :func:`sitl.plant.inside` its
    default bounds (one compiled call; lockstep checks the states after the first in its compiled tick)."""
    if not state_inside(v.plant.x):
        raise DivergedError(v, k, named)
