"""The PD baseline the paper compares against (it gives no gains; DESIGN.md §3, erratum 9).

A conventional PD per channel with derivative on the measurement (no derivative kick), gravity
feed-forward and tilt compensation on thrust, and inputs scaled by the model's inertias so that each
linearised channel closes as ë + kd·ė + kp·e = 0:

    u1 = m·(g + kp_h·(h_r − h) − kd_h·ḣ) / (cφ·cθ)
    u2 = (Ix/l)·(kp_φ·(φ_r − φ) − kd_φ·φ̇)
    u3 = (Iy/l)·(kp_θ·(θ_r − θ) − kd_θ·θ̇)
    u4 = Iz·(kp_ψ·wrap(ψ_r − ψ) − kd_ψ·ψ̇)

Fair tuning: the shipped presets set kp = k_i·k_(i+1) and kd = k_i + k_(i+1), which puts the PD's
linearised poles at −k_i and −k_(i+1), where the backstepping puts its (continuous-time equivalent)
poles. What differs is structure, not bandwidth: the PD does not cancel drag, gyroscopic and
cross-coupling terms, and it does not anticipate the discrete step.

:func:`pd` is the law, compiled (:mod:`quadsitl.jit`); it reads the same parameter array as the
backstepping (:mod:`autopilot.control_params`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np

from autopilot.control_params import (
    COS_MAX_TILT,
    KD,
    KP,
    MAX_TILT,
    MEM_SIZE,
    MEM_U,
    PD,
    POSITION,
    THRUST_MAX,
    THRUST_MIN,
    control_array,
)
from autopilot.limits import clamp, tilt_factor
from quadsitl.compiled_frames import altitude, climb_rate, wrap_pi
from quadsitl.config import PositionParams, VehicleParams
from quadsitl.jit import jit, specialized
from quadsitl.param_arrays import ARM, IXX, IYY, IZZ, MASS, G, vehicle_array
from quadsitl.state import Inputs, Reference, VehicleState


@jit(inline=True)
def pd_vertical(
    h: float, climb: float, h_ref: float, climb_ff: float, climb_acc: float, mode: int, v: np.ndarray, c: np.ndarray
) -> float:  # fmt: skip
    """The altitude channel: the upward acceleration the thrust must give [m/s²], u1 = m·a/(cφcθ). ``mode`` as
    the backstepping's (POSITION: the altitude error acts; VELOCITY: only the climb-rate error)."""
    e = h_ref - h if mode == POSITION else 0.0
    return v[G] + climb_acc + c[KP] * e + c[KD] * (climb_ff - climb)


@jit(inline=True)
def pd_attitude(
    x: tuple[float, ...], roll_ref: float, pitch_ref: float, yaw_ref: float, yaw_rate_ff: float, yaw_mode: int,
    v: np.ndarray, c: np.ndarray,
) -> tuple[float, float, float]:  # fmt: skip
    """u2, u3 [N] and u4 [N·m] for the attitude reference (the yaw rate ``yaw_rate_ff`` alone when ``yaw_mode``
    is VELOCITY)."""
    max_tilt = c[MAX_TILT]
    roll_ref = clamp(roll_ref, -max_tilt, max_tilt)
    pitch_ref = clamp(pitch_ref, -max_tilt, max_tilt)
    roll, pitch, yaw = x[6], x[7], x[8]
    e_yaw = wrap_pi(yaw_ref - yaw) if yaw_mode == POSITION else 0.0
    u2 = v[IXX] / v[ARM] * (c[KP + 1] * (roll_ref - roll) - c[KD + 1] * x[9])
    u3 = v[IYY] / v[ARM] * (c[KP + 2] * (pitch_ref - pitch) - c[KD + 2] * x[10])
    u4 = v[IZZ] * (c[KP + 3] * e_yaw + c[KD + 3] * (yaw_rate_ff - x[11]))
    return u2, u3, u4


@jit(inline=True)
def pd_thrust(a: float, roll: float, pitch: float, v: np.ndarray, c: np.ndarray) -> float:
    """u1 = m·a/(cφcθ), cφcθ bounded below (erratum 8), clamped to the thrust bounds [N]."""
    cc = tilt_factor(roll, pitch, c[COS_MAX_TILT])
    return clamp(v[MASS] * a / cc, c[THRUST_MIN], c[THRUST_MAX])


@jit(inline=True)
def pd(x: tuple[float, ...], ref: tuple[float, float, float, float], v: np.ndarray, c: np.ndarray) -> Inputs:
    """One step of the PD law for the state ``x`` (the 12 VehicleState fields) and the reference (altitude,
    roll, pitch, yaw)."""
    a = pd_vertical(altitude(x), climb_rate(x), ref[0], 0.0, 0.0, POSITION, v, c)
    u2, u3, u4 = pd_attitude(x, ref[1], ref[2], ref[3], 0.0, POSITION, v, c)
    return Inputs(pd_thrust(a, x[6], x[7], v, c), u2, u3, u4)


@jit
def step_arrays(x: np.ndarray, ref: np.ndarray, mem: np.ndarray, v: np.ndarray, c: np.ndarray) -> None:
    """:func:`pd` on arrays, in place: ``x`` (12) the state, ``ref`` (4) the reference, the command into
    ``mem`` (MEM_SIZE)."""
    s = (x[0], x[1], x[2], x[3], x[4], x[5], x[6], x[7], x[8], x[9], x[10], x[11])
    u = pd(s, (ref[0], ref[1], ref[2], ref[3]), v, c)
    for i in range(4):
        mem[MEM_U + i] = u[i]


class PDController:
    """PD baseline. ``kp`` [1/s²] and ``kd`` [1/s] per channel (altitude, roll, pitch, yaw)."""

    kind = PD
    plug = None  # a built-in: nothing plugged (autopilot.plugin)

    def __init__(
        self,
        vehicle: VehicleParams,
        kp: Sequence[float],
        kd: Sequence[float],
        max_tilt: float = math.radians(80.0),
        thrust_min: float = -math.inf,
        thrust_max: float = math.inf,
        period: float = 0.0,
        poles: Sequence[float] = (0.0,) * 8,
        position: PositionParams | None = None,
    ) -> None:
        self.vehicle = vehicle
        self.kp = tuple(kp)
        self.kd = tuple(kd)
        self.v = vehicle_array(vehicle)
        self.c = control_array(poles, period, kp, kd, max_tilt, thrust_min, thrust_max, position)
        self.x, self.ref, self.mem = np.zeros(12), np.zeros(4), np.zeros(MEM_SIZE)
        self._step: Callable | None = None  # specialized at the first step (a process never: its tick is compiled)
        self.last = Inputs()

    @property
    def max_tilt(self) -> float:
        """The bound on the roll and pitch references [rad]."""
        return float(self.c[MAX_TILT])

    def reset(self) -> None:
        self.last = Inputs()

    def step(self, state: VehicleState, reference: Reference) -> Inputs:
        self.x[:], self.ref[:] = state, reference
        if self._step is None:
            self._step = specialized(step_arrays, self.x, self.ref, self.mem, self.v, self.c)
        self._step(self.x, self.ref, self.mem, self.v, self.c)
        self.last = Inputs._make(self.mem[MEM_U : MEM_U + 4].tolist())
        return self.last
