"""The wire (ODOMETRY, HIL_ACTUATOR_CONTROLS, PX4 modes), the commander state machine, and trajectories."""

import math

import numpy as np
import pytest

from autopilot.commander import FAILSAFE_SETPOINT_LOST, Commander, CommanderSettings
from groundstation import trajectories
from quadsitl import codec, telemetry, wire
from quadsitl.cli_util import UsageError
from quadsitl.frames import body_rates_to_euler_rates, quaternion_to_euler
from quadsitl.state import Reference, VehicleState

mav = wire.mavlink


def test_state_survives_the_wire_to_float32_precision():
    s = VehicleState(1.5, -2.0, -5.0, 0.3, -0.2, -1.1, 0.9, -0.7, 2.5, 0.4, -0.3, 0.2)
    link = wire.link(1, 1)
    buf = wire.state_message(123_000, s).pack(link)
    (m,) = wire.link(1, 1).parse_buffer(buf)
    assert m.time_usec == 123_000 and m.get_type() == "ODOMETRY"
    out = np.zeros(codec.DECODED_SIZE)
    assert codec.decode_state(_buffer(buf), len(buf), out) == 123_000  # the autopilot's decoder
    back = VehicleState._make(out[:12].tolist())
    assert back == pytest.approx(s, abs=2e-6)


def test_actuators_survive_the_wire_normalised():
    link = wire.link(1, 1)
    forces = (-130.0, 605.0, 0.0, 42.0)
    (m,) = wire.link(1, 1).parse_buffer(wire.actuator_message(7000, forces, 1e4, True).pack(link))
    assert m.controls[1] == pytest.approx(0.0605)
    assert wire.forces_from_message(m, 1e4) == pytest.approx(forces, rel=1e-6)
    assert m.mode & mav.MAV_MODE_FLAG_SAFETY_ARMED


def test_px4_custom_modes():
    assert wire.Mode.OFFBOARD.px4_custom_mode == 6 << 16 == 393216
    assert wire.Mode.HOLD.px4_custom_mode == (4 << 16) | (3 << 24)
    assert wire.Mode.LAND.px4_custom_mode == (4 << 16) | (6 << 24)
    for mode in wire.Mode:
        assert wire.Mode.from_px4(mode.px4_custom_mode) is mode
    assert wire.Mode.from_px4(7 << 16) is wire.Mode.STABILIZED and wire.Mode.from_px4(3 << 16) is wire.Mode.POSCTL
    assert wire.Mode.from_px4(1 << 16) is None  # MANUAL (rate-free manual thrust): not ours
    assert wire.Mode.from_px4((3 << 16) | (1 << 24)) is wire.Mode.ORBIT  # POSCTL's sub mode 1 is PX4's orbit
    assert wire.Mode.from_px4((3 << 16) | (2 << 24)) is None
    assert wire.Mode.from_px4((4 << 16) | (8 << 24)) is wire.Mode.FOLLOW  # AUTO.FOLLOW_TARGET
    assert {int(m): m.name.lower() for m in wire.Mode} == telemetry.MODES  # telemetry's names are the modes'
    assert wire.Mode.MISSION.px4_custom_mode == 67371008 and wire.Mode.TAKEOFF.px4_custom_mode == 33816576
    assert codec.tick_of(codec.usec_of(12345, 0.001), 0.001) == 12345


def test_telemetry_encoding_round_trip_and_bad_payload():
    rec = telemetry.STREAMS["status"].pack(10, 0.01, 1, 1, 0, 7, 16.1, 18.2, 120.0, 7000.0, 0.9)
    assert telemetry.decode("status", rec) == {
        "tick": 10, "t": 0.01, "armed": 1, "mode": 1, "failsafe": 0, "offboard_tick": 7, "battery_v": 16.1,
        "battery_a": 18.2, "battery_mah": 120.0, "battery_j": 7000.0, "battery_remaining": 0.9,
    }  # fmt: skip
    with pytest.raises(ValueError, match="expected"):
        telemetry.decode("state", b"\x00" * 5)
    assert telemetry.key("v1", "state") == "quadsitl/v1/state"


AT_REST = VehicleState()


def _tick(c: Commander, k: int, state=AT_REST, period=0.001):
    return c.update(k, k * period, state)


def test_offboard_needs_a_setpoint_stream():
    c = Commander()
    _tick(c, 0)
    assert c.set_mode(wire.Mode.OFFBOARD) == (False, "Offboard denied: no setpoint stream")
    assert c.arm()[0]  # arming in hold is fine
    c.on_attitude_setpoint(0.1, 0.2, 0.3)
    c.on_altitude_setpoint(5.0)
    assert c.set_mode(wire.Mode.OFFBOARD)[0]
    ref = _tick(c, 1)
    assert ref == Reference(5.0, 0.1, 0.2, 0.3) and c.offboard_tick == 1


def test_setpoint_loss_is_timed_in_simulated_time_and_lands():
    c = Commander(CommanderSettings(setpoint_timeout=0.5))
    _tick(c, 0)
    c.on_altitude_setpoint(2.0)
    c.arm()
    c.set_mode(wire.Mode.OFFBOARD)
    hovering = VehicleState(z=-2.0)
    for k in range(1, 500):
        assert _tick(c, k, hovering).altitude == 2.0 and c.mode == wire.Mode.OFFBOARD
    _tick(c, 501, hovering)
    assert c.mode == wire.Mode.LAND and c.failsafe == FAILSAFE_SETPOINT_LOST
    assert any("Failsafe" in text for _, text in c.messages)
    # Landing: the reference descends at 1 m/s, level, then touchdown disarms.
    ref = _tick(c, 1501, hovering)
    assert ref.roll == 0 and ref.pitch == 0 and ref.altitude == pytest.approx(1.0, abs=0.005)
    for k in range(1502, 2200):
        ref = _tick(c, k, VehicleState())  # on the ground, still
    assert ref is None and not c.armed and c.messages[-1][1] == "Landed, disarmed"


def test_a_ground_station_on_the_wall_clock_is_not_lost_to_a_sped_up_simulation():
    """The stream is lost only when stale on both clocks: 40× real time, a ground station's setpoints 25 ms of
    wall time apart are 1 s of simulated time apart, and PX4's 1 s (simulated) would land the vehicle."""
    c = Commander(CommanderSettings(setpoint_timeout=0.5))
    _tick(c, 0)
    c.on_altitude_setpoint(2.0, wall=100.0)
    c.arm()
    c.set_mode(wire.Mode.OFFBOARD)
    hovering = VehicleState(z=-2.0)
    c.wall_clock(100.3)  # 0.3 s of wall time: fresh on that clock
    for k in range(1, 2000):  # 2 s simulated: stale on that one
        assert _tick(c, k, hovering).altitude == 2.0 and c.mode == wire.Mode.OFFBOARD
    c.wall_clock(100.6)  # now stale on both
    _tick(c, 2000, hovering)
    assert c.mode == wire.Mode.LAND and c.failsafe == FAILSAFE_SETPOINT_LOST
    # A fresh setpoint in simulated time alone keeps the stream, whatever the wall clock says (slow motion).
    c = Commander(CommanderSettings(setpoint_timeout=0.5))
    _tick(c, 0)
    c.on_position_setpoint(vertical=(2.0, math.nan, math.nan), wall=100.0)
    c.arm()
    c.set_mode(wire.Mode.OFFBOARD)
    c.wall_clock(105.0)
    assert _tick(c, 400, hovering).altitude == 2.0 and c.mode == wire.Mode.OFFBOARD
    assert _tick(c, 600, hovering).altitude != 2.0 and c.mode == wire.Mode.LAND


def test_arming_into_offboard_without_stream_is_denied():
    c = Commander()
    _tick(c, 0)
    c.on_altitude_setpoint(1.0)
    c.set_mode(wire.Mode.OFFBOARD)
    _tick(c, 3000)  # 3 s later: the stream is stale
    assert c.arm() == (False, "Arming denied: no offboard setpoint stream")


def test_trajectories(tmp_path):
    ref = Reference(5.0, 0.5, -0.5, 1.0)
    assert trajectories.make("step", ref)(3.0) == ref
    assert trajectories.make("ramp", ref)(1.0) == pytest.approx((2.5, 0.25, -0.25, 0.5))
    assert trajectories.make("sine", ref)(0.5) == pytest.approx(tuple(v * 1.2 for v in ref))
    f = tmp_path / "traj.csv"
    f.write_text("t,altitude,roll,pitch,yaw\n0,0,0,0,0\n2,4,0.2,0,1\n")
    traj = trajectories.make(str(f), ref)
    assert traj(1.0) == pytest.approx((2.0, 0.1, 0.0, 0.5)) and traj(9.0) == pytest.approx((4.0, 0.2, 0.0, 1.0))
    f.write_text("t,altitude,roll\n0,0,0\n")
    with pytest.raises(UsageError, match="missing column"):
        trajectories.make(str(f), ref)
    f.write_text("t,altitude,roll,pitch,yaw\n0,0,2.0,0,0\n")
    with pytest.raises(UsageError, match=r"line 2, column roll: .*π/2"):
        trajectories.make(str(f), ref)
    with pytest.raises(UsageError, match="expected step, ramp, sine"):
        trajectories.make("zigzag", ref)
    assert math.isfinite(trajectories.make("sine", ref)(123.4).altitude)


# ---- the per-tick codec ----------------------------------------------------------------------------------


def _pymavlink_send(msg, link) -> bytes:
    """What pymavlink's ``link.send(msg)`` puts on the wire: the frame, then the sequence number advances."""
    buf = msg.pack(link)
    link.seq = (link.seq + 1) % 256
    return buf


def _frame(n: int, buf: np.ndarray) -> bytes:
    return buf[:n].tobytes()


def _buffer(data: bytes) -> np.ndarray:
    """A received datagram as the processes hold it: a byte buffer larger than the frame."""
    buf = np.zeros(max(len(data), codec.FRAME_MAX), dtype=np.uint8)
    buf[: len(data)] = np.frombuffer(data, dtype=np.uint8)
    return buf


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_fast_codec_frames_are_byte_identical_to_pymavlink_and_both_sides_accept_each_other(seed):
    import random

    rng = random.Random(seed)
    ref, buf = wire.link(1, 25), np.zeros(codec.FRAME_MAX, dtype=np.uint8)
    out, forces_out = np.zeros(codec.DECODED_SIZE), np.zeros(4)
    for i in range(600):  # > 256: the sequence number wraps
        seq = (2 * i) & 0xFF  # two frames an iteration, as pymavlink counts them
        s = VehicleState(*(rng.uniform(-3, 3) for _ in range(12)))
        usec = rng.randrange(0, 2**63) if i % 7 == 0 else i * 1000
        forces = tuple(rng.choice([0.0, rng.uniform(-1e4, 1e4)]) for _ in range(4))  # zeros exercise trimming
        armed = rng.random() < 0.5
        a = _frame(codec.encode_state(buf, seq, 1, 25, usec, tuple(s)), buf)
        b = _pymavlink_send(wire.state_message(usec, s), ref)
        assert a == b
        assert codec.decode_state(_buffer(a), len(a), out) == usec
        (p,) = wire.link(1, 1).parse_buffer(b)
        assert p.time_usec == usec
        roll, pitch, yaw = quaternion_to_euler(*p.q)
        rates = body_rates_to_euler_rates(roll, pitch, p.rollspeed, p.pitchspeed, p.yawspeed)
        assert tuple(out) == (p.x, p.y, p.z, p.vx, p.vy, p.vz, roll, pitch, yaw, *rates, p.rollspeed, p.pitchspeed,
                              p.yawspeed)  # fmt: skip
        a = _frame(codec.encode_actuators(buf, (seq + 1) & 0xFF, 1, 25, usec, forces, 1e4, armed), buf)
        b = _pymavlink_send(wire.actuator_message(usec, forces, 1e4, armed), ref)
        assert a == b
        assert codec.decode_actuators(_buffer(a), len(a), forces_out, 1e4) == usec
        (p,) = wire.link(1, 1).parse_buffer(b)
        assert p.time_usec == usec and p.mode == (codec.SAFETY_ARMED if armed else 0)
        assert tuple(forces_out) == wire.forces_from_message(p, 1e4)


def test_fast_parser_refuses_corrupt_frames_and_leaves_other_messages_to_pymavlink():
    buf, out = np.zeros(codec.FRAME_MAX, dtype=np.uint8), np.zeros(codec.DECODED_SIZE)
    frame = bytearray(_frame(codec.encode_state(buf, 0, 1, 25, 5000, tuple(VehicleState(z=-1.0))), buf))
    frame[20] ^= 0x01  # a flipped bit in the payload
    assert codec.decode_state(_buffer(bytes(frame)), len(frame), out) == codec.BAD_CRC
    actuators = _frame(codec.encode_actuators(buf, 0, 1, 25, 1, (0.0,) * 4, 1.0, False), buf)
    assert codec.decode_state(_buffer(actuators), len(actuators), out) == codec.NOT_THIS_FRAME  # another message
    hb = wire.mavlink.MAVLink_heartbeat_message(2, 12, 0, 0, 0, 3).pack(wire.link(1, 25))
    assert codec.decode_state(_buffer(hb), len(hb), out) == codec.NOT_THIS_FRAME
    assert codec.decode_actuators(_buffer(hb), len(hb), np.zeros(4), 1.0) == codec.NOT_THIS_FRAME
    state = _frame(codec.encode_state(buf, 0, 1, 25, 1, (0.0,) * 12), buf)
    two = state + state
    assert codec.decode_state(_buffer(two), len(two), out) == codec.NOT_THIS_FRAME  # two frames: pymavlink's job
    assert codec.decode_state(_buffer(b""), 0, out) == codec.NOT_THIS_FRAME
    assert codec.decode_state(_buffer(b"\xfd" * 300), 300, out) == codec.NOT_THIS_FRAME
    nan = _frame(codec.encode_state(buf, 0, 1, 25, 1, (math.nan,) + (0.0,) * 11), buf)
    assert codec.decode_state(_buffer(nan), len(nan), out) == codec.NOT_FINITE  # a state never to fly


def test_telemetry_samples_carry_one_or_more_records():
    one = telemetry.STREAMS["setpoint"].pack(5, 0.005, 1.0, 0.1, 0.2, 0.3, 4.0, -2.0)
    two = one + telemetry.STREAMS["setpoint"].pack(6, 0.006, 1.5, 0.1, 0.2, 0.3, math.nan, math.nan)
    assert telemetry.records("setpoint", one) == [(5, 0.005, 1.0, 0.1, 0.2, 0.3, 4.0, -2.0)]
    assert [r[0] for r in telemetry.records("setpoint", two)] == [5, 6]
    assert telemetry.FIELDS["setpoint"][-2:] == ("x_ref", "y_ref") and telemetry.SCHEMA_VERSION == 4
    for bad in (b"", two[:-1]):
        with pytest.raises(ValueError, match="multiple of 64"):
            telemetry.records("setpoint", bad)


def test_period_stats_jitter_and_deadline_misses():
    from quadsitl.timing import percentile, period_stats

    T = 0.001
    perfect = period_stats([k * T for k in range(1000)], T)
    assert perfect["jitter_max_us"] == pytest.approx(0.0, abs=1e-6) and perfect["deadline_miss_ratio"] == 0.0
    assert perfect["mean_period_us"] == pytest.approx(1000.0)
    starts = [k * T for k in range(100)]
    starts[50] += 0.0015  # one tick starts 1.5 periods late: a miss, two periods off by 1.5 ms
    late = period_stats(starts, T)
    assert late["deadline_miss_ratio"] == pytest.approx(0.01)
    assert late["jitter_max_us"] == pytest.approx(1500.0) and late["jitter_p50_us"] == pytest.approx(0.0, abs=1e-6)
    assert late["lateness_p50_us"] == pytest.approx(0.0, abs=1e-6) and late["lateness_p99_us"] == pytest.approx(
        0.0, abs=1e-6
    )
    # every tick after the first 60 µs into its period: no jitter at all, and the lateness says so
    offset = period_stats([0.0] + [k * T + 60e-6 for k in range(1, 100)], T)
    assert offset["jitter_p50_us"] == pytest.approx(0.0, abs=1e-6) and offset["deadline_miss_ratio"] == 0.0
    assert offset["lateness_p50_us"] == pytest.approx(60.0) and offset["lateness_p99_us"] == pytest.approx(60.0)
    assert percentile([3.0, 1.0, 2.0], 50) == 2.0 and percentile([], 99) == 0.0
