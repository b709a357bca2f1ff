"""The batch engine: every trial of a chunk flown in one compiled call, on the very functions the plant
process, the autopilot process and ``quadsitl sim`` run.

One control tick of a trial is the paper's experiment on the law alone (``quadsitl sim`` flies the whole vehicle,
commander and limits included, through :mod:`groundstation.vehicle`; for the paper's reference the two are the same
to the bit): the controller's
law on the state (:func:`autopilot.backstepping.backstepping`, eqs (18)–(33), or :func:`autopilot.pd.pd`), the
allocation of the autopilot (:func:`quadsitl.mixer.allocate`, the inverse of eq (8) with saturation, on the
autopilot's model), then one control period of the plant (:func:`sitl.plant.step`: actuators, eq (8), eqs
(2)–(7) integrated, ground plane). No equation is written here: :func:`run_trial` composes those compiled
functions, keeps a trial's state in registers from its first tick to its last (the ticks fused, no Python
between them), and folds each tick into the trial's metrics as it goes (:data:`METRICS`), so nothing of a
trajectory is stored unless it is asked for (``keep``).

The metrics are those of :func:`groundstation.metrics.run_metrics` on the rows ``quadsitl sim`` writes (the
state x(k) at the start of tick k, k = 0..N−1, t = k·T), computed on the fly with the same definitions:

- rise time: t of the first row at 90 % of the step minus t of the first at 10 % [s];
- settling time: t of the row after the last outside ±2 % of the step [s] (0 if none; NaN if the last row is
  outside: not settled within the run);
- overshoot: max(0, max over rows of the fraction of the step − 1) [%];
- steady-state error: final reference − final output; peak |u| of the channel's input (u1 [N], u2, u3 [N],
  u4 [N·m]); RMS of reference − output.

The step is from the first row's output to the final reference; yaw is unwrapped as numpy's ``unwrap`` does
and its reference taken on the branch of the unwrapped yaw at the end. That branch is known only at the end:
a trial flies on the branch it is given (``turns``, in whole turns of 2π: 0 for a trial that does not turn
round) and reports the branch it ended on (M_YAW_TURNS); :func:`groundstation.sweep.run.run_chunk` flies again
the rare trial that ended on another one, on its own branch. A trial is deterministic, so the second flight is
the first one's to the bit.

Besides: the time with the allocation saturated (any commanded motor force at a bound of the motors, or u1 at
a bound of the controller) [s], and divergence: a trial whose state at the start of a tick is not finite or out
of the bounds ``limits`` (position, speed, roll and pitch, Euler-angle rates) ends there; it is marked diverged
with that tick's time, and its response metrics are NaN (its peak |u| and saturation time are those up to then).
"""

from __future__ import annotations

import math

import numpy as np

from autopilot.backstepping import backstepping
from autopilot.control_params import BACKSTEPPING, THRUST_MAX, THRUST_MIN
from autopilot.control_params import SIZE as CONTROL_SIZE
from autopilot.pd import pd
from quadsitl.config import (
    DEFAULT_LIMITS as DEFAULT_LIMITS,  # divergence bounds: the plant process's (sitl.plant.inside)
)
from quadsitl.config import LIMITS_SIZE as LIMITS_SIZE
from quadsitl.jit import constants, jit
from quadsitl.mixer import allocate
from quadsitl.param_arrays import ACTUATOR_SIZE, D_OVER_B, F_MAX, F_MIN, VEHICLE_SIZE
from sitl.dynamics import CALM
from sitl.plant import inside, step

CHANNELS = ("altitude", "roll", "pitch", "yaw")
STEP_METRICS = ("rise_time", "settling_time", "overshoot_pct", "steady_state_error", "peak_abs_u", "rms_error")
"""Per channel, in :func:`groundstation.metrics.step_metrics`'s names and units."""
PER_CHANNEL = len(STEP_METRICS)
RISE, SETTLE, OVERSHOOT, SSE, PEAK_U, RMS = range(PER_CHANNEL)
M_SATURATED, M_DIVERGED, M_DIVERGED_AT, M_TICKS, M_YAW_TURNS = range(4 * PER_CHANNEL, 4 * PER_CHANNEL + 5)
METRICS = (
    *(f"{ch}_{m}" for ch in CHANNELS for m in STEP_METRICS),
    "saturation_time",  # [s]
    "diverged",  # 1.0 or 0.0
    "diverged_at",  # [s], NaN when it did not
    "ticks",  # control ticks flown
    "yaw_turns",  # the branch of the yaw reference at the end, in turns of 2π (see the module's docstring)
)
"""The columns of the metrics array :func:`run_chunk` fills, one row per trial."""
METRICS_SIZE = len(METRICS)


# A kept trajectory's columns per tick: the state (12), the reference (4), u1..u4, the commanded forces (4).
K_STATE, K_REF, K_INPUTS, K_FORCES, KEEP_SIZE = 0, 12, 16, 20, 24

TWO_PI = 2.0 * math.pi


@jit(inline=True)
def _unwrap_step(previous: float, now: float) -> float:
    """numpy's ``unwrap`` correction for one difference (period 2π, discontinuity π): what to add to the running
    sum of corrections when the raw angle goes from ``previous`` to ``now``."""
    dd = now - previous
    if abs(dd) < math.pi:
        return 0.0
    ddmod = (dd + math.pi) % TWO_PI - math.pi
    if ddmod == -math.pi and dd > 0.0:
        ddmod = math.pi
    return ddmod - dd


@jit(inline=True)
def _wrapped(d: float) -> float:
    """d on (−π, π] (the angle of e^(i·d)); d itself when it is there already."""
    if -math.pi < d <= math.pi:
        return d
    return math.atan2(math.sin(d), math.cos(d))


@jit(inline=True)
def _fly(
    x0: np.ndarray, v: np.ndarray, a: np.ndarray, vm: np.ndarray, c: np.ndarray, r: np.ndarray, kind: int,
    ticks: int, period: float, substeps: int, method: int, turns: float, lim: np.ndarray, m: np.ndarray,
    keep: np.ndarray, kept: bool,
) -> None:  # fmt: skip
    """Fly one trial for ``ticks`` control periods and write its metrics into ``m`` (METRICS_SIZE).

    ``x0`` the initial state (12, VehicleState order); ``v``, ``a`` the plant's vehicle and actuator arrays
    (:mod:`quadsitl.param_arrays`); ``vm``, ``c`` the autopilot's model of the vehicle and its control array
    (:mod:`autopilot.control_params`); ``r`` the reference (altitude [m], roll, pitch, yaw [rad]), constant;
    ``kind`` BACKSTEPPING or PD; ``period`` T [s]; ``substeps``, ``method`` the plant's integration; ``turns``
    the yaw reference's branch; ``lim`` the divergence bounds. With ``kept``, tick k's row goes to keep[k]
    (KEEP_SIZE columns)."""
    s = (x0[0], x0[1], x0[2], x0[3], x0[4], x0[5], x0[6], x0[7], x0[8], x0[9], x0[10], x0[11])
    # The trial's parameters as tuples: what depends on them alone is computed once, not on every tick.
    v, a, vm, c = (constants(v, VEHICLE_SIZE), constants(a, ACTUATOR_SIZE), constants(vm, VEHICLE_SIZE),
                   constants(c, CONTROL_SIZE))  # fmt: skip
    lim = constants(lim, LIMITS_SIZE)
    ref = (r[0], r[1], r[2], r[3])
    motors = (0.0, 0.0, 0.0, 0.0)
    last = (0.0, 0.0, 0.0, 0.0)  # the previous command: the backstepping's Ωr is the one it makes
    f_min, f_max = a[F_MIN], a[F_MAX]
    t_min, t_max = c[THRUST_MIN], c[THRUST_MAX]
    d_over_b = vm[D_OVER_B]  # the autopilot allocates with its own model (autopilot.tick.control_tick)
    # The outputs' targets: altitude, roll, pitch as given; yaw on the branch `turns`.
    target = (r[0], r[1], r[2], r[3] + TWO_PI * turns)
    y0 = (-s[2], s[6], s[7], s[8])
    steps = (target[0] - y0[0], target[1] - y0[1], target[2] - y0[2], target[3] - y0[3])
    band = np.empty(4)
    i10 = np.full(4, -1)
    i90 = np.full(4, -1)
    outside = np.full(4, -1)  # the last row outside the band
    extreme = np.empty(4)  # the output furthest in the step's direction
    peak = np.zeros(4)
    sq = np.zeros(4)
    y = np.empty(4)
    for j in range(4):
        band[j] = 0.02 * abs(steps[j])
        extreme[j] = y0[j]
    yaw_raw, yaw_fix = s[8], 0.0  # numpy.unwrap: the raw yaw of the previous row and the corrections so far
    saturated = 0
    diverged_at = -1
    err_yaw = 0.0
    for k in range(ticks):
        if not inside(s, lim):
            diverged_at = k
            break
        # ---- the controller on x(k) (the autopilot's model vm), and its allocation ----------------------
        if kind == BACKSTEPPING:
            u, _errors, _omega_r = backstepping(s, ref, last, vm, c)
        else:
            u = pd(s, ref, vm, c)
        last = (u[0], u[1], u[2], u[3])
        forces = allocate(last, d_over_b, f_min, f_max)
        if kept:
            for i in range(12):
                keep[k, K_STATE + i] = s[i]
            for i in range(4):
                keep[k, K_REF + i] = ref[i]
                keep[k, K_INPUTS + i] = u[i]
                keep[k, K_FORCES + i] = forces[i]
        # ---- the row's metrics ---------------------------------------------------------------------------
        yaw_fix += _unwrap_step(yaw_raw, s[8])
        yaw_raw = s[8]
        y[0], y[1], y[2], y[3] = -s[2], s[6], s[7], s[8] + yaw_fix
        err_yaw = _wrapped(r[3] - y[3])
        for j in range(4):
            yj = y[j]
            if i90[j] < 0 and steps[j] != 0.0:
                frac = (yj - y0[j]) / steps[j]
                if i10[j] < 0 and frac >= 0.1:
                    i10[j] = k
                if frac >= 0.9:
                    i90[j] = k
            if abs(yj - target[j]) > band[j]:
                outside[j] = k
            if (yj > extreme[j]) if steps[j] > 0.0 else (yj < extreme[j]):
                extreme[j] = yj
            e = err_yaw if j == 3 else target[j] - yj
            sq[j] += e * e
            au = abs(u[j])
            if au > peak[j]:
                peak[j] = au
        if (u[0] <= t_min or u[0] >= t_max or min(min(forces[0], forces[1]), min(forces[2], forces[3])) <= f_min
                or max(max(forces[0], forces[1]), max(forces[2], forces[3])) >= f_max):  # fmt: skip
            saturated += 1
        # ---- the plant: one control period under the commanded forces ------------------------------------
        s, motors, _applied, _inputs, _wr, _ground = step(s, motors, forces, v, a, period, substeps, method,
                                                            math.nan, CALM)  # fmt: skip
    flown = ticks if diverged_at < 0 else diverged_at
    nan = math.nan
    m[M_SATURATED] = saturated * period
    m[M_TICKS] = flown
    m[M_DIVERGED] = 0.0 if diverged_at < 0 else 1.0
    m[M_DIVERGED_AT] = nan if diverged_at < 0 else diverged_at * period
    for j in range(4):
        m[PER_CHANNEL * j + PEAK_U] = peak[j]
    if diverged_at >= 0 or flown == 0:
        for j in range(4):
            for q in (RISE, SETTLE, OVERSHOOT, SSE, RMS):
                m[PER_CHANNEL * j + q] = nan
        m[M_YAW_TURNS] = turns
        return
    final = (target[0] - y[0], target[1] - y[1], target[2] - y[2], err_yaw)
    # The yaw reference's branch at the end (run_metrics: the unwrapped yaw plus the wrapped error).
    m[M_YAW_TURNS] = round((y[3] + err_yaw - r[3]) / TWO_PI)
    for j in range(4):
        base = PER_CHANNEL * j
        m[base + SSE] = final[j]
        m[base + RMS] = math.sqrt(sq[j] / flown)
        if abs(steps[j]) < 1e-12:  # no step: rise, settling and overshoot are not defined
            m[base + RISE], m[base + SETTLE], m[base + OVERSHOOT] = nan, nan, nan
            continue
        m[base + RISE] = i90[j] * period - i10[j] * period if i10[j] >= 0 and i90[j] >= 0 else nan
        if outside[j] < 0:
            m[base + SETTLE] = 0.0
        elif outside[j] + 1 < flown:
            m[base + SETTLE] = (outside[j] + 1) * period
        else:
            m[base + SETTLE] = nan
        m[base + OVERSHOOT] = max(0.0, (extreme[j] - y0[j]) / steps[j] - 1.0) * 100.0


@jit
def run_trial(
    x0: np.ndarray, v: np.ndarray, a: np.ndarray, vm: np.ndarray, c: np.ndarray, r: np.ndarray, kind: int,
    ticks: int, period: float, substeps: int, method: int, turns: float, lim: np.ndarray, m: np.ndarray,
    keep: np.ndarray, kept: bool,
) -> None:  # fmt: skip
    """Fly one trial and write its metrics into ``m`` (:func:`_fly`): any controller, integrator and step count."""
    _fly(x0, v, a, vm, c, r, kind, ticks, period, substeps, method, turns, lim, m, keep, kept)


@jit
def run_trial_paper(
    x0: np.ndarray, v: np.ndarray, a: np.ndarray, vm: np.ndarray, c: np.ndarray, r: np.ndarray, ticks: int,
    period: float, method: int, turns: float, lim: np.ndarray, m: np.ndarray, keep: np.ndarray, kept: bool,
) -> None:  # fmt: skip
    """:func:`run_trial` with the paper's controller and step count compiled in: the backstepping, one step of the
    plant per tick (see :func:`run_chunk`)."""
    _fly(x0, v, a, vm, c, r, BACKSTEPPING, ticks, period, 1, method, turns, lim, m, keep, kept)


def run_chunk(
    x0: np.ndarray, v: np.ndarray, a: np.ndarray, vm: np.ndarray, c: np.ndarray, r: np.ndarray, kind: int,
    ticks: int, period: float, substeps: int, method: int, turns: np.ndarray, lim: np.ndarray, m: np.ndarray,
    slots: np.ndarray, keep: np.ndarray,
) -> None:  # fmt: skip
    """Fly each trial i of a chunk (row i of every per-trial array), one after the other: metrics into m[i]; a
    trial with slots[i] ≥ 0 writes its trajectory into keep[slots[i]].

    The paper's configuration (the backstepping, one step of the plant per tick) runs a version compiled for it
    (:func:`run_trial_paper`): with the controller and the step count known to the compiler, the plant's step is
    one straight pass, and the cosines of roll and pitch the law's u1 takes (28) are the plant's own (eqs (2)–(4)),
    computed once a tick. The results are the same to the bit, in about 12 % less time. (Compiling the integrator
    in as well made it slower.) Each version is compiled the first time it is used."""
    if kind == BACKSTEPPING and substeps == 1:
        _chunk_paper(x0, v, a, vm, c, r, ticks, period, method, turns, lim, m, slots, keep)
    else:
        _chunk(x0, v, a, vm, c, r, kind, ticks, period, substeps, method, turns, lim, m, slots, keep)


@jit
def _chunk(
    x0: np.ndarray, v: np.ndarray, a: np.ndarray, vm: np.ndarray, c: np.ndarray, r: np.ndarray, kind: int,
    ticks: int, period: float, substeps: int, method: int, turns: np.ndarray, lim: np.ndarray, m: np.ndarray,
    slots: np.ndarray, keep: np.ndarray,
) -> None:  # fmt: skip
    for i in range(x0.shape[0]):
        slot = slots[i]
        run_trial(x0[i], v[i], a[i], vm[i], c[i], r[i], kind, ticks, period, substeps, method, turns[i], lim, m[i],
                  keep[max(slot, 0)], slot >= 0)  # fmt: skip


@jit
def _chunk_paper(
    x0: np.ndarray, v: np.ndarray, a: np.ndarray, vm: np.ndarray, c: np.ndarray, r: np.ndarray, ticks: int,
    period: float, method: int, turns: np.ndarray, lim: np.ndarray, m: np.ndarray, slots: np.ndarray, keep: np.ndarray,
) -> None:  # fmt: skip
    for i in range(x0.shape[0]):
        slot = slots[i]
        run_trial_paper(x0[i], v[i], a[i], vm[i], c[i], r[i], ticks, period, method, turns[i], lim, m[i],
                        keep[max(slot, 0)], slot >= 0)  # fmt: skip
