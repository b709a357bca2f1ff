"""The vehicle, composed once: one control tick of the closed loop, and the loop that ``quadsitl sim`` runs over it.

A tick k, compiled (:func:`vehicle_tick`), is what the three processes do between them in a lockstep run:

1. what the autopilot sees of the state x(k): the state itself, or in sensor mode the plant's sensor datagram
   (:func:`sitl.tick.encode_tick`, the plant process's encoder) decoded (:func:`quadsitl.hil.decode_sensors`) and
   estimated (:func:`autopilot.tick.estimate`), as the autopilot process decodes and estimates it; and the battery's
   report, in the wire's units (:func:`quadsitl.hil.battery_fields`);
2. the autopilot's tick (:func:`autopilot.tick.autopilot_step`): commander and auto modes, position, altitude and
   attitude control with their limits and integrators, allocation;
3. one control period of the plant (:func:`sitl.plant.step_arrays`): air, actuators and dynamics, ground.

The offboard setpoints the ground station would send (:class:`Setpoints`) take effect at the tick they are made
for, as ``quadsitl fly``'s autopilot flies them (:mod:`autopilot.offboard_lockstep`). :func:`fly_ticks` is the loop:
the setpoints due, the divergence check (:func:`sitl.plant.inside`), the tick, its row of the result. Nothing of the
vehicle is written here: the equations, the commander and the plant are the processes' own functions. What
differs from ``quadsitl fly`` is the wire alone: ``fly``'s processes carry the state, the setpoints and the motor
commands in MAVLink's float32 fields, so ``fly`` equals ``sim`` to float32.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable
from dataclasses import dataclass

import numpy as np
from numba import types
from numba.extending import overload

from autopilot import commander as cmd
from autopilot import plugin, setpoints
from autopilot.commander import Commander, CommanderSettings
from autopilot.control_params import MEM_FORCES, MEM_SIZE, MEM_U
from autopilot.estimator import REPORT_SIZE, Estimator, report_of
from autopilot.params import commander_settings
from autopilot.stream_frames import reference_shown
from autopilot.tick import autopilot_step, estimate
from groundstation.setpoint_grid import POSITION_VELOCITY_YAW
from quadsitl import codec, hil
from quadsitl.config import DEFAULT_LIMITS, SENSOR_GROUND_S, PositionParams, Preset
from quadsitl.frames import PX4_HOME
from quadsitl.jit import DISABLED, borrowed, jit
from quadsitl.state import Reference, VehicleState
from sitl import tick as plant_tick
from sitl.plant import (
    OUT_CHARGE,
    OUT_CURRENT,
    OUT_ENERGY,
    OUT_REMAINING,
    OUT_VOLTAGE,
    W_AIR,
    W_COMMANDED,
    W_MOTORS,
    W_OUT,
    W_X,
    Plant,
    inside,
    step_arrays,
)

# The commander's offboard setpoint fields, in its state array's order: what a setpoint sets (cmd.SP_X..SP_THRUST).
SP_FIELDS = cmd.SETPOINT_END - cmd.SETPOINT_FIRST
# A row of the result (fly_ticks): the truth x(k) (12), what the autopilot flew on (12), the reference shown
# (altitude, roll, pitch, yaw, x, y: autopilot.stream_frames.reference_shown), u1..u4, the commanded forces f1..f4
# [N], the battery as the autopilot knows it (V, A, mAh, J, share left: the status record's; NaN without one). On
# sensors the row goes on with the estimator's report (autopilot.estimator.report: the telemetry's sensors record).
R_STATE, R_SEEN, R_REF, R_XY_REF, R_INPUTS, R_FORCES, R_BATTERY, ROW_SIZE = 0, 12, 24, 28, 30, 34, 38, 43
R_SENSORS, SENSING_ROW_SIZE = ROW_SIZE, ROW_SIZE + REPORT_SIZE


@jit(inline=True)
def _look(x: np.ndarray, st: np.ndarray) -> None:
    for i in range(12):
        st[i] = x[i]


@jit(inline=True)
def _sense(k: int, period: float, x: np.ndarray, out: np.ndarray, air: np.ndarray, st: np.ndarray, sens: tuple,
           est: tuple, pio: np.ndarray, datagram: np.ndarray, home: tuple, truth: np.ndarray,
           frame: np.ndarray) -> None:  # fmt: skip
    plant_tick.encode_tick(datagram, pio, x, out, air, sens, k, period)
    t, flags, _ = hil.decode_sensors(datagram, pio[plant_tick.TX_LEN], home, est[0], truth, frame)
    estimate(flags, t, period, est, st)


def observe(k: int, period: float, x: np.ndarray, out: np.ndarray, air: np.ndarray, st: np.ndarray, sens: tuple,
            est: tuple, pio: np.ndarray, datagram: np.ndarray, home: tuple, truth: np.ndarray,
            frame: np.ndarray) -> None:  # fmt: skip
    """What the autopilot sees of x(k), into ``st``: with the estimator's arrays (``est``), the plant's sensor
    datagram of tick k (:func:`sitl.tick.encode_tick`, the plant process's encoder) decoded
    (:func:`quadsitl.hil.decode_sensors`) and estimated (:func:`autopilot.tick.estimate`), as the autopilot process
    does; with none (``est`` = ()), the state itself (the body rates, which only telemetry shows, are not computed).
    Compiled, the choice is made by ``est``'s type, so a loop on the true state never compiles the sensors' path."""
    if len(est) == 0:
        _look(x, st)
    else:
        _sense(k, period, x, out, air, st, sens, est, pio, datagram, home, truth, frame)


if not DISABLED:

    @overload(observe, inline="always")
    def _observe(k, period, x, out, air, st, sens, est, pio, datagram, home, truth, frame):
        if isinstance(est, types.BaseTuple) and len(est) == 0:
            return lambda k, period, x, out, air, st, sens, est, pio, datagram, home, truth, frame: _look(x, st)
        return lambda k, period, x, out, air, st, sens, est, pio, datagram, home, truth, frame: _sense(
            k, period, x, out, air, st, sens, est, pio, datagram, home, truth, frame
        )


@jit(inline=True)
def vehicle_tick(k: int, kind: int, period: float, substeps: int, method: int, plant: tuple,
                 sens: tuple, ap: tuple, est: tuple, home: tuple, f_min: float, f_max: float) -> int:  # fmt: skip
    """Tick ``k`` of the vehicle (the module's steps 1–3): x(k) in the plant's work array → x(k+1). Returns the
    commander's event. ``plant`` = (work, vehicle, actuators, air_rng, io, datagram): :class:`sitl.plant.Plant`'s
    arrays (the parameters as arrays or, for a compiled loop that reads them every tick, tuples), the plant tick's
    bookkeeping (:mod:`sitl.tick`) and the sensor datagram's buffer; ``sens`` the sensors' arrays;
    ``ap`` = (st, cm, mem, v, c, truth, frame, plug): the state seen (:data:`quadsitl.codec.DECODED_SIZE`), the
    commander, the controller's memory, the autopilot's vehicle model and control parameters, the decoder's scratch,
    and a plugged controller (:meth:`autopilot.plugin.Plugged.plug`; a built-in's :func:`autopilot.plugin.no_plug`);
    ``est`` the estimator's arrays; ``home`` the local origin (lat, lon [deg], alt [m AMSL])."""
    w, pv, pa, air_rng, pio, datagram = plant
    st, cm, mem, v, c, truth, frame, plug = ap
    x, out, air = w[W_X:W_MOTORS], w[W_OUT:W_AIR], w[W_AIR:]
    observe(k, period, x, out, air, st, sens, est, pio, datagram, home, truth, frame)
    if out[OUT_REMAINING] >= 0.0:  # the battery's report, as the wire carries it (an ideal supply: none)
        cmd.battery_seen(cm, hil.battery_values(hil.battery_fields(out[OUT_VOLTAGE], out[OUT_CURRENT],
                                                                   out[OUT_CHARGE], out[OUT_ENERGY],
                                                                   out[OUT_REMAINING])))  # fmt: skip
    forces, event = autopilot_step(kind, plug, st, cm, mem, v, c, f_min, f_max, k, k * period)
    commanded = w[W_COMMANDED:W_OUT]
    for i in range(4):
        commanded[i] = forces[i]
    step_arrays(x, w[W_MOTORS:W_COMMANDED], commanded, out, pv, pa, air, air_rng, period, substeps, method,
                math.nan)  # fmt: skip
    return event


@jit(inline=True)
def setpoints_due(k: int, cm: np.ndarray, sp_ticks: np.ndarray, sp_values: np.ndarray, sp_next: np.ndarray) -> None:
    """The offboard setpoints made for tick ``k`` or before and not yet flown (``sp_next``[0] the first) to the
    commander, as the autopilot's handlers set them (cmd.SP_X..SP_THRUST), stamped with the commander's time."""
    while sp_next[0] < sp_ticks.shape[0] and sp_ticks[sp_next[0]] <= k:
        for i in range(SP_FIELDS):
            cm[cmd.SP_X + i] = sp_values[sp_next[0], i]
        cm[cmd.LAST_SP_TIME] = cm[cmd.NOW]
        sp_next[0] += 1


@jit(inline=True)
def see(cm: np.ndarray, x: np.ndarray, period: float) -> None:
    """The commander sees the state ``x`` (12, VehicleState order) at tick −1, before the first: as the processes'
    commander has seen the vehicle on the ground, the tick before it is armed, so the first tick flown is a period
    after it (an auto mode's reference moves from the first tick on, as in ``quadsitl fly``)."""
    # (tick −1 as an int64, not a constant: numba compiles a function called with a constant argument again)
    cmd.update(cm, np.int64(-1), -period, x[0], x[1], -x[2], x[3], x[4], -x[5], x[8])


@jit(inline=True)
def arm_offboard(k: int, cm: np.ndarray, x: np.ndarray, period: float, sp_ticks: np.ndarray, sp_values: np.ndarray,
                 sp_next: np.ndarray) -> None:  # fmt: skip
    """Armed in offboard at tick ``k`` as ``quadsitl fly``'s ground station arms the vehicle on its ground hold:
    the setpoints due first (the stream is then fresh, so neither the switch nor the arming can be refused), then
    offboard, then armed (:meth:`autopilot.commander.Commander.set_mode` and :meth:`~.Commander.arm` change the
    state so, after their checks). Before the first tick (k = 0) the commander first sees the state ``x``
    (:func:`see`)."""
    if k == 0:
        see(cm, x, period)
    setpoints_due(k, cm, sp_ticks, sp_values, sp_next)
    cmd.enter(cm, cmd.OFFBOARD)
    cmd.arm(cm)


@jit(inline=True)
def record(rows: np.ndarray, j: int, s: tuple, st: np.ndarray, cm: np.ndarray, mem: np.ndarray) -> None:
    """Row ``j`` of ``rows`` (R_*) for the tick just flown: the truth ``s`` = x(k) (12) it started from, what the
    autopilot flew on, the reference shown (:func:`autopilot.stream_frames.reference_shown`), u1..u4, the forces and the
    battery."""
    for i in range(12):
        rows[j, R_STATE + i] = s[i]
        rows[j, R_SEEN + i] = st[i]
    shown = reference_shown(cm, mem)
    for i in range(4):
        rows[j, R_REF + i] = shown[i]
        rows[j, R_INPUTS + i] = mem[MEM_U + i]
        rows[j, R_FORCES + i] = mem[MEM_FORCES + i]
    rows[j, R_XY_REF], rows[j, R_XY_REF + 1] = shown[4], shown[5]
    for i in range(5):
        rows[j, R_BATTERY + i] = cm[cmd.BAT_V + i]


@jit(inline=True)
def _report(rows: np.ndarray, j: int, est: tuple) -> None:
    values = report_of(est)
    for i in range(REPORT_SIZE):
        rows[j, R_SENSORS + i] = values[i]


def record_sensors(rows: np.ndarray, j: int, est: tuple) -> None:
    """On sensors (``est``: the estimator's arrays), row ``j``'s R_SENSORS columns: the estimator's report after the
    tick; on the true state (``est`` = ()) nothing, and compiled, nothing is compiled for it."""
    if len(est):
        _report(rows, j, est)


if not DISABLED:

    @overload(record_sensors, inline="always")
    def _record_sensors(rows, j, est):
        if isinstance(est, types.BaseTuple) and len(est) == 0:
            return lambda rows, j, est: None
        return lambda rows, j, est: _report(rows, j, est)


@jit
def fly_ticks(first: int, n: int, recording: bool, kind: int, period: float, substeps: int, method: int,
              plant: tuple, sens: tuple, ap: tuple, est: tuple, home: tuple, f_min: float, f_max: float,
              sp_ticks: np.ndarray, sp_values: np.ndarray, sp_next: np.ndarray, rows: np.ndarray) -> int:  # fmt: skip
    """Ticks ``first`` .. ``first`` + n − 1 of the vehicle: at each, the offboard setpoints made for it or before
    (``sp_ticks``, ``sp_values``: :class:`Setpoints`; ``sp_next``[0] the first not yet flown) go to the commander, as
    the autopilot's handlers set them (cmd.SP_X..SP_YAW_RATE, stamped with the commander's time), then the tick
    (:func:`vehicle_tick`). With ``recording``, a state x(k) outside the bounds (:func:`sitl.plant.inside`) ends the
    loop before its tick, and each tick's row goes to rows[k − first] (R_*; on sensors SENSING_ROW_SIZE wide).
    Returns the number of ticks flown (n unless the state diverged)."""
    plant, sens, ap, est, sp_ticks, sp_values, sp_next, rows = borrowed(
        (plant, sens, ap, est, sp_ticks, sp_values, sp_next, rows)
    )  # quadsitl.jit.borrowed
    w, cm = plant[0], ap[1]
    st, mem = ap[0], ap[2]
    for j in range(n):
        k = first + j
        x = w[W_X:W_MOTORS]
        s = (x[0], x[1], x[2], x[3], x[4], x[5], x[6], x[7], x[8], x[9], x[10], x[11])
        if recording and not inside(s, DEFAULT_LIMITS):
            return j
        setpoints_due(k, cm, sp_ticks, sp_values, sp_next)
        vehicle_tick(k, kind, period, substeps, method, plant, sens, ap, est, home, f_min, f_max)
        if recording:
            record(rows, j, s, st, cm, mem)
            record_sensors(rows, j, est)
    return n


def frame_of(preset: Preset, home: tuple[float, float, float], commander: Commander, yaw: float) -> setpoints.Frame:
    """Where the autopilot measures setpoints from, and the limits they must keep, as the autopilot process's
    (:meth:`autopilot.process.Autopilot.frame`): the local origin ``home``, the commander's home and settings, the
    vehicle's ``yaw`` [rad] now."""
    st = commander.settings
    return setpoints.Frame(home, commander.home, yaw, st.altitude_max, st.max_distance, st.xy_vel_max, st.z_vel_up,
                           st.z_vel_dn, -1.0 if preset.actuators.reversible else 0.0)  # fmt: skip


def commander_for(position: PositionParams) -> Commander:
    """The autopilot's commander, with the limits its auto modes share with the position loop (``position``), as
    the autopilot process starts it."""
    return Commander(commander_settings(position, CommanderSettings()))


@dataclass
class Setpoints:
    """Offboard setpoints as the commander holds them: ticks[i] the tick setpoint i is flown from (ascending),
    values[i] the commander's fields it sets (cmd.SP_X..SP_THRUST, NaN where not given)."""

    ticks: np.ndarray  # (N,) int64
    values: np.ndarray  # (N, SP_FIELDS)

    @classmethod
    def of(cls, moments: Iterable[tuple[int, object]], frame: setpoints.Frame) -> Setpoints:
        """From (tick, setpoint) pairs in order: a :class:`quadsitl.state.Reference` is an attitude setpoint and an
        altitude (as ``quadsitl fly``'s ground station sends it: SET_ATTITUDE_TARGET and a z-only position target);
        a :class:`groundstation.trajectories.PositionSetpoint` a position, velocity and yaw target in LOCAL_NED
        (type_mask 2496), read by the autopilot's parser (:func:`autopilot.setpoints.position_target`, with the
        limits of ``frame``). Each goes to a commander through its handlers, as in the autopilot process. A
        setpoint the autopilot would refuse raises :class:`autopilot.setpoints.SetpointError`, naming its tick."""
        scratch = Commander()
        ticks, values = [], []
        nan = math.nan
        previous, row = None, None
        for tick, sp in moments:
            if row is not None and sp == previous:  # the same setpoint parses the same: a hold is parsed once
                ticks.append(tick)
                values.append(row)
                continue
            previous = sp
            if isinstance(sp, Reference):
                scratch.on_attitude_setpoint(sp.roll, sp.pitch, sp.yaw)
                scratch.on_altitude_setpoint(sp.altitude)
            else:
                try:
                    groups = setpoints.position_target(setpoints.LOCAL_NED, POSITION_VELOCITY_YAW,
                                                       (sp.x, sp.y, -sp.altitude), (sp.vx, sp.vy, -sp.climb),
                                                       (nan, nan, nan), sp.yaw, nan, frame)  # fmt: skip
                except setpoints.SetpointError as exc:
                    raise setpoints.SetpointError(f"the setpoint for tick {tick}: {exc}") from None
                scratch.on_position_setpoint(*groups)
            row = scratch.cm[cmd.SETPOINT_FIRST : cmd.SETPOINT_END].copy()
            ticks.append(tick)
            values.append(row)
        return cls(np.array(ticks, dtype=np.int64), np.array(values).reshape(-1, SP_FIELDS))


PROGRESS_TICKS = 500  # the loop returns to Python (progress, nothing else) every this many ticks


class Vehicle:
    """One vehicle of a preset, composed once: the plant (:class:`sitl.plant.Plant`, with its sensors and air) and
    the autopilot's arrays (commander, controller memory, model, gains, estimator), for :func:`fly_ticks`.

    ``kind``: the controller's code (:data:`autopilot.control_params.KINDS`, or PLUGGED with its ``plug``:
    :meth:`autopilot.plugin.Plugged.plug`); ``v``, ``c``: the autopilot's model and control arrays (a controller's,
    :func:`autopilot.factory.make_controller`); ``integrator``, ``substeps``: the plant's integration (default: the
    preset's)."""

    def __init__(self, preset: Preset, kind: int, v: np.ndarray, c: np.ndarray, integrator: str | None = None,
                 substeps: int | None = None, home: tuple[float, float, float] = PX4_HOME,
                 plug: tuple | None = None) -> None:  # fmt: skip
        self.preset, self.kind, self.home = preset, kind, home
        self.period = preset.sim.period
        self.plant = Plant(preset, integrator=integrator, substeps=substeps, home=home)
        self.sensing = preset.sensors is not None
        p = self.plant
        pio = np.zeros(plant_tick.IO_SIZE, dtype=np.int64)
        pio[plant_tick.SENSING] = plant_tick.SENSORS_ONLY if self.sensing else 0  # the rows take the truth from x
        self.plant_arrays = (p.work, p.v, p.a, p.air_rng, pio, np.zeros(hil.DATAGRAM_MAX, dtype=np.uint8))
        self.commander = commander_for(preset.position)
        self.st = np.zeros(codec.DECODED_SIZE)
        self.mem = np.zeros(MEM_SIZE)
        self.ap = (self.st, self.commander.cm, self.mem, np.asarray(v, dtype=float), np.asarray(c, dtype=float),
                   np.zeros(codec.DECODED_SIZE), np.zeros(codec.FRAME_MAX, dtype=np.uint8),
                   plug if plug is not None else plugin.no_plug())  # fmt: skip
        s = preset.sensors  # in sensor mode the autopilot flies on its estimator's estimate (observe)
        self.estimator = None if s is None else Estimator.for_sensors(s, self.period, preset.vehicle.gravity)
        self.est = () if self.estimator is None else self.estimator.arrays
        a = preset.actuators
        self.f_min, self.f_max = a.min_thrust, a.max_thrust
        self.tick = 0  # the next tick to fly
        self.sp = Setpoints(np.zeros(0, dtype=np.int64), np.zeros((0, SP_FIELDS)))
        self.sp_next = np.zeros(1, dtype=np.int64)

    def frame(self) -> setpoints.Frame:
        """Where the autopilot measures setpoints from, and the limits they must keep (:func:`frame_of`)."""
        return frame_of(self.preset, self.home, self.commander, float(self.st[8]))

    @property
    def state(self) -> VehicleState:
        """The truth x(k) before the next tick."""
        return self.plant.state

    def _rows(self, n: int) -> np.ndarray:
        """Room for ``n`` rows of the result (R_*; on sensors with the estimator's report)."""
        return np.empty((n, SENSING_ROW_SIZE if self.sensing else ROW_SIZE))

    def _ticks(self, n: int, record: bool, rows: np.ndarray) -> int:
        """:func:`fly_ticks` on this vehicle's arrays from its next tick: the ticks flown."""
        return fly_ticks(self.tick, n, record, self.kind, self.period, self.plant.substeps, self.plant.method,
                         self.plant_arrays, self.plant.sensors.arrays, self.ap, self.est, self.home, self.f_min,
                         self.f_max, self.sp.ticks, self.sp.values, self.sp_next, rows)  # fmt: skip

    def compile(self) -> None:
        """The loop (:func:`fly_ticks`) for this vehicle's types compiled, or loaded from numba's cache, now: it flies
        no tick."""
        self._ticks(0, False, self._rows(0))

    def fly(self, n: int, record: bool = True, progress: Callable[[int], None] | None = None,
            after_tick: Callable[[], bool] | None = None) -> tuple[np.ndarray, int]:  # fmt: skip
        """Fly the next ``n`` ticks: (their rows, R_*; the ticks flown, fewer than n when the state diverged: then
        ``state`` is the state that left its bounds, or when ``after_tick`` said stop). ``progress`` is called with
        the ticks flown so far every PROGRESS_TICKS; it only observes. ``after_tick``, when given, is called after
        every tick, as the autopilot process runs its mission executor after its compiled tick: False stops."""
        rows = self._rows(n if record else 0)
        done = 0
        while done < n:
            if progress is not None and done % PROGRESS_TICKS == 0:
                progress(done)
            m = 1 if after_tick is not None else min(PROGRESS_TICKS, n - done)
            chunk = rows[done : done + m] if record else rows
            flown = self._ticks(m, record, chunk)
            self.tick += flown
            done += flown
            if flown < m or (after_tick is not None and not after_tick()):
                break
        if progress is not None:
            progress(done)
        return rows[:done], done

    def seen(self) -> None:
        """Before the first tick, the commander has seen nothing: give it the plant's initial state (as the processes'
        commander has seen the vehicle on the ground before it is armed)."""
        if self.tick == 0:
            see(self.commander.cm, self.plant.x, self.period)

    def start_offboard(self, sp: Setpoints) -> None:
        """Arm in offboard on the setpoints ``sp`` (those for ticks up to now go to the commander at once), as
        ``quadsitl fly``'s ground station does once the vehicle is on its ground hold (:func:`arm_offboard`)."""
        self.sp, self.sp_next[0] = sp, 0
        arm_offboard(self.tick, self.commander.cm, self.plant.x, self.period, sp.ticks, sp.values, self.sp_next)


def ground_ticks(preset: Preset) -> int:
    """The ticks a flight on sensors spends on the ground first, motors off: ``quadsitl fly``'s plant holds its
    clock at SENSOR_GROUND_S until the vehicle arms, and that tick is answered disarmed; the flight's first tick
    is the one after."""
    return round(SENSOR_GROUND_S / preset.sim.period) + 1 if preset.sensors is not None else 0
