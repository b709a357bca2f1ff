"""Fixed-step integrators over plain tuples: ``euler`` (the paper's forward Euler, eq (9)) and ``rk4``."""

from __future__ import annotations

from collections.abc import Callable

State = tuple[float, ...]
Derivative = Callable[[State], State]


def euler(f: Derivative, s: State, h: float) -> State:
    """Forward Euler, paper eq (9): s⁺ = s + h·f(s)."""
    d = f(s)
    return tuple(a + h * b for a, b in zip(s, d))


def rk4(f: Derivative, s: State, h: float) -> State:
    """Classic fourth-order Runge–Kutta with the inputs held over the step (zero-order hold)."""
    k1 = f(s)
    k2 = f(tuple(a + 0.5 * h * b for a, b in zip(s, k1)))
    k3 = f(tuple(a + 0.5 * h * b for a, b in zip(s, k2)))
    k4 = f(tuple(a + h * b for a, b in zip(s, k3)))
    h6 = h / 6.0
    return tuple(a + h6 * (b1 + 2.0 * b2 + 2.0 * b3 + b4) for a, b1, b2, b3, b4 in zip(s, k1, k2, k3, k4))


INTEGRATORS: dict[str, Callable[[Derivative, State, float], State]] = {"euler": euler, "rk4": rk4}
