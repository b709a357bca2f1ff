"""The frame conversions of :mod:`quadsitl.frames`, compiled (:mod:`quadsitl.jit`), for compiled code and the
processes that run it (the plant, the autopilot, ``quadsitl sim``, the sweeps' batch engine).

Each is the very function of :mod:`quadsitl.frames`, compiled once here: the equations are written there only.
The three that every control tick calls are inlined into their compiled callers.
"""

from __future__ import annotations

from quadsitl import frames
from quadsitl.jit import jit

wrap_pi = jit(frames.wrap_pi, inline=True)
altitude = jit(frames.altitude, inline=True)
climb_rate = jit(frames.climb_rate, inline=True)
euler_rates_to_body_rates = jit(frames.euler_rates_to_body_rates)
body_rates_to_euler_rates = jit(frames.body_rates_to_euler_rates)
euler_to_quaternion = jit(frames.euler_to_quaternion)
quaternion_to_euler = jit(frames.quaternion_to_euler)
ned_to_geodetic = jit(frames.ned_to_geodetic)
geodetic_to_ned = jit(frames.geodetic_to_ned)
body_to_ned = jit(frames.body_to_ned)
ned_to_body = jit(frames.ned_to_body)
quaternion_multiply = jit(frames.quaternion_multiply)
rotation_vector_to_quaternion = jit(frames.rotation_vector_to_quaternion)
normalize_quaternion = jit(frames.normalize_quaternion)
