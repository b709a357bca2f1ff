"""The per-tick telemetry messages built by compiled code (autopilot.stream_frames): the bytes pymavlink sends for
the same fields, computed here independently from the messages' definitions (PX4's conventions), on random states;
and the schedule per link the tick follows."""

from __future__ import annotations

import math

import numpy as np
import pytest

from autopilot import commander
from autopilot import stream_frames as sf
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
    Commander,
)
from autopilot.control_params import MEM_ATTITUDE_REF, MEM_FORCES, MEM_SIZE, MEM_U
from quadsitl import codec, wire
from quadsitl.frames import euler_to_quaternion, ned_to_geodetic
from quadsitl.wire import Mode, mavlink

ORIGIN = (47.397742, 8.545594, 488.0)


def _int(value: float, lo: int, hi: int) -> int:
    return int(min(max(round(value), lo), hi)) if math.isfinite(value) else 0


def _cdeg(angle: float) -> int:
    return round(math.degrees(angle) % 360.0 * 100) % 36000 if math.isfinite(angle) else 0


def _pwm(control: float, reversible: bool) -> int:
    c = (control + 1.0) / 2.0 if reversible else control
    return round(1000.0 + 1000.0 * min(max(c, 0.0), 1.0)) if math.isfinite(c) else 0


def reference_message(mid: int, time_ms: int, x, rates, ref, thrust: float, origin, home_z: float, target, controls,
                      armed: bool, reversible: bool):  # fmt: skip
    """The message as its definition says, in plain Python (the test's own reading of the MAVLink messages)."""
    ms = time_ms & 0xFFFFFFFF
    if mid == mavlink.MAVLINK_MSG_ID_SERVO_OUTPUT_RAW:  # port 0: the four motors, 0 µs while disarmed
        out = [_pwm(c, reversible) if armed else 0 for c in controls]
        return mavlink.MAVLink_servo_output_raw_message((time_ms * 1000) & 0xFFFFFFFF, 0, *out, *[0] * 12)
    if mid == mavlink.MAVLINK_MSG_ID_ACTUATOR_OUTPUT_STATUS:
        return mavlink.MAVLink_actuator_output_status_message(time_ms * 1000, 0b1111, [*controls, *[0.0] * 28])
    if mid == mavlink.MAVLINK_MSG_ID_POSITION_TARGET_LOCAL_NED:  # a field not controlled: its ignore bit, 0
        tx, ty, tvx, tvy, alt, climb = target
        values = (tx, ty, -alt, tvx, tvy, -climb)
        mask = 64 | 128 | 256 | 2048 | sum(1 << i for i, v in enumerate(values) if not math.isfinite(v))
        mask |= 0 if math.isfinite(ref[3]) else 1024
        finite = [v if math.isfinite(v) else 0.0 for v in values]
        yaw = ref[3] if math.isfinite(ref[3]) else 0.0
        return mavlink.MAVLink_position_target_local_ned_message(ms, mavlink.MAV_FRAME_LOCAL_NED, mask, *finite,
                                                                 0.0, 0.0, 0.0, yaw, 0.0)  # fmt: skip
    roll, pitch, yaw = x[6:9]
    if math.isfinite(x[0]) and math.isfinite(x[1]):
        lat, lon = ned_to_geodetic(x[0], x[1], origin[0], origin[1])
        lat, lon = _int(lat * 1e7, -900_000_000, 900_000_000), _int(lon * 1e7, -1_800_000_000, 1_800_000_000)
    else:
        lat = lon = 0
    alt = _int((origin[2] - x[2]) * 1000, -(2**31), 2**31 - 1)
    if mid == mavlink.MAVLINK_MSG_ID_ATTITUDE:
        return mavlink.MAVLink_attitude_message(ms, roll, pitch, yaw, *rates)
    if mid == mavlink.MAVLINK_MSG_ID_ATTITUDE_QUATERNION:
        return mavlink.MAVLink_attitude_quaternion_message(ms, *euler_to_quaternion(roll, pitch, yaw), *rates, [0] * 4)
    if mid == mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED:
        return mavlink.MAVLink_local_position_ned_message(ms, *x[:6])
    if mid == mavlink.MAVLINK_MSG_ID_ATTITUDE_TARGET:
        q = euler_to_quaternion(ref[1], ref[2], ref[3])
        return mavlink.MAVLink_attitude_target_message(ms, 7, q, 0.0, 0.0, 0.0, thrust)
    if mid == mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT:
        v = [_int(c * 100, -32768, 32767) for c in x[3:6]]
        rel = _int((home_z - x[2]) * 1000, -(2**31), 2**31 - 1)
        return mavlink.MAVLink_global_position_int_message(ms, lat, lon, alt, rel, *v, _cdeg(yaw))
    assert mid == mavlink.MAVLINK_MSG_ID_GPS_RAW_INT
    vel = _int(math.hypot(x[3], x[4]) * 100, 0, 65534)
    cog = _cdeg(math.atan2(x[4], x[3])) if vel > 0 else 65535
    return mavlink.MAVLink_gps_raw_int_message(max(time_ms * 1000, 0), 3, lat, lon, alt, 100, 100, vel, cog, 10, alt,
                                               11, 1, 10, 0, 0)  # fmt: skip


def random_case(rng: np.random.Generator):
    x = tuple(float(v) for v in rng.normal(0.0, [50, 50, 30, 5, 5, 2, 0.5, 0.5, 3, 1, 1, 1]))
    rates = tuple(float(v) for v in rng.normal(0.0, 1.0, 3))
    ref = tuple(float(v) for v in rng.normal(0.0, [5, 0.3, 0.3, 2]))
    target = tuple(float(v) if rng.uniform() < 0.8 else math.nan for v in rng.normal(0.0, [50, 50, 5, 5, 30, 2]))
    controls = tuple(float(v) for v in rng.uniform(-1.2, 1.2, 4))
    return (int(rng.integers(0, 2**33)), x, rates, ref, float(rng.uniform(0, 1)), -float(rng.uniform(0, 5)), target,
            controls, bool(rng.integers(2)), bool(rng.integers(2)))  # fmt: skip


NAN6 = (math.nan,) * 6


@pytest.mark.parametrize("mid", sf.COMPILED)
def test_each_frame_is_the_bytes_pymavlink_sends_for_the_messages_definition(mid):
    rng = np.random.default_rng(mid)
    buf, mav = np.zeros(codec.FRAME_MAX, dtype=np.uint8), wire.link(3, 1)
    cases = [random_case(rng) for _ in range(200)]
    rest = (0.0,) * 12, (0.0,) * 3, (0.0, 0.0, 0.0, math.nan), 0.0, 0.0, (0.0,) * 6, (0.0,) * 4
    cases.append((1234, *rest, True, True))  # at rest; a yaw rate alone
    far = (1e9, -1e9, -1e9, 1e5, -1e5, 1e5, 0.0, 0.0, -7.0, 0, 0, 0)
    cases.append((5, far, (0.0,) * 3, (0,) * 4, 1.0, 0.0, (1e9, -1e9, 1e5, -1e5, 1e9, 1e5), (1.0, -1.0, 2.0, -2.0),
                  True, False))  # fmt: skip
    nothing = (math.nan,) * 12, (0.0,) * 3, (0,) * 4, 0.5, 0.0, NAN6, (0.5,) * 4
    cases.append((7, *nothing, False, False))  # nothing finite: the fields say 0
    for seq, (time_ms, x, rates, ref, thrust, home_z, target, controls, armed, reversible) in enumerate(cases):
        servo = tuple(_pwm(c, reversible) if armed else 0 for c in controls)
        n = sf.encode(buf, sf.SLOT_OF[mid], seq & 0xFF, 3, 1, time_ms, x, rates, ref, thrust, ORIGIN, home_z,
                      target, controls, servo)  # fmt: skip
        mav.seq = seq & 0xFF
        want = reference_message(mid, time_ms, x, rates, ref, thrust, ORIGIN, home_z, target, controls, armed,
                                 reversible)  # fmt: skip
        assert bytes(buf[:n]) == want.pack(mav), (seq, x)


def test_the_motor_outputs_are_pwm_of_the_controls_and_none_while_disarmed():
    """SERVO_OUTPUT_RAW's PWM: [0, 1] → 1000..2000 µs, reversible [−1, 1] → 1000..2000 (1500 = zero), clamped; no
    pulse (0) for a control that is not finite, and for every motor while disarmed."""
    assert [sf.pwm(c, True) for c in (-1.0, 0.0, 1.0, 2.0, 0.5)] == [1000, 1500, 2000, 2000, 1750]
    assert [sf.pwm(c, False) for c in (0.0, 0.25, 1.0, -1.0, math.nan)] == [1000, 1250, 2000, 1000, 0]
    assert sf.pwms((0.5, -0.5, 1.0, 0.0), True, True) == (1750, 1250, 2000, 1500)
    assert sf.pwms((0.5, -0.5, 1.0, 0.0), False, True) == (0, 0, 0, 0)


def test_the_helpers_round_half_to_even_and_clamp_as_python_does():
    for value in (0.5, 1.5, 2.5, -0.5, -2.5, 1e30, -1e30, 12.4999, math.inf, math.nan):
        assert sf.clamp_int(value, -100, 100) == _int(value, -100, 100)
    for angle in (-0.1, -3.5, 7.0, -1e-18, 0.0, math.pi, math.nan):
        assert sf.cdeg(angle) == _cdeg(angle)


def tick_arrays(armed: bool, position_loop: bool = False):
    st = np.arange(15, dtype=float) * 0.1
    c = Commander()
    cm = c.cm
    cm[ARMED] = 1.0 if armed else 0.0
    cm[REF_ALT], cm[REF_ROLL], cm[REF_PITCH], cm[REF_YAW] = 5.0, 0.1, -0.1, 1.0
    cm[REF_X], cm[REF_Y], cm[REF_VX], cm[REF_VY], cm[REF_CLIMB] = 3.0, -4.0, 0.5, math.nan, 1.5
    cm[TARGET_ALT], cm[HOLD_YAW], cm[HOME_ALT] = 2.0, -1.0, 0.25
    mem = np.zeros(MEM_SIZE)
    mem[MEM_U] = 30.0
    mem[MEM_FORCES : MEM_FORCES + 4] = (5.0, -5.0, 10.0, 0.0)
    # the roll and pitch the position loop made this tick (autopilot.tick.control_step), NaN when it did not fly
    mem[MEM_ATTITUDE_REF : MEM_ATTITUDE_REF + 2] = (0.2, -0.3) if position_loop else (math.nan, math.nan)
    return st, cm, mem


@pytest.mark.parametrize("armed", [True, False])
@pytest.mark.parametrize("reversible", [True, False])
@pytest.mark.parametrize("position_loop", [True, False])
def test_the_tick_shows_the_reference_flown_or_disarmed_the_one_held(armed, reversible, position_loop):
    """ATTITUDE_TARGET shows the attitude flown: the setpoint's, or the position loop's roll and pitch when it flies
    (PX4's vehicle_attitude_setpoint); disarmed, the altitude and heading held, level. The same reference as the
    records' and ``sim``'s (sf.reference_shown)."""
    st, cm, mem = tick_arrays(armed, position_loop)
    frames = sf.StreamFrames(1, ORIGIN, 40.0, reversible)
    x, rates, ref, thrust, origin, home_z, target, controls, servo = sf.tick_values(st, cm, mem, frames.tel)
    assert x == tuple(st[:12]) and rates == tuple(st[12:15]) and origin == ORIGIN and home_z == -0.25
    flown = (5.0, 0.2, -0.3, 1.0) if position_loop else (5.0, 0.1, -0.1, 1.0)
    assert ref == (flown if armed else (2.0, 0.0, 0.0, -1.0))
    assert ref == sf.reference_shown(cm, mem)[:4]
    assert thrust == 0.75
    if armed:
        assert target[:3] == (3.0, -4.0, 0.5) and math.isnan(target[3]) and target[4:] == (5.0, 1.5)
    else:  # the altitude held alone
        assert all(math.isnan(v) for v in target[:4] + target[5:]) and target[4] == 2.0
    assert controls == (0.5, -0.5, 1.0, 0.0)  # F_j over F_max = 10 N
    pulses = (1750, 1250, 2000, 1500) if reversible else (1500, 1000, 2000, 1000)
    assert servo == (pulses if armed else (0, 0, 0, 0))


def test_the_tick_builds_what_is_due_on_each_link_once_in_id_order():
    st, cm, mem = tick_arrays(True)
    frames = sf.StreamFrames(2, ORIGIN, 40.0, False)
    att, gpi, lpn = (sf.SLOT_OF[m] for m in (30, 33, 32))
    frames.sched[0, att] = (20, 4)  # 50 Hz at phase 4
    frames.sched[1, att] = (10, 4)  # 100 Hz on the other link
    frames.sched[0, gpi] = (100, 4)
    frames.sched[1, lpn] = (20, 5)
    seq = np.array([250], dtype=np.int64)

    def tick(k: int) -> list[list[int]]:
        due = sf.stream_tick(k, 0.001, st, cm, mem, seq, 1, 1, frames.out)
        out = []
        for link in range(2):
            msgs = wire.link(0, 0).parse_buffer(frames.datagram(link)) or []
            out.append([(m.get_msgId(), m.get_seq()) for m in msgs])
        assert due == any(out)
        return out

    assert tick(3) == [[], []] and seq[0] == 250
    assert tick(4) == [[(30, 250), (33, 251)], [(30, 250)]]  # ATTITUDE built once, in both; then GPI
    assert tick(14) == [[], [(30, 252)]]
    assert tick(25) == [[], [(32, 253)]]
    assert tick(24) == [[(30, 254)], [(30, 254)]]
    assert tick(104) == [[(30, 255), (33, 0)], [(30, 255)]]  # the sequence wraps
    a, b = frames.datagram(0), frames.datagram(1)
    assert a[: len(b)] == b  # the same ATTITUDE bytes on both links


def test_nothing_compiles_on_the_tick_path_once_warmed_up():
    """After the autopilot's warm-up, building any streamed message from Python (a requested message, a signed
    link, the slower streams), from a snapshot of ints or floats, packing one (quadsitl.codec.pack: STATUSTEXT,
    parameters, command answers), or a mode change from Python (Commander.set_mode), compiles nothing more: no
    stall on the tick path (a first STATUSTEXT compiling the checksum's entry from Python kept autopilots on a cold
    cache silent for longer than the plant's 0.5 s)."""
    from autopilot import gcs_messages
    from autopilot.streams import MessageStreams
    from autopilot.tick import warm_up
    from quadsitl.state import Reference, VehicleState

    warm_up()
    compiled = (sf.clamp_int, sf.cdeg, sf.lat_lon_e7, sf.amsl_mm, sf.pwms, sf.encode, sf.tick_values, codec.crc16,
                commander.enter, commander._entered)  # fmt: skip
    before = [len(f.signatures) for f in compiled]
    # what a Python-built message shows of the last tick (autopilot.process.Autopilot.snapshot): the process's arrays
    sf.tick_values(
        np.zeros(codec.DECODED_SIZE), Commander().cm, np.zeros(MEM_SIZE), sf.StreamFrames(1, ORIGIN, 40.0, False).tel
    )
    for value in (0, 1.5):  # ints as a caller may pass them, and floats
        s = gcs_messages.Snapshot(time_ms=12, state=VehicleState(*(value,) * 12), body_rates=(value,) * 3,
                                  reference=Reference(value, value, value, value), u1=value, controls=(value,) * 4,
                                  reversible=False, max_total_thrust=40, home=(value,) * 4)  # fmt: skip
        for mid in MessageStreams(0.001, 50.0).defaults:
            gcs_messages.build(mid, s, Commander(), gcs_messages.Origin())
    mav = wire.link(7, 1)
    for msg in (mav.statustext_encode(mavlink.MAV_SEVERITY_WARNING, b"low battery"),
                mav.param_value_encode(b"MPC_XY_VEL_MAX", 12.0, mavlink.MAV_PARAM_TYPE_REAL32, 90, 3),
                mav.command_ack_encode(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, mavlink.MAV_RESULT_ACCEPTED)):  # fmt: skip
        assert mav.parse_buffer(codec.pack(msg, wire.link(7, 1)))[0].get_type() == msg.get_type()
    c = Commander()
    assert c.set_mode(Mode.LAND) == (True, "") and c.mode == Mode.LAND
    assert [len(f.signatures) for f in compiled] == before
