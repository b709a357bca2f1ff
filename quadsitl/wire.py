"""MAVLink on the wire between the processes (DESIGN.md §4), in one place.

Plant → autopilot, once a tick: ``ODOMETRY`` (all float32): ``time_usec`` = simulated time, position in
``MAV_FRAME_LOCAL_NED``, quaternion [w, x, y, z] FRD → NED, velocity in NED (``child_frame_id`` =
``MAV_FRAME_LOCAL_NED``), body rates p, q, r (FRD).

Autopilot → plant, once a tick: ``HIL_ACTUATOR_CONTROLS`` with ``time_usec`` echoing the state it answers
and ``controls[0..3]`` = F_j / F_max for motors 1..4 (eq (8) numbering): in [0, 1], or [−1, 1] for
reversible (ideal) actuators.

Ground station ↔ autopilot: PX4 conventions (custom modes below, COMMAND_LONG/ACK, setpoints).
"""

from __future__ import annotations

import math
from enum import IntEnum

from pymavlink.dialects.v20 import common as mavlink

from quadsitl.frames import (
    body_rates_to_euler_rates,
    euler_rates_to_body_rates,
    euler_to_quaternion,
    geodetic_to_ned,
    ned_to_geodetic,
    quaternion_to_euler,
)
from quadsitl.jit import jit
from quadsitl.state import VehicleState

PLANT_SYSTEM_ID = 1
PLANT_COMPONENT_ID = mavlink.MAV_COMP_ID_USER1  # the simulator, as PX4's SIH/Gazebo bridges use a separate component
AUTOPILOT_COMPONENT_ID = mavlink.MAV_COMP_ID_AUTOPILOT1
GCS_SYSTEM_ID = 255
GCS_COMPONENT_ID = mavlink.MAV_COMP_ID_MISSIONPLANNER

_NAN21 = [math.nan] + [0.0] * 20


STATUSTEXT_LEN = 50
_ASCII = str.maketrans(
    {
        "λ": "l",
        "ε": "eps",
        "²": "^2",
        "−": "-",
        "≥": ">=",
        "≤": "<=",
        "·": "*",
        "…": "...",
        "φ": "roll",
        "θ": "pitch",
        "ψ": "yaw",
        "°": " deg",
    }
)


def statustext(severity: int, text: str, chunk_id: int) -> list[mavlink.MAVLink_statustext_message]:
    """``text`` as STATUSTEXT, in ASCII (Greek letters and math signs spelt out, anything else
    replaced by "?"): one message when it fits in 50 bytes, else MAVLink 2 chunks sharing ``chunk_id``
    (1..65535) with ``chunk_seq`` 0, 1, …; the first chunk shorter than 50 bytes (an empty one if
    need be) ends the text, as the MAVLink spec has it."""
    data = text.translate(_ASCII).encode("ascii", errors="replace")
    if len(data) <= STATUSTEXT_LEN:
        return [mavlink.MAVLink_statustext_message(severity, data, 0, 0)]
    chunks = [data[i : i + STATUSTEXT_LEN] for i in range(0, len(data), STATUSTEXT_LEN)]
    if len(chunks[-1]) == STATUSTEXT_LEN:
        chunks.append(b"")
    return [mavlink.MAVLink_statustext_message(severity, ch, chunk_id, i) for i, ch in enumerate(chunks)]


class Mode(IntEnum):
    """The autopilot's flight modes (the numbers in telemetry's status) and their PX4 custom-mode encoding
    (main << 16 | sub << 24, DESIGN.md §9)."""

    HOLD = 0  # PX4 AUTO.LOITER (4/3): hold position, altitude and heading
    OFFBOARD = 1  # PX4 OFFBOARD (6): external position, velocity, acceleration or attitude setpoints
    LAND = 2  # PX4 AUTO.LAND (4/6): stop, descend where the vehicle is, disarm on touchdown
    TAKEOFF = 3  # PX4 AUTO.TAKEOFF (4/2): climb to the takeoff altitude, then hold
    RTL = 4  # PX4 AUTO.RTL (4/5): climb to RTL_RETURN_ALT, fly home, land, disarm
    MISSION = 5  # PX4 AUTO.MISSION (4/4): fly the uploaded mission (autopilot.missions)

    @property
    def px4_custom_mode(self) -> int:
        main, sub = _PX4_MODES[self]
        return (main << 16) | (sub << 24)

    @classmethod
    def from_px4(cls, custom_mode: int) -> Mode | None:
        main, sub = (custom_mode >> 16) & 0xFF, (custom_mode >> 24) & 0xFF
        if main == 6:
            return cls.OFFBOARD
        for mode, (m, s) in _PX4_MODES.items():
            if main == m == 4 and sub == s:
                return mode
        return None


_PX4_MODES = {
    Mode.HOLD: (4, 3), Mode.OFFBOARD: (6, 0), Mode.LAND: (4, 6), Mode.TAKEOFF: (4, 2), Mode.RTL: (4, 5),
    Mode.MISSION: (4, 4),
}  # fmt: skip


def link(system: int, component: int) -> mavlink.MAVLink:
    """A MAVLink 2 encoder/decoder (no file: ``msg.pack(link)`` gives bytes, ``link.parse_buffer`` reads)."""
    mav = mavlink.MAVLink(None, srcSystem=system, srcComponent=component)
    mav.robust_parsing = True
    return mav


def state_message(time_usec: int, s: VehicleState) -> mavlink.MAVLink_odometry_message:
    """The plant's state as ODOMETRY (Euler-angle rates converted to body rates with eq (1))."""
    q = euler_to_quaternion(s.roll, s.pitch, s.yaw)
    p, qr, r = euler_rates_to_body_rates(s.roll, s.pitch, s.roll_dot, s.pitch_dot, s.yaw_dot)
    return mavlink.MAVLink_odometry_message(
        time_usec, mavlink.MAV_FRAME_LOCAL_NED, mavlink.MAV_FRAME_LOCAL_NED,
        s.x, s.y, s.z, q, s.vx, s.vy, s.vz, p, qr, r, _NAN21, _NAN21, 0, mavlink.MAV_ESTIMATOR_TYPE_NAIVE, 100,
    )  # fmt: skip


def actuator_message(
    time_usec: int, forces: tuple[float, float, float, float], max_thrust: float, armed: bool
) -> mavlink.MAVLink_hil_actuator_controls_message:
    """Motor forces [N] → HIL_ACTUATOR_CONTROLS with controls[j] = F_j / F_max."""
    controls = [f / max_thrust for f in forces] + [0.0] * 12
    mode = mavlink.MAV_MODE_FLAG_SAFETY_ARMED if armed else 0
    return mavlink.MAVLink_hil_actuator_controls_message(time_usec, controls, mode, 0)


def forces_from_message(m: mavlink.MAVLink_hil_actuator_controls_message, max_thrust: float) -> tuple[float, ...]:
    """HIL_ACTUATOR_CONTROLS → commanded motor forces [N]."""
    c = m.controls
    return (c[0] * max_thrust, c[1] * max_thrust, c[2] * max_thrust, c[3] * max_thrust)


UINT16_UNKNOWN = 65535  # MAVLink's "unknown" for uint16 fields (GPS eph, epv, vel, cog)


def hil_gps_message(
    time_usec: int,
    position: tuple[float, float, float],
    velocity: tuple[float, float, float],
    home: tuple[float, float, float],
    eph: float,
    epv: float,
    satellites: int,
) -> mavlink.MAVLink_hil_gps_message:
    """A GPS fix as PX4's simulators send it (``HIL_GPS``): ``position`` [m, NED from the local origin ``home`` =
    (lat [deg], lon [deg], alt [m AMSL])] as latitude and longitude [1e-7 deg] (PX4's projection,
    :func:`quadsitl.frames.ned_to_geodetic`) and altitude AMSL [mm]; ``velocity`` [m/s, NED] as vn, ve, vd and
    ground speed [cm/s], course over ground [cdeg, 0 = north; unknown below 1 cm/s]; fix type 3 (3D);
    ``eph``/``epv`` [m] in cm, as PX4's simulator bridge reads them."""
    lat, lon = ned_to_geodetic(position[0], position[1], home[0], home[1])
    vn, ve, vd = (max(-32768, min(32767, round(v * 100))) for v in velocity)
    speed = min(round(math.hypot(velocity[0], velocity[1]) * 100), UINT16_UNKNOWN - 1)
    cog = round(math.degrees(math.atan2(velocity[1], velocity[0])) % 360.0 * 100) % 36000 if speed else UINT16_UNKNOWN
    eph_cm, epv_cm = (min(round(e * 100), UINT16_UNKNOWN - 1) for e in (eph, epv))
    alt_mm = round((home[2] - position[2]) * 1000)
    return mavlink.MAVLink_hil_gps_message(
        time_usec, mavlink.GPS_FIX_TYPE_3D_FIX, round(lat * 1e7), round(lon * 1e7), alt_mm, eph_cm, epv_cm, speed,
        vn, ve, vd, cog, satellites,
    )  # fmt: skip


def gps_from_message(
    m: mavlink.MAVLink_hil_gps_message, home: tuple[float, float, float]
) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
    """The inverse of :func:`hil_gps_message`: (position [m, NED from ``home``], velocity [m/s, NED])."""
    north, east = geodetic_to_ned(m.lat * 1e-7, m.lon * 1e-7, home[0], home[1])
    return (north, east, home[2] - m.alt * 1e-3), (m.vn * 0.01, m.ve * 0.01, m.vd * 0.01)


@jit
def tick_of(time_usec: int, period: float) -> int:
    """The control tick a ``time_usec`` stamp belongs to."""
    return round(time_usec * 1e-6 / period)


@jit
def usec_of(tick: int, period: float) -> int:
    """The ``time_usec`` stamp of a control tick (simulated time, µs)."""
    return round(tick * period * 1e6)


# ---- the per-tick hot path: the two lockstep messages, compiled -----------------------------------------
#
# pymavlink builds a message object, then packs it (≈ 6 µs) and parses a frame through a generic state
# machine (≈ 12 µs for ODOMETRY). At tens of thousands of ticks per second those microseconds are the
# budget, so the two messages exchanged every tick are framed here by compiled functions (:mod:`quadsitl.jit`)
# that write into and read from byte buffers (numpy uint8 arrays) in place. The layouts come from
# pymavlink's own generated metadata (checked at import), and a test shows the frames are byte-identical to
# pymavlink's and that each side accepts the other's. Anything else on the link (signed frames, several
# messages in one datagram, other messages) goes through pymavlink.

import struct  # noqa: E402

import numpy as np  # noqa: E402

from quadsitl.rawbytes import get, put  # noqa: E402

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
    "<21f21fBBBBb", *_NAN21, *_NAN21, mavlink.MAV_FRAME_LOCAL_NED, mavlink.MAV_FRAME_LOCAL_NED, 0,
    mavlink.MAV_ESTIMATOR_TYPE_NAIVE, 100,
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
    table lookups do not wait on each other (a byte at a time, each waits on the last: 3.5 times as long for an
    ODOMETRY frame), then the rest a byte at a time."""
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
    """ODOMETRY (= :func:`state_message`) for the 12 VehicleState fields ``s`` into ``buf`` (FRAME_MAX bytes);
    returns the frame's length."""
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
    buf[HEADER_SIZE + ODOMETRY_TAIL_AT : HEADER_SIZE + ODOMETRY_SIZE] = ODOMETRY_TAIL
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
    """HIL_ACTUATOR_CONTROLS (= :func:`actuator_message`) into ``buf``: controls[j] = F_j / F_max."""
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
    the commanded motor forces [N], :func:`forces_from_message`). Returns its time_usec, or NOT_THIS_FRAME,
    BAD_CRC, NOT_FINITE (a non-finite control, never to apply: ``out`` is then not written)."""
    status = check_frame(buf, length, HIL_ID, HIL_CRC_EXTRA, HIL_SIZE)
    if status < 0:
        return status
    c0, c1, c2, c3 = _get_f32(buf, 16), _get_f32(buf, 20), _get_f32(buf, 24), _get_f32(buf, 28)
    if not (math.isfinite(c0) and math.isfinite(c1) and math.isfinite(c2) and math.isfinite(c3)):
        return NOT_FINITE
    out[0], out[1], out[2], out[3] = c0 * scale, c1 * scale, c2 * scale, c3 * scale
    return int(get(buf, HEADER_SIZE, np.uint64) & 0x7FFFFFFFFFFFFFFF)


SAFETY_ARMED = mavlink.MAV_MODE_FLAG_SAFETY_ARMED


# ---- any other message, for the ground-station links ---------------------------------------------------

_HEADER = struct.Struct("<BBBBBBBHB")  # stx, len, incompat, compat, seq, sysid, compid, msgid (24 bit)


def _payload_only(mav: object, crc_extra: int, payload: bytes, force_mavlink1: bool = False) -> bytes:
    return payload


def pack(msg: mavlink.MAVLink_message, mav: mavlink.MAVLink) -> bytes:
    """= what ``mav.send(msg)`` puts on the wire (the frame, then ``mav.seq`` advances), without pymavlink's
    per-message framing machinery (≈ 10 µs a message, a third of it) on an unsigned link: pymavlink makes
    the payload (its generated ``pack`` with the framing step replaced), and the frame is put together here
    with the same compiled CRC as the per-tick frames.
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


_PARSER = link(0, 0)


def message_of(frame: bytes) -> mavlink.MAVLink_message:
    """The pymavlink message of one unsigned MAVLink 2 frame (a frame built by compiled code, to be sent through
    pymavlink: a signed link, a message asked for)."""
    msg = _PARSER.decode(bytearray(frame))
    _PARSER.seq = 0
    return msg


# ---- MAVLink 2 message signing on the ground-station links -------------------------------------------

SIGNING_ENV = "QUADSITL_SIGNING_KEY"
_SIGNING_EPOCH = 1420070400  # 2015-01-01T00:00:00Z: MAVLink signing timestamps count 10 µs from here


def load_signing_key(option: str, text: str) -> bytes:
    """A 32-byte signing key from 64 hex digits, or from a file holding them (or the 32 raw bytes).
    Errors name the option and what is allowed, never the value: a key must not reach a log."""
    from pathlib import Path

    from quadsitl.cli_util import UsageError

    candidate = text.strip()
    if len(candidate) == 64:
        try:
            return bytes.fromhex(candidate)
        except ValueError:
            pass
    path = Path(text)
    if path.is_file():
        data = path.read_bytes()
        if len(data) == 32:
            return data
        try:
            key = bytes.fromhex(data.decode("ascii").strip())
        except (UnicodeDecodeError, ValueError):
            key = b""
        if len(key) == 32:
            return key
        raise UsageError(f"{option}: the file holds neither 64 hex digits nor 32 raw bytes")
    raise UsageError(f"{option}: expected 64 hex digits (a 32-byte key) or the path of a file holding them")


def resolve_signing_key(text: str | None, option: str = "--signing-key") -> bytes | None:
    """The key an option gives, else ``$QUADSITL_SIGNING_KEY``, else None (no signing)."""
    import os

    text = text or os.environ.get(SIGNING_ENV)
    return load_signing_key(option, text) if text else None


def enable_signing(mav: mavlink.MAVLink, key: bytes, link_id: int = 0) -> None:
    """Sign everything ``mav`` packs and accept only correctly signed, fresh frames when it parses
    (pymavlink refuses unsigned frames, bad signatures and replayed timestamps, and counts them in
    ``mav.signing.badsig_count`` and ``reject_count``)."""
    import time

    mav.signing.secret_key = key
    mav.signing.sign_outgoing = True
    mav.signing.link_id = link_id
    mav.signing.timestamp = int((time.time() - _SIGNING_EPOCH) * 100_000)
    mav.signing.allow_unsigned_callback = None


def signing_refusals(mav: mavlink.MAVLink) -> int:
    """Frames refused for their signature: unsigned, wrongly signed or replayed."""
    s = mav.signing
    return s.badsig_count + s.reject_count if s.secret_key is not None else 0
