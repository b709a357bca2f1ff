"""quadsitl: the pieces every process shares.

This package is the leaf of the dependency graph. ``sitl`` (the plant), ``autopilot`` (the
controllers) and ``groundstation`` (the operator side and the ``quadsitl`` command) import from
it; it imports none of them. It holds the state and reference types, the frame and unit
conversions (DESIGN.md §2), the mixer of paper eq (8), and the preset loader.
"""

__version__ = "0.1.0"
