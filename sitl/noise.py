"""Seeded random numbers for the simulated sensors (and, later, the wind), compiled.

Why not numpy's or numba's generators: numba's ``np.random`` inside compiled code has one hidden state per
thread, shared by every compiled function of the process, so two plants in one process (or any other use)
would interleave their draws; numpy's ``Generator`` cannot be called from compiled code, and does not promise
the same normal deviates across numpy versions. Here each stream's state is four words in an array the
caller owns: the same seed gives the same samples, bit for bit, compiled or not (``NUMBA_DISABLE_JIT=1``),
on any machine.

The generator is xoshiro128** (Blackman & Vigna, "Scrambled linear pseudorandom number generators", ACM
Transactions on Mathematical Software 47(4), 2021): 128 bits of state, period 2¹²⁸ − 1, 32-bit outputs. The
words are held in int64 and masked to 32 bits, so no operation overflows in either runtime. Uniform deviates
take 53 bits from two outputs; normal deviates come from the Box–Muller transform (Box & Muller, 1958), one of a
pair or both.
A seed becomes the streams' states through numpy's ``SeedSequence`` (one child per stream), so nearby seeds
give unrelated streams.
"""

from __future__ import annotations

import math

import numpy as np

from quadsitl.jit import jit

MASK32 = 0xFFFFFFFF
WORDS = 4  # state words per stream


def seed_streams(seed: int, streams: int) -> np.ndarray:
    """The states (``streams`` × 4, int64) of independent streams for ``seed`` (an integer >= 0)."""
    children = np.random.SeedSequence(seed).spawn(streams)
    state = np.array([c.generate_state(WORDS, np.uint32) for c in children], dtype=np.int64)
    for row in state:
        if not row.any():  # xoshiro's one forbidden state; SeedSequence practically never gives it
            row[0] = 1
    return state


@jit
def _rotl(x: int, k: int) -> int:
    return ((x << k) | (x >> (32 - k))) & MASK32


@jit
def next_u32(s: np.ndarray, i: int) -> int:
    """The next 32-bit output of stream ``i`` of the states ``s`` (advanced in place)."""
    s0, s1, s2, s3 = s[i, 0], s[i, 1], s[i, 2], s[i, 3]
    result = (_rotl((s1 * 5) & MASK32, 7) * 9) & MASK32
    t = (s1 << 9) & MASK32
    s2 ^= s0
    s3 ^= s1
    s1 ^= s2
    s0 ^= s3
    s2 ^= t
    s3 = _rotl(s3, 11)
    s[i, 0], s[i, 1], s[i, 2], s[i, 3] = s0, s1, s2, s3
    return result


@jit
def uniform(s: np.ndarray, i: int) -> float:
    """A uniform deviate in [0, 1) with 53 random bits, from stream ``i``."""
    a = next_u32(s, i) >> 5
    b = next_u32(s, i) >> 6
    return (a * 67108864.0 + b) / 9007199254740992.0


@jit(inline=True)
def _box_muller(s: np.ndarray, i: int) -> tuple[float, float]:
    """The Box–Muller transform's radius and angle [rad] from two uniforms of stream ``i``."""
    u1 = 1.0 - uniform(s, i)  # in (0, 1]: the logarithm is finite
    u2 = uniform(s, i)
    return math.sqrt(-2.0 * math.log(u1)), 2.0 * math.pi * u2


@jit
def normal(s: np.ndarray, i: int) -> float:
    """A standard normal deviate from stream ``i`` (Box–Muller; the second deviate of the pair is not kept)."""
    r, angle = _box_muller(s, i)
    return r * math.cos(angle)


@jit
def normal_pair(s: np.ndarray, i: int) -> tuple[float, float]:
    """Two independent standard normal deviates from stream ``i``: both of a Box–Muller pair (the first is
    :func:`normal`'s), for half the logarithms and uniforms where a sample needs two."""
    r, angle = _box_muller(s, i)
    return r * math.cos(angle), r * math.sin(angle)


@jit
def gauss_markov_coefficients(dt: float, tau: float, sigma: float) -> tuple[float, float]:
    """(φ, k) of :func:`gauss_markov`'s step over ``dt``: x⁺ = φ·x + k·w, for a process whose steps are all ``dt``
    long (computed once, the step is the same to the bit)."""
    phi = math.exp(-dt / tau)
    return phi, sigma * math.sqrt(1.0 - phi * phi)


@jit
def gauss_markov(x: float, dt: float, tau: float, sigma: float, w: float) -> float:
    """One exact step of the first-order Gauss–Markov process ẋ = −x/τ + σ·√(2/τ)·n(t) (stationary standard
    deviation ``sigma``) over ``dt``, with ``w`` a standard normal deviate:
    x⁺ = e^(−dt/τ)·x + σ·√(1 − e^(−2dt/τ))·w (Maybeck, Stochastic Models, Estimation and Control, vol. 1,
    eq. 4-114)."""
    phi, k = gauss_markov_coefficients(dt, tau, sigma)
    return phi * x + k * w
