"""The plant: actuators, rigid-body dynamics, integrator and ground plane, one control period at a time.

Pure computation, no I/O. :func:`step` (compiled, :mod:`quadsitl.jit`) advances the truth state by the
control period T, using ``substeps`` integration steps with the inputs held (zero-order hold); the
:class:`Plant` object keeps its arrays between calls for the processes and ``quadsitl sim``.

Ground plane (altitude 0, NED z = 0): after every sub-step, a vehicle at or below the ground that is
not climbing is put on it (z = 0) and stopped (velocity zero: ground friction). A vehicle whose
thrust does not lift it therefore rests on the ground, and nothing falls through. A climb starting
from the ground is not touched, so the paper's experiment is unaltered by starting on the ground.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np

from quadsitl.compiled_frames import wrap_pi
from quadsitl.config import (
    DEFAULT_LIMITS,
    L_POSITION,
    L_RATE,
    L_SPEED,
    L_TILT,
    MAX_YAW,
    Preset,
    SensorParams,
    initial_state,
)
from quadsitl.frames import PX4_HOME
from quadsitl.jit import borrowed, jit, specialized
from quadsitl.mixer import Forces, forces_to_inputs, residual_rotor_speed
from quadsitl.param_arrays import D_OVER_B, VEHICLE_SIZE, B, actuator_array, vehicle_array
from quadsitl.state import Inputs, VehicleState
from sitl import battery
from sitl.actuators import advance
from sitl.dynamics import Disturbance, State
from sitl.integrators import INTEGRATORS, integrate
from sitl.sensors import Sensors
from sitl.wind import AIR_SIZE, air_arrays, air_tick

# The outputs of a step besides the state, in Plant.out: mean motor forces (4), inputs u1..u4 (4), Ωr, on ground,
# the mean acceleration over the step (3, [m/s², NED]: the change of velocity over the period, the ground's stop
# included; what the accelerometer measures, :mod:`sitl.sensors`); the battery (sitl.battery): its current over the
# step [A], the charge [C] and energy [J] drawn since the start, its voltage at the step's end [V] and the share of its
# charge left (−1: an ideal supply, no battery; set before the first step by sitl.battery.start).
OUT_FORCES, OUT_INPUTS, OUT_OMEGA_R, OUT_ON_GROUND, OUT_MEAN_ACCEL = 0, 4, 8, 9, 10
OUT_CURRENT, OUT_CHARGE, OUT_ENERGY, OUT_VOLTAGE, OUT_REMAINING, OUT_SIZE = 13, 14, 15, 16, 17, 18
# Plant.work, the one array its per-step arrays are views of: the state, the motor forces, the command, the outputs,
# the air (sitl.wind's layout).
W_X, W_MOTORS, W_COMMANDED, W_OUT, W_AIR = 0, 12, 16, 20, 20 + OUT_SIZE
WORK_SIZE = W_AIR + AIR_SIZE


@jit(inline=True)
def ground(s: State) -> tuple[State, bool]:
    """The ground plane: (the state, whether the vehicle rests on the ground)."""
    if s[2] >= 0.0 and s[5] >= 0.0:  # at/below ground and not climbing (NED: z, vz down)
        return (s[0], s[1], 0.0, 0.0, 0.0, 0.0, s[6], s[7], s[8], s[9], s[10], s[11]), True
    return s, False


@jit(inline=True)
def step(s: State, motors: Forces, commanded: Forces, v: np.ndarray, a: np.ndarray, period: float, substeps: int,
         method: int, omega_r: float, d: Disturbance) -> tuple[State, Forces, Forces, Inputs, float, bool]:  # fmt: skip
    """One control period under the commanded motor forces [N] and the wind and external force ``d`` (held over
    the period; :data:`sitl.dynamics.CALM` for none): (state, motor forces at the end, mean motor forces over the
    last sub-step, the inputs u1..u4 they make (eq (8)), Ωr, on ground).

    ``omega_r`` overrides the residual rotor speed Ωr that eqs (5)–(6) use; NaN computes it from the
    applied forces (tests give the plant the Ωr the controller assumed)."""
    h = period / substeps
    forces = motors
    u = Inputs(0.0, 0.0, 0.0, 0.0)
    wr = 0.0
    on_ground = False
    for _ in range(substeps):
        motors, forces = advance(motors, commanded, h, a)
        u = forces_to_inputs(forces, v[D_OVER_B])  # eq (8)
        wr = residual_rotor_speed(forces, v[B]) if math.isnan(omega_r) else omega_r
        s, on_ground = ground(integrate(method, s, u, wr, v, d, h))
    s = (s[0], s[1], s[2], s[3], s[4], s[5], s[6], s[7], wrap_pi(s[8]), s[9], s[10], s[11])
    return s, motors, forces, u, wr, on_ground


@jit(inline=True)
def step_arrays(x: np.ndarray, motors: np.ndarray, commanded: np.ndarray, out: np.ndarray, v: np.ndarray,
                a: np.ndarray, air: np.ndarray, air_rng: np.ndarray, period: float, substeps: int, method: int,
                omega_r: float) -> None:  # fmt: skip
    """:func:`step` on arrays, in place, in the tick's wind: ``x`` (12) the state, ``motors`` (4) the motor
    forces [N], ``out`` (OUT_SIZE) the step's other outputs; ``air`` and ``air_rng`` the wind model's
    (:func:`sitl.wind.air_arrays`), whose :func:`sitl.wind.air_tick` makes the tick's wind and force first.

    Inlined into its callers, as are the wind's functions it calls: called out of line, numba counts a reference to
    every array passed and every slice made (an atomic operation each), a large share of the step; inlined, the
    compiler drops the counts that cancel (docs/performance.md#per-call). The same code, so the same bits."""
    air_tick(air, air_rng, period, x, out[OUT_ON_GROUND] > 0.0)
    d = air[:6]
    s = (x[0], x[1], x[2], x[3], x[4], x[5], x[6], x[7], x[8], x[9], x[10], x[11])
    v0 = (x[3], x[4], x[5])
    m = (motors[0], motors[1], motors[2], motors[3])
    c = (commanded[0], commanded[1], commanded[2], commanded[3])
    if battery.empty(out[OUT_CHARGE], a):  # an empty battery powers no motor
        c = (0.0, 0.0, 0.0, 0.0)
    s, m, forces, u, wr, on_ground = step(s, m, c, v, a, period, substeps, method, omega_r,
                                          (d[0], d[1], d[2], d[3], d[4], d[5]))  # fmt: skip
    for i in range(12):
        x[i] = s[i]
    for i in range(4):
        motors[i] = m[i]
        out[OUT_FORCES + i] = forces[i]
        out[OUT_INPUTS + i] = u[i]
    out[OUT_OMEGA_R] = wr
    out[OUT_ON_GROUND] = 1.0 if on_ground else 0.0
    battery.step(out[OUT_CURRENT:OUT_SIZE], forces, v, a, period)
    for i in range(3):
        out[OUT_MEAN_ACCEL + i] = (s[3 + i] - v0[i]) / period


@jit
def step_work(w: np.ndarray, params: np.ndarray, air_rng: np.ndarray, period: float, substeps: int, method: int,
              omega_r: float) -> None:  # fmt: skip
    """:func:`step_arrays` on :class:`Plant`'s arrays: ``w`` its work array (WORK_SIZE: W_*), ``params`` its
    vehicle array then its actuator array. Three arrays to unpack instead of eight when Python calls it: numba
    wraps each array it is given in an object of its own on every call (docs/performance.md#per-call)."""
    w, params, air_rng = borrowed((w, params, air_rng))  # quadsitl.jit.borrowed
    step_arrays(w[W_X:W_MOTORS], w[W_MOTORS:W_COMMANDED], w[W_COMMANDED:W_OUT], w[W_OUT:W_AIR],
                params[:VEHICLE_SIZE], params[VEHICLE_SIZE:], w[W_AIR:], air_rng, period, substeps, method,
                omega_r)  # fmt: skip


# Divergence: the bounds a state must stay within (``lim``, LIMITS_SIZE; the names, indices and defaults are in
# :mod:`quadsitl.config`). One check (:func:`inside`) for every runtime: the sweeps' batch engine (with a sweep's own
# ``[limits]``), the plant process and ``quadsitl sim`` (with DEFAULT_LIMITS), on the state x(k) at the start of
# tick k.


@jit(inline=True)
def inside(s: State, lim: tuple | np.ndarray) -> bool:
    """The state is finite and within the bounds ``lim`` (every comparison with NaN is false): what the sweeps'
    batch engine, the plant process and ``quadsitl sim`` check at the start of every tick; a state outside has
    diverged."""
    p, v, tilt, rate = lim[L_POSITION], lim[L_SPEED], lim[L_TILT], lim[L_RATE]
    return (abs(s[0]) <= p and abs(s[1]) <= p and abs(s[2]) <= p and abs(s[3]) <= v and abs(s[4]) <= v
            and abs(s[5]) <= v and abs(s[6]) < tilt and abs(s[7]) < tilt and abs(s[8]) <= MAX_YAW
            and abs(s[9]) <= rate and abs(s[10]) <= rate and abs(s[11]) <= rate)  # fmt: skip


@jit
def state_inside(x: np.ndarray) -> bool:
    """:func:`inside` the default bounds, for a state array ``x`` (12, VehicleState order): the check of the
    plant process's real-time loop and of ``quadsitl sim``, one compiled call per tick."""
    return inside((x[0], x[1], x[2], x[3], x[4], x[5], x[6], x[7], x[8], x[9], x[10], x[11]), DEFAULT_LIMITS)


def outside_what(x: Sequence[float], lim: Sequence[float] = DEFAULT_LIMITS) -> str:
    """Which quantity of a state that is not :func:`inside` ``lim`` left its bound, in words, ASCII (it also goes
    out in a STATUSTEXT): the quantity, its value, the bound and which one, e.g. ``|roll| = 1.59357 rad is not <
    1.5708 (tilt bound)``; the first found."""
    names = ("x", "y", "z", "vx", "vy", "vz", "roll", "pitch", "yaw", "roll rate", "pitch rate", "yaw rate")
    units = ("m",) * 3 + ("m/s",) * 3 + ("rad",) * 3 + ("rad/s",) * 3
    bounds = (lim[L_POSITION],) * 3 + (lim[L_SPEED],) * 3 + (lim[L_TILT],) * 2 + (MAX_YAW,) + (lim[L_RATE],) * 3
    kinds = ("position",) * 3 + ("speed",) * 3 + ("tilt",) * 2 + ("yaw: 1000 turns",) + ("rate",) * 3
    for i, (name, unit, bound, kind) in enumerate(zip(names, units, bounds, kinds)):
        value = float(x[i])
        strict = i in (6, 7)
        if not math.isfinite(value) or (abs(value) >= bound if strict else abs(value) > bound):
            return f"|{name}| = {abs(value):.6g} {unit} is not {'<' if strict else '<='} {bound:.6g} ({kind} bound)"
    return "every quantity within its bound"


class Plant:
    """The simulated quadrotor of a preset.

    Attributes after each step: ``state`` (VehicleState), ``forces`` (the mean motor forces applied
    over the last sub-step [N]), ``inputs`` (u1..u4 they make, eq (8)), ``omega_r`` [rad/s],
    ``on_ground`` (bool), ``time`` [s], ``wind`` (the wind of the last step [m/s, NED]).
    The arrays ``x`` (the state), ``motors``, ``air`` and ``air_rng`` (the wind model's, :func:`sitl.wind.air_arrays`:
    the wind and external force of the last step first, ``d``) are what the compiled step works on. ``sensors``
    (:class:`sitl.sensors.Sensors`, at ``home`` = (lat [deg], lon [deg], alt [m AMSL]), the local origin) measures
    the state in sensor mode (the preset's [sensors]).
    """

    def __init__(self, preset: Preset, integrator: str | None = None, substeps: int | None = None,
                 home: tuple[float, float, float] = PX4_HOME) -> None:  # fmt: skip
        self.params = preset.vehicle
        self.period = float(preset.sim.period)
        name = integrator or preset.sim.integrator
        if name not in INTEGRATORS:
            raise ValueError(f"integrator {name!r}: expected one of {', '.join(INTEGRATORS)}")
        self.method = INTEGRATORS[name]
        self.substeps = int(substeps or preset.sim.substeps)
        # The arrays the compiled step works on, as views of two (step_work): the parameters, and the rest.
        self.params = np.concatenate([vehicle_array(preset.vehicle), actuator_array(preset.actuators, preset.battery)])
        self.work = np.zeros(WORK_SIZE)
        self._views()
        self.x[:] = initial_state(preset)
        self.out[OUT_ON_GROUND] = self.x[2] >= 0.0
        battery.start(self.out[OUT_CURRENT:OUT_SIZE], self.a)
        self.time = 0.0
        self.air[:], self.air_rng = air_arrays(preset.wind)
        # The sensors (the preset's, else the defaults, whose arrays the compiled tick is not given: sens).
        self.sensors = Sensors(preset.sensors or SensorParams(), self.period, preset.vehicle.gravity, home)
        self.sensing = preset.sensors is not None
        self._step: Callable | None = None  # step_work, specialized when first stepped (a lockstep plant never is)

    @property
    def sens(self) -> tuple | None:
        """The sensors' arrays for the compiled tick (:func:`sitl.tick.encode_tick`) in sensor mode (the preset has
        [sensors]); None on the true state, for which numba compiles no sensors' path."""
        return self.sensors.arrays if self.sensing else None

    _VIEWS = ("v", "a", "x", "motors", "commanded", "out", "air")

    def _views(self) -> None:
        self.v, self.a = self.params[:VEHICLE_SIZE], self.params[VEHICLE_SIZE:]
        self.x = self.work[W_X:W_MOTORS]
        self.motors = self.work[W_MOTORS:W_COMMANDED]
        self.commanded = self.work[W_COMMANDED:W_OUT]
        self.out = self.work[W_OUT:W_AIR]
        self.air = self.work[W_AIR:]

    def __getstate__(self) -> dict:  # copies and pickles: the views are made again from the two arrays
        return {k: v for k, v in self.__dict__.items() if k not in self._VIEWS}

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)
        self._views()

    @property
    def state(self) -> VehicleState:
        return VehicleState._make(self.x.tolist())

    @state.setter
    def state(self, state: VehicleState) -> None:
        self.x[:] = state

    @property
    def forces(self) -> Forces:
        return tuple(self.out[OUT_FORCES : OUT_FORCES + 4].tolist())  # type: ignore[return-value]

    @property
    def inputs(self) -> Inputs:
        return Inputs._make(self.out[OUT_INPUTS : OUT_INPUTS + 4].tolist())

    @property
    def omega_r(self) -> float:
        return float(self.out[OUT_OMEGA_R])

    @property
    def on_ground(self) -> bool:
        return bool(self.out[OUT_ON_GROUND])

    @property
    def d(self) -> np.ndarray:
        """The wind [m/s, NED] and the external force [N, NED] of the last step (a view)."""
        return self.air[:6]

    @property
    def wind(self) -> tuple[float, float, float]:
        return tuple(self.air[:3].tolist())  # type: ignore[return-value]

    def step(self, commanded: Forces | None = None, omega_r: float | None = None) -> None:
        """Advance one control period under the commanded motor forces [N] (default: ``self.commanded``).

        ``omega_r`` overrides the residual rotor speed Ωr that eqs (5)–(6) use (the default computes it
        from the applied forces); tests use it to give the plant the Ωr the controller assumed.
        """
        if commanded is not None:
            self.commanded[:] = commanded
        omega_r = math.nan if omega_r is None else float(omega_r)
        if self._step is None:
            self._step = specialized(step_work, self.work, self.params, self.air_rng, self.period, self.substeps,
                                     self.method, math.nan)  # fmt: skip
        self._step(self.work, self.params, self.air_rng, self.period, self.substeps, self.method, omega_r)
        self.time += self.period
