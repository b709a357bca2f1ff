"""How well a loop kept its period: pure statistics over the wall times at which its ticks started."""

from __future__ import annotations

import itertools
from collections.abc import Sequence


def percentile(values: Sequence[float], q: float) -> float:
    """The q-th percentile (0..100) by nearest rank; 0 for no values."""
    if not values:
        return 0.0
    ordered = sorted(values)
    k = min(len(ordered) - 1, max(0, round(q / 100.0 * (len(ordered) - 1))))
    return ordered[k]


def late_periods(starts: Sequence[float], period: float, t0: float) -> list[int]:
    """The ticks k (ascending) of a loop scheduled at ``t0`` + k·``period`` [s] that started a whole period or more
    after their scheduled time (``starts``: their actual start times [s]): its deadline misses."""
    return [k for k, s in enumerate(starts) if s - (t0 + k * period) >= period]


def period_stats(starts: Sequence[float], period: float) -> dict[str, float]:
    """Tick start times [s] of a loop scheduled at t0 + k·period → jitter and deadline misses.

    jitter: |actual period − period| per tick, in µs (p50, p99, max). lateness: how far into its period each tick
    started (actual − scheduled start, µs; p50, p99): what a constant delay of every tick, which jitter does not see,
    takes from the time the tick's work has before the next is due. A tick misses its deadline when it starts a whole
    period or more after its scheduled time (it could not start before the next one was due).
    """
    if len(starts) < 2:
        return {"ticks": len(starts), "jitter_p50_us": 0.0, "jitter_p99_us": 0.0, "jitter_max_us": 0.0,
                "lateness_p50_us": 0.0, "lateness_p99_us": 0.0, "deadline_miss_ratio": 0.0,
                "mean_period_us": 0.0}  # fmt: skip
    t0 = starts[0]
    jitter = [abs(b - a - period) * 1e6 for a, b in itertools.pairwise(starts)]
    lateness = [(s - (t0 + k * period)) * 1e6 for k, s in enumerate(starts)]
    misses = len(late_periods(starts, period, t0))
    return {
        "ticks": len(starts),
        "jitter_p50_us": percentile(jitter, 50),
        "jitter_p99_us": percentile(jitter, 99),
        "jitter_max_us": max(jitter),
        "lateness_p50_us": percentile(lateness, 50),
        "lateness_p99_us": percentile(lateness, 99),
        "deadline_miss_ratio": misses / len(starts),
        "mean_period_us": (starts[-1] - t0) / (len(starts) - 1) * 1e6,
    }
