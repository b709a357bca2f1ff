"""The plant's work for one lockstep tick, compiled (:mod:`quadsitl.jit`): take the autopilot's answer,
integrate one period, and encode the next tick's datagram, in one call from the process's loop
(:func:`sitl.lockstep.run_lockstep`).

The datagram is the state as ODOMETRY, or in sensor mode (io[SENSING]) what the vehicle's sensors measure of it
(:mod:`quadsitl.hil`: HIL_SENSOR, HIL_GPS when a fix is delivered, and HIL_STATE_QUATERNION, the truth, unless
io[SENSING] is SENSORS_ONLY).
``sens`` is :attr:`sitl.sensors.Sensors.arrays`, or None on the true state (:attr:`sitl.plant.Plant.sens`): numba then
compiles no sensors' path, which the first run after an install would otherwise wait for
(docs/performance.md#compiling-on-first-run)."""

from __future__ import annotations

import math

import numpy as np

from quadsitl.codec import HEADER_SIZE, HIL_SIZE, NOT_THIS_FRAME, SAFETY_ARMED, decode_actuators, encode_state, usec_of
from quadsitl.compiled_frames import euler_to_quaternion
from quadsitl.config import DEFAULT_LIMITS
from quadsitl.hil import encode_battery, encode_gps, encode_sensor, encode_truth
from quadsitl.jit import borrowed, copy_into, jit
from sitl import sensors as sn
from sitl.plant import (
    OUT_CHARGE,
    OUT_CURRENT,
    OUT_ENERGY,
    OUT_MEAN_ACCEL,
    OUT_ON_GROUND,
    OUT_REMAINING,
    OUT_VOLTAGE,
    inside,
    step_arrays,
)

# The tick's integer bookkeeping (``io``, int64): the link's sequence number, the length of the state frame
# in tx, the stamp of the newest actuator message used, and what was refused: stale or duplicate answers,
# corrupt frames or non-finite forces; the plant's MAVLink ids; 1 in sensor mode; the tick at which the clock holds
# until the autopilot arms (−1: none) and whether the answer being taken says armed; 1 when the clock holds once the
# flight is over (an answer says disarmed, the vehicle on the ground, after one said armed), and 1 once one did.
(SEQ, TX_LEN, LAST_USEC, DISCARDED, CORRUPT, SYSTEM, COMPONENT, SENSING, HOLD_TICK, ANSWER_ARMED, HOLD_LANDED, FLOWN,
 IO_SIZE) = range(13)  # fmt: skip
# What lockstep_tick reports besides STEPPED: an answer from the future, or no actuator message for this
# tick in the datagram (NOTHING; ANOTHER_FRAME: not exactly one unsigned HIL_ACTUATOR_CONTROLS, for pymavlink).
# DIVERGED: stepped, and the new state is outside sitl.plant's DEFAULT_LIMITS (or not finite): not to be sent.
# HELD: the answer to the hold tick, disarmed (io[HOLD_TICK]), or one saying disarmed with the vehicle on the ground
# after a flight (io[HOLD_LANDED]): the clock waits.
STEPPED, FUTURE, NOTHING, ANOTHER_FRAME, DIVERGED, HELD = 0, 1, 2, 3, 4, 5
# io[SENSING]: the state as ODOMETRY (0), or the sensors' measurements and the truth for the autopilot's telemetry
# (SENSORS), or the measurements alone (SENSORS_ONLY: quadsitl sim, which records the plant's state itself).
SENSORS, SENSORS_ONLY = 1, 2


@jit(inline=True)
def encode_sensors(tx: np.ndarray, io: np.ndarray, x: np.ndarray, out: np.ndarray, air: np.ndarray, sens: tuple,
                   tick: int, period: float) -> None:  # fmt: skip
    """Tick ``tick``'s sensor datagram into ``tx``: the sensors sample the state ``x`` once (:func:`sitl.sensors.
    sensors_tick`), the accelerometer the mean acceleration of the step that made ``x`` (a landing's stop included,
    as a real IMU's delta-velocity has it); then the truth."""
    p, rng, bias, clock, queue, so = sens
    s = (x[0], x[1], x[2], x[3], x[4], x[5], x[6], x[7], x[8], x[9], x[10], x[11])
    d = (air[0], air[1], air[2])
    acc = (out[OUT_MEAN_ACCEL], out[OUT_MEAN_ACCEL + 1], out[OUT_MEAN_ACCEL + 2])
    t = usec_of(tick, period)
    fields = sn.sensors_tick(t, s, acc, period, p, rng, bias, clock, queue, so)
    home = (p[sn.HOME_LAT_DEG], p[sn.HOME_LON_DEG], p[sn.HOME_ALT_M])
    system, component = io[SYSTEM], io[COMPONENT]
    io[SEQ] = (io[SEQ] + 1) & 0xFF
    n = encode_sensor(tx, io[SEQ], system, component, t, (so[sn.OUT_ACCEL], so[sn.OUT_ACCEL + 1], so[sn.OUT_ACCEL + 2]),
                      (so[sn.OUT_GYRO], so[sn.OUT_GYRO + 1], so[sn.OUT_GYRO + 2]),
                      (so[sn.OUT_MAG], so[sn.OUT_MAG + 1], so[sn.OUT_MAG + 2]), so[sn.OUT_PRESSURE],
                      so[sn.OUT_PRESSURE_ALT], so[sn.OUT_TEMPERATURE], fields)  # fmt: skip
    if so[sn.OUT_GPS_NEW] != 0.0:
        io[SEQ] = (io[SEQ] + 1) & 0xFF
        n += encode_gps(tx[n:], io[SEQ], system, component, int(so[sn.OUT_GPS_TIME]),
                        (so[sn.OUT_GPS_POS], so[sn.OUT_GPS_POS + 1], so[sn.OUT_GPS_POS + 2]),
                        (so[sn.OUT_GPS_VEL], so[sn.OUT_GPS_VEL + 1], so[sn.OUT_GPS_VEL + 2]), home, p[sn.GPS_XY],
                        p[sn.GPS_Z], int(p[sn.SATELLITES]))  # fmt: skip
    if io[SENSING] == SENSORS_ONLY:
        io[TX_LEN] = n
        return
    f = sn.specific_force(euler_to_quaternion(s[6], s[7], s[8]), acc, p[sn.GRAVITY])
    airspeed = math.sqrt((s[3] - d[0]) ** 2 + (s[4] - d[1]) ** 2 + (s[5] - d[2]) ** 2)
    io[SEQ] = (io[SEQ] + 1) & 0xFF
    n += encode_truth(tx[n:], io[SEQ], system, component, t, s, airspeed, f, home)
    io[TX_LEN] = n


@jit(inline=True)
def encode_tick(tx: np.ndarray, io: np.ndarray, x: np.ndarray, out: np.ndarray, air: np.ndarray, sens: tuple | None,
                tick: int, period: float) -> None:  # fmt: skip
    """Tick ``tick``'s datagram into ``tx``: the state ``x`` stamped with the tick's simulated time as ODOMETRY, or
    in sensor mode (io[SENSING], ``sens`` not None) its measurements (:func:`encode_sensors`); then, for a vehicle with
    a battery, its BATTERY_STATUS (:func:`quadsitl.hil.encode_battery`: the battery's state in ``out`` after the step
    that made ``x``). Compiled with ``sens`` None, the sensors' branch is pruned (never typed nor compiled)."""
    if sens is None or io[SENSING] == 0:
        io[SEQ] = (io[SEQ] + 1) & 0xFF
        io[TX_LEN] = encode_state(tx, io[SEQ], io[SYSTEM], io[COMPONENT], usec_of(tick, period), x)
    else:
        encode_sensors(tx, io, x, out, air, sens, tick, period)
    if out[OUT_REMAINING] >= 0.0:  # a battery (an ideal supply's is −1)
        io[SEQ] = (io[SEQ] + 1) & 0xFF
        n = io[TX_LEN]
        io[TX_LEN] = n + encode_battery(tx[n:], io[SEQ], io[SYSTEM], io[COMPONENT], out[OUT_VOLTAGE], out[OUT_CURRENT],
                                        out[OUT_CHARGE], out[OUT_ENERGY], out[OUT_REMAINING])  # fmt: skip


@jit(inline=True)
def sensors_of(sens: tuple | None, i: int) -> tuple | None:
    """Vehicle ``i``'s sensors' arrays (:attr:`sitl.sensors.Sensors.arrays`) of a fleet's, a row per vehicle
    (:class:`sitl.fleet_arrays.FleetArrays`); None for a fleet on the true state (None)."""
    if sens is None:
        return None
    p, rng, bias, clock, queue, out = sens
    return p[i], rng[i], bias[i], clock[i], queue[i], out[i]


@jit
def take_and_step(t: int, want: int, commanded: np.ndarray, received: np.ndarray, x: np.ndarray,
                  motors: np.ndarray, out: np.ndarray, v: np.ndarray, a: np.ndarray, air: np.ndarray,
                  air_rng: np.ndarray, period: float, substeps: int, method: int, tx: np.ndarray, io: np.ndarray,
                  sens: tuple | None, tick: int) -> int:  # fmt: skip
    """An actuator message stamped ``t`` (its forces in ``received``): when it answers tick ``tick``
    (``want``), make it the command, integrate one period in the tick's wind (:func:`sitl.plant.step_arrays`) and
    encode the state of tick + 1 (DIVERGED when that state is not :func:`sitl.plant.inside` the default
    bounds). At io[HOLD_TICK] the clock holds (HELD) until the answer says armed (io[ANSWER_ARMED]); with
    io[HOLD_LANDED], it holds at any tick once the flight is over: the answer says disarmed, an earlier one said
    armed, and the vehicle rests on the ground (``out``'s on-ground flag of the step that made ``x``)."""
    commanded, received, x, motors, out, v, a, air, air_rng, tx, io = borrowed(
        (commanded, received, x, motors, out, v, a, air, air_rng, tx, io)
    )  # quadsitl.jit.borrowed; not ``sens``, whose None numba prunes as an argument only
    if t < 0:
        return NOTHING
    if t <= io[LAST_USEC]:
        io[DISCARDED] += 1
        return NOTHING
    if t != want:
        io[DISCARDED] += 1
        return FUTURE
    if io[ANSWER_ARMED] == 0:
        if tick == io[HOLD_TICK] or (io[HOLD_LANDED] != 0 and io[FLOWN] != 0 and out[OUT_ON_GROUND] > 0.0):
            return HELD
    else:
        io[FLOWN] = 1
    io[LAST_USEC] = t
    copy_into(commanded, received)
    step_arrays(x, motors, commanded, out, v, a, air, air_rng, period, substeps, method, np.nan)
    encode_tick(tx, io, x, out, air, sens, tick + 1, period)
    s = (x[0], x[1], x[2], x[3], x[4], x[5], x[6], x[7], x[8], x[9], x[10], x[11])
    return STEPPED if inside(s, DEFAULT_LIMITS) else DIVERGED


@jit
def lockstep_tick(rx: np.ndarray, length: int, want: int, max_thrust: float, received: np.ndarray,
                  commanded: np.ndarray, x: np.ndarray, motors: np.ndarray, out: np.ndarray, v: np.ndarray,
                  a: np.ndarray, air: np.ndarray, air_rng: np.ndarray, period: float, substeps: int, method: int,
                  tx: np.ndarray, io: np.ndarray, sens: tuple | None, tick: int) -> int:  # fmt: skip
    """A datagram from the autopilot (rx[:length]) during tick ``tick``: STEPPED (the next state is in tx),
    DIVERGED (it is, but outside its bounds), FUTURE, NOTHING or ANOTHER_FRAME."""
    rx, received, commanded, x, motors, out, v, a, air, air_rng, tx, io = borrowed(
        (rx, received, commanded, x, motors, out, v, a, air, air_rng, tx, io)
    )  # quadsitl.jit.borrowed (not ``sens``: take_and_step)
    t = decode_actuators(rx, length, received, max_thrust)
    if t == NOT_THIS_FRAME:
        return ANOTHER_FRAME
    if t < 0:
        io[CORRUPT] += 1  # a bad CRC, or a non-finite force: never integrated
        return NOTHING
    io[ANSWER_ARMED] = 1 if rx[HEADER_SIZE + HIL_SIZE - 1] & SAFETY_ARMED else 0
    return take_and_step(t, want, commanded, received, x, motors, out, v, a, air, air_rng, period, substeps, method,
                         tx, io, sens, tick)  # fmt: skip
