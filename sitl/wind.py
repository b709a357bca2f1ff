"""Wind for the plant: a mean wind, Dryden turbulence and a discrete 1 − cos gust, compiled and seeded.

Everything is the wind velocity w [m/s] in the local NED frame, the velocity of the air over the ground. It is
pure: the caller owns the filter states and the random stream (:func:`wind_state`) and calls
:func:`wind_step` once per tick; the plant calls it through :func:`air_tick`, which also gives the external force,
and the wind acts through the drag terms of eqs (2)–(4) on the air-relative velocity (:mod:`sitl.dynamics`).

- **Mean wind**: a speed and the direction it blows FROM, as weather reports give it, in degrees clockwise
  from north: 270 is a west wind, the air moving east: w = −speed·(cos ψ, sin ψ, 0).
- **Turbulence**: the Dryden model of MIL-F-8785C (§3.7.3, low altitude, h < 1000 ft), as MIL-HDBK-1797 and
  MATLAB's Dryden block give it. With h the altitude in feet (held within 10..1000 ft) and W20 the wind speed
  at 20 ft (15, 30, 45 knots for light, moderate, severe turbulence):
  L_w = h, L_u = L_v = h/(0.177 + 0.000823·h)^1.2 [ft]; σ_w = 0.1·W20, σ_u = σ_v = σ_w/(0.177 + 0.000823·h)^0.4.
  Shaping filters of white noise, with V the airspeed [m/s] and the lengths in metres:
  H_u(s) = σ_u·√(2L_u/(πV))/(1 + (L_u/V)s) and H_v(s) = σ_v·√(L_v/(πV))·(1 + √3(L_v/V)s)/(1 + (L_v/V)s)²
  (H_w likewise with L_w, σ_w). u lies along the mean wind (north when calm), v 90° to its right, w down.
- **Gust**: the discrete gust of MIL-F-8785C §3.7.4, 1 − cos in time: amplitude A from its own direction,
  A/2·(1 − cos(π·(t − start)/rise)) while it rises, A after (it holds), nothing before.

**Discretisation, exact.** u is a first-order Gauss–Markov process with τ = L_u/V, stepped exactly
(:func:`sitl.noise.gauss_markov`). v and w are the state-space form x' = A·x + B·n, A = [[−a, 1], [0, −a]],
B = (0, 1), a = V/L, whose output y = σ·√a·((1 − √3)·a·x₁ + √3·x₂) has the Dryden spectrum and variance σ²
(the unit filter's stationary covariance is P = [[1/(4a³), 1/(4a²)], [1/(4a²), 1/(2a)]], so its output
variance is a). A step of h seconds is x⁺ = Φ·x + q with Φ = e^(−ah)·[[1, h], [0, 1]] and q normal with the
covariance Q = ∫₀ʰ e^(As)·B·Bᵀ·e^(Aᵀs) ds = [[γ(3,2ah)/(2a)³, γ(2,2ah)/(2a)²], [γ(2,2ah)/(2a)², γ(1,2ah)/(2a)]]
(γ the lower incomplete gamma function, by its series where 2ah < 1, so nothing cancels at 1 kHz): samples
taken every h have the continuous process's variance and autocorrelation exactly, at any step size.
The filters' coefficients follow the altitude and airspeed of each step (floored at 1 m/s).
"""

from __future__ import annotations

import math

import numpy as np

from quadsitl.config import TURBULENCE_W20_KNOTS, WindParams
from quadsitl.jit import jit
from sitl.noise import gauss_markov, normal, normal_pair, seed_streams

KNOT = 0.514444  # m/s
FOOT = 0.3048  # m
MIN_AIRSPEED = 1.0  # m/s: the filters' V is at least this (their time constants L/V stay finite when calm)
SQRT3 = math.sqrt(3.0)
HALF_ULP = 2.0**-54  # x·HALF_ULP is below half the spacing of doubles at x

# The parameter array's layout (wind_params); the external force last
MEAN_N, MEAN_E, W20, GUST_A, GUST_RISE, GUST_START, GUST_N, GUST_E, U_N, U_E, FORCE = range(11)
N_PARAMS = FORCE + 3
CLOCK = 5  # the wind's clock, in the state array after the filters': ticks since lift-off, −1 before
N_STATE = 6  # u; v (2 states); w (2 states); the clock
# The plant's air array (air_arrays), one array for one compiled call: the disturbance d the dynamics take (6: the
# wind [m/s, NED], the external force [N, NED]), then the wind model's state and its parameters.
AIR_STATE = 6
AIR_PARAMS = AIR_STATE + N_STATE
AIR_SIZE = AIR_PARAMS + N_PARAMS


def blowing(speed: float, from_deg: float) -> tuple[float, float]:
    """The NED (north, east) velocity [m/s] of air moving at ``speed`` FROM ``from_deg`` (meteorological)."""
    psi = math.radians(from_deg)
    return -speed * math.cos(psi), -speed * math.sin(psi)


def wind_params(wind: WindParams) -> np.ndarray:
    """The compiled step's parameters (float64, layout above) for ``wind``."""
    p = np.zeros(N_PARAMS)
    p[MEAN_N], p[MEAN_E] = blowing(wind.speed_m_s, wind.from_deg)
    p[W20] = TURBULENCE_W20_KNOTS[wind.turbulence] * KNOT
    p[GUST_A], p[GUST_RISE], p[GUST_START] = wind.gust_m_s, wind.gust_rise_s, wind.gust_start_s
    p[GUST_N], p[GUST_E] = blowing(1.0, wind.gust_from_deg)
    # u along the mean wind, north when calm
    p[U_N], p[U_E] = (p[MEAN_N] / wind.speed_m_s, p[MEAN_E] / wind.speed_m_s) if wind.speed_m_s > 0 else (1.0, 0.0)
    p[FORCE : FORCE + 3] = wind.force_n
    return p


def wind_state(seed: int) -> tuple[np.ndarray, np.ndarray]:
    """The turbulence's filter states (zeros: it starts calm and builds up over a few L/V), the wind's clock (not
    started) and its random stream for ``seed``."""
    x = np.zeros(N_STATE)
    x[CLOCK] = -1.0
    return x, seed_streams(seed, 1)


@jit
def gamma_lower(n: int, x: float) -> float:
    """γ(n, x) = ∫₀ˣ tⁿ⁻¹·e⁻ᵗ dt for n = 1, 2, 3 and x >= 0: its series for x < 1 (no cancellation), else its
    closed form."""
    if x < 1.0:
        total, term, k = 0.0, 1.0, 0  # xⁿ·Σ (−x)ᵏ/(k!·(k + n))
        while k < 30:
            step = term / (k + n)
            # Below half an ulp of the sum, this term and every later one (smaller, alternating) leave it as it is.
            if abs(step) < total * HALF_ULP:
                break
            total += step
            k += 1
            term *= -x / k
        return x**n * total
    e = math.exp(-x)
    if n == 1:
        return 1.0 - e
    if n == 2:
        return 1.0 - e * (1.0 + x)
    return 2.0 - e * (2.0 + 2.0 * x + x * x)


@jit(inline=True)
def dryden_second_order(x: np.ndarray, i: int, rng: np.ndarray, a: float, sigma: float, h: float) -> float:
    """One exact step (``h`` s) of the second-order Dryden filter whose states are ``x[i]``, ``x[i + 1]``, with
    a = V/L [1/s] and intensity ``sigma`` [m/s]; returns its output after the step (see the module's
    docstring)."""
    two_a = 2.0 * a
    q11 = gamma_lower(3, two_a * h) / two_a**3
    q12 = gamma_lower(2, two_a * h) / two_a**2
    q22 = gamma_lower(1, two_a * h) / two_a
    l11 = math.sqrt(q11)
    l21 = q12 / l11
    l22 = math.sqrt(max(q22 - l21 * l21, 0.0))
    n1, n2 = normal_pair(rng, 0)
    decay = math.exp(-a * h)
    x1 = decay * (x[i] + h * x[i + 1]) + l11 * n1
    x2 = decay * x[i + 1] + l21 * n1 + l22 * n2
    x[i], x[i + 1] = x1, x2
    return sigma * math.sqrt(a) * ((1.0 - SQRT3) * a * x1 + SQRT3 * x2)


@jit(inline=True)
def gust(p: np.ndarray, t: float) -> float:
    """The 1 − cos gust's magnitude [m/s] at simulated time ``t`` [s]."""
    s = t - p[GUST_START]
    if s <= 0.0 or p[GUST_A] == 0.0:
        return 0.0
    if s >= p[GUST_RISE]:
        return p[GUST_A]
    return 0.5 * p[GUST_A] * (1.0 - math.cos(math.pi * s / p[GUST_RISE]))


@jit(inline=True)
def dryden_scales(altitude: float, w20: float) -> tuple[float, float, float, float]:
    """(σ_u = σ_v [m/s], σ_w [m/s], L_u = L_v [m], L_w [m]) of MIL-F-8785C's low-altitude Dryden model at
    ``altitude`` [m above ground, held within 10..1000 ft] for the wind speed at 20 ft ``w20`` [m/s]."""
    h_ft = min(max(altitude / FOOT, 10.0), 1000.0)
    scale = 0.177 + 0.000823 * h_ft
    sigma_w = 0.1 * w20
    return sigma_w / scale**0.4, sigma_w, h_ft / scale**1.2 * FOOT, h_ft * FOOT


@jit(inline=True)
def wind_step(
    out: np.ndarray,
    x: np.ndarray,
    rng: np.ndarray,
    p: np.ndarray,
    t: float,
    dt: float,
    altitude: float,
    airspeed: float,
) -> None:
    """The wind [m/s, NED] at simulated time ``t`` [s] into ``out``: mean + gust + turbulence, the turbulence's
    filters (``x``, ``rng``) advanced by ``dt`` [s] at ``altitude`` [m above ground] and ``airspeed`` [m/s]."""
    g = gust(p, t)
    out[0] = p[MEAN_N] + g * p[GUST_N]
    out[1] = p[MEAN_E] + g * p[GUST_E]
    out[2] = 0.0
    if p[W20] == 0.0:
        return
    sigma_uv, sigma_w, l_uv, l_w = dryden_scales(altitude, p[W20])
    v = max(airspeed, MIN_AIRSPEED)
    x[0] = gauss_markov(x[0], dt, l_uv / v, sigma_uv, normal(rng, 0))
    tv = dryden_second_order(x, 1, rng, v / l_uv, sigma_uv, dt)
    tw = dryden_second_order(x, 3, rng, v / l_w, sigma_w, dt)
    out[0] += x[0] * p[U_N] - tv * p[U_E]
    out[1] += x[0] * p[U_E] + tv * p[U_N]
    out[2] += tw


def air_arrays(wind: WindParams) -> tuple[np.ndarray, np.ndarray]:
    """The plant's air array (AIR_SIZE, layout above; calm to start with) and the turbulence's random stream, for
    ``wind``."""
    air = np.zeros(AIR_SIZE)
    x, rng = wind_state(wind.seed)
    air[AIR_STATE:AIR_PARAMS] = x
    air[AIR_PARAMS:] = wind_params(wind)
    return air, rng


@jit(inline=True)
def air_tick(air: np.ndarray, rng: np.ndarray, dt: float, state: np.ndarray, on_ground: bool) -> None:
    """The plant's disturbance for a tick of ``dt`` [s] that starts in state ``state`` (12, VehicleState order),
    resting on the ground or not, into ``air[:6]`` (:data:`sitl.dynamics.CALM`'s layout): the wind [m/s, NED],
    then the external force [N, NED]. ``air`` is :func:`air_arrays`' array, ``rng`` its random stream.

    The wind's clock (``x[CLOCK]``) starts when the vehicle first leaves the ground, or at once when it starts in
    the air: the gust's start counts from lift-off, and the turbulence's filters run from then on, at the
    vehicle's altitude (−z, above the ground) and airspeed (against the wind of the tick before, in ``d``). So a
    flight meets the same air however long its vehicle waited on the ground (``quadsitl fly`` arms and switches
    modes first, ``quadsitl sim`` does not). Before that, only the mean wind blows (the ground holds the vehicle)."""
    d, x, p = air[:AIR_STATE], air[AIR_STATE:AIR_PARAMS], air[AIR_PARAMS:]
    d[3], d[4], d[5] = p[FORCE], p[FORCE + 1], p[FORCE + 2]
    if x[CLOCK] < 0.0:
        if on_ground:
            d[0], d[1], d[2] = p[MEAN_N], p[MEAN_E], 0.0
            return
        x[CLOCK] = 0.0
    airspeed = math.sqrt((state[3] - d[0]) ** 2 + (state[4] - d[1]) ** 2 + (state[5] - d[2]) ** 2)
    wind_step(d, x, rng, p, x[CLOCK] * dt, dt, -state[2], airspeed)
    x[CLOCK] += 1.0
