"""Motor models: commanded motor forces [N] → forces acting on the airframe [N].

``ideal`` (the paper's assumption): reversible, clamped to [−F_max, F_max], no lag.
``realistic``: clamped to [0, F_max] with an optional first-order lag (separate time constants for
spinning up and down, as PX4's Gazebo motor model has).
"""

from __future__ import annotations

import math

from quadsitl.config import ActuatorParams

Forces = tuple[float, float, float, float]


class Actuators:
    """Holds the motor forces between steps (needed for the lag)."""

    def __init__(self, params: ActuatorParams) -> None:
        self.params = params
        self.f_min = params.min_thrust
        self.f_max = params.max_thrust
        self.forces: Forces = (0.0, 0.0, 0.0, 0.0)

    def reset(self, forces: Forces = (0.0, 0.0, 0.0, 0.0)) -> None:
        self.forces = forces

    def clamp(self, commanded: Forces) -> Forces:
        lo, hi = self.f_min, self.f_max
        return tuple(min(max(f, lo), hi) for f in commanded)  # type: ignore[return-value]

    def advance(self, commanded: Forces, h: float) -> Forces:
        """Advance the motors by h seconds under ``commanded``; return the mean force over the interval.

        With lag, the exact solution of τ·Ḟ = F_cmd − F is used: F(t) = c + (F0 − c)·e^(−t/τ), and its
        mean over [0, h] is c + (F0 − c)·(τ/h)·(1 − e^(−h/τ)).
        """
        target = self.clamp(commanded)
        up, down = self.params.time_constant_up, self.params.time_constant_down
        if up == 0.0 and down == 0.0:
            self.forces = target
            return target
        new, mean = [], []
        for f0, c in zip(self.forces, target):
            tau = up if c > f0 else down
            if tau == 0.0:
                new.append(c)
                mean.append(c)
                continue
            decay = math.exp(-h / tau)
            new.append(c + (f0 - c) * decay)
            mean.append(c + (f0 - c) * (tau / h) * (1.0 - decay))
        self.forces = tuple(new)  # type: ignore[assignment]
        return tuple(mean)  # type: ignore[return-value]
