"""The battery the motors draw from (docs/battery.md), one control period at a time, compiled (:mod:`quadsitl.jit`).

A pack of n cells in series: its open-circuit voltage falls linearly with the charge drawn, from n·v_full full to
n·v_empty empty (the model PX4's battery estimate assumes), behind the pack's internal resistance R. Each motor turns
at Ω = √(F/b) (F = b·Ω², the paper's thrust factor) against the rotor drag torque d·Ω², so its shaft power is d·Ω³;
the electric power P is the four shafts' over the motors' efficiency, and the avionics'. The current I that gives P
at the terminals, V·I = (V_oc − R·I)·I = P, is the smaller root; the preset's check (:func:`quadsitl.config.
full_power`) keeps P within what the pack can give. Empty, the pack gives nothing and the motors stop.

``a`` is the plant's :func:`quadsitl.param_arrays.actuator_array` (BAT_*: capacity 0 is an ideal supply, which
draws nothing and never empties); the battery's state ``bat`` (the plant's outputs from OUT_CURRENT on) is the current
[A], the charge [C] and energy [J] drawn since the start, the voltage at the terminals [V] and the share of the charge
left (−1 for an ideal supply: no battery to report; not NaN, so that the plant's arrays compare equal to themselves).
"""

from __future__ import annotations

import math

import numpy as np

from quadsitl.jit import jit
from quadsitl.mixer import Forces
from quadsitl.param_arrays import (
    BAT_AVIONICS,
    BAT_CAPACITY,
    BAT_CELLS,
    BAT_EFFICIENCY,
    BAT_REMAINING,
    BAT_RESISTANCE,
    BAT_V_EMPTY,
    BAT_V_FULL,
    B,
    D,
)

CURRENT, CHARGE, ENERGY, VOLTAGE, REMAINING = range(5)  # the battery's state, ``bat``
NONE = -1.0  # bat[REMAINING] of an ideal supply: no battery


@jit(inline=True)
def remaining(charge: float, a: np.ndarray) -> float:
    """The share of a full pack's charge left after ``charge`` [C] was drawn, from 0 (empty) to 1 (full)."""
    return max(a[BAT_REMAINING] - charge / a[BAT_CAPACITY], 0.0)


@jit(inline=True)
def open_circuit(charge: float, a: np.ndarray) -> float:
    """The pack's open-circuit voltage [V] after ``charge`` [C] was drawn."""
    return a[BAT_CELLS] * (a[BAT_V_EMPTY] + (a[BAT_V_FULL] - a[BAT_V_EMPTY]) * remaining(charge, a))


@jit(inline=True)
def terminal_voltage(current: float, charge: float, a: np.ndarray) -> float:
    """The voltage [V] at the pack's terminals while it gives ``current`` [A]: V_oc − R·I."""
    return open_circuit(charge, a) - a[BAT_RESISTANCE] * current


@jit(inline=True)
def power(forces: Forces, v: np.ndarray, a: np.ndarray) -> float:
    """The electric power [W] the vehicle draws while its motors give ``forces`` [N]: Σ d·Ω³ / efficiency with
    Ω = √(|F|/b), and the avionics'."""
    shafts = 0.0
    for i in range(4):
        omega = math.sqrt(abs(forces[i]) / v[B])
        shafts += v[D] * omega * omega * omega
    return shafts / a[BAT_EFFICIENCY] + a[BAT_AVIONICS]


@jit(inline=True)
def empty(charge: float, a: np.ndarray) -> bool:
    """The pack is a battery (not an ideal supply) and has nothing left: the motors get no power."""
    return a[BAT_CAPACITY] > 0.0 and remaining(charge, a) <= 0.0


@jit(inline=True)
def draw(forces: Forces, charge: float, energy: float, v: np.ndarray, a: np.ndarray,
         period: float) -> tuple[float, float, float]:  # fmt: skip
    """One period at ``forces`` [N] → (current [A], charge [C] and energy [J] drawn since the start). The current is
    the one at the period's start voltage, held over it; an empty pack, or an ideal supply, gives none."""
    if a[BAT_CAPACITY] <= 0.0 or empty(charge, a):
        return 0.0, charge, energy
    p = power(forces, v, a)
    voc, r = open_circuit(charge, a), a[BAT_RESISTANCE]
    current = p / voc if r == 0.0 else (voc - math.sqrt(max(voc * voc - 4.0 * r * p, 0.0))) / (2.0 * r)
    return current, charge + current * period, energy + (voc - r * current) * current * period


@jit(inline=True)
def start(bat: np.ndarray, a: np.ndarray) -> None:
    """The battery before the first step: nothing drawn, at rest (its open-circuit voltage); an ideal supply, none
    (share left −1)."""
    bat[CURRENT] = bat[CHARGE] = bat[ENERGY] = 0.0
    if a[BAT_CAPACITY] > 0.0:
        bat[VOLTAGE], bat[REMAINING] = open_circuit(0.0, a), remaining(0.0, a)
    else:
        bat[VOLTAGE], bat[REMAINING] = 0.0, NONE


@jit(inline=True)
def step(bat: np.ndarray, forces: Forces, v: np.ndarray, a: np.ndarray, period: float) -> None:
    """One period at ``forces`` [N] (:func:`draw`), in place: the voltage and the share left at its end."""
    if a[BAT_CAPACITY] <= 0.0:
        return
    current, charge, energy = draw(forces, bat[CHARGE], bat[ENERGY], v, a, period)
    bat[CURRENT], bat[CHARGE], bat[ENERGY] = current, charge, energy
    bat[VOLTAGE], bat[REMAINING] = terminal_voltage(current, charge, a), remaining(charge, a)
