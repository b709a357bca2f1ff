"""quadsitl: the pieces every process shares, and the Python API's front door.

This package is the leaf of the dependency graph. ``sitl`` (the plant), ``autopilot`` (the
controllers) and ``groundstation`` (the operator side and the ``quadsitl`` command) import from
it; it imports none of them. It holds the state and reference types, the frame and unit
conversions (DESIGN.md §2), the mixer of paper eq (8), and the preset loader.

``quadsitl.sim``, ``quadsitl.sweep``, ``quadsitl.Flight`` and ``quadsitl.Vehicle`` are the Python API
(:mod:`groundstation.api`, docs/python.md), loaded on first use: ``import quadsitl`` alone loads none of it.
"""

from __future__ import annotations

from typing import Any

__version__ = "0.1.0"
API = ("sim", "sweep", "Flight", "Vehicle")
__all__ = ["__version__", *API]


def __getattr__(name: str) -> Any:
    if name in API:
        import importlib

        return getattr(importlib.import_module("groundstation.api"), name)
    raise AttributeError(f"module 'quadsitl' has no attribute {name!r}")
