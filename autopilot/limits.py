"""Tilt and thrust limits shared by the controllers (DESIGN.md §3, erratum 8)."""

from __future__ import annotations

import math

from quadsitl.state import Reference


def limit_reference(ref: Reference, max_tilt: float) -> Reference:
    """Clamp the roll and pitch references to ±max_tilt [rad]."""
    roll = min(max(ref.roll, -max_tilt), max_tilt)
    pitch = min(max(ref.pitch, -max_tilt), max_tilt)
    if roll == ref.roll and pitch == ref.pitch:
        return ref
    return Reference(ref.altitude, roll, pitch, ref.yaw)


def tilt_factor(roll: float, pitch: float, cos_max_tilt: float) -> float:
    """cφ·cθ with each cosine bounded below by cos(max_tilt): keeps 1/(cφcθ) finite (u1 is singular
    at ±90°)."""
    return max(math.cos(roll), cos_max_tilt) * max(math.cos(pitch), cos_max_tilt)


def clamp(value: float, lo: float, hi: float) -> float:
    return lo if value < lo else hi if value > hi else value
