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
    quaternion_to_euler,
)
from quadsitl.state import VehicleState

PLANT_SYSTEM_ID = 1
PLANT_COMPONENT_ID = mavlink.MAV_COMP_ID_USER1  # the simulator, as PX4's SIH/Gazebo bridges use a separate component
AUTOPILOT_COMPONENT_ID = mavlink.MAV_COMP_ID_AUTOPILOT1
GCS_SYSTEM_ID = 255
GCS_COMPONENT_ID = mavlink.MAV_COMP_ID_MISSIONPLANNER

_NAN21 = [math.nan] + [0.0] * 20


class Mode(IntEnum):
    """The autopilot's flight modes and their PX4 custom-mode encoding (main << 16 | sub << 24)."""

    HOLD = 0  # PX4 auto/loiter: level attitude, hold altitude
    OFFBOARD = 1  # PX4 offboard: external attitude and altitude setpoints
    LAND = 2  # PX4 auto/land: level, descend, disarm on touchdown

    @property
    def px4_custom_mode(self) -> int:
        return {Mode.HOLD: (4 << 16) | (3 << 24), Mode.OFFBOARD: 6 << 16, Mode.LAND: (4 << 16) | (6 << 24)}[self]

    @classmethod
    def from_px4(cls, custom_mode: int) -> Mode | None:
        main, sub = (custom_mode >> 16) & 0xFF, (custom_mode >> 24) & 0xFF
        if main == 6:
            return cls.OFFBOARD
        if main == 4 and sub == 3:
            return cls.HOLD
        if main == 4 and sub == 6:
            return cls.LAND
        return None


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


def state_from_message(m: mavlink.MAVLink_odometry_message) -> VehicleState:
    """ODOMETRY → VehicleState (body rates → Euler-angle rates with the inverse of eq (1))."""
    roll, pitch, yaw = quaternion_to_euler(*m.q)
    rd, pd, yd = body_rates_to_euler_rates(roll, pitch, m.rollspeed, m.pitchspeed, m.yawspeed)
    return VehicleState(m.x, m.y, m.z, m.vx, m.vy, m.vz, roll, pitch, yaw, rd, pd, yd)


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


def tick_of(time_usec: int, period: float) -> int:
    """The control tick a ``time_usec`` stamp belongs to."""
    return round(time_usec * 1e-6 / period)


def usec_of(tick: int, period: float) -> int:
    return round(tick * period * 1e6)


# ---- the per-tick hot path: the two lockstep messages without pymavlink's object machinery -------------
#
# pymavlink builds a message object, then packs it (≈ 6 µs) and parses a frame through a generic state
# machine (≈ 12 µs for ODOMETRY). At 10,000 ticks/s those microseconds are the budget, so the two messages
# exchanged every tick are framed here with ``struct`` and the same CRC library pymavlink uses. The layouts
# come from pymavlink's own generated metadata (checked at import), and a test shows the frames are
# byte-identical to pymavlink's and that each side accepts the other's. Anything else on the link (signed
# frames, several messages in one datagram, other messages) goes through pymavlink.

import struct  # noqa: E402
from typing import NamedTuple  # noqa: E402

from fastcrc.crc16 import mcrf4xx  # noqa: E402

MAVLINK2_STX = 0xFD
_HEADER = struct.Struct("<BBBBBBBHB")  # stx, len, incompat, compat, seq, sysid, compid, msgid (24 bit)
_CRC = struct.Struct("<H")
_ODOMETRY = mavlink.MAVLink_odometry_message
_HIL = mavlink.MAVLink_hil_actuator_controls_message
_ODO_STRUCT = struct.Struct("<Qfff4fffffff21f21fBBBBb")
_HIL_STRUCT = struct.Struct("<QQ16fB")
assert _ODO_STRUCT.format == _ODOMETRY.unpacker.format and _HIL_STRUCT.format == _HIL.unpacker.format
_ODO_HEAD = struct.Struct("<Qfff4fffffff")  # the per-tick fields; the rest of the payload is constant
_ODO_TAIL = struct.pack(
    "<21f21fBBBBb", *_NAN21, *_NAN21, mavlink.MAV_FRAME_LOCAL_NED, mavlink.MAV_FRAME_LOCAL_NED, 0,
    mavlink.MAV_ESTIMATOR_TYPE_NAIVE, 100,
)  # fmt: skip
_HIL_ZEROS = (0.0,) * 12


class Odometry(NamedTuple):
    """The ODOMETRY fields the autopilot uses (names as pymavlink's message attributes)."""

    time_usec: int
    x: float
    y: float
    z: float
    q: tuple[float, float, float, float]
    vx: float
    vy: float
    vz: float
    rollspeed: float
    pitchspeed: float
    yawspeed: float


class ActuatorControls(NamedTuple):
    time_usec: int
    controls: tuple[float, ...]
    mode: int


class FrameError(Exception):
    """A MAVLink 2 frame of one of the two per-tick messages whose CRC does not match."""


class FastLink:
    """Packs and parses the two per-tick messages as MAVLink 2 frames (unsigned), like pymavlink's
    ``msg.pack(link)`` and ``link.parse_buffer`` but for these two messages only."""

    def __init__(self, system: int, component: int) -> None:
        self.system, self.component = system, component
        self.seq = 0

    def _frame(self, msg_id: int, crc_extra: int, payload: bytes) -> bytes:
        n = len(payload)
        while n > 1 and payload[n - 1] == 0:  # MAVLink 2 drops trailing zero bytes of the payload
            n -= 1
        header = _HEADER.pack(MAVLINK2_STX, n, 0, 0, self.seq, self.system, self.component, msg_id & 0xFFFF,
                              msg_id >> 16)  # fmt: skip
        self.seq = (self.seq + 1) & 0xFF
        body = header[1:] + payload[:n]
        crc = mcrf4xx(bytes((crc_extra,)), mcrf4xx(body, 0xFFFF))
        return b"\xfd" + body + _CRC.pack(crc)

    def pack_state(self, time_usec: int, s: VehicleState) -> bytes:
        """= ``state_message(time_usec, s).pack(link)``."""
        q = euler_to_quaternion(s.roll, s.pitch, s.yaw)
        p, qr, r = euler_rates_to_body_rates(s.roll, s.pitch, s.roll_dot, s.pitch_dot, s.yaw_dot)
        head = _ODO_HEAD.pack(time_usec, s.x, s.y, s.z, *q, s.vx, s.vy, s.vz, p, qr, r)
        return self._frame(_ODOMETRY.id, _ODOMETRY.crc_extra, head + _ODO_TAIL)

    def pack_actuators(self, time_usec: int, forces: tuple[float, ...], max_thrust: float, armed: bool) -> bytes:
        """= ``actuator_message(time_usec, forces, max_thrust, armed).pack(link)``."""
        f0, f1, f2, f3 = forces
        mode = mavlink.MAV_MODE_FLAG_SAFETY_ARMED if armed else 0
        payload = _HIL_STRUCT.pack(time_usec, 0, f0 / max_thrust, f1 / max_thrust, f2 / max_thrust, f3 / max_thrust,
                                   *_HIL_ZEROS, mode)  # fmt: skip
        return self._frame(_HIL.id, _HIL.crc_extra, payload)


def _payload(data: bytes, msg_id: int, crc_extra: int, size: int) -> bytes | None:
    """The zero-padded payload if ``data`` is exactly one unsigned MAVLink 2 frame of ``msg_id``; None if it
    is something else (for pymavlink to parse); FrameError if the CRC is wrong."""
    if len(data) < 12 or data[0] != MAVLINK2_STX or data[2] != 0:
        return None
    n = data[1]
    if len(data) != n + 12 or (data[7] | data[8] << 8 | data[9] << 16) != msg_id:
        return None
    if mcrf4xx(bytes((crc_extra,)), mcrf4xx(data[1 : 10 + n], 0xFFFF)) != _CRC.unpack_from(data, 10 + n)[0]:
        raise FrameError(f"message {msg_id}: CRC mismatch")
    payload = data[10 : 10 + n]
    return payload + bytes(size - n) if n < size else payload[:size]


def parse_state(data: bytes) -> Odometry | None:
    """One ODOMETRY frame → :class:`Odometry`; None when ``data`` is not exactly one such frame."""
    payload = _payload(data, _ODOMETRY.id, _ODOMETRY.crc_extra, _ODO_STRUCT.size)
    if payload is None:
        return None
    t, x, y, z, q0, q1, q2, q3, vx, vy, vz, p, q, r = _ODO_HEAD.unpack_from(payload)
    return Odometry(t, x, y, z, (q0, q1, q2, q3), vx, vy, vz, p, q, r)


def parse_actuators(data: bytes) -> ActuatorControls | None:
    """One HIL_ACTUATOR_CONTROLS frame → :class:`ActuatorControls`; None when it is not exactly one."""
    payload = _payload(data, _HIL.id, _HIL.crc_extra, _HIL_STRUCT.size)
    if payload is None:
        return None
    fields = _HIL_STRUCT.unpack(payload)
    return ActuatorControls(fields[0], fields[2:18], fields[18])


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
