"""One process, no network: the closed loop of a plant and any controller, one readable loop.

The controller is any object with ``step(state, reference) -> Inputs`` (u1..u4); ``allocate`` turns
inputs into commanded motor forces (the autopilot's control allocation). The result holds one row per
control tick k: the state x(k), the reference r(k) and the command u(k) computed from them.

The state x(k) is checked at the start of every tick, before the controller sees it, with the check of the
plant process and the sweeps' batch engine (:func:`sitl.plant.inside`, its default bounds): a state that is not
finite or out of its bounds ends the run there, diverged at t = k·T, with the rows 0..k−1 flown.

In sensor mode an ``observe`` function stands between the plant and the controller: what the autopilot's
estimator makes of the plant's sensors (``groundstation.offline.SensorObserver``), after ``ground_ticks`` ticks on
the ground with the motors off, as ``quadsitl fly`` waits while the estimator aligns.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from quadsitl.compiled_frames import euler_rates_to_body_rates
from quadsitl.state import Inputs, Reference, VehicleState
from sitl.plant import Plant, outside_what, state_inside


class Controller(Protocol):
    def step(self, state: VehicleState, reference: Reference) -> Inputs: ...


ReferenceSource = Callable[[float], Reference]
PROGRESS_TICKS = 500  # simulate() reports progress every this many ticks (0.5 s simulated at T = 1 ms)


@dataclass
class SimResult:
    """Arrays with one row per control tick. Units: SI, radians; NED for positions and velocities."""

    t: np.ndarray  # (N,) [s]
    state: np.ndarray  # (N, 12) VehicleState fields (Euler-angle rates)
    reference: np.ndarray  # (N, 4) altitude, roll, pitch, yaw
    inputs: np.ndarray  # (N, 4) u1..u4 commanded
    forces: np.ndarray  # (N, 4) commanded motor forces [N]
    diverged_at: float | None = None  # [s]: the time of the tick whose state left the bounds (None: it did not)
    diverged_what: str = ""  # what left its bound (sitl.plant.outside_what)
    estimate: np.ndarray | None = None  # (N, 12) what the controller flew on (sensor mode); ``state`` is the truth

    def body_rates(self, state: np.ndarray | None = None) -> np.ndarray:
        """(N, 3) body rates p, q, r [rad/s] from the Euler-angle rates of ``state`` (default: the truth), eq (1)."""
        s = self.state if state is None else state
        return np.array([euler_rates_to_body_rates(r[6], r[7], r[9], r[10], r[11]) for r in s]).reshape(-1, 3)


def simulate(
    plant: Plant,
    controller: Controller,
    reference: ReferenceSource | Reference,
    duration: float,
    allocate: Callable[[Inputs], tuple[float, float, float, float]],
    omega_r_from: Callable[[], float] | None = None,
    progress: Callable[[float], None] | None = None,
    observe: Callable[[int], VehicleState] | None = None,
    ground_ticks: int = 0,
) -> SimResult:
    """Run the loop for ``duration`` seconds of simulated time (round(duration / T) ticks), or until the state
    diverges (then the result has the ticks flown before it, and ``diverged_at``).

    ``omega_r_from``, when given, supplies the Ωr the plant uses each tick (for example the one the
    controller assumed), instead of the one the applied motor forces make.

    ``progress``, when given, is called with the simulated seconds done every ``PROGRESS_TICKS`` ticks
    and once at the end; it only observes, the result is the same with or without it.

    ``observe``, when given, is what the controller sees each tick instead of the true state, called with the
    tick's number since the plant started (the result's ``estimate``); ``ground_ticks`` ticks with the motors
    off come first (observed, not in the result: t = 0 is the first tick flown).
    """
    period = plant.period
    for k in range(ground_ticks):
        if observe is not None:
            observe(k)
        plant.step((0.0, 0.0, 0.0, 0.0))
    n = round(duration / period)
    ref_of = reference if callable(reference) else (lambda _t, r=reference: r)
    t = np.arange(n) * period
    states = np.empty((n, 12))
    refs = np.empty((n, 4))
    inputs = np.empty((n, 4))
    forces = np.empty((n, 4))
    estimate = None if observe is None else np.empty((n, 12))
    for k in range(n):
        if progress is not None and k % PROGRESS_TICKS == 0:
            progress(k * period)
        if not state_inside(plant.x):
            if progress is not None:
                progress(n * period)
            return SimResult(t[:k], states[:k], refs[:k], inputs[:k], forces[:k], k * period, outside_what(plant.x),
                             None if estimate is None else estimate[:k])  # fmt: skip
        state = plant.state
        seen = state if observe is None else observe(ground_ticks + k)
        ref = ref_of(k * period)
        u = controller.step(seen, ref)
        f = allocate(u)
        states[k] = state
        if estimate is not None:
            estimate[k] = seen
        refs[k] = ref
        inputs[k] = u
        forces[k] = f
        plant.step(f, omega_r=None if omega_r_from is None else omega_r_from())
    if progress is not None:
        progress(n * period)
    return SimResult(t, states, refs, inputs, forces, estimate=estimate)
