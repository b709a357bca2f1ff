"""The mixer of paper eq (8), its inverse, rotor speeds and Ωr.

Motor layout implied by eq (8), "+" frame, body FRD (DESIGN.md §2): motor 1 rear, 2 right,
3 front, 4 left, each at distance l from the centre. Motors 1 and 3 spin one way, 2 and 4 the
other. Forces F_j [N] act along −z_body (up when level).

    u1 = F1 + F2 + F3 + F4              collective thrust [N]
    u2 = −F2 + F4                       roll torque / l [N]   (left motor rolls right-wing-down)
    u3 = −F1 + F3                       pitch torque / l [N]  (front motor pitches nose-up)
    u4 = (d/b)(−F1 + F2 − F3 + F4)      yaw torque [N·m]

with F_j = b·Ω_j² (b thrust factor [N·s²]) and the rotor drag torque d·Ω_j² (d [N·m·s²]).
"""

from __future__ import annotations

import math

from quadsitl.state import Inputs


def forces_to_inputs(forces: tuple[float, float, float, float], d_over_b: float) -> Inputs:
    """Paper eq (8): motor forces (F1..F4) [N] → inputs (u1..u4)."""
    f1, f2, f3, f4 = forces
    return Inputs(f1 + f2 + f3 + f4, f4 - f2, f3 - f1, d_over_b * (-f1 + f2 - f3 + f4))


def inputs_to_forces(u: tuple[float, float, float, float], d_over_b: float) -> tuple[float, float, float, float]:
    """Inverse of eq (8): inputs (u1..u4) → motor forces (F1..F4) [N]."""
    u1, u2, u3, u4 = u
    yaw_share = u4 / d_over_b  # = (F2 + F4) − (F1 + F3)
    s13 = 0.5 * (u1 - yaw_share)  # F1 + F3
    s24 = 0.5 * (u1 + yaw_share)  # F2 + F4
    return 0.5 * (s13 - u3), 0.5 * (s24 - u2), 0.5 * (s13 + u3), 0.5 * (s24 + u2)


def rotor_speeds(forces: tuple[float, float, float, float], b: float) -> tuple[float, float, float, float]:
    """Signed rotor speeds Ω_j = sign(F_j)·sqrt(|F_j|/b) [rad/s] (reversible rotors keep the sign)."""
    f1, f2, f3, f4 = forces  # unrolled: this runs every control tick
    copysign, sqrt = math.copysign, math.sqrt
    return (
        copysign(sqrt(abs(f1) / b), f1),
        copysign(sqrt(abs(f2) / b), f2),
        copysign(sqrt(abs(f3) / b), f3),
        copysign(sqrt(abs(f4) / b), f4),
    )


def residual_rotor_speed(forces: tuple[float, float, float, float], b: float) -> float:
    """Ωr = Ω1 − Ω2 + Ω3 − Ω4 [rad/s] (erratum 5: the paper prints + Ω4)."""
    w1, w2, w3, w4 = rotor_speeds(forces, b)
    return w1 - w2 + w3 - w4


def allocate(
    u: tuple[float, float, float, float], d_over_b: float, f_min: float, f_max: float
) -> tuple[float, float, float, float]:
    """Control allocation with saturation: inputs → motor forces within [f_min, f_max].

    When the exact inverse of eq (8) fits, it is returned unchanged. Otherwise the torques are kept
    and the collective thrust is shifted (all motors by the same amount) to fit; if the torques alone
    need more than the range, they are scaled down (attitude keeps priority over thrust, as in PX4's
    mixer). The result always lies in [f_min, f_max].
    """
    forces = inputs_to_forces(u, d_over_b)
    lo, hi = min(forces), max(forces)
    if lo >= f_min and hi <= f_max:
        return forces
    mean = 0.25 * u[0]
    dev = [f - mean for f in forces]  # the torque part, zero-sum
    spread_lo, spread_hi = min(dev), max(dev)
    span = f_max - f_min
    if spread_hi - spread_lo > span:
        scale = span / (spread_hi - spread_lo)
        dev = [scale * x for x in dev]
        spread_lo, spread_hi = spread_lo * scale, spread_hi * scale
    mean = min(max(mean, f_min - spread_lo), f_max - spread_hi)
    return tuple(min(max(mean + x, f_min), f_max) for x in dev)  # type: ignore[return-value]
