"""The Earth the sensors measure: the standard atmosphere (barometer) and a constant magnetic field
(magnetometer), in one place for the plant, which makes the measurements, and the autopilot, which
inverts them.

**Atmosphere.** The ICAO/ISO standard atmosphere's troposphere (ISO 2533:1975, valid below 11 km):
temperature T = T0 − L·h, pressure p = p0·(T/T0)^(g0·M/(R·L)), with T0 = 288.15 K, p0 = 101325 Pa,
L = 0.0065 K/m, g0 = 9.80665 m/s², M = 0.0289644 kg/mol, R = 8.31446 J/(mol·K). The exponent is 5.25588
(PX4's Gazebo barometer rounds it to 5.256). ``h`` is the altitude above mean sea level [m] (geopotential;
the difference from geometric altitude is 0.08 % at 500 m and is not modelled).

**Magnetic field.** A constant field at home given by its total intensity F [gauss], declination D (east of
true north, [rad]) and inclination I (below the horizontal, [rad]); in NED:
B = F·(cos I·cos D, cos I·sin D, sin I). The defaults are jMAVSim's Zürich figures (``Simulator.java``:
inclination 63.39°, declination 2.75°, and its field vector (0.21506, 0.01021, 0.42974) G, whose magnitude
is 0.4807 G), for PX4 SITL's default home (:data:`quadsitl.frames.PX4_HOME`).

Compiled (:mod:`quadsitl.jit`).
"""

from __future__ import annotations

import math

from quadsitl.jit import jit

# ISA troposphere
T0 = 288.15  # [K] sea-level temperature
P0 = 101325.0  # [Pa] sea-level pressure
LAPSE = 0.0065  # [K/m]
G0 = 9.80665  # [m/s²] standard gravity
MOLAR_MASS = 0.0289644  # [kg/mol] dry air
GAS_CONSTANT = 8.31446  # [J/(mol·K)]
EXPONENT = G0 * MOLAR_MASS / (GAS_CONSTANT * LAPSE)  # 5.25588
ZERO_CELSIUS = 273.15  # [K]
ISA_CEILING = 11000.0  # [m] top of the troposphere

# jMAVSim's Zürich field
MAG_STRENGTH = 0.4807  # [gauss]
MAG_DECLINATION_DEG = 2.75  # [deg] east
MAG_INCLINATION_DEG = 63.39  # [deg] down


@jit
def isa_temperature(h: float) -> float:
    """ISA temperature [K] at altitude ``h`` [m AMSL]."""
    return T0 - LAPSE * h


@jit
def isa_pressure(h: float) -> float:
    """ISA static pressure [Pa] at altitude ``h`` [m AMSL]."""
    return P0 * (isa_temperature(h) / T0) ** EXPONENT


@jit
def isa_altitude(p: float) -> float:
    """Pressure altitude [m AMSL] of the static pressure ``p`` [Pa]: the inverse of :func:`isa_pressure`."""
    return T0 / LAPSE * (1.0 - (p / P0) ** (1.0 / EXPONENT))


@jit
def isa_density(h: float) -> float:
    """ISA air density [kg/m³] at altitude ``h`` [m AMSL]: ρ = p·M / (R·T)."""
    return isa_pressure(h) * MOLAR_MASS / (GAS_CONSTANT * isa_temperature(h))


@jit
def magnetic_field_ned(strength: float, declination: float, inclination: float) -> tuple[float, float, float]:
    """The Earth's field in NED [gauss] from its intensity [gauss], declination and inclination [rad]."""
    horizontal = strength * math.cos(inclination)
    return horizontal * math.cos(declination), horizontal * math.sin(declination), strength * math.sin(inclination)
