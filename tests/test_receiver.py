"""The ground-station receiver (autopilot.receiver): each MAVLink message becomes one typed record for its route, or
is refused with a reason; nothing in it calls control code."""

import math

import numpy as np
import pytest

from autopilot import records, setpoints
from autopilot import tick as kernel
from autopilot.receiver import Receiver
from quadsitl import wire

M = wire.mavlink


class Said:
    """The receiver's outbox, as far as it uses one: what was said and refused."""

    def __init__(self, counters: records.Counters) -> None:
        self.counters, self.texts = counters, []

    def refuse(self, topic: str, text: str) -> None:
        self.counters.refused += 1
        self.texts.append(text)

    def say_once(self, topic: str, text: str, every: float = 5.0) -> None:
        self.texts.append(text)


@pytest.fixture
def rx():
    got: list = []
    routes = records.Routes(*([got.append] * 12))
    counters = records.Counters()
    outbox = Said(counters)
    frame = setpoints.Frame((47.397742, 8.545594, 488.0), xy_vel_max=12.0, z_vel_up=3.0, z_vel_dn=1.5)
    io = np.zeros(kernel.IO_SIZE, dtype=np.int64)
    receiver = Receiver(1, 1, routes, outbox, counters, lambda: frame, lambda: 0.6, io)
    return receiver, got, counters, outbox


def local_ned(x, y, z, mask=0b1001_1111_1000, system=1):  # position and yaw
    return M.MAVLink_set_position_target_local_ned_message(0, system, 1, M.MAV_FRAME_LOCAL_NED, mask, x, y, z,
                                                           0, 0, 0, 0, 0, 0, 0.5, 0)  # fmt: skip


def test_a_position_setpoint_becomes_a_trajectory_setpoint_in_local_ned(rx):
    receiver, got, counters, _ = rx
    receiver.on_message(local_ned(1.0, -2.0, -3.0), link=None)
    (r,) = got
    assert isinstance(r, records.TrajectorySetpoint)
    assert r.horizontal[:2] == (1.0, -2.0) and all(math.isnan(v) for v in r.horizontal[2:])
    assert r.vertical[0] == 3.0 and r.heading[0] == 0.5  # altitude up; the yaw given
    assert counters.refused == 0


def test_a_setpoint_beyond_the_limits_is_refused_with_a_reason_and_never_delivered(rx):
    receiver, got, counters, outbox = rx
    velocity_only = 0b0000_1111_1100_0111
    m = M.MAVLink_set_position_target_local_ned_message(0, 1, 1, M.MAV_FRAME_LOCAL_NED, velocity_only, 0, 0, 0,
                                                        40.0, 0, 0, 0, 0, 0, 0, 0)  # fmt: skip
    receiver.on_message(m, link=None)
    assert got == [] and counters.refused == 1 and "MPC_XY_VEL_MAX" in outbox.texts[0]


def test_messages_for_another_vehicle_are_counted_not_delivered(rx):
    receiver, got, counters, _ = rx
    receiver.on_message(local_ned(1.0, 2.0, -3.0, system=7), link=None)
    assert got == [] and counters.not_for_us == 1


def test_a_command_int_carries_its_location_in_degrees_and_nan_where_not_given(rx):
    receiver, got, _, _ = rx
    m = M.MAVLink_command_int_message(1, 1, M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, M.MAV_CMD_DO_REPOSITION, 0, 0,
                                      -1, 1, 0, math.nan, 473977420, setpoints.INT32_MAX, 10.0)  # fmt: skip
    receiver.on_message(m, link="api")
    (c,) = got
    assert isinstance(c, records.Command) and c.command == M.MAV_CMD_DO_REPOSITION and c.link == "api"
    lat, lon, alt, frame = c.location()
    assert lat == pytest.approx(47.397742) and math.isnan(lon) and alt == 10.0
    assert frame == M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT


def test_an_attitude_beyond_the_tilt_limit_is_refused_and_a_unit_quaternion_flown(rx):
    receiver, got, counters, outbox = rx
    half = math.radians(50) / 2  # 50° of roll, beyond 0.6 rad
    m = M.MAVLink_set_attitude_target_message(0, 1, 1, 0, [math.cos(half), math.sin(half), 0, 0], 0, 0, 0, 0.5)
    receiver.on_message(m, link=None)
    assert got == [] and counters.refused == 1 and "ATT_TILT_MAX" in outbox.texts[0]
    half = math.radians(20) / 2
    m = M.MAVLink_set_attitude_target_message(0, 1, 1, 0, [math.cos(half), math.sin(half), 0, 0], 0, 0, 0, 0.5)
    receiver.on_message(m, link=None)
    (a,) = got
    assert isinstance(a, records.AttitudeSetpoint) and a.roll == pytest.approx(math.radians(20))


def test_unknown_messages_and_short_ftp_requests_are_counted(rx):
    receiver, got, counters, _ = rx
    receiver.on_message(M.MAVLink_file_transfer_protocol_message(0, 1, 1, [0] * 4), link=None)
    receiver.on_message(M.MAVLink_debug_vect_message(b"x", 0, 0.0, 0.0, 0.0), link=None)  # a broadcast we do not take
    assert got == [] and counters.unknown == 2


def attitude_target(mask: int, thrust: float, thrust_body: tuple[float, float, float] | None = None):
    """A SET_ATTITUDE_TARGET as it arrives: packed, and with ``thrust_body`` its MAVLink 2 extension (which
    pymavlink's dialect predates) appended to the payload as a newer sender packs it, then parsed."""
    import struct

    from pymavlink.generator.mavcrc import x25crc

    mav = M.MAVLink(None, srcSystem=255, srcComponent=190)
    frame = bytearray(M.MAVLink_set_attitude_target_message(0, 1, 1, mask, [1, 0, 0, 0], 0, 0, 0, thrust).pack(mav))
    if thrust_body is not None:
        payload = bytes(frame[10 : 10 + frame[1]]).ljust(39, b"\0") + struct.pack("<3f", *thrust_body)
        frame = bytearray(frame[:10]) + payload
        frame[1] = len(payload)
        crc = x25crc(frame[1:])
        crc.accumulate(bytes([M.MAVLink_set_attitude_target_message.crc_extra]))
        frame += struct.pack("<H", crc.crc)
    (m,) = mav.parse_buffer(bytes(frame))
    return m


def test_an_attitude_setpoints_thrust_is_its_collective_thrust_unless_ignored(rx):
    receiver, got, counters, _ = rx
    receiver.on_message(attitude_target(7, 0.7), link=None)  # MAVSDK's set_attitude: rates ignored
    receiver.on_message(attitude_target(7 | 64, 0.7), link=None)  # THROTTLE_IGNORE: the vertical setpoint stays
    receiver.on_message(attitude_target(7 | 32, 0.0, (0.0, 0.0, -0.55)), link=None)  # THRUST_BODY_SET: −z is up
    assert [r.thrust for r in got[:1] + got[2:]] == pytest.approx([0.7, 0.55]) and math.isnan(got[1].thrust)
    assert counters.refused == 0


def test_a_thrust_out_of_range_or_off_the_body_z_axis_is_refused_with_the_field_named(rx):
    receiver, got, counters, outbox = rx
    receiver.on_message(attitude_target(7, 1.5), link=None)
    receiver.on_message(attitude_target(7, -0.2), link=None)  # the x500's motors do not reverse
    receiver.on_message(attitude_target(7 | 32, 0.0, (0.3, 0.0, -0.5)), link=None)
    assert got == [] and counters.refused == 3
    assert "thrust 1.5; allowed: [0, 1]" in outbox.texts[0] and "thrust -0.2; allowed: [0, 1]" in outbox.texts[1]
    assert "thrust_body x 0.3" in outbox.texts[2]


def manual_control(x=0, y=0, z=500, r=0, target=1):
    return M.MAVLink_manual_control_message(target, x, y, z, r, 0)


def test_manual_control_becomes_px4s_sticks_and_an_invalid_axis_is_centred(rx):
    receiver, got, counters, _ = rx
    receiver.on_message(manual_control(x=500, y=-250, z=750, r=1000), link=None)
    receiver.on_message(manual_control(x=32767, y=32767, z=32767, r=32767, target=0), link=None)  # INT16_MAX: unused
    (a, b) = got
    assert isinstance(a, records.ManualControl)
    assert (a.pitch, a.roll, a.throttle, a.yaw) == (0.5, -0.25, 0.5, 1.0)  # PX4: throttle = z / 1000 · 2 − 1
    assert (b.pitch, b.roll, b.throttle, b.yaw) == (0.0, 0.0, 0.0, 0.0)
    assert counters.refused == 0


@pytest.mark.parametrize(
    ("axes", "named"),
    [
        ({"x": 1001}, "x 1001"),
        ({"y": -1001}, "y -1001"),
        ({"z": -1}, "z -1"),
        ({"z": 1001}, "z 1001"),
        ({"r": -2000}, "r -2000"),
    ],
)
def test_manual_control_out_of_range_is_refused_whole_with_the_axis_named(rx, axes, named):
    receiver, got, counters, outbox = rx
    receiver.on_message(manual_control(**axes), link=None)
    assert got == [] and counters.refused == 1
    assert named in outbox.texts[0] and "allowed" in outbox.texts[0]


def test_manual_control_for_another_system_is_counted_not_delivered(rx):
    receiver, got, counters, _ = rx
    receiver.on_message(manual_control(target=2), link=None)
    assert got == [] and counters.not_for_us == 1
