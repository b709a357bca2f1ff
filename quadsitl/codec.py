"""The per-tick MAVLink codec, compiled (:mod:`quadsitl.jit`): the two messages the plant and the autopilot exchange
every tick, and the framing of any other message the processes send.

pymavlink builds a message object, then packs it and parses a frame through a generic state machine, each costing more
than a whole compiled tick (docs/performance.md#per-call). In a lockstep run that time is the budget, so the two
messages exchanged every tick (:mod:`quadsitl.wire` says what they hold) are framed here by compiled functions that
write into and read from byte buffers (numpy uint8 arrays) in place. The layouts come from pymavlink's own generated
metadata (checked at import), and a test shows the frames are byte-identical to pymavlink's and that each side accepts
the other's. Anything else on the link (signed frames, several messages in one datagram, other messages) goes through
pymavlink; :func:`pack` frames such a message with the same compiled CRC.

Only the processes that run compiled code import this module; :mod:`quadsitl.wire` (pymavlink only) is what the
ground side needs.
"""

from __future__ import annotations

import math
import struct

import numpy as np

from quadsitl.compiled_frames import (
    body_rates_to_euler_rates,
    euler_rates_to_body_rates,
    euler_to_quaternion,
    quaternion_to_euler,
)
from quadsitl.jit import jit
from quadsitl.rawbytes import get, put
from quadsitl.wire import UNKNOWN_COVARIANCE, mavlink


@jit
def tick_of(time_usec: int, period: float) -> int:
    """The control tick a ``time_usec`` stamp belongs to."""
    return round(time_usec * 1e-6 / period)


@jit
def usec_of(tick: int, period: float) -> int:
    """The ``time_usec`` stamp of a control tick (simulated time, µs)."""
    return round(tick * period * 1e6)


# ---- the two per-tick messages ------------------------------------------------------------------------

MAVLINK2_STX = 0xFD
HEADER_SIZE = 10  # stx, len, incompat, compat, seq, sysid, compid, msgid (24 bit)
FRAME_MAX = 280  # a MAVLink 2 frame's largest size: header, 255 bytes of payload, CRC, 13-byte signature
_ODOMETRY = mavlink.MAVLink_odometry_message
_HIL = mavlink.MAVLink_hil_actuator_controls_message
_ODO_STRUCT = struct.Struct("<Qfff4fffffff21f21fBBBBb")
_HIL_STRUCT = struct.Struct("<QQ16fB")
assert _ODO_STRUCT.format == _ODOMETRY.unpacker.format and _HIL_STRUCT.format == _HIL.unpacker.format
ODOMETRY_ID, ODOMETRY_CRC_EXTRA, ODOMETRY_SIZE = _ODOMETRY.id, _ODOMETRY.crc_extra, _ODO_STRUCT.size
HIL_ID, HIL_CRC_EXTRA, HIL_SIZE = _HIL.id, _HIL.crc_extra, _HIL_STRUCT.size
# The ODOMETRY fields after the per-tick ones: unknown covariances, frames, estimator type, quality.
ODOMETRY_TAIL = np.frombuffer(struct.pack(
    "<21f21fBBBBb", *UNKNOWN_COVARIANCE, *UNKNOWN_COVARIANCE, mavlink.MAV_FRAME_LOCAL_NED,
    mavlink.MAV_FRAME_LOCAL_NED, 0, mavlink.MAV_ESTIMATOR_TYPE_NAIVE, 100,
), dtype=np.uint8).copy()  # fmt: skip
ODOMETRY_TAIL_AT = 60  # payload offset of the first covariance
# Decoded plant state (decode_state's ``out``): the 12 VehicleState fields, then body rates p, q, r [rad/s].
BODY_RATES = 12
DECODED_SIZE = 15
# Return codes of the decoders (a time_usec is >= 0).
NOT_THIS_FRAME, BAD_CRC, NOT_FINITE = -1, -2, -3


def _crc_tables() -> np.ndarray:
    """CRC-16/MCRF4XX (X.25), MAVLink's checksum, as tables for eight bytes at a time ("slicing by 8", Intel's
    scheme for reflected CRCs): row 0 is the one-byte table, row k what a byte does to the CRC with k more zero
    bytes after it."""
    tables = np.zeros((8, 256), dtype=np.int32)  # int32: its numbers mix with int64's in compiled code
    for i in range(256):
        tmp = i  # crc_accumulate with crc = 0: tmp = byte ^ (crc & 0xff)
        tmp = (tmp ^ (tmp << 4)) & 0xFF
        tables[0, i] = ((tmp << 8) ^ (tmp << 3) ^ (tmp >> 4)) & 0xFFFF
    for k in range(1, 8):
        for i in range(256):
            prev = int(tables[k - 1, i])
            tables[k, i] = (prev >> 8) ^ int(tables[0, prev & 0xFF])
    return tables


CRC_TABLES = _crc_tables()


@jit(inline=True)
def crc16(buf: np.ndarray, start: int, end: int, crc_extra: int) -> int:
    """MAVLink's CRC of buf[start:end] followed by the message's CRC_EXTRA byte: eight bytes per step, whose
    table lookups do not wait on each other (a byte at a time, each waits on the last: several times as long,
    docs/performance.md#per-call), then the rest a byte at a time."""
    t = CRC_TABLES
    crc = 0xFFFF
    i = start
    while i + 8 <= end:
        c = crc ^ (int(buf[i]) | int(buf[i + 1]) << 8)
        crc = (int(t[7, c & 0xFF]) ^ int(t[6, c >> 8]) ^ int(t[5, buf[i + 2]]) ^ int(t[4, buf[i + 3]])
               ^ int(t[3, buf[i + 4]]) ^ int(t[2, buf[i + 5]]) ^ int(t[1, buf[i + 6]])
               ^ int(t[0, buf[i + 7]]))  # fmt: skip
        i += 8
    for j in range(i, end):
        crc = (crc >> 8) ^ int(t[0, (crc ^ int(buf[j])) & 0xFF])
    return (crc >> 8) ^ int(t[0, (crc ^ crc_extra) & 0xFF])


@jit(inline=True)
def finish_frame(buf: np.ndarray, size: int, seq: int, system: int, component: int, msg_id: int,
                 crc_extra: int) -> int:  # fmt: skip
    """Frame the ``size``-byte payload at buf[HEADER_SIZE:]: drop its trailing zero bytes (MAVLink 2 does),
    write the header and the CRC. Returns the frame's length."""
    n = size
    while n > 1 and buf[HEADER_SIZE + n - 1] == 0:
        n -= 1
    buf[0], buf[1], buf[2], buf[3], buf[4] = MAVLINK2_STX, n, 0, 0, seq & 0xFF
    buf[5], buf[6] = system, component
    buf[7], buf[8], buf[9] = msg_id & 0xFF, (msg_id >> 8) & 0xFF, msg_id >> 16
    crc = crc16(buf, 1, HEADER_SIZE + n, crc_extra)
    buf[HEADER_SIZE + n], buf[HEADER_SIZE + n + 1] = crc & 0xFF, crc >> 8
    return HEADER_SIZE + n + 2


@jit
def check_frame(buf: np.ndarray, length: int, msg_id: int, crc_extra: int, size: int) -> int:
    """If buf[:length] is exactly one unsigned MAVLink 2 frame of ``msg_id``: zero-pad its payload to
    ``size`` bytes in place (the CRC bytes after it are not needed again) and return 0; NOT_THIS_FRAME when
    it is something else (for pymavlink to parse), BAD_CRC when its CRC does not match."""
    if length < 12 or buf[0] != MAVLINK2_STX or buf[2] != 0:
        return NOT_THIS_FRAME
    n = int(buf[1])
    if length != n + 12 or (int(buf[7]) | int(buf[8]) << 8 | int(buf[9]) << 16) != msg_id:
        return NOT_THIS_FRAME
    if crc16(buf, 1, HEADER_SIZE + n, crc_extra) != (int(buf[HEADER_SIZE + n]) | int(buf[HEADER_SIZE + n + 1]) << 8):
        return BAD_CRC
    for i in range(HEADER_SIZE + n, HEADER_SIZE + size):
        buf[i] = 0
    return 0


@jit(inline=True)
def _put_f32(buf: np.ndarray, at: int, value: float) -> None:
    put(buf, HEADER_SIZE + at, np.float32(value))


@jit(inline=True)
def _get_f32(buf: np.ndarray, at: int) -> float:
    return np.float64(get(buf, HEADER_SIZE + at, np.float32))  # float() keeps float32


@jit
def encode_state(buf: np.ndarray, seq: int, system: int, component: int, time_usec: int, s: tuple) -> int:
    """ODOMETRY (= :func:`quadsitl.wire.state_message`) for the 12 VehicleState fields ``s`` into ``buf`` (FRAME_MAX
    bytes); returns the frame's length."""
    roll, pitch, yaw = s[6], s[7], s[8]
    q = euler_to_quaternion(roll, pitch, yaw)
    p, qr, r = euler_rates_to_body_rates(roll, pitch, s[9], s[10], s[11])
    put(buf, HEADER_SIZE, np.uint64(time_usec))
    _put_f32(buf, 8, s[0])
    _put_f32(buf, 12, s[1])
    _put_f32(buf, 16, s[2])
    for i in range(4):
        _put_f32(buf, 20 + 4 * i, q[i])
    _put_f32(buf, 36, s[3])
    _put_f32(buf, 40, s[4])
    _put_f32(buf, 44, s[5])
    _put_f32(buf, 48, p)
    _put_f32(buf, 52, qr)
    _put_f32(buf, 56, r)
    for i in range(ODOMETRY_TAIL.size):
        buf[HEADER_SIZE + ODOMETRY_TAIL_AT + i] = ODOMETRY_TAIL[i]
    return finish_frame(buf, ODOMETRY_SIZE, seq, system, component, ODOMETRY_ID, ODOMETRY_CRC_EXTRA)


@jit
def decode_state(buf: np.ndarray, length: int, out: np.ndarray) -> int:
    """An ODOMETRY frame in buf[:length] → ``out`` (DECODED_SIZE: the VehicleState fields, Euler-angle rates
    by the inverse of eq (1), then body rates p, q, r). Returns its time_usec, or NOT_THIS_FRAME, BAD_CRC,
    NOT_FINITE (a state never to fly: ``out`` is then not written)."""
    status = check_frame(buf, length, ODOMETRY_ID, ODOMETRY_CRC_EXTRA, ODOMETRY_SIZE)
    if status < 0:
        return status
    x, y, z = _get_f32(buf, 8), _get_f32(buf, 12), _get_f32(buf, 16)
    q0, q1, q2, q3 = _get_f32(buf, 20), _get_f32(buf, 24), _get_f32(buf, 28), _get_f32(buf, 32)
    vx, vy, vz = _get_f32(buf, 36), _get_f32(buf, 40), _get_f32(buf, 44)
    p, q, r = _get_f32(buf, 48), _get_f32(buf, 52), _get_f32(buf, 56)
    total = x + y + z + q0 + q1 + q2 + q3 + vx + vy + vz + p + q + r
    if not math.isfinite(total):  # a NaN or an infinity in any field (or an overflow of their sum)
        for v in (x, y, z, q0, q1, q2, q3, vx, vy, vz, p, q, r):
            if not math.isfinite(v):
                return NOT_FINITE
    roll, pitch, yaw = quaternion_to_euler(q0, q1, q2, q3)
    rd, pd, yd = body_rates_to_euler_rates(roll, pitch, p, q, r)
    out[0], out[1], out[2], out[3], out[4], out[5] = x, y, z, vx, vy, vz
    out[6], out[7], out[8], out[9], out[10], out[11] = roll, pitch, yaw, rd, pd, yd
    out[12], out[13], out[14] = p, q, r
    return int(get(buf, HEADER_SIZE, np.uint64) & 0x7FFFFFFFFFFFFFFF)


@jit
def encode_actuators(buf: np.ndarray, seq: int, system: int, component: int, time_usec: int, forces: tuple,
                     max_thrust: float, armed: bool) -> int:  # fmt: skip
    """HIL_ACTUATOR_CONTROLS (= :func:`quadsitl.wire.actuator_message`) into ``buf``: controls[j] = F_j / F_max."""
    put(buf, HEADER_SIZE, np.uint64(time_usec))
    put(buf, HEADER_SIZE + 8, np.uint64(0))
    for i in range(4):
        _put_f32(buf, 16 + 4 * i, forces[i] / max_thrust)
    buf[HEADER_SIZE + 32 : HEADER_SIZE + HIL_SIZE - 1] = 0
    buf[HEADER_SIZE + HIL_SIZE - 1] = SAFETY_ARMED if armed else 0
    return finish_frame(buf, HIL_SIZE, seq, system, component, HIL_ID, HIL_CRC_EXTRA)


@jit
def decode_actuators(buf: np.ndarray, length: int, out: np.ndarray, scale: float) -> int:
    """A HIL_ACTUATOR_CONTROLS frame in buf[:length] → ``out`` (4): controls[0..3] × ``scale`` (F_max gives
    the commanded motor forces [N], :func:`quadsitl.wire.forces_from_message`). Returns its time_usec, or
    NOT_THIS_FRAME, BAD_CRC, NOT_FINITE (a non-finite control, never to apply: ``out`` is then not written)."""
    status = check_frame(buf, length, HIL_ID, HIL_CRC_EXTRA, HIL_SIZE)
    if status < 0:
        return status
    c0, c1, c2, c3 = _get_f32(buf, 16), _get_f32(buf, 20), _get_f32(buf, 24), _get_f32(buf, 28)
    if not (math.isfinite(c0) and math.isfinite(c1) and math.isfinite(c2) and math.isfinite(c3)):
        return NOT_FINITE
    out[0], out[1], out[2], out[3] = c0 * scale, c1 * scale, c2 * scale, c3 * scale
    return int(get(buf, HEADER_SIZE, np.uint64) & 0x7FFFFFFFFFFFFFFF)


SAFETY_ARMED = mavlink.MAV_MODE_FLAG_SAFETY_ARMED


# ---- any other message, on the ground-station links -----------------------------------------------------

_HEADER = struct.Struct("<BBBBBBBHB")  # stx, len, incompat, compat, seq, sysid, compid, msgid (24 bit)


def _payload_only(mav: object, crc_extra: int, payload: bytes, force_mavlink1: bool = False) -> bytes:
    return payload


def pack(msg: mavlink.MAVLink_message, mav: mavlink.MAVLink) -> bytes:
    """= what ``mav.send(msg)`` puts on the wire (the frame, then ``mav.seq`` advances), without pymavlink's
    per-message framing machinery (a good part of a send's cost: docs/performance.md#per-call) on an unsigned link:
    pymavlink makes the payload (its generated ``pack`` with the framing step replaced), and the frame is put
    together here with the same compiled CRC as the per-tick frames.
    A signed link goes through pymavlink whole."""
    if mav.signing.sign_outgoing:
        frame = msg.pack(mav)
    else:
        msg._pack = _payload_only  # the generated pack() hands its payload to _pack: take it as it is
        try:
            payload = msg.pack(mav)
        finally:
            del msg._pack
        n = len(payload)
        while n > 1 and payload[n - 1] == 0:  # MAVLink 2 drops trailing zero bytes of the payload
            n -= 1
        msg_id = msg.get_msgId()  # not msg.id: STATUSTEXT has a field of that name
        body = _HEADER.pack(MAVLINK2_STX, n, 0, 0, mav.seq, mav.srcSystem, mav.srcComponent, msg_id & 0xFFFF,
                            msg_id >> 16)[1:] + payload[:n]  # fmt: skip
        crc = crc16(np.frombuffer(body, dtype=np.uint8), 0, len(body), msg.crc_extra)
        frame = b"\xfd" + body + struct.pack("<H", crc)
    mav.seq = (mav.seq + 1) & 0xFF
    return frame
