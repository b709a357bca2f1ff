"""The mixer of paper eq (8), its inverse, rotor speeds and Ωr.

Motor layout implied by eq (8), "+" frame, body FRD (DESIGN.md §2): motor 1 rear, 2 right,
3 front, 4 left, each at distance l from the centre. Motors 1 and 3 spin one way, 2 and 4 the
other. Forces F_j [N] act along −z_body (up when level).

    u1 = F1 + F2 + F3 + F4              collective thrust [N]
    u2 = −F2 + F4                       roll torque / l [N]   (left motor rolls right-wing-down)
    u3 = −F1 + F3                       pitch torque / l [N]  (front motor pitches nose-up)
    u4 = (d/b)(−F1 + F2 − F3 + F4)      yaw torque [N·m]

with F_j = b·Ω_j² (b thrust factor [N·s²]) and the rotor drag torque d·Ω_j² (d [N·m·s²]).

Compiled (:mod:`quadsitl.jit`): forces and inputs are 4-tuples of floats.
"""

from __future__ import annotations

import math

from quadsitl.jit import jit
from quadsitl.state import Inputs

Forces = tuple[float, float, float, float]


@jit(inline=True)
def forces_to_inputs(forces: Forces, d_over_b: float) -> Inputs:
    """Paper eq (8): motor forces (F1..F4) [N] → inputs (u1..u4)."""
    f1, f2, f3, f4 = forces
    return Inputs(f1 + f2 + f3 + f4, f4 - f2, f3 - f1, d_over_b * (-f1 + f2 - f3 + f4))


@jit(inline=True)
def inputs_to_forces(u: tuple[float, float, float, float], d_over_b: float) -> Forces:
    """Inverse of eq (8): inputs (u1..u4) → motor forces (F1..F4) [N]."""
    u1, u2, u3, u4 = u
    yaw_share = u4 / d_over_b  # = (F2 + F4) − (F1 + F3)
    s13 = 0.5 * (u1 - yaw_share)  # F1 + F3
    s24 = 0.5 * (u1 + yaw_share)  # F2 + F4
    return 0.5 * (s13 - u3), 0.5 * (s24 - u2), 0.5 * (s13 + u3), 0.5 * (s24 + u2)


@jit(inline=True)
def rotor_speed(force: float, b: float) -> float:
    """Signed rotor speed Ω = sign(F)·sqrt(|F|/b) [rad/s] (reversible rotors keep the sign)."""
    return math.copysign(math.sqrt(abs(force) / b), force)


@jit(inline=True)
def rotor_speeds(forces: Forces, b: float) -> Forces:
    """Ω_j of each motor [rad/s]."""
    f1, f2, f3, f4 = forces
    return rotor_speed(f1, b), rotor_speed(f2, b), rotor_speed(f3, b), rotor_speed(f4, b)


@jit(inline=True)
def residual_rotor_speed(forces: Forces, b: float) -> float:
    """Ωr = Ω1 − Ω2 + Ω3 − Ω4 [rad/s] (erratum 5: the paper prints + Ω4)."""
    w1, w2, w3, w4 = rotor_speeds(forces, b)
    return w1 - w2 + w3 - w4


@jit(inline=True)
def allocate(u: tuple[float, float, float, float], d_over_b: float, f_min: float, f_max: float) -> Forces:
    """Control allocation with saturation: inputs → motor forces within [f_min, f_max], in PX4's order of priority
    (its sequential desaturation, ``ControlAllocationSequentialDesaturation``): roll and pitch, then the collective
    thrust, then yaw.

    When the exact inverse of eq (8) fits, it is returned unchanged. Otherwise roll, pitch and thrust are
    allocated first: the torques kept and the collective shifted (all motors by the same amount) to fit, or, when
    the torques alone need more than the range, scaled down. Yaw comes last, with what the motors have left: it is
    reduced until it fits. So a large yaw demand turns the vehicle more slowly instead of costing it height (PX4
    lets yaw lower the collective by up to 15 % of the range; its yaw demands are small, the backstepping's in a
    large turn are not). The result always lies in [f_min, f_max].
    """
    forces = inputs_to_forces(u, d_over_b)
    f1, f2, f3, f4 = forces
    lo, hi = min(min(f1, f2), min(f3, f4)), max(max(f1, f2), max(f3, f4))
    if lo >= f_min and hi <= f_max:
        return forces
    g1, g2, g3, g4 = inputs_to_forces((u[0], u[1], u[2], 0.0), d_over_b)
    lo, hi = min(min(g1, g2), min(g3, g4)), max(max(g1, g2), max(g3, g4))
    if lo < f_min or hi > f_max:
        mean = 0.25 * u[0]
        d1, d2, d3, d4 = g1 - mean, g2 - mean, g3 - mean, g4 - mean  # the torque part, zero-sum
        spread_lo, spread_hi = lo - mean, hi - mean
        span = f_max - f_min
        if spread_hi - spread_lo > span:
            scale = span / (spread_hi - spread_lo)
            d1, d2, d3, d4 = scale * d1, scale * d2, scale * d3, scale * d4
            spread_lo, spread_hi = spread_lo * scale, spread_hi * scale
        mean = min(max(mean, f_min - spread_lo), f_max - spread_hi)
        g1, g2, g3, g4 = clamp4((mean + d1, mean + d2, mean + d3, mean + d4), f_min, f_max)
    # Yaw: +y on motors 2 and 4, −y on 1 and 3 (u4 = (d/b)·4y, u1..u3 unchanged), y within what each motor has left.
    y = u[3] / (4.0 * d_over_b)
    up24, down13 = min(f_max - g2, f_max - g4), min(g1 - f_min, g3 - f_min)  # room for y > 0
    up13, down24 = min(f_max - g1, f_max - g3), min(g2 - f_min, g4 - f_min)  # room for y < 0
    y = min(max(y, -min(up13, down24)), min(up24, down13))
    return clamp4((g1 - y, g2 + y, g3 - y, g4 + y), f_min, f_max)


@jit(inline=True)
def clamp4(forces: Forces, lo: float, hi: float) -> Forces:
    """Each of four values clamped to [lo, hi]."""
    f1, f2, f3, f4 = forces
    return min(max(f1, lo), hi), min(max(f2, lo), hi), min(max(f3, lo), hi), min(max(f4, lo), hi)
