"""A sweep's distributions: what one varied parameter's values are drawn from (:class:`Distribution`), read from a
[vary] value with its own bounds checked (:func:`parse_distribution`). Pure: no I/O, nothing compiled.

A number (fixed), ``fixed`` (value), ``uniform`` (low < high), ``normal`` (mean, std > 0, and optional low < high:
redrawn until inside), ``grid`` (values, or low, high and num ≥ 2 evenly spaced) and ``choice`` (values, optional
weights).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from quadsitl.config import ConfigError

DISTRIBUTIONS = {
    "fixed": ("value",),
    "uniform": ("low", "high"),
    "normal": ("mean", "std", "low", "high"),
    "grid": ("values", "low", "high", "num"),
    "choice": ("values", "weights"),
}
MIN_NORMAL_MASS = 0.01  # a bounded normal must keep at least this probability inside its bounds (redraws)


@dataclass(frozen=True)
class Distribution:
    """One parameter's distribution. ``values``: the grid's or the choice's values (a fixed value: one)."""

    kind: str
    low: float = -math.inf
    high: float = math.inf
    mean: float = 0.0
    std: float = 0.0
    values: tuple[float, ...] = ()
    weights: tuple[float, ...] = ()

    def support(self) -> tuple[float, ...]:
        """The values it can take at the ends of its range (all of them for a finite set)."""
        if self.kind in ("fixed", "grid", "choice"):
            return self.values if self.kind != "choice" else tuple(v for v, w in zip(self.values, self.weights) if w)
        return (self.low, self.high)

    def draw(self, rng: np.random.Generator) -> float:
        """One value from ``rng`` (not for grids, which are not drawn)."""
        if self.kind == "fixed":
            return self.values[0]
        if self.kind == "uniform":
            return float(rng.uniform(self.low, self.high))
        if self.kind == "choice":
            return self.values[int(rng.choice(len(self.values), p=np.asarray(self.weights) / sum(self.weights)))]
        while True:  # normal, redrawn until inside its bounds (validated to hold enough probability)
            v = float(rng.normal(self.mean, self.std))
            if self.low <= v <= self.high:
                return v

    def describe(self) -> dict[str, Any]:
        """For summary.json."""
        out: dict[str, Any] = {"dist": self.kind}
        if self.kind in ("uniform", "normal"):
            if self.kind == "normal":
                out.update(mean=self.mean, std=self.std)
            if math.isfinite(self.low):
                out["low"] = self.low
            if math.isfinite(self.high):
                out["high"] = self.high
        else:
            out["values"] = list(self.values)
            if self.kind == "choice":
                out["weights"] = list(self.weights)
        return out


def _normal_mass(mean: float, std: float, low: float, high: float) -> float:
    """P(low ≤ X ≤ high) for X ~ N(mean, std²)."""

    def cdf(x: float) -> float:
        return 0.5 * (1.0 + math.erf((x - mean) / (std * math.sqrt(2.0)))) if math.isfinite(x) else float(x > 0)

    return cdf(high) - cdf(low)


def parse_distribution(key: str, raw: Any, where: str) -> Distribution:
    """A [vary] value (a number, or a table with ``dist``) → its Distribution, its own bounds checked."""

    def fail(what: str, value: Any = raw) -> ConfigError:
        return ConfigError(f"{where}: vary.{key} = {value!r}: expected {what}")

    def number(k: str, v: Any, ok: Any = math.isfinite, allowed: str = "a finite number") -> float:
        if not isinstance(v, (int, float)) or isinstance(v, bool) or not ok(float(v)):
            raise ConfigError(f"{where}: vary.{key}.{k} = {v!r}: expected {allowed}")
        return float(v)

    def numbers(k: str, v: Any) -> tuple[float, ...]:
        if not isinstance(v, list) or not v:
            raise ConfigError(f"{where}: vary.{key}.{k} = {v!r}: expected a non-empty list of finite numbers")
        return tuple(number(f"{k}[{i}]", x) for i, x in enumerate(v))

    if isinstance(raw, (int, float)) and not isinstance(raw, bool):
        return Distribution("fixed", values=(number("value", raw),))
    if not isinstance(raw, dict) or "dist" not in raw:
        raise fail(f"a number or a table with dist = one of {', '.join(DISTRIBUTIONS)}")
    kind = raw["dist"]
    if kind not in DISTRIBUTIONS:
        raise ConfigError(f"{where}: vary.{key}.dist = {kind!r}: expected one of {', '.join(DISTRIBUTIONS)}")
    for k in raw:
        if k != "dist" and k not in DISTRIBUTIONS[kind]:
            raise ConfigError(f"{where}: vary.{key}.{k}: unknown key for dist = {kind!r}; allowed: "
                              f"{', '.join(DISTRIBUTIONS[kind])}")  # fmt: skip
    need = {"fixed": ("value",), "uniform": ("low", "high"), "normal": ("mean", "std"), "choice": ("values",)}
    for k in need.get(kind, ()):
        if k not in raw:
            raise ConfigError(f"{where}: vary.{key}: dist = {kind!r} needs {' and '.join(need[kind])}")
    if kind == "fixed":
        return Distribution(kind, values=(number("value", raw["value"]),))
    if kind == "uniform":
        low, high = number("low", raw["low"]), number("high", raw["high"])
        if not low < high:
            raise ConfigError(f"{where}: vary.{key}.high = {raw['high']!r}: expected a number above low = {low!r}")
        return Distribution(kind, low=low, high=high)
    if kind == "normal":
        mean = number("mean", raw["mean"])
        std = number("std", raw["std"], lambda v: 0 < v < math.inf, "a finite number > 0")
        low = number("low", raw["low"]) if "low" in raw else -math.inf
        high = number("high", raw["high"]) if "high" in raw else math.inf
        if not low < high:
            raise ConfigError(f"{where}: vary.{key}.high = {raw['high']!r}: expected a number above low = {low!r}")
        mass = _normal_mass(mean, std, low, high)
        if mass < MIN_NORMAL_MASS:
            raise ConfigError(f"{where}: vary.{key}: [low, high] = [{low:g}, {high:g}] holds {mass:.2g} of "
                              f"N({mean:g}, {std:g}²); expected at least {MIN_NORMAL_MASS:g}")  # fmt: skip
        return Distribution(kind, low=low, high=high, mean=mean, std=std)
    if kind == "grid":
        if "values" in raw:
            if any(k in raw for k in ("low", "high", "num")):
                raise ConfigError(f"{where}: vary.{key}: a grid takes values, or low, high and num, not both")
            return Distribution(kind, values=numbers("values", raw["values"]))
        if not all(k in raw for k in ("low", "high", "num")):
            raise ConfigError(f"{where}: vary.{key}: dist = 'grid' needs values, or low, high and num")
        low, high = number("low", raw["low"]), number("high", raw["high"])
        num = raw["num"]
        if not isinstance(num, int) or isinstance(num, bool) or not 2 <= num <= 100_000:
            raise ConfigError(f"{where}: vary.{key}.num = {num!r}: expected an integer in [2, 100000]")
        if not low < high:
            raise ConfigError(f"{where}: vary.{key}.high = {raw['high']!r}: expected a number above low = {low!r}")
        return Distribution(kind, values=tuple(float(v) for v in np.linspace(low, high, num)))
    values = numbers("values", raw["values"])  # choice
    if "weights" in raw:
        weights = numbers("weights", raw["weights"])
        if len(weights) != len(values) or min(weights) < 0 or sum(weights) <= 0:
            raise ConfigError(f"{where}: vary.{key}.weights = {raw['weights']!r}: expected {len(values)} numbers "
                              ">= 0, not all 0 (one per value)")  # fmt: skip
    else:
        weights = (1.0,) * len(values)
    return Distribution(kind, values=values, weights=weights)
