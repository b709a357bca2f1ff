"""Quadrotor equations of motion, paper eqs (2)–(7), in NED/FRD (DESIGN.md §2).

State (the fields of :class:`quadsitl.state.VehicleState`, as a 12-tuple): position and velocity in NED,
ZYX Euler angles and their *rates* (the paper's angular state). With the paper's height h = −z the
equations read

    ẍ = −(cφ sθ cψ + sφ sψ)·u1/m − K1·ẋ/m                      (2) in NED
    ÿ = −(cφ sθ sψ − sφ cψ)·u1/m − K2·ẏ/m                      (3) in NED (erratum 6: parenthesis)
    z̈ = −(cφ cθ)·u1/m + g − K3·ż/m                             (4) in NED, i.e. ḧ = cφcθ·u1/m − g − K3ḣ/m
    φ̈ = θ̇ψ̇(Iy − Iz)/Ix + (Jr/Ix)·θ̇·Ωr + (l/Ix)·u2 − (K4·l/Ix)·φ̇   (5)
    θ̈ = φ̇ψ̇(Iz − Ix)/Iy + (Jr/Iy)·φ̇·Ωr + (l/Iy)·u3 − (K5·l/Iy)·θ̇   (6)
    ψ̈ = φ̇θ̇(Ix − Iy)/Iz + u4/Iz − (K6/Iz)·ψ̇                          (7)

A forward-Euler step of these with period T is exactly the paper's discrete model (10)–(17) with
errata 1–3 applied.

Wind and disturbance (docs/sensors.md, "Wind"): the drag of (2)–(4) acts on the velocity through the air,
−K1·(ẋ − w_N)/m and likewise, with w the wind [m/s, NED], and a constant external force F [N, NED] adds F/m.
Both come in ``d`` = (w_N, w_E, w_D, F_N, F_E, F_D); in calm air (:data:`CALM`) every result is the
paper's, to the bit (x − 0.0 is x). Compiled (:mod:`quadsitl.jit`); ``v`` is the vehicle's
:func:`quadsitl.param_arrays.vehicle_array`.
"""

from __future__ import annotations

import math

import numpy as np

from quadsitl.jit import jit
from quadsitl.param_arrays import ARM, IXX, IYY, IZZ, JR, K1, K2, K3, K4, K5, K6, MASS, G

State = tuple[float, ...]  # the 12 fields of VehicleState, as a plain tuple for the integrators
Disturbance = tuple[float, float, float, float, float, float]  # wind [m/s, NED], external force [N, NED]
CALM: Disturbance = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)


@jit(inline=True)
def derivatives(s: State, u: tuple[float, float, float, float], omega_r: float, v: np.ndarray,
                d: Disturbance) -> State:  # fmt: skip
    """Time derivative of the state for inputs u = (u1..u4), residual rotor speed Ωr [rad/s] and the wind and
    external force ``d``."""
    vx, vy, vz = s[3], s[4], s[5]
    phi, theta, psi, phid, thetad, psid = s[6], s[7], s[8], s[9], s[10], s[11]
    u1, u2, u3, u4 = u
    m, ix, iy, iz, arm, jr = v[MASS], v[IXX], v[IYY], v[IZZ], v[ARM], v[JR]
    cphi, sphi = math.cos(phi), math.sin(phi)
    cth, sth = math.cos(theta), math.sin(theta)
    cpsi, spsi = math.cos(psi), math.sin(psi)
    ax = -(cphi * sth * cpsi + sphi * spsi) * u1 / m - v[K1] * (vx - d[0]) / m + d[3] / m  # (2), air-relative
    ay = -(cphi * sth * spsi - sphi * cpsi) * u1 / m - v[K2] * (vy - d[1]) / m + d[4] / m  # (3)
    az = -(cphi * cth) * u1 / m + v[G] - v[K3] * (vz - d[2]) / m + d[5] / m  # (4)
    phidd = thetad * psid * (iy - iz) / ix + jr / ix * thetad * omega_r + arm / ix * u2 - v[K4] * arm / ix * phid  # (5)
    thetadd = phid * psid * (iz - ix) / iy + jr / iy * phid * omega_r + arm / iy * u3 - v[K5] * arm / iy * thetad  # (6)
    psidd = phid * thetad * (ix - iy) / iz + u4 / iz - v[K6] / iz * psid  # (7)
    return (vx, vy, vz, ax, ay, az, phid, thetad, psid, phidd, thetadd, psidd)
