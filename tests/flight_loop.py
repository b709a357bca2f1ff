"""A closed loop of the autopilot's compiled tick (commander, position loop, controller, allocation) and the
plant, in one process and in lockstep, for tests of the flight controller without sockets.

It calls :func:`autopilot.tick.control_tick` (what the autopilot process calls once a state is decoded) and
:meth:`sitl.plant.Plant.step` (what the plant process calls), so it flies the same equations as ``quadsitl up``.
The plant flies in the preset's [wind] (a wind, an external force), and the autopilot may be given another
vehicle model than the plant's (a mismatch).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from autopilot.commander import Commander, CommanderSettings
from autopilot.control_params import MEM_FORCES, MEM_SIZE
from autopilot.factory import make_controller
from autopilot.params import commander_settings
from autopilot.plugin import no_plug
from autopilot.tick import EVENT, IO_SIZE, control_tick
from quadsitl import codec
from quadsitl.config import Preset
from quadsitl.state import VehicleState
from sitl.plant import Plant


class Flight:
    def __init__(
        self,
        preset: Preset,
        controller: str = "backstepping",
        model: Preset | None = None,
        settings: CommanderSettings | None = None,
    ) -> None:
        self.preset = preset
        self.plant = Plant(preset)
        ctl = make_controller(model or preset, controller)
        self.kind, self.v, self.c = ctl.kind, ctl.v, ctl.c
        self.commander = Commander(commander_settings((model or preset).position, settings or CommanderSettings()))
        self.cm = self.commander.cm
        self.mem = np.zeros(MEM_SIZE)
        self.st = np.zeros(codec.DECODED_SIZE)
        self.tx = np.zeros(codec.FRAME_MAX, dtype=np.uint8)
        self.io = np.zeros(IO_SIZE, dtype=np.int64)
        self.records = np.zeros(0, dtype=np.uint8)
        self.period = preset.sim.period
        self.f_min, self.f_max = preset.actuators.min_thrust, preset.actuators.max_thrust
        self.tick = 0
        self.step(1)  # the commander has seen a state

    @property
    def state(self) -> VehicleState:
        return self.plant.state

    @property
    def time(self) -> float:
        return self.tick * self.period

    def step(self, n: int = 1) -> None:
        for _ in range(n):
            self.st[:12] = self.plant.x
            t = self.tick * self.period
            control_tick(self.kind, no_plug(), self.st, self.cm, self.mem, self.v, self.c, self.f_min, self.f_max,
                         self.tx, self.io, codec.usec_of(self.tick, self.period), self.tick, t,
                         self.records)  # fmt: skip
            self.commander.announce(int(self.io[EVENT]))
            self.plant.step(tuple(self.mem[MEM_FORCES : MEM_FORCES + 4]))
            self.tick += 1

    def run(self, seconds: float) -> None:
        self.step(round(seconds / self.period))

    def until(self, cond: Callable[[Flight], bool], timeout: float) -> float:
        """Fly until ``cond(self)`` holds; the simulated time it took [s]. Fails after ``timeout`` seconds."""
        start = self.time
        while not cond(self):
            assert self.time - start < timeout, f"not within {timeout} s: {self.state}, mode {self.commander.mode}"
            self.step(10)
        return self.time - start

    def horizontal_error(self, x: float, y: float) -> float:
        s = self.state
        return float(np.hypot(s.x - x, s.y - y))
