"""Backstepping gains and the paper's stability conditions (41)–(44).

Two parametrisations (DESIGN.md §3, erratum 7):

- rates k_i [1/s] (the default): the discrete pole is λ_i = 1 − T·k_i. The paper's k_i = 10 means
  λ_i = 0.99 at T = 1 ms.
- poles λ_i: the designed error dynamics e_i⁺ = λ_i·e_i + T·e_{i+1}, e_{i+1}⁺ = λ_{i+1}·e_{i+1}
  directly. The paper's literal form e_i⁺ = −k_i·e_i + T·e_{i+1} (eq 27) is λ_i = −k_i.

With k replaced by λ, conditions (41)–(44) ask, for each channel j = 1..4 (odd index i = 2j − 1):

    λ_i² − 1 + 4T²λ_i²/ε < 0     →  ε > 4T²λ_i² / (1 − λ_i²)      (needs |λ_i| < 1)
    T² + λ_{i+1}² − 1 + ε < 0    →  ε < 1 − T² − λ_{i+1}²          (needs λ_{i+1}² < 1 − T²)

so they hold for some ε > 0 exactly when the largest lower bound is below the smallest upper bound.
"""

from __future__ import annotations

from collections.abc import Sequence

CHANNELS = ("altitude", "roll", "pitch", "yaw")


class GainError(ValueError):
    """Gains violate the stability conditions. The message names the inequality and the gain."""


def poles_from_rates(rates: Sequence[float], period: float) -> tuple[float, ...]:
    """λ_i = 1 − T·k_i."""
    return tuple(1.0 - period * k for k in rates)


def rates_from_poles(poles: Sequence[float], period: float) -> tuple[float, ...]:
    """k_i = (1 − λ_i)/T [1/s]."""
    return tuple((1.0 - lam) / period for lam in poles)


def _describe(i: int, lam: float, period: float) -> str:
    return f"λ{i} = {lam:.6g} (k{i} = {(1.0 - lam) / period:.6g} 1/s)"


def epsilon_bounds(i: int, lam_i: float, lam_n: float, period: float, eq: str, channel: str) -> tuple[float, float]:
    """One channel pair's bounds on ε from the paper's conditions, k replaced by λ (module docstring):
    ε > 4T²λ_i²/(1 − λ_i²) and ε < 1 − T² − λ_(i+1)². Raises :class:`GainError` naming condition ``eq``
    when either cannot hold for any ε > 0."""
    T2 = period * period
    if not abs(lam_i) < 1.0:
        raise GainError(
            f"condition {eq} λ{i}² − 1 + 4T²λ{i}²/ε < 0 ({channel}) cannot hold for any ε > 0: "
            f"{_describe(i, lam_i, period)} has |λ{i}| ≥ 1; allowed: |λ{i}| < 1, "
            f"i.e. 0 < k{i} < {2.0 / period:.6g} 1/s"
        )
    hi = 1.0 - T2 - lam_n * lam_n
    if not hi > 0.0:
        raise GainError(
            f"condition {eq} T² + λ{i + 1}² − 1 + ε < 0 ({channel}) cannot hold for any ε > 0: "
            f"{_describe(i + 1, lam_n, period)}; allowed: λ{i + 1}² < 1 − T² = {1.0 - T2:.9g}"
        )
    return 4.0 * T2 * lam_i * lam_i / (1.0 - lam_i * lam_i), hi


def stability_interval(poles: Sequence[float], period: float) -> tuple[float, float]:
    """The open interval (ε_min, ε_max) of ε for which conditions (41)–(44) all hold.

    Raises :class:`GainError` naming the violated inequality and the offending gain.
    """
    if len(poles) != 8:
        raise GainError(f"expected 8 gains (k1..k8 or λ1..λ8), got {len(poles)}")
    lower: list[tuple[float, int]] = []
    upper: list[tuple[float, int]] = []
    for j in range(4):
        i = 2 * j + 1
        lo, hi = epsilon_bounds(i, poles[2 * j], poles[2 * j + 1], period, f"({41 + j})", CHANNELS[j])
        lower.append((lo, i))
        upper.append((hi, i + 1))
    eps_lo, i_lo = max(lower)
    eps_hi, i_hi = min(upper)
    if not eps_lo < eps_hi:
        eq_lo, eq_hi = 41 + (i_lo - 1) // 2, 41 + (i_hi - 2) // 2
        raise GainError(
            f"conditions ({eq_lo}) and ({eq_hi}) conflict: ({eq_lo}) needs ε > {eps_lo:.6g} because of "
            f"{_describe(i_lo, poles[i_lo - 1], period)}, but ({eq_hi}) needs ε < {eps_hi:.6g} because of "
            f"{_describe(i_hi, poles[i_hi - 1], period)}; move λ{i_lo} towards 0 or λ{i_hi} towards 0"
        )
    return eps_lo, eps_hi


TIME_SCALE = 3.0  # the horizontal loop's rates stay this many times below the attitude loop's slowest (56)
XY_NAMES = ("k9 (x position)", "k10 (x velocity)", "k11 (y position)", "k12 (y velocity)")


def check_position_gains(
    rates: Sequence[float], integral: Sequence[float], attitude_rates: Sequence[float], period: float
) -> tuple[float, float]:
    """Check the flight controller's gains (docs/position.md): the horizontal loop's rates k9..k12 [1/s] against
    conditions (41)–(44) read for the channel pairs (k9, k10) and (k11, k12) (eq (53)) and against the
    time-scale bound k ≤ min(k3..k6)/3 (56); the integral rates k_I [1/s] (altitude, horizontal) against
    0 ≤ T·k_I < 1 (58). Returns the ε interval of (53). Raises :class:`GainError` naming the gain and the bound."""
    if len(rates) != 4:
        raise GainError(f"expected 4 horizontal gains (k9..k12), got {len(rates)}")
    inner = min(attitude_rates)
    bound = inner / TIME_SCALE
    for name, k in zip(XY_NAMES, rates):
        if not 0.0 < k <= bound:
            raise GainError(
                f"condition (56) k ≤ min(k3..k6)/{TIME_SCALE:g}: {name} = {k:.6g} 1/s is too fast for the attitude "
                f"loop (its slowest rate is {inner:.6g} 1/s); allowed: 0 < {name.split()[0]} ≤ {bound:.6g} 1/s"
            )
    poles = [1.0 - period * k for k in rates]
    x = epsilon_bounds(9, poles[0], poles[1], period, "(53)", "x")
    y = epsilon_bounds(11, poles[2], poles[3], period, "(53)", "y")
    eps_lo, eps_hi = max(x[0], y[0]), min(x[1], y[1])
    if not eps_lo < eps_hi:
        raise GainError(f"condition (53): no ε > {eps_lo:.6g} below {eps_hi:.6g}; move k9..k12 towards each other")
    for name, k in zip(("integral rate k_I (altitude)", "integral rate k_I (horizontal)"), integral):
        if not 0.0 <= period * k < 1.0:
            raise GainError(
                f"condition (58) 0 ≤ T·k_I < 1: {name} = {k:.6g} 1/s; allowed: 0 ≤ k_I < {1.0 / period:.6g} 1/s"
            )
    return eps_lo, eps_hi
