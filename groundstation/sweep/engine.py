"""The batch engine: every trial of a chunk flown in one compiled call, on the vehicle ``quadsitl sim`` and the
processes fly (:mod:`groundstation.vehicle`).

A trial is flown as ``quadsitl sim`` flies it: the commander sees the initial state, takes the offboard setpoint of
the trial's reference (sent again at every moment of ``quadsitl fly``'s grid), arms in offboard, and each control
tick is :func:`groundstation.vehicle.vehicle_tick`: the autopilot's tick (commander, position, altitude and attitude
control with their limits and integrators, allocation on the autopilot's model) and one control period of the plant.
No equation and no composition of the vehicle is written here: :func:`run_trial` loops that tick with a trial's
parameters as constants of the compiled loop (the ticks fused, no Python between them), and folds each tick into
the trial's metrics as it goes (:data:`METRICS`), so nothing of a trajectory is stored unless it is asked for
(``keep``). Its trials equal ``quadsitl sim``'s flights to the bit.

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

from autopilot import plugin
from autopilot.commander_state import BAT_J
from autopilot.control_params import BACKSTEPPING, MEM_FORCES, MEM_SIZE, MEM_U, THRUST_MAX, THRUST_MIN
from autopilot.control_params import SIZE as CONTROL_SIZE
from autopilot.stream_frames import reference_shown
from groundstation.vehicle import (
    R_FORCES,
    R_INPUTS,
    R_REF,
    R_STATE,
    ROW_SIZE,
    SP_FIELDS,
    arm_offboard,
    record,
    setpoints_due,
    vehicle_tick,
)
from quadsitl import codec, hil
from quadsitl.config import (
    DEFAULT_LIMITS as DEFAULT_LIMITS,  # divergence bounds: the plant process's (sitl.plant.inside)
)
from quadsitl.config import LIMITS_SIZE as LIMITS_SIZE
from quadsitl.config import WindParams
from quadsitl.frames import PX4_HOME as HOME
from quadsitl.jit import borrowed, constants, jit
from quadsitl.param_arrays import ACTUATOR_SIZE, F_MAX, F_MIN, VEHICLE_SIZE
from sitl import battery
from sitl import tick as plant_tick
from sitl.plant import OUT_CURRENT, OUT_ON_GROUND, OUT_SIZE, W_AIR, W_MOTORS, W_OUT, W_X, WORK_SIZE, inside
from sitl.wind import air_arrays

CHANNELS = ("altitude", "roll", "pitch", "yaw")
STEP_METRICS = ("rise_time", "settling_time", "overshoot_pct", "steady_state_error", "peak_abs_u", "rms_error")
"""Per channel, in :func:`groundstation.metrics.step_metrics`'s names and units."""
PER_CHANNEL = len(STEP_METRICS)
RISE, SETTLE, OVERSHOOT, SSE, PEAK_U, RMS = range(PER_CHANNEL)
M_SATURATED, M_DIVERGED, M_DIVERGED_AT, M_TICKS, M_YAW_TURNS, M_HORIZONTAL_RMS, M_HORIZONTAL_MAX, M_ALTITUDE_RMS = (
    range(4 * PER_CHANNEL, 4 * PER_CHANNEL + 8)
)
M_ENERGY = 4 * PER_CHANNEL + 8
POSITION_METRICS = ("horizontal_rms", "horizontal_max", "altitude_rms")
"""Position tracking, in :func:`groundstation.metrics.position_metrics`' names and units [m]: NaN while the
horizontal position is not controlled (the task's attitude reference)."""
METRICS = (
    *(f"{ch}_{m}" for ch in CHANNELS for m in STEP_METRICS),
    "saturation_time",  # [s]
    "diverged",  # 1.0 or 0.0
    "diverged_at",  # [s], NaN when it did not
    "ticks",  # control ticks flown
    "yaw_turns",  # the branch of the yaw reference at the end, in turns of 2π (see the module's docstring)
    *POSITION_METRICS,
    "energy_j",  # [J] drawn from the battery over the rows flown (its report's, docs/battery.md); NaN: no battery
)
"""The columns of the metrics array :func:`run_chunk` fills, one row per trial."""
METRICS_SIZE = len(METRICS)


# A kept trajectory's columns per tick: sim's rows (groundstation.vehicle.record): the state (12), what the
# autopilot saw (12), the reference (4), x and y flown (2), u1..u4, the commanded forces (4).
K_STATE, K_REF, K_INPUTS, K_FORCES, KEEP_SIZE = R_STATE, R_REF, R_INPUTS, R_FORCES, ROW_SIZE

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
def _step_row(k: int, s: tuple, r: np.ndarray, target: tuple, y0: tuple, steps: tuple, band: np.ndarray,
              i10: np.ndarray, i90: np.ndarray, outside: np.ndarray, extreme: np.ndarray, sq: np.ndarray, y: np.ndarray,
              yaw_fix: float, yaw_raw: float) -> tuple[float, float, float]:  # fmt: skip
    """Row k (the state ``s`` = x(k)) folded into the step response's metrics (the module's docstring): the first
    rows at 10 % and 90 % of each step, the last outside its band, the extreme, the squared errors. Returns the yaw's
    unwrapping (its corrections so far, the raw yaw) and its wrapped error."""
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
    return yaw_fix, yaw_raw, err_yaw


@jit(inline=True)
def _fly(
    x0: np.ndarray, v: np.ndarray, a: np.ndarray, vm: np.ndarray, c: np.ndarray, r: np.ndarray, sp: np.ndarray,
    kind: int, ticks: int, period: float, substeps: int, method: int, turns: float, position: bool, lim: np.ndarray,
    m: np.ndarray, keep: np.ndarray, kept: bool, ctx: tuple,
) -> None:  # fmt: skip
    """Fly one trial for ``ticks`` control periods and write its metrics into ``m`` (METRICS_SIZE).

    ``x0`` the initial state (12, VehicleState order); ``v``, ``a`` the plant's vehicle and actuator arrays
    (:mod:`quadsitl.param_arrays`); ``vm``, ``c`` the autopilot's model of the vehicle and its control array
    (:mod:`autopilot.control_params`); ``r`` the reference the metrics measure against (altitude [m], roll, pitch,
    yaw [rad]), and ``sp`` the offboard setpoint that flies it (the commander's fields, :class:`groundstation.vehicle.
    Setpoints`), sent at every moment of ``quadsitl fly``'s grid; ``kind`` BACKSTEPPING or PD; ``period`` T [s];
    ``substeps``, ``method`` the plant's integration; ``turns`` the yaw reference's branch; ``position``: ``sp`` is a
    position hold, whose metrics are the position tracking's (:data:`POSITION_METRICS`; the step's are NaN, as
    :mod:`groundstation.sweep.trial_row` has them for a position trajectory); ``lim`` the divergence bounds. With
    ``kept``, tick k's row goes to keep[k] (KEEP_SIZE columns). ``ctx``: the vehicle's arrays, reused from trial to
    trial (:func:`context`). The trial is flown as ``quadsitl sim`` flies it: the commander sees the
    initial state, takes the setpoint, arms in offboard, and each tick is :func:`groundstation.vehicle.vehicle_tick`."""
    w, air_rng, pio, datagram, st, cm, mem, truth, frame, cm0, air0, rng0, sens, sp_ticks, table, \
        sp_next, plug = borrowed(ctx)  # fmt: skip
    x0, r, sp, lim, m, keep = borrowed((x0, r, sp, lim, m, keep))
    # ---- the vehicle, at rest before its first tick (groundstation.vehicle.Vehicle) -------------------------------
    w[:] = 0.0
    for i in range(12):
        w[W_X + i] = x0[i]
    w[W_OUT + OUT_ON_GROUND] = 1.0 if x0[2] >= 0.0 else 0.0
    battery.start(w[W_OUT + OUT_CURRENT : W_OUT + OUT_SIZE], a)
    w[W_AIR:] = air0
    air_rng[:] = rng0
    cm[:] = cm0
    mem[:] = 0.0
    st[:] = 0.0
    for j in range(table.shape[0]):
        table[j, :] = sp
    sp_next[0] = 0
    arm_offboard(0, cm, x0, period, sp_ticks, table, sp_next)
    plant = (w, constants(v, VEHICLE_SIZE), constants(a, ACTUATOR_SIZE), air_rng, pio, datagram)
    # The autopilot's parameters as tuples: what depends on them alone is computed once, not on every tick.
    ap = (st, cm, mem, constants(vm, VEHICLE_SIZE), constants(c, CONTROL_SIZE), truth, frame, plug)
    f_min, f_max = a[F_MIN], a[F_MAX]
    t_min, t_max = c[THRUST_MIN], c[THRUST_MAX]
    x = w[W_X:W_MOTORS]
    s = (x0[0], x0[1], x0[2], x0[3], x0[4], x0[5], x0[6], x0[7], x0[8], x0[9], x0[10], x0[11])
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
    tracked, e2, e_max, ea2 = 0, 0.0, 0.0, 0.0  # a position hold's samples, squared errors and largest error
    e_first = math.nan  # the energy drawn, as the first row has it [J]
    for k in range(ticks):
        s = (x[0], x[1], x[2], x[3], x[4], x[5], x[6], x[7], x[8], x[9], x[10], x[11])
        if not inside(s, lim):
            diverged_at = k
            break
        # ---- the vehicle's tick: the autopilot on x(k), its allocation, the plant's period -----------------------
        setpoints_due(k, cm, sp_ticks, table, sp_next)
        vehicle_tick(k, kind, period, substeps, method, plant, sens, ap, (), HOME, f_min, f_max)
        if k == 0:
            e_first = cm[BAT_J]
        u = (mem[MEM_U], mem[MEM_U + 1], mem[MEM_U + 2], mem[MEM_U + 3])
        forces = (mem[MEM_FORCES], mem[MEM_FORCES + 1], mem[MEM_FORCES + 2], mem[MEM_FORCES + 3])
        if kept:
            record(keep, k, s, st, cm, mem)
        # ---- the row's metrics ---------------------------------------------------------------------------
        if position:  # groundstation.metrics.position_metrics, over the rows whose x_ref and y_ref are finite
            shown = reference_shown(cm, mem)
            if not (math.isnan(shown[4]) or math.isnan(shown[5])):
                tracked += 1
                e = math.hypot(s[0] - shown[4], s[1] - shown[5])
                e2 += e * e
                e_max = max(e_max, e)
                ea = shown[0] + s[2]  # altitude_ref − altitude
                ea2 += ea * ea
        else:
            yaw_fix, yaw_raw, err_yaw = _step_row(k, s, r, target, y0, steps, band, i10, i90, outside, extreme, sq, y,
                                                  yaw_fix, yaw_raw)  # fmt: skip
        for j in range(4):
            au = abs(u[j])
            if au > peak[j]:
                peak[j] = au
        if (u[0] <= t_min or u[0] >= t_max or min(min(forces[0], forces[1]), min(forces[2], forces[3])) <= f_min
                or max(max(forces[0], forces[1]), max(forces[2], forces[3])) >= f_max):  # fmt: skip
            saturated += 1
    flown = ticks if diverged_at < 0 else diverged_at
    nan = math.nan
    m[M_SATURATED] = saturated * period
    m[M_ENERGY] = cm[BAT_J] - e_first if flown > 0 else nan  # the last row's less the first's
    m[M_HORIZONTAL_RMS], m[M_HORIZONTAL_MAX], m[M_ALTITUDE_RMS] = nan, nan, nan  # the attitude reference flown
    m[M_TICKS] = flown
    m[M_DIVERGED] = 0.0 if diverged_at < 0 else 1.0
    m[M_DIVERGED_AT] = nan if diverged_at < 0 else diverged_at * period
    for j in range(4):
        m[PER_CHANNEL * j + PEAK_U] = peak[j]
    if position or diverged_at >= 0 or flown == 0:
        for j in range(4):
            for q in (RISE, SETTLE, OVERSHOOT, SSE, RMS):
                m[PER_CHANNEL * j + q] = nan
        m[M_YAW_TURNS] = 0.0 if position else turns
        if position and diverged_at < 0 and tracked > 0:
            m[M_HORIZONTAL_RMS] = math.sqrt(e2 / tracked)
            m[M_HORIZONTAL_MAX] = e_max
            m[M_ALTITUDE_RMS] = math.sqrt(ea2 / tracked)
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
    x0: np.ndarray, v: np.ndarray, a: np.ndarray, vm: np.ndarray, c: np.ndarray, r: np.ndarray, sp: np.ndarray,
    kind: int, ticks: int, period: float, substeps: int, method: int, turns: float, position: bool, lim: np.ndarray,
    m: np.ndarray, keep: np.ndarray, kept: bool, ctx: tuple,
) -> None:  # fmt: skip
    """Fly one trial and write its metrics into ``m`` (:func:`_fly`): any controller, integrator and step count."""
    _fly(x0, v, a, vm, c, r, sp, kind, ticks, period, substeps, method, turns, position, lim, m, keep, kept, ctx)


@jit
def run_trial_paper(
    x0: np.ndarray, v: np.ndarray, a: np.ndarray, vm: np.ndarray, c: np.ndarray, r: np.ndarray, sp: np.ndarray,
    ticks: int, period: float, method: int, turns: float, position: bool, lim: np.ndarray, m: np.ndarray,
    keep: np.ndarray, kept: bool, ctx: tuple,
) -> None:  # fmt: skip
    """:func:`run_trial` with the paper's controller and step count compiled in: the backstepping, one step of the
    plant per tick (see :func:`run_chunk`)."""
    _fly(x0, v, a, vm, c, r, sp, BACKSTEPPING, ticks, period, 1, method, turns, position, lim, m, keep, kept, ctx)


def context(cm0: np.ndarray, sp_ticks: np.ndarray) -> tuple:
    """The arrays a chunk's trials are flown in, one after the other (:func:`_fly`): the vehicle's
    (:class:`groundstation.vehicle.Vehicle`'s, in calm air and on the true state), ``cm0`` the commander as it
    starts (its settings), ``sp_ticks`` the ticks the setpoint is sent at (``quadsitl fly``'s grid)."""
    air0, rng0 = air_arrays(WindParams())
    pio = np.zeros(plant_tick.IO_SIZE, dtype=np.int64)
    return (np.zeros(WORK_SIZE), rng0.copy(), pio,
            np.zeros(hil.DATAGRAM_MAX, dtype=np.uint8), np.zeros(codec.DECODED_SIZE), np.zeros(len(cm0)),
            np.zeros(MEM_SIZE), np.zeros(codec.DECODED_SIZE), np.zeros(codec.FRAME_MAX, dtype=np.uint8),
            np.asarray(cm0, dtype=np.float64), air0, rng0, (),
            np.asarray(sp_ticks, dtype=np.int64), np.zeros((len(sp_ticks), SP_FIELDS)),
            np.zeros(1, dtype=np.int64), plugin.no_plug())  # fmt: skip


def run_chunk(
    x0: np.ndarray, v: np.ndarray, a: np.ndarray, vm: np.ndarray, c: np.ndarray, r: np.ndarray, sp: np.ndarray,
    kind: int, ticks: int, period: float, substeps: int, method: int, turns: np.ndarray, position: bool,
    lim: np.ndarray, m: np.ndarray, slots: np.ndarray, keep: np.ndarray, ctx: tuple,
) -> None:  # fmt: skip
    """Fly each trial i of a chunk (row i of every per-trial array), one after the other: metrics into m[i]; a
    trial with slots[i] ≥ 0 writes its trajectory into keep[slots[i]]. ``position``: the setpoints are a position
    hold (:func:`_fly`).

    The paper's configuration (the backstepping, one step of the plant per tick) runs a version compiled for it
    (:func:`run_trial_paper`): with the controller and the step count known to the compiler, the tick is one
    straight pass. Each version is compiled the first time it is used."""
    if kind == BACKSTEPPING and substeps == 1:
        _chunk_paper(x0, v, a, vm, c, r, sp, ticks, period, method, turns, position, lim, m, slots, keep, ctx)
    else:
        _chunk(x0, v, a, vm, c, r, sp, kind, ticks, period, substeps, method, turns, position, lim, m, slots, keep,
               ctx)  # fmt: skip


@jit
def _chunk(
    x0: np.ndarray, v: np.ndarray, a: np.ndarray, vm: np.ndarray, c: np.ndarray, r: np.ndarray, sp: np.ndarray,
    kind: int, ticks: int, period: float, substeps: int, method: int, turns: np.ndarray, position: bool,
    lim: np.ndarray, m: np.ndarray, slots: np.ndarray, keep: np.ndarray, ctx: tuple,
) -> None:  # fmt: skip
    for i in range(x0.shape[0]):
        slot = slots[i]
        run_trial(x0[i], v[i], a[i], vm[i], c[i], r[i], sp[i], kind, ticks, period, substeps, method, turns[i],
                  position, lim, m[i], keep[max(slot, 0)], slot >= 0, ctx)  # fmt: skip


@jit
def _chunk_paper(
    x0: np.ndarray, v: np.ndarray, a: np.ndarray, vm: np.ndarray, c: np.ndarray, r: np.ndarray, sp: np.ndarray,
    ticks: int, period: float, method: int, turns: np.ndarray, position: bool, lim: np.ndarray, m: np.ndarray,
    slots: np.ndarray, keep: np.ndarray, ctx: tuple,
) -> None:  # fmt: skip
    for i in range(x0.shape[0]):
        slot = slots[i]
        run_trial_paper(x0[i], v[i], a[i], vm[i], c[i], r[i], sp[i], ticks, period, method, turns[i], position, lim,
                        m[i], keep[max(slot, 0)], slot >= 0, ctx)  # fmt: skip
