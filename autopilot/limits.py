"""Tilt and thrust limits shared by the controllers (DESIGN.md §3, erratum 8). Compiled (:mod:`quadsitl.jit`)."""

from __future__ import annotations

import math

from quadsitl.jit import jit


@jit(inline=True)
def clamp(value: float, lo: float, hi: float) -> float:
    return lo if value < lo else hi if value > hi else value


@jit(inline=True)
def tilt_factor(roll: float, pitch: float, cos_max_tilt: float) -> float:
    """cφ·cθ with each cosine bounded below by cos(max_tilt): keeps 1/(cφcθ) finite (u1 is singular
    at ±90°)."""
    return max(math.cos(roll), cos_max_tilt) * max(math.cos(pitch), cos_max_tilt)
