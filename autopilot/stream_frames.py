"""The telemetry messages that follow every tick, built by compiled code (:mod:`quadsitl.jit`): GPS_RAW_INT,
ATTITUDE, ATTITUDE_QUATERNION, LOCAL_POSITION_NED, GLOBAL_POSITION_INT, SERVO_OUTPUT_RAW, ATTITUDE_TARGET,
POSITION_TARGET_LOCAL_NED and ACTUATOR_OUTPUT_STATUS (:data:`COMPILED`).

These are the messages a ground station asks for at 5 Hz and more, on the ticks their stream is due
(:mod:`autopilot.streams`). Built in Python, each cost the autopilot's loop a return from compiled code and a
snapshot, pymavlink's message and the frame in Python, while the plant waited: in an unpaced lockstep run the 50 Hz
ATTITUDE stream alone took a large share of the run (docs/performance.md#in-lockstep). Here the tick builds them
(:func:`stream_tick`, called by :func:`autopilot.tick.autopilot_tick`) into one datagram per link, from the arrays
the tick already has, and the compiled plant loop sends them (:func:`autopilot.plant_loop.serve`).

Each message's fields are computed once, here: :func:`encode` is also what ``gcs_messages.build`` returns for
these ids (a ``MAV_CMD_REQUEST_MESSAGE``, a signed link, the Python loop). The payload layouts are read from
pymavlink's message classes (their ``struct`` formats), never typed by hand, and the frames are the bytes pymavlink
would send (tested). Units and frames as :mod:`autopilot.gcs_messages` documents them (PX4's conventions).
"""

from __future__ import annotations

import math
import re

import numpy as np

from autopilot.commander import (
    ARMED,
    HOLD_YAW,
    HOME_ALT,
    REF_ALT,
    REF_CLIMB,
    REF_PITCH,
    REF_ROLL,
    REF_VX,
    REF_VY,
    REF_X,
    REF_Y,
    REF_YAW,
    TARGET_ALT,
)
from autopilot.control_params import MEM_ATTITUDE_REF, MEM_FORCES, MEM_U
from quadsitl.codec import BODY_RATES, FRAME_MAX, HEADER_SIZE, finish_frame
from quadsitl.compiled_frames import euler_to_quaternion, ned_to_geodetic
from quadsitl.jit import copy_into, jit
from quadsitl.rawbytes import put
from quadsitl.wire import UINT16_UNKNOWN, mavlink

_CLASSES = (  # by message id, the order of the frames in a datagram
    mavlink.MAVLink_gps_raw_int_message,
    mavlink.MAVLink_attitude_message,
    mavlink.MAVLink_attitude_quaternion_message,
    mavlink.MAVLink_local_position_ned_message,
    mavlink.MAVLink_global_position_int_message,
    mavlink.MAVLink_servo_output_raw_message,
    mavlink.MAVLink_attitude_target_message,
    mavlink.MAVLink_position_target_local_ned_message,
    mavlink.MAVLink_actuator_output_status_message,
)
COMPILED: tuple[int, ...] = tuple(c.id for c in _CLASSES)
"""The message ids built here, in the order of their slots (GPS, ATT, …), which is their ids' order."""
GPS, ATT, ATT_Q, LPN, GPI, SERVO, ATT_T, POS_T, ACT = range(len(_CLASSES))  # slots
SLOT_COUNT = len(_CLASSES)
SLOT_OF = {mid: i for i, mid in enumerate(COMPILED)}

# A field's type on the wire: struct codes → what put_field writes.
_TYPES = {"B": 0, "h": 1, "H": 2, "i": 3, "I": 4, "Q": 5, "f": 6}
_SIZES = {"B": 1, "h": 2, "H": 2, "i": 4, "I": 4, "Q": 8, "f": 4}
MAX_FIELDS = 34  # ACTUATOR_OUTPUT_STATUS: time, mask and 32 actuators


def _layout(cls: type) -> list[tuple[int, int]]:
    """(payload offset, type) of every value of ``cls``'s payload in wire order, an array field's elements one by
    one: read from pymavlink's ``struct`` format."""
    out, at = [], 0
    for count, code in re.findall(r"(\d*)([BhHiIQf])", cls.unpacker.format):
        for _ in range(int(count or 1)):
            out.append((at, _TYPES[code]))
            at += _SIZES[code]
    assert at == cls.unpacker.size, cls
    return out


_LAYOUTS = [_layout(c) for c in _CLASSES]
LAYOUT = np.zeros((SLOT_COUNT, MAX_FIELDS, 2), dtype=np.int64)
FIELD_COUNT = np.array([len(f) for f in _LAYOUTS], dtype=np.int64)
for _i, _fields in enumerate(_LAYOUTS):
    LAYOUT[_i, : len(_fields)] = _fields
PAYLOAD_SIZE = np.array([c.unpacker.size for c in _CLASSES], dtype=np.int64)
MSG_ID = np.array(COMPILED, dtype=np.int64)
CRC_EXTRA = np.array([c.crc_extra for c in _CLASSES], dtype=np.int64)

# ``tel`` (float64): what the frames need besides the tick's arrays: the local frame's geodetic origin (latitude,
# longitude [deg], altitude AMSL [m]), the largest total thrust 4·F_max [N] (ATTITUDE_TARGET's thrust is u1 over it,
# each motor's control F_j over a quarter of it) and whether the motors are reversible (1) or not (0).
ORIGIN_LAT, ORIGIN_LON, ORIGIN_ALT, MAX_TOTAL_THRUST, REVERSIBLE, TEL_SIZE = range(6)

INT32_MIN, INT32_MAX = -(2**31), 2**31 - 1
# What GPS_RAW_INT claims about the simulated receiver. Its fix is the true state, so its uncertainties are
# those of the encoding: 1e-7 deg of latitude ≈ 1.1 cm, 1 mm of altitude, 1 cm/s of speed.
GPS_SATELLITES = 10
GPS_DOP = 1.0  # HDOP and VDOP (an ideal geometry)
GPS_H_ACC = 11  # [mm]
GPS_V_ACC = 1  # [mm]
GPS_VEL_ACC = 10  # [mm/s]
GPS_FIX_3D = mavlink.GPS_FIX_TYPE_3D_FIX
ATTITUDE_TARGET_MASK = 7  # the body-rate fields are not used
# POSITION_TARGET_LOCAL_NED's type_mask: the accelerations and the yaw rate are never targets (the yaw is); the bit
# of each of x, y, z, vx, vy, vz (bits 0..5) and yaw (bit 10) is set too while it is not controlled.
POSITION_TARGET_IGNORED = 64 | 128 | 256 | 2048
YAW_IGNORED = 1024
ACTUATORS_ACTIVE = 0b1111  # ACTUATOR_OUTPUT_STATUS.active: the four motors


@jit(inline=True)
def clamp_int(value: float, lo: int, hi: int) -> int:
    """``value`` rounded (half to even, as Python's round) into [lo, hi]; 0 when it is not finite."""
    if not math.isfinite(value):
        return 0
    return round(min(max(value, float(lo)), float(hi)))


@jit
def cdeg(angle: float) -> int:
    """An angle [rad] → centidegrees in [0, 36000); 0 when it is not finite."""
    if not math.isfinite(angle):
        return 0
    return round(math.degrees(angle) % 360.0 * 100) % 36000


@jit
def lat_lon_e7(lat0: float, lon0: float, north: float, east: float) -> tuple[int, int]:
    """Local north/east [m] from the origin (lat0, lon0 [deg]) → (lat, lon) [1e-7 deg], PX4's projection; (0, 0)
    for a non-finite position."""
    if not (math.isfinite(north) and math.isfinite(east)):
        return 0, 0
    lat, lon = ned_to_geodetic(north, east, lat0, lon0)
    return clamp_int(lat * 1e7, -900_000_000, 900_000_000), clamp_int(lon * 1e7, -1_800_000_000, 1_800_000_000)


@jit
def amsl_mm(alt0: float, z: float) -> int:
    """Local z [m, down] below an origin at ``alt0`` [m AMSL] → altitude AMSL [mm]."""
    return clamp_int((alt0 - z) * 1000, INT32_MIN, INT32_MAX)


@jit
def pwm(control: float, reversible: bool) -> int:
    """A normalised motor command → PWM [µs]: [0, 1] → 1000..2000, or [−1, 1] → 1000..2000 (1500 = zero) for
    reversible motors; 0 (no pulse) when it is not finite."""
    c = (control + 1.0) / 2.0 if reversible else control
    return clamp_int(1000.0 + 1000.0 * c, 1000, 2000)


@jit
def pwms(controls: tuple, armed: bool, reversible: bool) -> tuple:
    """SERVO_OUTPUT_RAW's first four outputs [µs] for the motors' ``controls`` (F_j / F_max): 0 while disarmed."""
    if not armed:
        return 0, 0, 0, 0
    return (pwm(controls[0], reversible), pwm(controls[1], reversible), pwm(controls[2], reversible),
            pwm(controls[3], reversible))  # fmt: skip


@jit
def _values(slot: int, vals: np.ndarray, time_ms: int, x: tuple, rates: tuple, ref: tuple, thrust: float,
            origin: tuple, home_z: float, target: tuple, controls: tuple, servo: tuple) -> None:  # fmt: skip
    """The payload values of message ``slot`` in wire order (pymavlink's ``ordered_fieldnames``, arrays expanded),
    into ``vals`` (zeros)."""
    ms = time_ms & 0xFFFFFFFF
    if slot == GPS:  # a perfect receiver at the state: a 3D fix, its course unknown while it does not move
        lat, lon = lat_lon_e7(origin[0], origin[1], x[0], x[1])
        alt = amsl_mm(origin[2], x[2])
        vel = clamp_int(math.hypot(x[3], x[4]) * 100, 0, UINT16_UNKNOWN - 1)
        cog = cdeg(math.atan2(x[4], x[3])) if vel > 0 else UINT16_UNKNOWN
        dop = round(GPS_DOP * 100)
        _set(vals, (max(time_ms * 1000, 0), lat, lon, alt, dop, dop, vel, cog, GPS_FIX_3D, GPS_SATELLITES, alt,
                    GPS_H_ACC, GPS_V_ACC, GPS_VEL_ACC, 0, 0))  # fmt: skip
    elif slot == ATT:
        _set(vals, (float(ms), x[6], x[7], x[8], rates[0], rates[1], rates[2]))
    elif slot == ATT_Q:
        q = euler_to_quaternion(x[6], x[7], x[8])
        _set(vals, (float(ms), q[0], q[1], q[2], q[3], rates[0], rates[1], rates[2], 0.0, 0.0, 0.0, 0.0))
    elif slot == LPN:
        _set(vals, (float(ms), x[0], x[1], x[2], x[3], x[4], x[5]))
    elif slot == GPI:  # relative_alt: above home; velocity [cm/s]; heading from yaw
        lat, lon = lat_lon_e7(origin[0], origin[1], x[0], x[1])
        _set(vals, (ms, lat, lon, amsl_mm(origin[2], x[2]), clamp_int((home_z - x[2]) * 1000, INT32_MIN, INT32_MAX),
                    clamp_int(x[3] * 100, -32768, 32767), clamp_int(x[4] * 100, -32768, 32767),
                    clamp_int(x[5] * 100, -32768, 32767), cdeg(x[8])))  # fmt: skip
    elif slot == ATT_T:  # the attitude reference as a quaternion, the thrust as a fraction of the largest
        q = euler_to_quaternion(ref[1], ref[2], ref[3])
        _set(vals, (float(ms), q[0], q[1], q[2], q[3], 0.0, 0.0, 0.0, thrust, float(ATTITUDE_TARGET_MASK)))
    elif slot == SERVO:  # port 0: the four motors' PWM, the other twelve outputs unused
        vals[0] = float((time_ms * 1000) & 0xFFFFFFFF)
        _set(vals[1:], servo)
    elif slot == POS_T:  # the position and velocity flown to (target: x, y, vx, vy, altitude, climb rate), NED
        values = (target[0], target[1], -target[4], target[2], target[3], -target[5])
        mask = POSITION_TARGET_IGNORED
        for bit in range(6):
            if not math.isfinite(values[bit]):
                mask |= 1 << bit
        yaw = ref[3]
        if not math.isfinite(yaw):
            yaw, mask = 0.0, mask | YAW_IGNORED
        vals[0] = float(ms)
        for i in range(6):
            vals[1 + i] = values[i] if math.isfinite(values[i]) else 0.0
        vals[10], vals[12], vals[13] = yaw, float(mask), float(mavlink.MAV_FRAME_LOCAL_NED)
    else:  # ACT: the four motors' controls, F_j / F_max
        vals[0], vals[1] = float(max(time_ms * 1000, 0)), float(ACTUATORS_ACTIVE)
        _set(vals[2:], controls)


@jit(inline=True)
def _set(vals: np.ndarray, v: tuple) -> None:
    for i in range(len(v)):
        vals[i] = v[i]


@jit(inline=True)
def _put(buf: np.ndarray, at: int, kind: int, value: float) -> None:
    if kind == 6:
        put(buf, at, np.float32(value))
    elif kind == 0:
        buf[at] = np.uint8(int(value) & 0xFF)
    elif kind == 1 or kind == 2:
        put(buf, at, np.uint16(int(value) & 0xFFFF))
    elif kind == 3 or kind == 4:
        put(buf, at, np.uint32(int(value) & 0xFFFFFFFF))
    else:
        put(buf, at, np.uint64(int(value)))


@jit
def encode(buf: np.ndarray, slot: int, seq: int, system: int, component: int, time_ms: int, x: tuple, rates: tuple,
           ref: tuple, thrust: float, origin: tuple, home_z: float, target: tuple, controls: tuple,
           servo: tuple) -> int:  # fmt: skip
    """Message ``slot`` (:data:`COMPILED`'s order) as a MAVLink 2 frame at the start of ``buf`` (FRAME_MAX bytes) →
    its length. ``time_ms``: simulated time [ms]; ``x``: the 12 VehicleState fields (local NED [m], [m/s], ZYX Euler
    angles [rad] and their rates); ``rates``: body rates p, q, r [rad/s]; ``ref``: the reference shown (altitude [m],
    roll, pitch, yaw [rad]); ``thrust``: u1 over the largest total thrust; ``origin``: the local frame's (lat, lon
    [deg], alt [m AMSL]); ``home_z``: home's local z [m, down]; ``target``: the position reference flown (local NED
    x, y [m], vx, vy [m/s], altitude [m], climb rate [m/s]; NaN where not controlled); ``controls``: the motors' F_j /
    F_max; ``servo``: their PWM [µs] (:func:`pwms`)."""
    vals = np.zeros(MAX_FIELDS)  # the fields a message leaves unused are 0
    _values(slot, vals, time_ms, x, rates, ref, thrust, origin, home_z, target, controls, servo)
    size = PAYLOAD_SIZE[slot]
    buf[HEADER_SIZE : HEADER_SIZE + size] = 0
    for i in range(FIELD_COUNT[slot]):
        _put(buf, HEADER_SIZE + LAYOUT[slot, i, 0], LAYOUT[slot, i, 1], vals[i])
    return finish_frame(buf, size, seq, system, component, MSG_ID[slot], CRC_EXTRA[slot])


@jit
def reference_shown(cm: np.ndarray, mem: np.ndarray) -> tuple[float, float, float, float, float, float]:
    """The reference the telemetry shows for the last :func:`autopilot.tick.autopilot_step` (ATTITUDE_TARGET, the
    records, ``sim``'s columns): (altitude [m], roll, pitch, yaw [rad],
    x, y [m, NED]). Armed, the one flown (roll and pitch: the position loop's when it flies; x, y NaN while the
    horizontal position is not controlled); disarmed, the altitude and heading held, level, x and y NaN."""
    if cm[ARMED] == 0.0:
        return cm[TARGET_ALT], 0.0, 0.0, cm[HOLD_YAW], np.nan, np.nan
    flown = not math.isnan(mem[MEM_ATTITUDE_REF])
    roll = mem[MEM_ATTITUDE_REF] if flown else cm[REF_ROLL]
    pitch = mem[MEM_ATTITUDE_REF + 1] if flown else cm[REF_PITCH]
    return cm[REF_ALT], roll, pitch, cm[REF_YAW], cm[REF_X], cm[REF_X + 1]


@jit
def tick_values(st: np.ndarray, cm: np.ndarray, mem: np.ndarray, tel: np.ndarray) -> tuple:
    """What :func:`encode` needs, from the tick's arrays (:mod:`autopilot.tick`): (x, rates, ref, thrust, origin,
    home_z, target, controls, servo). The reference shown is :func:`reference_shown`'s; the position target the one
    flown, or disarmed the altitude held alone."""
    x = (st[0], st[1], st[2], st[3], st[4], st[5], st[6], st[7], st[8], st[9], st[10], st[11])
    rates = (st[BODY_RATES], st[BODY_RATES + 1], st[BODY_RATES + 2])
    armed = cm[ARMED] != 0.0
    shown = reference_shown(cm, mem)
    ref = (shown[0], shown[1], shown[2], shown[3])
    if armed:
        target = (cm[REF_X], cm[REF_Y], cm[REF_VX], cm[REF_VY], cm[REF_ALT], cm[REF_CLIMB])
    else:
        target = (math.nan, math.nan, math.nan, math.nan, cm[TARGET_ALT], math.nan)
    thrust = min(max(mem[MEM_U] / tel[MAX_TOTAL_THRUST], 0.0), 1.0)
    origin = (tel[ORIGIN_LAT], tel[ORIGIN_LON], tel[ORIGIN_ALT])
    f_max = tel[MAX_TOTAL_THRUST] / 4.0
    controls = (mem[MEM_FORCES] / f_max, mem[MEM_FORCES + 1] / f_max, mem[MEM_FORCES + 2] / f_max,
                mem[MEM_FORCES + 3] / f_max)  # fmt: skip
    servo = pwms(controls, armed, tel[REVERSIBLE] != 0.0)
    return x, rates, ref, thrust, origin, -cm[HOME_ALT], target, controls, servo


@jit
def stream_tick(tick: int, period: float, st: np.ndarray, cm: np.ndarray, mem: np.ndarray, seq: np.ndarray,
                system: int, component: int, out: tuple) -> bool:  # fmt: skip
    """The frames due at ``tick`` on each link into that link's datagram → whether any is due. ``out``: (sched,
    frames, lens, tel, scratch): sched[link, slot] = (interval [ticks], phase [ticks]), interval 0 = not on this
    link; frames[link] the link's datagram, lens[link] its length (0: nothing due); ``tel`` (TEL_SIZE); ``scratch``
    FRAME_MAX bytes. A message due on several links is built once (one sequence number, seq[0], as a ground-station
    link's messages share one) and goes into each link's datagram, in :data:`COMPILED`'s order."""
    sched, frames, lens, tel, scratch = out
    links = sched.shape[0]
    lens[:] = 0
    due = False
    for slot in range(SLOT_COUNT):
        for link in range(links):
            every = sched[link, slot, 0]
            if every > 0 and (tick - sched[link, slot, 1]) % every == 0:
                due = True
    if not due:
        return False
    time_ms = round(tick * period * 1000)
    x, rates, ref, thrust, origin, home_z, target, controls, servo = tick_values(st, cm, mem, tel)
    for slot in range(SLOT_COUNT):
        n = 0
        for link in range(links):
            every = sched[link, slot, 0]
            if every > 0 and (tick - sched[link, slot, 1]) % every == 0:
                if n == 0:
                    n = encode(scratch, slot, seq[0], system, component, time_ms, x, rates, ref, thrust, origin,
                               home_z, target, controls, servo)  # fmt: skip
                    seq[0] = (seq[0] + 1) & 0xFF
                at = lens[link]
                copy_into(frames[link, at:], scratch[:n])
                lens[link] = at + n
    return True


DATAGRAM_MAX = SLOT_COUNT * FRAME_MAX


class StreamFrames:
    """The arrays :func:`stream_tick` works in, for ``links`` ground-station links (``out``), of a vehicle whose local
    frame has its origin at ``origin`` (lat, lon [deg], alt [m AMSL]), whose motors give at most ``max_total_thrust``
    [N] together and are ``reversible`` or not."""

    def __init__(self, links: int, origin: tuple[float, float, float], max_total_thrust: float,
                 reversible: bool) -> None:  # fmt: skip
        self.sched = np.zeros((links, SLOT_COUNT, 2), dtype=np.int64)
        self.frames = np.zeros((links, DATAGRAM_MAX), dtype=np.uint8)
        self.lens = np.zeros(links, dtype=np.int64)
        self.tel = np.zeros(TEL_SIZE)
        self.tel[ORIGIN_LAT : ORIGIN_ALT + 1] = origin
        self.tel[MAX_TOTAL_THRUST] = max_total_thrust
        self.tel[REVERSIBLE] = 1.0 if reversible else 0.0
        self.scratch = np.zeros(FRAME_MAX, dtype=np.uint8)
        self.out = (self.sched, self.frames, self.lens, self.tel, self.scratch)

    def datagram(self, link: int) -> bytes:
        return self.frames[link, : self.lens[link]].tobytes()
