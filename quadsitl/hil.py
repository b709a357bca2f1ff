"""The plant link in sensor mode (docs/sensors.md): what the plant sends every tick instead of ODOMETRY, compiled.

One datagram per control tick, as PX4's simulators send their sensors (``simulator_mavlink``):

- ``HIL_SENSOR``: ``time_usec`` = the tick's simulated time; accelerometer (specific force [m/s², FRD]),
  gyroscope [rad/s, FRD], magnetometer [gauss, FRD], ``abs_pressure`` [hPa], ``pressure_alt`` [m AMSL],
  ``temperature`` [°C]; ``fields_updated`` says which are new this tick (accel 0b111, gyro 0b111000, mag
  0b111000000, baro 0b1101000000000, :mod:`sitl.sensors`); ``id`` 0;
- ``HIL_GPS``, when a fix is delivered this tick (10 Hz, 120 ms after it was measured): ``time_usec`` = when it
  was measured; the fields of :func:`quadsitl.wire.hil_gps_message` (lat/lon [1e-7 deg] by PX4's projection from
  home, altitude AMSL [mm], velocities [cm/s], course [cdeg], ``eph``/``epv`` [cm], fix type 3, satellites);
- ``HIL_STATE_QUATERNION``: the ground truth, for logging and comparison only (PX4 takes it as its simulator's
  ground truth too): attitude quaternion (FRD → NED), body rates [rad/s], lat/lon [1e-7 deg], altitude AMSL
  [mm], velocity NED [cm/s], airspeeds [cm/s] (the speed through the air), the true specific force [mG, FRD].

The autopilot's estimator takes the first two; the truth goes to its telemetry only, never to the controllers
(:mod:`autopilot.tick`). The decoded measurements (``z``) are laid out as the estimator reads them (Z_*).

Layouts come from pymavlink's generated metadata (checked at import); a test shows the frames are byte-identical
to pymavlink's and that pymavlink reads them.
"""

from __future__ import annotations

import math

import numpy as np

from quadsitl.codec import (
    BAD_CRC,
    HEADER_SIZE,
    MAVLINK2_STX,
    NOT_THIS_FRAME,
    ODOMETRY_SIZE,
    _get_f32,
    _put_f32,
    crc16,
    finish_frame,
)
from quadsitl.compiled_frames import (
    body_rates_to_euler_rates,
    euler_rates_to_body_rates,
    euler_to_quaternion,
    geodetic_to_ned,
    ned_to_geodetic,
    quaternion_to_euler,
)
from quadsitl.jit import jit
from quadsitl.rawbytes import get, put
from quadsitl.wire import UINT16_UNKNOWN, mavlink

_SENSOR = mavlink.MAVLink_hil_sensor_message
_GPS = mavlink.MAVLink_hil_gps_message
_TRUTH = mavlink.MAVLink_hil_state_quaternion_message
_BATTERY = mavlink.MAVLink_battery_status_message
assert _SENSOR.unpacker.format == "<QfffffffffffffIB"
assert _BATTERY.unpacker.format == "<iih10HhBBBbiB4HBI"
assert _GPS.unpacker.format == "<QiiiHHHhhhHBBBH"
assert _TRUTH.unpacker.format == "<Q4ffffiiihhhHHhhh"
SENSOR_ID, SENSOR_CRC_EXTRA, SENSOR_SIZE = _SENSOR.id, _SENSOR.crc_extra, _SENSOR.unpacker.size
GPS_ID, GPS_CRC_EXTRA, GPS_SIZE = _GPS.id, _GPS.crc_extra, _GPS.unpacker.size
TRUTH_ID, TRUTH_CRC_EXTRA, TRUTH_SIZE = _TRUTH.id, _TRUTH.crc_extra, _TRUTH.unpacker.size
BATTERY_ID, BATTERY_CRC_EXTRA, BATTERY_SIZE = _BATTERY.id, _BATTERY.crc_extra, _BATTERY.unpacker.size
# A tick's datagram at its largest: the sensors' three frames or the state's ODOMETRY, then the battery's
DATAGRAM_MAX = (max(3 * (HEADER_SIZE + 2) + SENSOR_SIZE + GPS_SIZE + TRUTH_SIZE, HEADER_SIZE + 2 + ODOMETRY_SIZE)
                + HEADER_SIZE + 2 + BATTERY_SIZE)  # fmt: skip

G_MILLI = 9.80665e-3  # [m/s² per mG]: HIL_STATE_QUATERNION's accelerations count standard gravity's thousandths
GPS_FIX_3D = mavlink.GPS_FIX_TYPE_3D_FIX

# HIL_SENSOR.fields_updated, as PX4 reads them: accel, gyro, mag, baro (abs pressure, pressure alt, temperature)
ACCEL_UPDATED, GYRO_UPDATED, MAG_UPDATED, BARO_UPDATED = 0b111, 0b111000, 0b111000000, 0b1101000000000
IMU_UPDATED = ACCEL_UPDATED | GYRO_UPDATED

# ---- what a sensor datagram decodes to (``z``: the estimator's measurements of a tick) and which are new -------
# (Z_GPS_TIME: the fix's HIL_GPS time_usec [µs], when it was measured; Z_BATTERY: the battery's BATTERY_STATUS,
# :func:`decode_battery`'s five values, for the commander)
Z_GYRO, Z_ACCEL, Z_MAG, Z_BARO, Z_GPS_POS, Z_GPS_VEL, Z_GPS_TIME, Z_BATTERY, Z_SIZE = 0, 3, 6, 9, 10, 13, 16, 17, 22
MAG_NEW, BARO_NEW, GPS_NEW, IMU_NEW, BATTERY_NEW = 1, 2, 4, 8, 16
# ... and the ground truth (``truth``): the 12 VehicleState fields (Euler-angle rates by the inverse of eq (1)),
# then body rates p, q, r [rad/s] (as quadsitl.codec.decode_state's), NaN when the datagram carried none.
TRUTH_DECODED = 15
# What was dropped (``dropped``, bits): a sample with a NaN or an infinity is never used.
IMU_DROPPED, MAG_DROPPED, BARO_DROPPED, GPS_DROPPED = 1, 2, 4, 8


@jit(inline=True)
def _put(buf: np.ndarray, at: int, dtype_bytes: int, value: int) -> None:
    """An integer field of ``dtype_bytes`` bytes (2, 4 or 8), little-endian two's complement, at payload offset
    ``at`` (its low bytes, as C's cast to the field's type keeps them)."""
    if dtype_bytes == 8:
        put(buf, HEADER_SIZE + at, np.int64(value))
    elif dtype_bytes == 4:
        put(buf, HEADER_SIZE + at, np.uint32(value & 0xFFFFFFFF))
    else:
        put(buf, HEADER_SIZE + at, np.uint16(value & 0xFFFF))


@jit(inline=True)
def _get_int(buf: np.ndarray, at: int, size: int, signed: bool) -> int:
    """The integer field of ``size`` bytes (2 or 4) at payload offset ``at``, signed or not."""
    if size == 4:
        v = int(get(buf, HEADER_SIZE + at, np.int32)) if signed else int(get(buf, HEADER_SIZE + at, np.uint32))
    else:
        v = int(get(buf, HEADER_SIZE + at, np.int16)) if signed else int(get(buf, HEADER_SIZE + at, np.uint16))
    return v


@jit
def _clamp(v: int, lo: int, hi: int) -> int:
    return max(lo, min(hi, v))


@jit
def encode_sensor(buf: np.ndarray, seq: int, system: int, component: int, time_usec: int, accel: tuple,
                  gyro: tuple, mag: tuple, pressure_hpa: float, pressure_alt: float, temperature_c: float,
                  fields: int) -> int:  # fmt: skip
    """HIL_SENSOR into ``buf``: ``accel`` [m/s², FRD], ``gyro`` [rad/s, FRD], ``mag`` [gauss, FRD], the barometer's
    pressure [hPa], pressure altitude [m AMSL] and temperature [°C], ``fields`` (fields_updated). Returns the
    frame's length."""
    _put(buf, 0, 8, time_usec)
    for i in range(3):
        _put_f32(buf, 8 + 4 * i, accel[i])
        _put_f32(buf, 20 + 4 * i, gyro[i])
        _put_f32(buf, 32 + 4 * i, mag[i])
    _put_f32(buf, 44, pressure_hpa)
    _put_f32(buf, 48, 0.0)  # diff_pressure: no airspeed sensor on a multicopter
    _put_f32(buf, 52, pressure_alt)
    _put_f32(buf, 56, temperature_c)
    _put(buf, 60, 4, fields)
    buf[HEADER_SIZE + 64] = 0  # id: the first sensor instance
    return finish_frame(buf, SENSOR_SIZE, seq, system, component, SENSOR_ID, SENSOR_CRC_EXTRA)


@jit(inline=True)
def battery_fields(voltage: float, current: float, charge: float, energy: float,
                   remaining: float) -> tuple[int, int, int, int, int]:  # fmt: skip
    """The battery as BATTERY_STATUS carries it (PX4's units and rounding): (voltage [mV], current [cA], charge drawn
    [mAh], energy drawn [hJ], remaining [%]), from the voltage [V], current [A], charge [C], energy [J] and the
    remaining share (0..1)."""
    return (round(voltage * 1000.0), _clamp(round(current * 100.0), -1, 32767), round(charge / 3.6),
            round(energy / 100.0), _clamp(round(remaining * 100.0), 0, 100))  # fmt: skip


@jit(inline=True)
def battery_values(fields: tuple[int, int, int, int, int]) -> tuple[float, float, float, float, float]:
    """:func:`battery_fields` back to (voltage [V], current [A], charge drawn [mAh], energy drawn [J], remaining
    share): what the autopilot knows of its battery, from the wire or, in ``quadsitl sim``, from the plant itself."""
    mv, ca, mah, hj, pct = fields
    return mv / 1000.0, ca / 100.0, float(mah), hj * 100.0, pct / 100.0


@jit
def encode_battery(buf: np.ndarray, seq: int, system: int, component: int, voltage: float, current: float,
                   charge: float, energy: float, remaining: float) -> int:  # fmt: skip
    """BATTERY_STATUS into ``buf``, as a smart battery reports itself (:func:`battery_fields`): the pack's voltage in
    the first cell (over 65.534 V, the rest in the next: MAVLink's rule), the others unknown; a LiPo powering
    everything; temperature unknown. Returns the frame's length."""
    mv, ca, mah, hj, pct = battery_fields(voltage, current, charge, energy, remaining)
    _put(buf, 0, 4, mah)
    _put(buf, 4, 4, hj)
    _put(buf, 8, 2, 32767)  # temperature: unknown (INT16_MAX)
    for i in range(10):
        cell = min(mv, UINT16_UNKNOWN - 1)
        _put(buf, 10 + 2 * i, 2, cell if mv > 0 or i == 0 else UINT16_UNKNOWN)
        mv -= cell
    _put(buf, 30, 2, ca)
    buf[HEADER_SIZE + 32] = 0  # id
    buf[HEADER_SIZE + 33] = mavlink.MAV_BATTERY_FUNCTION_ALL
    buf[HEADER_SIZE + 34] = mavlink.MAV_BATTERY_TYPE_LIPO
    buf[HEADER_SIZE + 35] = pct
    for i in range(36, BATTERY_SIZE):  # time remaining, charge state, voltages_ext, mode, faults: none given
        buf[HEADER_SIZE + i] = 0
    return finish_frame(buf, BATTERY_SIZE, seq, system, component, BATTERY_ID, BATTERY_CRC_EXTRA)


@jit(inline=True)
def decode_battery(frame: np.ndarray) -> tuple[float, float, float, float, float]:
    """A BATTERY_STATUS frame (its payload zero-padded) → :func:`battery_values`; the cells' voltages summed up to the
    first unknown one."""
    mv = 0
    for i in range(10):
        cell = _get_int(frame, 10 + 2 * i, 2, False)
        if cell == UINT16_UNKNOWN:
            break
        mv += cell
    fields = (mv, _get_int(frame, 30, 2, True), _get_int(frame, 0, 4, True), _get_int(frame, 4, 4, True),
              int(np.int8(frame[HEADER_SIZE + 35])))  # fmt: skip
    return battery_values(fields)


@jit
def encode_gps(buf: np.ndarray, seq: int, system: int, component: int, time_usec: int, position: tuple,
               velocity: tuple, home: tuple, eph: float, epv: float, satellites: int) -> int:  # fmt: skip
    """HIL_GPS (= :func:`quadsitl.wire.hil_gps_message`, byte for byte) into ``buf``: ``position`` [m, NED from
    ``home`` = (lat [deg], lon [deg], alt [m AMSL])], ``velocity`` [m/s, NED], ``eph``/``epv`` [m]."""
    lat, lon = ned_to_geodetic(position[0], position[1], home[0], home[1])
    vn = _clamp(round(velocity[0] * 100), -32768, 32767)
    ve = _clamp(round(velocity[1] * 100), -32768, 32767)
    vd = _clamp(round(velocity[2] * 100), -32768, 32767)
    speed = min(round(math.hypot(velocity[0], velocity[1]) * 100), UINT16_UNKNOWN - 1)
    cog = UINT16_UNKNOWN
    if speed:
        cog = round(math.degrees(math.atan2(velocity[1], velocity[0])) % 360.0 * 100) % 36000
    _put(buf, 0, 8, time_usec)
    _put(buf, 8, 4, round(lat * 1e7))
    _put(buf, 12, 4, round(lon * 1e7))
    _put(buf, 16, 4, round((home[2] - position[2]) * 1000))
    _put(buf, 20, 2, min(round(eph * 100), UINT16_UNKNOWN - 1))
    _put(buf, 22, 2, min(round(epv * 100), UINT16_UNKNOWN - 1))
    _put(buf, 24, 2, speed)
    _put(buf, 26, 2, vn)
    _put(buf, 28, 2, ve)
    _put(buf, 30, 2, vd)
    _put(buf, 32, 2, cog)
    buf[HEADER_SIZE + 34] = GPS_FIX_3D
    buf[HEADER_SIZE + 35] = satellites
    buf[HEADER_SIZE + 36] = 0  # id
    _put(buf, 37, 2, 0)  # yaw: not available
    return finish_frame(buf, GPS_SIZE, seq, system, component, GPS_ID, GPS_CRC_EXTRA)


@jit
def encode_truth(buf: np.ndarray, seq: int, system: int, component: int, time_usec: int, s: tuple, airspeed: float,
                 specific_force: tuple, home: tuple) -> int:  # fmt: skip
    """HIL_STATE_QUATERNION, the ground truth, into ``buf``: the 12 VehicleState fields ``s`` (positions [m, NED
    from ``home``], Euler-angle rates turned into body rates by eq (1)), ``airspeed`` [m/s] (indicated = true here),
    the true specific force [m/s², FRD] in mG."""
    q = euler_to_quaternion(s[6], s[7], s[8])
    p, qr, r = euler_rates_to_body_rates(s[6], s[7], s[9], s[10], s[11])
    lat, lon = ned_to_geodetic(s[0], s[1], home[0], home[1])
    _put(buf, 0, 8, time_usec)
    for i in range(4):
        _put_f32(buf, 8 + 4 * i, q[i])
    _put_f32(buf, 24, p)
    _put_f32(buf, 28, qr)
    _put_f32(buf, 32, r)
    _put(buf, 36, 4, round(lat * 1e7))
    _put(buf, 40, 4, round(lon * 1e7))
    _put(buf, 44, 4, round((home[2] - s[2]) * 1000))
    for i in range(3):
        _put(buf, 48 + 2 * i, 2, _clamp(round(s[3 + i] * 100), -32768, 32767))
    speed = min(round(airspeed * 100), UINT16_UNKNOWN - 1)
    _put(buf, 54, 2, speed)
    _put(buf, 56, 2, speed)
    for i in range(3):
        _put(buf, 58 + 2 * i, 2, _clamp(round(specific_force[i] / G_MILLI), -32768, 32767))
    return finish_frame(buf, TRUTH_SIZE, seq, system, component, TRUTH_ID, TRUTH_CRC_EXTRA)


@jit(inline=True)
def take_frame(buf: np.ndarray, at: int, length: int, frame: np.ndarray) -> tuple[int, int]:
    """The MAVLink 2 frame at buf[at:length], when it is an unsigned HIL_SENSOR, HIL_GPS, HIL_STATE_QUATERNION or
    BATTERY_STATUS with a good CRC: its header and payload copied into ``frame`` (FRAME_MAX), the payload
    zero-padded to the message's size (MAVLink 2 drops trailing zeros). Returns (message id or NOT_THIS_FRAME or
    BAD_CRC, where the next frame starts)."""
    if length - at < 12 or buf[at] != MAVLINK2_STX or buf[at + 2] != 0:
        return NOT_THIS_FRAME, length
    n = np.int64(buf[at + 1])
    end = at + HEADER_SIZE + n + 2
    if end > length:
        return NOT_THIS_FRAME, length
    msg_id = np.int64(buf[at + 7]) | np.int64(buf[at + 8]) << 8 | np.int64(buf[at + 9]) << 16  # int() would be unsigned
    if msg_id == SENSOR_ID:
        crc_extra, size = SENSOR_CRC_EXTRA, SENSOR_SIZE
    elif msg_id == GPS_ID:
        crc_extra, size = GPS_CRC_EXTRA, GPS_SIZE
    elif msg_id == TRUTH_ID:
        crc_extra, size = TRUTH_CRC_EXTRA, TRUTH_SIZE
    elif msg_id == BATTERY_ID:
        crc_extra, size = BATTERY_CRC_EXTRA, BATTERY_SIZE
    else:
        return NOT_THIS_FRAME, end
    if n > size:
        return NOT_THIS_FRAME, end
    crc = int(buf[at + HEADER_SIZE + n]) | int(buf[at + HEADER_SIZE + n + 1]) << 8
    if crc16(buf, at + 1, at + HEADER_SIZE + n, crc_extra) != crc:
        return BAD_CRC, end
    for i in range(HEADER_SIZE + n):
        frame[i] = buf[at + i]
    for i in range(HEADER_SIZE + n, HEADER_SIZE + size):
        frame[i] = 0
    return msg_id, end


@jit
def _finite3(a: float, b: float, c: float) -> bool:
    return math.isfinite(a) and math.isfinite(b) and math.isfinite(c)


@jit(inline=True)
def decode_sensors(buf: np.ndarray, length: int, home: tuple, z: np.ndarray, truth: np.ndarray,
                   frame: np.ndarray) -> tuple[int, int, int]:  # fmt: skip
    """A sensor datagram in buf[:length] (a HIL_SENSOR, then a HIL_GPS when a fix is delivered, the
    HIL_STATE_QUATERNION truth, and the BATTERY_STATUS of a vehicle with a battery) → the measurements into ``z``
    (Z_*; a GPS position in m NED from ``home``; the battery's values), the truth into ``truth`` (TRUTH_DECODED, NaN
    when absent). Returns (HIL_SENSOR's time_usec, or NOT_THIS_FRAME when the datagram holds anything else or no
    HIL_SENSOR (for pymavlink), or BAD_CRC; which measurements are new (IMU_NEW | MAG_NEW | BARO_NEW | GPS_NEW |
    BATTERY_NEW: a HIL_SENSOR whose fields_updated lacks the accelerometer or the gyroscope carries no IMU sample,
    and z keeps the last); what was dropped for a non-finite value (*_DROPPED: a dropped IMU sample leaves z's
    previous one in place))."""
    t, flags, dropped = NOT_THIS_FRAME, 0, 0
    truth[:] = math.nan
    at = 0
    while at < length:
        msg_id, at = take_frame(buf, at, length, frame)
        if msg_id < 0:
            return msg_id, 0, 0
        if msg_id == SENSOR_ID:
            t = get(frame, HEADER_SIZE, np.int64) & 0x7FFFFFFFFFFFFFFF
            fields = _get_int(frame, 60, 4, False)
            ax, ay, az = _get_f32(frame, 8), _get_f32(frame, 12), _get_f32(frame, 16)
            gx, gy, gz = _get_f32(frame, 20), _get_f32(frame, 24), _get_f32(frame, 28)
            if fields & IMU_UPDATED != IMU_UPDATED:
                pass  # no IMU sample this tick (a failed sensor): z keeps the last one, IMU_NEW not set
            elif _finite3(ax, ay, az) and _finite3(gx, gy, gz):
                z[Z_ACCEL], z[Z_ACCEL + 1], z[Z_ACCEL + 2] = ax, ay, az
                z[Z_GYRO], z[Z_GYRO + 1], z[Z_GYRO + 2] = gx, gy, gz
                flags |= IMU_NEW
            else:
                dropped |= IMU_DROPPED
            if fields & MAG_UPDATED == MAG_UPDATED:
                mx, my, mz = _get_f32(frame, 32), _get_f32(frame, 36), _get_f32(frame, 40)
                if _finite3(mx, my, mz):
                    z[Z_MAG], z[Z_MAG + 1], z[Z_MAG + 2] = mx, my, mz
                    flags |= MAG_NEW
                else:
                    dropped |= MAG_DROPPED
            if fields & BARO_UPDATED == BARO_UPDATED:
                alt = _get_f32(frame, 52)
                if math.isfinite(alt):
                    z[Z_BARO] = alt
                    flags |= BARO_NEW
                else:
                    dropped |= BARO_DROPPED
        elif msg_id == GPS_ID:
            if frame[HEADER_SIZE + 34] >= GPS_FIX_3D:
                lat, lon = _get_int(frame, 8, 4, True) * 1e-7, _get_int(frame, 12, 4, True) * 1e-7
                if abs(lat) <= 90.0 and abs(lon) <= 180.0:
                    north, east = geodetic_to_ned(lat, lon, home[0], home[1])
                    z[Z_GPS_POS], z[Z_GPS_POS + 1] = north, east
                    z[Z_GPS_POS + 2] = home[2] - _get_int(frame, 16, 4, True) * 1e-3
                    for i in range(3):
                        z[Z_GPS_VEL + i] = _get_int(frame, 26 + 2 * i, 2, True) * 0.01
                    z[Z_GPS_TIME] = float(get(frame, HEADER_SIZE, np.int64) & 0x7FFFFFFFFFFFFFFF)
                    flags |= GPS_NEW
                else:
                    dropped |= GPS_DROPPED
        elif msg_id == BATTERY_ID:
            battery = decode_battery(frame)
            for i in range(5):
                z[Z_BATTERY + i] = battery[i]
            flags |= BATTERY_NEW
        else:  # the truth
            q0, q1, q2, q3 = _get_f32(frame, 8), _get_f32(frame, 12), _get_f32(frame, 16), _get_f32(frame, 20)
            p, q, r = _get_f32(frame, 24), _get_f32(frame, 28), _get_f32(frame, 32)
            if _finite3(q0, q1, q2) and _finite3(q3, p, q) and math.isfinite(r):
                north, east = geodetic_to_ned(_get_int(frame, 36, 4, True) * 1e-7, _get_int(frame, 40, 4, True) * 1e-7,
                                              home[0], home[1])  # fmt: skip
                roll, pitch, yaw = quaternion_to_euler(q0, q1, q2, q3)
                rd, pd, yd = body_rates_to_euler_rates(roll, pitch, p, q, r)
                truth[0], truth[1], truth[2] = north, east, home[2] - _get_int(frame, 44, 4, True) * 1e-3
                for i in range(3):
                    truth[3 + i] = _get_int(frame, 48 + 2 * i, 2, True) * 0.01
                truth[6], truth[7], truth[8], truth[9], truth[10], truth[11] = roll, pitch, yaw, rd, pd, yd
                truth[12], truth[13], truth[14] = p, q, r
    return t, flags, dropped
