"""The autopilot's work for one control tick, compiled (:mod:`quadsitl.jit`): the control law, the
allocation, the answer to the plant and the telemetry records, in one call from the process's loop.

The process (:mod:`autopilot.process`) decodes the state (:func:`quadsitl.codec.decode_state`), asks the
commander for the reference, then calls :func:`control_tick`; everything else it does per tick is a
few comparisons. The arrays it passes:

- ``st``: the decoded state (:data:`quadsitl.codec.DECODED_SIZE`: the VehicleState fields, then p, q, r);
- ``mem``: the controller's memory and outputs (:mod:`autopilot.control_params`: MEM_*);
- ``v``, ``c``: the autopilot's vehicle model and control parameters (:mod:`quadsitl.param_arrays`,
  :mod:`autopilot.control_params`);
- ``tx``: the buffer the answer frame is written to; ``records``: the telemetry batch (:class:`Batch`).
"""

from __future__ import annotations

import math

import numpy as np

from autopilot import commander, manual, plugin, stream_frames
from autopilot import estimator as ekf
from autopilot.backstepping import Errors, altitude_law, attitude_law, thrust
from autopilot.commander import (
    ARMED,
    EVENT_CONTROLLER_FAILED,
    EVENT_NONE,
    FAILSAFE,
    MODE,
    OFFBOARD_TICK,
    REF_ALT,
    REF_AY,
    REF_CLIMB,
    REF_CLIMB_ACC,
    REF_LIMITED,
    REF_PITCH,
    REF_ROLL,
    REF_THROTTLE,
    REF_THRUST,
    REF_X,
    REF_YAW,
    REF_YAW_RATE,
    TOUCHDOWN_ALT,
    TOUCHDOWN_CLIMB,
)
from autopilot.control_params import (
    BACKSTEPPING,
    MEM_ATTITUDE_REF,
    MEM_ERRORS,
    MEM_ERRORS_XY,
    MEM_FORCES,
    MEM_OMEGA_R,
    MEM_PLUG_FAILED,
    MEM_PLUG_FAILED_TICK,
    MEM_SIZE,
    MEM_U,
    MEM_ZETA,
    PD,
    PERIOD,
    PLUGGED,
    POSITION,
    TAN_TILT_AIR,
    THRUST_MAX,
    THRUST_MIN,
    VELOCITY,
    XY_VEL_MAX,
    Z_VEL_DN,
    Z_VEL_UP,
)
from autopilot.pd import pd_attitude, pd_thrust, pd_vertical
from autopilot.position import channel_mode, controls_horizontal, horizontal, or_zero
from quadsitl import telemetry
from quadsitl.codec import (
    BODY_RATES,
    HEADER_SIZE,
    MAVLINK2_STX,
    NOT_THIS_FRAME,
    check_frame,
    decode_state,
    encode_actuators,
    tick_of,
)
from quadsitl.compiled_frames import altitude, climb_rate, euler_rates_to_body_rates
from quadsitl.hil import (
    BATTERY_CRC_EXTRA,
    BATTERY_ID,
    BATTERY_NEW,
    BATTERY_SIZE,
    Z_BATTERY,
    Z_GYRO,
    decode_battery,
    decode_sensors,
)
from quadsitl.jit import borrowed, copy_into, jit
from quadsitl.mixer import Forces, allocate
from quadsitl.param_arrays import ARM, D_OVER_B, MASS, G
from quadsitl.rawbytes import put
from quadsitl.state import Inputs
from quadsitl.telemetry import (  # where a record's fields are [bytes]: globals, constants to the compiler
    ACTUATORS_AT_U,
    AT_T,
    AT_TICK,
    FLOAT64,
    SENSORS_AT_VALUES,
    SETPOINT_AT_REF,
    STATE_AT_P,
    STATE_AT_X,
    STATUS_AT_ARMED,
    STATUS_AT_BATTERY,
    STATUS_AT_FAILSAFE,
    STATUS_AT_MODE,
    STATUS_AT_OFFBOARD_TICK,
)

_ZERO_ERRORS = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
GROUND_IDLE_MARGIN = 1e-6  # [m]: a reference this little above the vehicle resting on the ground asks for no climb

# Telemetry record sizes [bytes] and where each stream's records start in a Batch row (quadsitl.telemetry).
STATE_SIZE, SETPOINT_SIZE, ACTUATORS_SIZE, STATUS_SIZE = (telemetry.STREAMS[s].size for s in telemetry.STREAMS)
assert tuple(telemetry.STREAMS) == ("state", "setpoint", "actuators", "status")
TRUTH_AT = STATE_SIZE + SETPOINT_SIZE + ACTUATORS_SIZE + STATUS_SIZE  # × capacity: the truth's region, after them
assert telemetry.TRUTH_RECORD is telemetry.STREAMS["state"]  # the truth's record: the state's offsets (STATE_AT_*)
SENSORS_AT = TRUTH_AT + STATE_SIZE  # × capacity: the sensors' region, after the truth's
SENSORS_SIZE = telemetry.SENSORS_RECORD.size
assert telemetry.SENSING == ("truth", "sensors") and len(telemetry.SENSORS_FIELDS) == 2 + ekf.REPORT_SIZE


@jit(inline=True)
def fly(
    kind: int, x: tuple, cm: np.ndarray, mem: np.ndarray, v: np.ndarray, c: np.ndarray
) -> tuple[Inputs, Errors, float]:
    """The flight controller's law for the commander's reference (cm[REF_*]): the altitude channel (position or
    climb rate), the horizontal loop (:mod:`autopilot.position`) when the reference controls x or y (else the
    attitude reference), then roll, pitch and yaw; ``kind`` picks the backstepping or the PD for the altitude
    and attitude channels. Returns (u1..u4, e1..e8, Ωr) and keeps the integrators, e9..e12 and the roll and
    pitch references flown in ``mem``.  With an altitude and attitude reference, the
    backstepping's output is :func:`autopilot.backstepping.backstepping`'s to the bit."""
    inf = math.inf
    limited = cm[REF_LIMITED] != 0.0
    lo, hi = (-c[Z_VEL_DN], c[Z_VEL_UP]) if limited else (-inf, inf)
    h, climb = altitude(x), climb_rate(x)
    h_ref, climb_ff, climb_acc = cm[REF_ALT], or_zero(cm[REF_CLIMB]), or_zero(cm[REF_CLIMB_ACC])
    alt_mode = channel_mode(h_ref, cm[REF_CLIMB])
    yaw_mode = VELOCITY if math.isnan(cm[REF_YAW]) else POSITION
    yaw_ref, yaw_rate = cm[REF_YAW], or_zero(cm[REF_YAW_RATE])
    zeta_h = mem[MEM_ZETA]
    if kind == PD:
        a_v = pd_vertical(h, climb, h_ref, climb_ff, climb_acc, alt_mode, v, c)
        b, e1, e2 = 0.0, 0.0, 0.0
    else:
        b, e1, e2, zeta_h = altitude_law(h, climb, h_ref, climb_ff, climb_acc, zeta_h, alt_mode, lo, hi, v, c)
        a_v = b / c[PERIOD]
    if not math.isnan(cm[REF_THRUST]):  # the thrust is given (autopilot_step flies it): no altitude channel
        a_v, e1, e2, zeta_h = 0.0, 0.0, 0.0, mem[MEM_ZETA]
    sp = (cm[REF_X], cm[REF_X + 1], cm[REF_X + 2], cm[REF_X + 3], cm[REF_X + 4], cm[REF_AY])
    if not controls_horizontal(sp):
        roll_ref, pitch_ref = cm[REF_ROLL], cm[REF_PITCH]
        exy = (0.0, 0.0, 0.0, 0.0)
        mem[MEM_ATTITUDE_REF], mem[MEM_ATTITUDE_REF + 1] = math.nan, math.nan
    else:
        roll_ref, pitch_ref, exy, zx, zy = horizontal(x, sp, mem[MEM_ZETA + 1], mem[MEM_ZETA + 2], a_v, v, c)
        mem[MEM_ZETA + 1], mem[MEM_ZETA + 2] = zx, zy
        mem[MEM_ATTITUDE_REF], mem[MEM_ATTITUDE_REF + 1] = roll_ref, pitch_ref
    for i in range(4):
        mem[MEM_ERRORS_XY + i] = exy[i]
    last = (mem[MEM_U], mem[MEM_U + 1], mem[MEM_U + 2], mem[MEM_U + 3])
    if kind == PD:
        u1 = pd_thrust(a_v, x[6], x[7], v, c)
        u2, u3, u4 = pd_attitude(x, roll_ref, pitch_ref, yaw_ref, yaw_rate, yaw_mode, v, c)
        return Inputs(u1, u2, u3, u4), _ZERO_ERRORS, 0.0
    u1 = thrust(b, x[6], x[7], v, c)
    if c[THRUST_MIN] < u1 < c[THRUST_MAX]:  # the altitude integrator holds while the thrust saturates
        mem[MEM_ZETA] = zeta_h
    u2, u3, u4, (e3, e4, e5, e6, e7, e8), omega_r = attitude_law(x, roll_ref, pitch_ref, yaw_ref, yaw_rate,
                                                                  yaw_mode, last, v, c)  # fmt: skip
    return Inputs(u1, u2, u3, u4), (e1, e2, e3, e4, e5, e6, e7, e8), omega_r


@jit
def _put(buf: np.ndarray, at: int, value: float) -> None:
    put(buf, at, np.float64(value))


@jit
def _put_int(buf: np.ndarray, at: int, value: int) -> None:
    put(buf, at, np.int64(value))


# The tick's integer bookkeeping (``io``, int64): the stamp of the last state flown, the answer's length, the
# plant link's sequence number, the telemetry rows batched and the batch's capacity, the first tick at which a
# telemetry message may be due, the last tick, the commander's event, and the autopilot's MAVLink ids.
# In sensor mode also: the sensor samples dropped for a non-finite value, and the estimator's status (ESTIMATE_*).
# GCS_SEQ: the ground-station links' MAVLink sequence number, shared by the frames built here
# (autopilot.stream_frames) and those pymavlink packs.
(LAST_USEC, TX_LEN, SEQ, ROWS, CAPACITY, NEXT_STREAM_TICK, TICK, EVENT, SYSTEM, COMPONENT, DROPPED, ESTIMATE, GCS_SEQ,
 IO_SIZE) = range(14)  # fmt: skip
# The estimator's status (io[ESTIMATE], bits): aligned, diverged, and each sensor lost (estimator.LOST_* << 2).
ESTIMATE_ALIGNED, ESTIMATE_DIVERGED, ESTIMATE_GPS_LOST, ESTIMATE_BARO_LOST, ESTIMATE_MAG_LOST = 1, 2, 4, 8, 16
ESTIMATE_IMU_LOST = 32
# What autopilot_tick reports (bits): an answer is in tx; telemetry messages are due; the commander has an
# event (io[EVENT]); the batch is full; the datagram is no per-tick frame (pymavlink's to parse); it was
# corrupt or carried a state never to fly; (sensor mode) the estimator's status changed; telemetry frames built here
# wait in the links' datagrams (autopilot.stream_frames.StreamFrames) to be sent.
ANSWER, STREAM, EVENT_DUE, BATCH_FULL, NOT_MINE, REFUSED, ESTIMATOR_CHANGED, FRAMES = 1, 2, 4, 8, 16, 32, 64, 128


@jit(inline=True)
def plugged(plug: tuple, x: tuple, cm: np.ndarray, v: np.ndarray, c: np.ndarray, now: float) -> Inputs:
    """A plugged controller's command (:mod:`quadsitl.controller`) for the state ``x`` and the commander's reference,
    as the paper's inputs (u2, u3 = the roll and pitch torques / l). ``plug`` = (the compiled law, its buffer, where
    its memory starts: :meth:`autopilot.plugin.Plugged.plug`); the command starts NaN, so one not written is not
    finite."""
    entry, buf, _ = plug
    for i in range(12):
        buf[plugin.B_STATE + i] = x[i]
    p, q, r = euler_rates_to_body_rates(x[6], x[7], x[9], x[10], x[11])  # eq (1)
    buf[plugin.B_STATE + 12], buf[plugin.B_STATE + 13], buf[plugin.B_STATE + 14] = p, q, r
    for i in range(REF_YAW_RATE + 1 - REF_X):
        buf[plugin.B_SETPOINT + i] = cm[REF_X + i]
    limited = cm[REF_LIMITED] != 0.0
    limits = plugin.B_SETPOINT + REF_YAW_RATE + 1 - REF_X  # SP_SPEED_MAX..SP_TILT_MAX
    buf[limits] = c[XY_VEL_MAX] if limited else math.inf
    buf[limits + 1] = c[Z_VEL_UP] if limited else math.inf
    buf[limits + 2] = c[Z_VEL_DN] if limited else math.inf
    buf[limits + 3] = math.atan(c[TAN_TILT_AIR])
    for i in range(4):
        buf[plugin.B_COMMAND + i] = math.nan
    plugin.call_law(entry, buf, now, c[PERIOD])  # the model ``v`` is in the buffer since it was built
    arm = v[ARM]
    c0 = plugin.B_COMMAND
    return Inputs(buf[c0], buf[c0 + 1] / arm, buf[c0 + 2] / arm, buf[c0 + 3])


@jit(inline=True)
def climb_asked(cm: np.ndarray, h: float) -> bool:
    """Whether the reference asks a vehicle resting on the ground at altitude ``h`` [m] to leave it: a thrust given
    (flown as it is; STABILIZED's throttle stick above the centre), an altitude above it, or (no altitude) a climb
    rate, or else an acceleration, upward."""
    if not math.isnan(cm[REF_THROTTLE]):
        return cm[REF_THROTTLE] > 0.0
    if not math.isnan(cm[REF_THRUST]):
        return True
    if not math.isnan(cm[REF_ALT]):
        return cm[REF_ALT] > max(h, 0.0) + GROUND_IDLE_MARGIN
    if not math.isnan(cm[REF_CLIMB]):
        return cm[REF_CLIMB] > 0.0
    return cm[REF_CLIMB_ACC] > 0.0  # False for NaN too


@jit(inline=True)
def motors_working(forces: Forces, off: int) -> Forces:
    """The forces [N] the motors make of the allocation's ``forces``: none from a motor that is off (bit i of ``off``:
    motor i, a failure injected), as PX4's simulated outputs block a failed motor; the allocation does not know."""
    if off == 0:
        return forces
    return (0.0 if off & 1 else forces[0], 0.0 if off & 2 else forces[1], 0.0 if off & 4 else forces[2],
            0.0 if off & 8 else forces[3])  # fmt: skip


@jit(inline=True)
def autopilot_step(kind: int, plug: tuple, st: np.ndarray, cm: np.ndarray, mem: np.ndarray, v: np.ndarray,
                   c: np.ndarray, f_min: float, f_max: float, tick: int, now: float) -> tuple[Forces, int]:  # fmt: skip
    """The autopilot's per-tick work, composed once (every runtime calls it: the autopilot process through
    :func:`control_tick`, ``quadsitl sim`` and the batch engine through :mod:`groundstation.vehicle`): for the state
    ``st`` seen at ``tick`` (``now`` = its simulated time [s]), the commander and its auto modes (cm[REF_*]), when armed
    the law (:func:`fly`: position, altitude and attitude control with their limits) and the allocation into ``mem``;
    disarmed, or idle on the ground, a zero command and zero forces. Returns (the commanded motor forces [N], the
    commander's event).

    **Idle on the ground**, as PX4's multicopter keeps its thrust at idle while landed until a setpoint asks it up:
    armed, resting on the ground (below TOUCHDOWN_ALT, |climb| below TOUCHDOWN_CLIMB) and with a reference that
    does not ask for a climb (:func:`climb_asked`: armed in hold, a landing touched down, an offboard altitude of
    the ground or a velocity along it), the motors idle and the integrators stay at zero. Without the idle, a
    vehicle whose autopilot believes it heavier than it is (a mass mismatch) would lift off in hold, and an offboard
    attitude or velocity setpoint on the ground would skate the vehicle along it, hovering at its height; with it, a
    flight starts from rest with a previous command of zero (the backstepping's Ωr).

    **A thrust given** (an offboard attitude setpoint's normalised collective thrust, cm[REF_THRUST]) is flown as
    it is, whichever law makes the torques: u1 = thrust × 4·f_max, every motor at that share of its largest force,
    as HIL_ACTUATOR_CONTROLS normalises them (PX4's normalised thrust).

    **STABILIZED's throttle stick** (cm[REF_THROTTLE]) is made that thrust here, on the autopilot's own model
    (:func:`autopilot.manual.throttle_curve`: THR_MIN at the bottom, the weight m·g at the centre, THR_MAX at the top),
    and then flown as a thrust given.

    **A plugged controller** (``kind`` PLUGGED, its law in ``plug``) is flown instead of :func:`fly`. A command of
    it that is not finite never reaches the motors: that tick and every one until the next arming fly the
    backstepping on the preset's gains, the commander lands (FAILSAFE_CONTROLLER), and the event is
    EVENT_CONTROLLER_FAILED."""
    h, climb = altitude(st), climb_rate(st)
    event = commander.update(cm, tick, now, st[0], st[1], h, st[3], st[4], climb, st[8])
    if not math.isnan(cm[REF_THROTTLE]):
        hover = v[MASS] * v[G]
        cm[REF_THRUST] = manual.throttle_curve(cm[REF_THROTTLE], c[THRUST_MIN], hover, c[THRUST_MAX]) / (4.0 * f_max)
    armed = cm[ARMED] != 0.0
    idle = h < TOUCHDOWN_ALT and abs(climb) < TOUCHDOWN_CLIMB and not climb_asked(cm, h)
    if armed and not idle:
        x = (st[0], st[1], st[2], st[3], st[4], st[5], st[6], st[7], st[8], st[9], st[10], st[11])
        law = kind
        if kind == PLUGGED:
            law = BACKSTEPPING
            if mem[MEM_PLUG_FAILED] == 0.0:
                u = plugged(plug, x, cm, v, c, now)
                if math.isfinite(u[0]) and math.isfinite(u[1]) and math.isfinite(u[2]) and math.isfinite(u[3]):
                    law = PLUGGED
                    errors, omega_r = _ZERO_ERRORS, 0.0
                    mem[MEM_ATTITUDE_REF], mem[MEM_ATTITUDE_REF + 1] = math.nan, math.nan
                else:
                    mem[MEM_PLUG_FAILED], mem[MEM_PLUG_FAILED_TICK] = 1.0, tick + 1.0
                    event = EVENT_CONTROLLER_FAILED
                    cm[FAILSAFE] = commander.FAILSAFE_CONTROLLER
                    if cm[MODE] != commander.LAND:
                        commander.enter(cm, commander.LAND)
        if law != PLUGGED:
            u, errors, omega_r = fly(law, x, cm, mem, v, c)
        if not math.isnan(cm[REF_THRUST]):
            u = Inputs(cm[REF_THRUST] * 4.0 * f_max, u[1], u[2], u[3])
        forces = motors_working(allocate(u, v[D_OVER_B], f_min, f_max), int(cm[commander.MOTORS_OFF]))
        for i in range(4):
            mem[MEM_U + i] = u[i]
            mem[MEM_FORCES + i] = forces[i]
        for i in range(8):
            mem[MEM_ERRORS + i] = errors[i]
        mem[MEM_OMEGA_R] = omega_r
    else:  # element by element: a slice assignment here was dropped once inlined (numba 0.6x, inline="always")
        for i in range(8):
            mem[MEM_U + i] = 0.0  # the command u1..u4 and the forces f1..f4
        for i in range(3):
            mem[MEM_ZETA + i] = 0.0  # the integrators start afresh at each arming
        mem[MEM_PLUG_FAILED] = 0.0  # a plugged controller is flown again, its memory zero
        buf, start = plug[1], plug[2]
        for i in range(start, buf.shape[0]):
            buf[i] = 0.0
        forces = (0.0, 0.0, 0.0, 0.0)
    return forces, event


@jit
def control_tick(kind: int, plug: tuple, st: np.ndarray, cm: np.ndarray, mem: np.ndarray, v: np.ndarray,
                 c: np.ndarray, f_min: float, f_max: float, tx: np.ndarray, io: np.ndarray, time_usec: int, tick: int,
                 now: float, records: np.ndarray) -> None:  # fmt: skip
    """The process's tick once the state (``st``) is known: :func:`autopilot_step` (its event into io[EVENT]), the
    answer into ``tx``, and the four telemetry records into the batch's next row when io[CAPACITY] > 0
    (``records``: :class:`Batch`)."""
    forces, event = autopilot_step(kind, plug, st, cm, mem, v, c, f_min, f_max, tick, now)
    io[EVENT] = event
    armed = cm[ARMED] != 0.0
    io[SEQ] = (io[SEQ] + 1) & 0xFF
    io[TX_LEN] = encode_actuators(tx, io[SEQ], io[SYSTEM], io[COMPONENT], time_usec, forces, f_max, armed)
    capacity, row = io[CAPACITY], io[ROWS]
    if row >= capacity:  # no session (capacity 0), or a full batch not yet published: never past the end
        return
    at = row * STATE_SIZE
    _put_int(records, at + AT_TICK, tick)
    _put(records, at + AT_T, now)
    for i in range(9):  # x, y, z, vx, vy, vz, roll, pitch, yaw
        _put(records, at + STATE_AT_X + FLOAT64 * i, st[i])
    for i in range(3):  # body rates p, q, r
        _put(records, at + STATE_AT_P + FLOAT64 * i, st[BODY_RATES + i])
    at = capacity * STATE_SIZE + row * SETPOINT_SIZE
    _put_int(records, at + AT_TICK, tick)
    _put(records, at + AT_T, now)
    shown = stream_frames.reference_shown(cm, mem)
    for i in range(6):  # altitude, roll, pitch, yaw, x_ref, y_ref
        _put(records, at + SETPOINT_AT_REF + FLOAT64 * i, shown[i])
    at = capacity * (STATE_SIZE + SETPOINT_SIZE) + row * ACTUATORS_SIZE
    _put_int(records, at + AT_TICK, tick)
    _put(records, at + AT_T, now)
    for i in range(8):  # u1..u4, f1..f4
        _put(records, at + ACTUATORS_AT_U + FLOAT64 * i, mem[MEM_U + i])
    at = capacity * (STATE_SIZE + SETPOINT_SIZE + ACTUATORS_SIZE) + row * STATUS_SIZE
    _put_int(records, at + AT_TICK, tick)
    _put(records, at + AT_T, now)
    records[at + STATUS_AT_ARMED], records[at + STATUS_AT_MODE] = armed, int(cm[MODE])
    records[at + STATUS_AT_FAILSAFE] = int(cm[FAILSAFE])
    _put_int(records, at + STATUS_AT_OFFBOARD_TICK, int(cm[OFFBOARD_TICK]))
    for i in range(5):  # the battery: V, A, mAh, J, share left (NaN: none)
        _put(records, at + STATUS_AT_BATTERY + FLOAT64 * i, cm[commander.BAT_V + i])
    io[ROWS] = row + 1


@jit
def _new_tick(t: int, io: np.ndarray) -> int:
    """The datagram stamped ``t``: 1 a new tick (io[LAST_USEC] takes it), 0 a re-sent one (the same answer again), −1
    a stale one (older than the last, by less than 1 s: a jump back by more is a restarted plant, whose ticks start
    again)."""
    last = io[LAST_USEC]
    if t == last:
        return 0
    if last - 1_000_000 < t < last:
        return -1
    if t < last:
        io[NEXT_STREAM_TICK] = 0
    io[LAST_USEC] = t
    return 1


@jit
def answer_again(t: int, cm: np.ndarray, mem: np.ndarray, f_max: float, tx: np.ndarray, io: np.ndarray) -> int:
    """A re-sent datagram (stamped ``t``, the last tick's): the same answer, its forces as computed then, with the
    armed flag as it is now (a lockstep plant holding its clock until the vehicle arms reads it)."""
    forces = (mem[MEM_FORCES], mem[MEM_FORCES + 1], mem[MEM_FORCES + 2], mem[MEM_FORCES + 3])
    io[TX_LEN] = encode_actuators(tx, io[SEQ], io[SYSTEM], io[COMPONENT], t, forces, f_max, cm[ARMED] != 0.0)
    return ANSWER


@jit
def _flags(io: np.ndarray, tick: int) -> int:
    flags = ANSWER
    if tick >= io[NEXT_STREAM_TICK]:
        flags |= STREAM
    if io[EVENT] != EVENT_NONE:
        flags |= EVENT_DUE
    if io[CAPACITY] > 0 and io[ROWS] == io[CAPACITY]:
        flags |= BATCH_FULL
    return flags


@jit
def _frames(tick: int, period: float, st: np.ndarray, cm: np.ndarray, mem: np.ndarray, io: np.ndarray,
            frames: tuple) -> int:  # fmt: skip
    """The telemetry frames due at ``tick`` (:func:`autopilot.stream_frames.stream_tick`) → FRAMES when any."""
    due = stream_frames.stream_tick(tick, period, st, cm, mem, io[GCS_SEQ : GCS_SEQ + 1], io[SYSTEM], io[COMPONENT],
                                    frames)  # fmt: skip
    return FRAMES if due else 0


@jit
def autopilot_tick(rx: np.ndarray, length: int, scratch: np.ndarray, st: np.ndarray, period: float, kind: int,
                   plug: tuple, cm: np.ndarray, mem: np.ndarray, v: np.ndarray, c: np.ndarray, f_min: float,
                   f_max: float, tx: np.ndarray, io: np.ndarray, records: np.ndarray,
                   frames: tuple) -> int:  # fmt: skip
    """A datagram from the plant (rx[:length]) → what to do (ANSWER | STREAM | ...). A new state becomes
    ``st`` and is flown (:func:`control_tick`), and its telemetry frames due are built (``frames``:
    :attr:`autopilot.stream_frames.StreamFrames.out`); a re-sent one gets the same answer again; a stale one (older
    than the last, by less than 1 s: a jump back by more is a restarted plant) none. A BATTERY_STATUS after the
    ODOMETRY (a vehicle with a battery) goes to the commander (:func:`autopilot.commander.battery_seen`)."""
    rx, scratch, st, plug, cm, mem, v, c, tx, io, records, frames = borrowed(
        (rx, scratch, st, plug, cm, mem, v, c, tx, io, records, frames)
    )  # no reference counts: quadsitl.jit.borrowed
    n = length  # the first frame's length: the ODOMETRY, a BATTERY_STATUS may follow
    if length >= 12 and rx[0] == MAVLINK2_STX:
        n = min(length, HEADER_SIZE + np.int64(rx[1]) + 2)
    if n < length:  # checked first: the state's check pads its payload in place, over what follows
        status = check_frame(rx[n:], length - n, BATTERY_ID, BATTERY_CRC_EXTRA, BATTERY_SIZE)
        if status < 0:
            return NOT_MINE if status == NOT_THIS_FRAME else REFUSED
    t = decode_state(rx, n, scratch)
    if t < 0:
        return NOT_MINE if t == NOT_THIS_FRAME else REFUSED
    new = _new_tick(t, io)
    if new <= 0:
        return answer_again(t, cm, mem, f_max, tx, io) if new == 0 else 0
    if n < length:
        commander.battery_seen(cm, decode_battery(rx[n:]))
    copy_into(st, scratch)
    tick = tick_of(t, period)
    io[TICK] = tick
    control_tick(kind, plug, st, cm, mem, v, c, f_min, f_max, tx, io, t, tick, tick * period, records)
    return _flags(io, tick) | _frames(tick, period, st, cm, mem, io, frames)


@jit(inline=True)
def estimate(flags: int, t_usec: int, period: float, est: tuple, st: np.ndarray) -> int:
    """Sensor mode: the estimator's tick on the measurements decoded into its ``est`` arrays (``flags``: which came,
    :func:`quadsitl.hil.decode_sensors`; ``t_usec`` [µs]: their HIL_SENSOR's time), its estimate into ``st`` (the
    VehicleState fields, then the body rates the controllers' eq (1) inverse came from: the bias-corrected gyro).
    Returns the estimator's status (ESTIMATE_*)."""
    z, x, P, hist, eio, acc, e, ratio, scratch, out, cal = est
    ekf.calibrated(flags, z, cal)
    ekf.estimator_tick(flags, z, t_usec, period, (0.0, 0.0, 0.0), x, P, hist, eio, acc, e, ratio, scratch, out)
    for i in range(12):
        st[i] = out[i]
    for i in range(3):
        st[BODY_RATES + i] = z[Z_GYRO + i] - x[ekf.X_BG + i]
    status = (ESTIMATE_ALIGNED if eio[ekf.ALIGNED] else 0) | (ESTIMATE_DIVERGED if eio[ekf.DIVERGED] else 0)
    return status | (eio[ekf.LOST] << 2 if eio[ekf.ALIGNED] else 0)


@jit
def sensor_tick(rx: np.ndarray, length: int, frame: np.ndarray, truth: np.ndarray, home: tuple, est: tuple,
                st: np.ndarray, period: float, kind: int, plug: tuple, cm: np.ndarray, mem: np.ndarray,
                v: np.ndarray, c: np.ndarray, f_min: float, f_max: float, tx: np.ndarray, io: np.ndarray,
                records: np.ndarray, frames: tuple) -> int:  # fmt: skip
    """Sensor mode: a sensor datagram from the plant (:mod:`quadsitl.hil`) → what to do, as :func:`autopilot_tick`.
    A new tick's measurements go to the estimator (``est``: :attr:`autopilot.estimator.Estimator.arrays`); its
    estimate becomes ``st`` and is flown. The plant's ground truth is decoded into ``truth`` and goes to the
    telemetry records only (the controllers never see it), with the estimator's report (the sensors' record).
    ``home``: the local origin (lat, lon [deg], alt [m AMSL]) the GPS positions are taken from."""
    rx, frame, truth, est, st, plug, cm, mem, v, c, tx, io, records, frames = borrowed(
        (rx, frame, truth, est, st, plug, cm, mem, v, c, tx, io, records, frames)
    )  # quadsitl.jit.borrowed
    t, flags, dropped = decode_sensors(rx, length, home, est[0], truth, frame)
    if t < 0:
        return NOT_MINE if t == NOT_THIS_FRAME else REFUSED
    new = _new_tick(t, io)
    if new <= 0:
        return answer_again(t, cm, mem, f_max, tx, io) if new == 0 else 0
    for bit in range(4):
        io[DROPPED] += (dropped >> bit) & 1
    if flags & BATTERY_NEW:
        z = est[0]
        commander.battery_seen(cm, (z[Z_BATTERY], z[Z_BATTERY + 1], z[Z_BATTERY + 2], z[Z_BATTERY + 3],
                                    z[Z_BATTERY + 4]))  # fmt: skip
    status = estimate(flags, t, period, est, st)
    tick = tick_of(t, period)
    io[TICK] = tick
    row = io[ROWS]
    if row < io[CAPACITY]:  # the truth's record, in the row control_tick fills next
        at = io[CAPACITY] * TRUTH_AT + row * STATE_SIZE
        _put_int(records, at + AT_TICK, tick)
        _put(records, at + AT_T, tick * period)
        for i in range(9):
            _put(records, at + STATE_AT_X + FLOAT64 * i, truth[i])
        for i in range(3):
            _put(records, at + STATE_AT_P + FLOAT64 * i, truth[BODY_RATES + i])
        at = io[CAPACITY] * SENSORS_AT + row * SENSORS_SIZE  # and the sensors' (what the estimator took, its health)
        _put_int(records, at + AT_TICK, tick)
        _put(records, at + AT_T, tick * period)
        values = ekf.report_of(est)
        for i in range(ekf.REPORT_SIZE):
            _put(records, at + SENSORS_AT_VALUES + FLOAT64 * i, values[i])
    control_tick(kind, plug, st, cm, mem, v, c, f_min, f_max, tx, io, t, tick, tick * period, records)
    flags = _flags(io, tick) | _frames(tick, period, st, cm, mem, io, frames)
    if status != io[ESTIMATE]:
        io[ESTIMATE] = status
        flags |= ESTIMATOR_CHANGED
    return flags


class Batch:
    """Telemetry records of up to ``capacity`` ticks: one buffer, the streams' regions one after the other
    (telemetry.STREAMS' layouts, then the truth's and the sensors', written in sensor mode only); io[ROWS] counts the
    rows written."""

    def __init__(self, capacity: int) -> None:
        self.capacity = capacity
        # the truth's (TRUTH_AT), then the sensors' (SENSORS_AT)
        layouts = {**telemetry.STREAMS, **{s: telemetry.layout(s)[0] for s in telemetry.SENSING}}
        self.records = np.zeros(capacity * sum(f.size for f in layouts.values()), dtype=np.uint8)
        self.regions, at = {}, 0
        for stream, f in layouts.items():
            self.regions[stream] = (at, f.size)
            at += capacity * f.size

    def payload(self, stream: str, rows: int) -> bytes:
        at, size = self.regions[stream]
        return self.records[at : at + rows * size].tobytes()


def made_up_datagram(sensing: bool, size: int) -> tuple[np.ndarray, int]:
    """A datagram of the plant's for a warm-up, at rest, in a buffer of ``size`` bytes → (buffer, its length):
    ODOMETRY, or (``sensing``) HIL_SENSOR and HIL_GPS. Made by pymavlink: the compiled encoders are the plant's, and
    an autopilot that compiled them only for this would wait seconds more on its first run."""
    from quadsitl import codec, hil, wire
    from quadsitl.state import VehicleState

    mav = wire.link(1, 1)
    if sensing:
        fields = hil.MAG_UPDATED | hil.BARO_UPDATED
        sensor = wire.mavlink.MAVLink_hil_sensor_message(0, 0.0, 0.0, -9.8, 0.0, 0.0, 0.0, 0.2, 0.0, 0.4, 1000.0, 0.0,
                                                         100.0, 15.0, fields, 0)  # fmt: skip
        gps = wire.hil_gps_message(0, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), (47.0, 8.0, 488.0), 1.0, 1.0, 10)
        data = codec.pack(sensor, mav) + codec.pack(gps, mav)
    else:
        data = codec.pack(wire.state_message(0, VehicleState(*(0.0,) * 12)), mav)
    buf = np.zeros(size, dtype=np.uint8)
    buf[: len(data)] = np.frombuffer(data, dtype=np.uint8)
    return buf, len(data)


class _MadeUp:
    """Made-up arrays of a tick's types, for the warm-ups: what a process passes its compiled tick."""

    def __init__(self) -> None:
        from autopilot.control_params import control_array
        from quadsitl import codec
        from quadsitl.param_arrays import VEHICLE_SIZE

        self.frame = np.zeros(codec.FRAME_MAX, dtype=np.uint8)
        self.st = np.zeros(codec.DECODED_SIZE)
        self.v = np.ones(VEHICLE_SIZE)
        self.c = control_array((0.5,) * 8, 0.001)
        self.mem = np.zeros(MEM_SIZE)
        self.batch = Batch(2)
        self.frames = stream_frames.StreamFrames(2, (47.0, 8.0, 488.0), 40.0, False)
        self.frames.sched[:, :, 0] = 1  # every message on every link, every tick
        self.io = np.zeros(IO_SIZE, dtype=np.int64)
        self.io[LAST_USEC], self.io[CAPACITY] = -1, self.batch.capacity


def warm_up_share(sensing: bool | None = None) -> None:
    """Compile into numba's cache the parts of :func:`warm_up`'s tick that another process can compile while the
    autopilot's compiles the bulk (:func:`control_tick`, which :func:`warm_up` does first): the frames the ground
    station's messages and streams are built with, the state's decoder, the answer to a re-sent state. The autopilot's
    tick then loads them instead of compiling them, and a cold start before a fleet waits less with a core each
    (groundstation.launcher.compile_once; docs/performance.md#compiling-on-first-run). Each part is called from
    Python with the argument types the tick passes it, so its cached code is the one the tick's compile looks up."""
    from autopilot import gcs_messages
    from autopilot.commander import Commander
    from quadsitl import codec

    gcs_messages.warm_up()
    m, cm = _MadeUp(), Commander().cm
    if sensing is not True:
        rx, n = made_up_datagram(False, codec.FRAME_MAX)
        codec.decode_state(rx, n, m.st.copy())
    answer_again(0, cm, m.mem, 1.0, m.frame, m.io)
    _frames(0, 0.001, m.st, cm, m.mem, m.io, m.frames.out)


def warm_up(sensing: bool | None = None) -> None:
    """Compile (or load from numba's cache) everything a tick calls, on made-up data, before the first tick: the
    state mode's tick (``sensing`` False), the sensor mode's (True), or both (None: a launcher's, for processes of
    either). A process compiles only the mode it flies (docs/performance.md#compiling-on-first-run). The bulk first,
    :func:`control_tick` (the commander and the controllers), while another process may compile the rest
    (:func:`warm_up_share`)."""
    from autopilot import gcs_messages
    from autopilot.commander import HOLD, Commander, enter
    from autopilot.control_params import BACKSTEPPING
    from autopilot.estimator import Estimator
    from quadsitl import codec, hil

    m = _MadeUp()
    frame, st, v, c, batch, frames = m.frame, m.st, m.v, m.c, m.batch, m.frames
    control_tick(BACKSTEPPING, plugin.no_plug(), st.copy(), Commander().cm, m.mem, v, c, -1.0, 1.0, frame.copy(),
                 m.io.copy(), 0, 0, 0.0, batch.records.copy())  # fmt: skip
    gcs_messages.warm_up()  # what Python builds (requested, signed, the slower streams) calls compiled code too
    for kind in (BACKSTEPPING, PD):
        for armed in (False, True):
            commander = Commander()
            if armed:
                commander.arm()
            io = np.zeros(IO_SIZE, dtype=np.int64)
            io[LAST_USEC], io[CAPACITY] = -1, batch.capacity
            if sensing is not True:
                rx, n = made_up_datagram(False, codec.FRAME_MAX)
                autopilot_tick(rx, n, st.copy(), st, 0.001, kind, plugin.no_plug(), commander.cm, np.zeros(MEM_SIZE),
                               v, c, -1.0, 1.0, frame, io, batch.records, frames.out)  # fmt: skip
                io[LAST_USEC] = -1
            if sensing is False:
                continue
            est = Estimator(0.001, 9.8, (0.2, 0.0, 0.4))
            datagram, n = made_up_datagram(True, hil.DATAGRAM_MAX)
            sensor_tick(datagram, n, frame.copy(), st.copy(), (47.0, 8.0, 488.0), est.arrays, st, 0.001, kind,
                        plugin.no_plug(), commander.cm, np.zeros(MEM_SIZE), v, c, -1.0, 1.0, frame, io, batch.records,
                        frames.out)  # fmt: skip
    # what a Python-built message shows of the last tick (autopilot.process.Autopilot.snapshot), called from Python
    stream_frames.tick_values(st, Commander().cm, np.zeros(MEM_SIZE), frames.tel)
    enter(Commander().cm, HOLD)  # a mode change from Python (Commander.set_mode and the like)
