"""The pure pieces behind the ground-station link: parameters, message intervals, telemetry messages,
the home projection."""

import math
from types import SimpleNamespace

import pytest

from autopilot import gcs_messages
from autopilot.backstepping import BacksteppingController
from autopilot.commander import Commander, CommanderSettings
from autopilot.factory import make_controller
from autopilot.params import INDEX, MAX_NAME, SPECS, ParamStore, apply
from autopilot.pd import PDController
from autopilot.stream_frames import COMPILED as COMPILED_STREAMS
from autopilot.streams import FAST, SLOTS, MessageStreams, phase_of, spread_of
from quadsitl.codec import pack
from quadsitl.config import load_preset
from quadsitl.frames import geodetic_to_ned, ned_to_geodetic
from quadsitl.state import Reference, VehicleState
from quadsitl.wire import Mode, link, mavlink


@pytest.fixture
def store():
    return ParamStore(load_preset("paper"), "backstepping", CommanderSettings())


# ---- parameters ----------------------------------------------------------------------------------


def test_parameter_names_fit_mavlink_and_indices_are_unique_and_stable(store):
    names = [name for _, name, _ in store]
    assert len(names) == len(set(names)) == len(store) == len(SPECS)
    assert all(len(n) <= MAX_NAME for n in names)
    assert [i for i, _, _ in store] == list(range(len(store)))
    for required in [f"BS_K{i}" for i in range(1, 9)] + ["CTL_TYPE", "VM_MASS", "VM_IXX", "COM_OF_LOSS_T"]:
        assert required in INDEX
    store.set("BS_K1", 12.0)
    assert [name for _, name, _ in store] == names  # a set never reorders


def test_defaults_describe_the_preset_and_rebuild_the_same_controller(store):
    preset = load_preset("paper")
    assert store.lookup("BS_K3")[2] == 10.0
    assert store.lookup("VM_MASS")[2] == preset.vehicle.mass
    assert store.lookup("VM_IZZ")[2] == preset.vehicle.izz
    assert store.lookup("COM_OF_LOSS_T")[2] == 1.0
    a = store.applied()
    assert a.preset.vehicle == preset.vehicle and a.controller == "backstepping"
    assert make_controller(a.preset).poles == pytest.approx(make_controller(preset).poles, abs=1e-15)


def test_x500_poles_round_trip_through_rates():
    preset = load_preset("x500")
    s = ParamStore(preset, "pd", CommanderSettings(setpoint_timeout=0.5))
    assert s.lookup("CTL_TYPE")[2] == 1.0 and s.lookup("COM_OF_LOSS_T")[2] == 0.5
    assert [s.lookup(f"BS_K{i}")[2] for i in range(1, 9)] == list(preset.controller.gains)
    assert isinstance(make_controller(s.applied().preset, s.applied().controller), PDController)


def test_lookup_by_name_and_by_index(store):
    i, name, value = store.lookup("VM_MASS")
    assert store.lookup(None, i) == (i, name, value)
    assert store.lookup("VM_MASS", i) == (i, name, value)
    assert store.lookup("NOPE") is None and store.lookup(None, len(store)) is None


def test_an_accepted_set_changes_what_the_controller_is_built_from(store):
    assert store.set("VM_MASS", 2.5) == ""
    assert store.set("BS_K2", 20.0) == ""
    assert store.set("COM_OF_LOSS_T", 0.25) == ""
    assert store.set("CTL_TYPE", 1) == ""
    a = store.applied()
    assert a.preset.vehicle.mass == 2.5 and a.settings.setpoint_timeout == 0.25 and a.controller == "pd"
    bs = make_controller(a.preset, "backstepping")
    assert isinstance(bs, BacksteppingController) and bs.poles[1] == pytest.approx(1 - 0.001 * 20)


@pytest.mark.parametrize(
    ("name", "value", "expect"),
    [
        ("VM_MASS", -1.0, "VM_MASS = -1: expected a number in (0, 10000] kg"),
        ("VM_MASS", math.nan, "expected a number in (0, 10000] kg"),
        ("CTL_TYPE", 0.5, "CTL_TYPE = 0.5: expected an integer in [0, 1]"),
        ("CTL_TYPE", 2, "expected an integer in [0, 1]"),
        ("BS_K1", 0.0, "BS_K1 = 0: expected a number in (0, 1e+06] 1/s"),
        ("ATT_TILT_MAX", 1.6, "ATT_TILT_MAX = 1.6: expected a number in (0, 1.5533] rad"),
        ("THR_MIN", 1e6, "THR_MIN must be below THR_MAX"),
        ("NOT_A_PARAM", 1.0, "NOT_A_PARAM: no such parameter"),
    ],
)
def test_out_of_range_values_are_refused_and_change_nothing(store, name, value, expect):
    before = dict(store.values)
    reason = store.set(name, value)
    assert expect in reason
    assert store.values == before


def test_gains_that_break_the_stability_conditions_are_refused_naming_the_condition(store):
    before = dict(store.values)
    # k2 = 2000 1/s: λ2 = −1, so λ2² ≥ 1 − T² and condition (41) cannot hold for any ε.
    reason = store.set("BS_K2", 2000.0)
    assert "condition (41)" in reason and "λ2" in reason
    assert store.values == before
    # k1 = 0.001 1/s alone is a valid rate, but then (41) needs ε > 2 while (41)–(44) need ε < 0.02.
    reason = store.set("BS_K1", 0.001)
    assert "conflict" in reason and "λ1" in reason
    assert store.values == before
    assert store.set("BS_K1", 5.0) == ""


def test_a_build_failure_refuses_the_set(store):
    def fail(_applied):
        raise ValueError("no")

    assert store.set("VM_MASS", 3.0, build=fail) == "VM_MASS = 3: no"
    assert store.lookup("VM_MASS")[2] == 2.0


def test_apply_keeps_the_wire_scale_and_simulation_settings(store):
    preset = load_preset("paper")
    a = apply(preset, CommanderSettings(), {**store.values, "VM_MASS": 9.0})
    assert a.preset.actuators == preset.actuators and a.preset.sim == preset.sim
    assert a.preset.vehicle.mass == 9.0


# ---- message intervals ---------------------------------------------------------------------------


def test_message_intervals_in_ticks():
    s = MessageStreams(0.001, 50.0)
    att = mavlink.MAVLINK_MSG_ID_ATTITUDE
    gpi = mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT
    assert s.interval_us(att) == 20_000 and s.interval_us(gpi) == 100_000
    sent = [t for t in range(1000) if att in s.due(t)]
    assert len(sent) == 50
    assert s.set_interval(att, 5_000) == "" and s.interval_us(att) == 5_000
    assert sum(att in s.due(t) for t in range(1000)) == 200
    assert s.set_interval(att, -1) == "" and s.interval_us(att) == -1
    assert not any(att in s.due(t) for t in range(1000))
    assert s.set_interval(att, 0) == "" and s.interval_us(att) == 20_000
    assert "not streamed" in s.set_interval(mavlink.MAVLINK_MSG_ID_ODOMETRY, 1000)
    assert "expected -1, 0" in s.set_interval(att, -5)
    assert s.interval_us(mavlink.MAVLINK_MSG_ID_ODOMETRY) == 0


def test_streams_are_spread_over_ticks_and_over_a_fleets_vehicles():
    """The messages the compiled tick builds go out with the four fast ones (on their own ticks of 10 and 5 Hz), each
    one Python builds on a tick of its own, never a fast one (once, every 100th tick built eleven in Python); each
    stream keeps its rate; vehicles of a fleet send their fast messages on different ticks; next_due finds every due
    tick."""
    fast, compiled = set(FAST), set(COMPILED_STREAMS)
    for sysid in (1, 2, 7, 11):
        s = MessageStreams(0.001, 50.0, phase_of(sysid))
        due = [s.due(t) for t in range(2000)]
        assert max(len(set(d) - compiled) for d in due) == 1
        assert all(fast <= set(d) <= compiled or len(d) <= 1 for d in due)
        assert sum(len(d) == len(compiled) for d in due) == 2000 // 200  # all of them together at 5 Hz
        for mid, n in s.defaults.items():
            assert sum(mid in d for d in due) == (2000 // n if n else 0), mid  # 0: off until asked for
        t, seen = -1, []
        while (t := s.next_due(t)) < 2000:
            seen.append(t)
        assert seen == [k for k, d in enumerate(due) if d]
    ticks = [[t for t in range(20) if mavlink.MAVLINK_MSG_ID_ATTITUDE in MessageStreams(0.001, 50.0, phase_of(i))
              .due(t)] for i in range(1, 11)]  # fmt: skip
    assert len({tuple(x) for x in ticks}) == 10
    # a changed interval keeps its phase: vehicle 3's SYS_STATUS at 2 · 22 + its slot, 9
    s = MessageStreams(0.001, 50.0, phase_of(3), spread_of(3))
    assert s.set_interval(mavlink.MAVLINK_MSG_ID_SYS_STATUS, 100_000) == ""
    assert [t for t in range(300) if mavlink.MAVLINK_MSG_ID_SYS_STATUS in s.due(t)] == [53, 153, 253]


def test_a_fleets_python_built_messages_are_spread_over_the_ticks():
    """The messages with a slot of their own (Python builds them: a trip out of the compiled loop) of a fleet of
    sixteen: at most three on one tick and eighteen in any 20 ticks in a row (sent at each vehicle's fast phase + slot,
    as before spread_of, sixteen fell on one tick and 112 within 20); the other messages stay where they were, and
    vehicle 1 streams as before."""
    slotted = {mid for mid, slot in SLOTS.items() if slot}
    fleet = [MessageStreams(0.001, 50.0, phase_of(i), spread_of(i)) for i in range(1, 17)]
    per_tick = [sum(len(slotted.intersection(s.due(t))) for s in fleet) for t in range(2000)]
    on = [mid for mid in slotted if fleet[0].defaults[mid]]  # HIGHRES_IMU is off until asked for
    assert sum(per_tick) == 16 * sum(2000 // fleet[0].defaults[mid] for mid in on)  # every one, at its rate
    assert max(per_tick) <= 3
    assert max(sum(per_tick[t : t + 20]) for t in range(1980)) <= 18  # 12.2 on average (38 a second per vehicle)
    for i, s in enumerate(fleet, start=1):
        alone = MessageStreams(0.001, 50.0, phase_of(i))
        assert all(s.phases[mid] == alone.phases[mid] for mid in s.phases if mid not in slotted)
        assert all(s.phases[mid] % 2 == 1 for mid in slotted)  # odd: off the vehicle's own fast ticks
    assert fleet[0].phases == MessageStreams(0.001, 50.0).phases


# ---- telemetry messages --------------------------------------------------------------------------


def snapshot(**kw):
    st = VehicleState(x=3.0, y=-4.0, z=-10.0, vx=1.0, vy=2.0, vz=-0.5, roll=0.1, pitch=-0.2, yaw=-0.5)
    base = dict(time_ms=1234, state=st, body_rates=(0.01, 0.02, 0.03), reference=Reference(10.0, 0.0, 0.0, 1.0),
                u1=20.0, controls=(0.5, -0.5, 1.0, 0.0), reversible=True, max_total_thrust=40.0)  # fmt: skip
    base.update(kw)
    return gcs_messages.Snapshot(**base)


def roundtrip(msg):
    mav = link(1, 1)
    return mav.parse_buffer(msg.pack(mav))[0]


def orbiting() -> Commander:
    """A commander orbiting: every streamed message has something to say (ORBIT_EXECUTION_STATUS only then)."""
    c = Commander()
    c.update(0, 0.0, VehicleState(z=-10.0))
    assert c.arm()[0] and c.orbit(10.0, 2.0, math.nan, math.nan, 0.0, 0.0, 10.0)[0]
    return c


def test_every_stream_message_encodes_and_decodes():
    c, home = orbiting(), gcs_messages.Home()
    s = MessageStreams(0.001, 50.0)
    for mid in s.defaults:
        m = roundtrip(gcs_messages.build(mid, snapshot(), c, home))
        assert m.get_msgId() == mid


def test_wire_pack_is_what_pymavlink_sends():
    # The ground links frame messages with quadsitl.codec.pack: the same bytes as pymavlink's mav.send(msg),
    # sequence numbers counting, for every streamed message, STATUSTEXT (whose field "id" is not its message
    # id) in chunks, acks and parameters; several frames in one datagram parse as several messages.
    c, home = orbiting(), gcs_messages.Home()
    msgs = [gcs_messages.build(mid, snapshot(), c, home) for mid in MessageStreams(0.001, 50.0).defaults]
    msgs += list(gcs_messages.statustext(4, "A warning long enough to need two chunks of fifty characters each", 7))
    msgs += [mavlink.MAVLink_command_ack_message(400, 0, 0, 0, 255, 190),
             mavlink.MAVLink_param_value_message(b"BS_K1", 10.0, mavlink.MAV_PARAM_TYPE_REAL32, 41, 3),
             gcs_messages.heartbeat(c)]  # fmt: skip
    ours, theirs = link(1, 1), link(1, 1)
    frames = []
    for msg in msgs:
        expected = msg.pack(theirs)
        theirs.seq = (theirs.seq + 1) % 256
        frames.append(pack(msg, ours))
        assert frames[-1] == expected, msg.get_type()
    assert ours.seq == len(msgs) % 256
    parsed = link(2, 1).parse_buffer(b"".join(frames))
    assert [m.get_msgId() for m in parsed] == [m.get_msgId() for m in msgs]


def test_global_position_from_home_and_back():
    home = gcs_messages.Home(47.397742, 8.545594, 488.0)
    m = roundtrip(gcs_messages.build(mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT, snapshot(), Commander(), home))
    north, east = geodetic_to_ned(m.lat * 1e-7, m.lon * 1e-7, home.lat, home.lon)
    assert north == pytest.approx(3.0, abs=0.02) and east == pytest.approx(-4.0, abs=0.02)  # 1e-7 deg ≈ 1 cm
    assert m.alt == 498_000 and m.relative_alt == 10_000
    assert (m.vx, m.vy, m.vz) == (100, 200, -50)
    assert m.hdg == round((360 - math.degrees(0.5)) * 100)


def test_ned_geodetic_round_trip_far_from_home():
    lat, lon = ned_to_geodetic(1500.0, -2500.0, -33.9, 151.2)
    assert geodetic_to_ned(lat, lon, -33.9, 151.2) == pytest.approx((1500.0, -2500.0), abs=1e-6)
    assert ned_to_geodetic(0.0, 0.0, 10.0, 20.0) == (10.0, 20.0)
    # one arc-minute of latitude is 1852 m on PX4's sphere, near enough
    assert ned_to_geodetic(1853.2, 0.0, 0.0, 0.0)[0] == pytest.approx(1 / 60, rel=1e-3)


def test_heartbeat_carries_px4_modes_and_the_armed_bit():
    c = Commander()
    hb = gcs_messages.heartbeat(c)
    assert hb.autopilot == mavlink.MAV_AUTOPILOT_PX4 and hb.type == mavlink.MAV_TYPE_QUADROTOR
    assert hb.custom_mode == (4 << 16) | (3 << 24) and not hb.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED
    assert hb.base_mode & mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
    c.arm()
    c.last_setpoint_time = 0.0
    c.set_mode(Mode.OFFBOARD)
    hb = gcs_messages.heartbeat(c)
    assert hb.custom_mode == 6 << 16 and hb.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED
    assert hb.system_status == mavlink.MAV_STATE_ACTIVE


def test_landed_state_and_motor_outputs():
    c = Commander()
    ground = VehicleState()
    assert gcs_messages.landed_state(c, ground) == mavlink.MAV_LANDED_STATE_ON_GROUND
    c.arm()
    assert gcs_messages.landed_state(c, ground) == mavlink.MAV_LANDED_STATE_ON_GROUND
    assert gcs_messages.landed_state(c, VehicleState(z=-2.0)) == mavlink.MAV_LANDED_STATE_IN_AIR
    c.set_mode(Mode.LAND)
    assert gcs_messages.landed_state(c, VehicleState(z=-2.0)) == mavlink.MAV_LANDED_STATE_LANDING
    m = roundtrip(gcs_messages.build(mavlink.MAVLINK_MSG_ID_SERVO_OUTPUT_RAW, snapshot(), c, gcs_messages.Home()))
    assert (m.servo1_raw, m.servo2_raw, m.servo3_raw, m.servo4_raw) == (1750, 1250, 2000, 1500)
    c.disarm()
    m = roundtrip(gcs_messages.build(mavlink.MAVLINK_MSG_ID_SERVO_OUTPUT_RAW, snapshot(), c, gcs_messages.Home()))
    assert (m.servo1_raw, m.servo2_raw, m.servo3_raw, m.servo4_raw) == (0, 0, 0, 0)


def test_long_statustext_is_chunked_in_ascii_and_reassembles():
    text = "Param set refused: condition (41) λ2² − 1 + 4T²λ2²/ε < 0 cannot hold for any ε > 0; allowed: λ2² < 1 − T²"
    msgs = gcs_messages.statustext(4, text, 7)
    assert len(msgs) > 1 and all(m.id == 7 for m in msgs) and [m.chunk_seq for m in msgs] == list(range(len(msgs)))
    decoded = [roundtrip(m) for m in msgs]
    assert all(len(m.text) == 50 for m in decoded[:-1]) and len(decoded[-1].text) < 50
    whole = "".join(m.text for m in decoded)
    assert whole.startswith("Param set refused: condition (41) l2^2 - 1 + 4T^2l2^2/eps < 0")
    short = gcs_messages.statustext(6, "Armed", 8)
    assert len(short) == 1 and short[0].id == 0


def test_autopilot_version_says_what_we_support():
    v = roundtrip(gcs_messages.autopilot_version(1))
    assert v.capabilities & mavlink.MAV_PROTOCOL_CAPABILITY_MAVLINK2
    assert v.capabilities & mavlink.MAV_PROTOCOL_CAPABILITY_SET_ATTITUDE_TARGET
    # MAVSDK refuses a mission upload without MISSION_INT; commands are taken as COMMAND_INT too
    assert v.capabilities & mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_INT
    assert v.capabilities & mavlink.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
    assert not v.capabilities & mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_FLOAT  # never implemented
    assert not v.capabilities & mavlink.MAV_PROTOCOL_CAPABILITY_FTP  # FTP requests get a NAK
    assert gcs_messages.version_number("1.2.3") >> 8 == 0x010203


# ---- health, GPS, home ---------------------------------------------------------------------------


def mavsdk_health(m) -> dict[str, bool]:
    """What MAVSDK's telemetry.health() makes of a SYS_STATUS (MAVSDK telemetry_impl.cpp,
    process_sys_status; home comes from HOME_POSITION, not from here)."""
    present, health = m.onboard_control_sensors_present, m.onboard_control_sensors_health
    gps = bool(present & health & mavlink.MAV_SYS_STATUS_SENSOR_GPS)
    return {
        "gyro": bool(
            present & mavlink.MAV_SYS_STATUS_SENSOR_3D_GYRO and health & mavlink.MAV_SYS_STATUS_SENSOR_3D_GYRO
        ),
        "accel": bool(health & mavlink.MAV_SYS_STATUS_SENSOR_3D_ACCEL),  # PX4: MAVSDK reads health only
        "mag": bool(present & mavlink.MAV_SYS_STATUS_SENSOR_3D_MAG and health & mavlink.MAV_SYS_STATUS_SENSOR_3D_MAG),
        "global": gps,
        "local": gps,
        "armable": bool(health & mavlink.MAV_SYS_STATUS_PREARM_CHECK),
    }


def test_sys_status_with_a_vehicle_state_is_healthy_and_armable_as_mavsdk_reads_it():
    m = roundtrip(gcs_messages.build(mavlink.MAVLINK_MSG_ID_SYS_STATUS, snapshot(load=0.25), Commander(),
                                     gcs_messages.Origin()))  # fmt: skip
    assert mavsdk_health(m) == dict.fromkeys(("gyro", "accel", "mag", "global", "local", "armable"), True)
    bits = (1, 2, 4, 8, 32, 1 << 28)  # gyro, accel, mag, absolute pressure, GPS, pre-arm check
    for bit in bits:
        assert m.onboard_control_sensors_present & bit and m.onboard_control_sensors_enabled & bit
        assert m.onboard_control_sensors_health & bit, bit
    control = (mavlink.MAV_SYS_STATUS_SENSOR_ATTITUDE_STABILIZATION | mavlink.MAV_SYS_STATUS_SENSOR_Z_ALTITUDE_CONTROL
               | mavlink.MAV_SYS_STATUS_SENSOR_MOTOR_OUTPUTS)  # fmt: skip
    assert m.onboard_control_sensors_present & control == control
    assert m.onboard_control_sensors_health & control == control
    assert not m.onboard_control_sensors_present & mavlink.MAV_SYS_STATUS_SENSOR_RC_RECEIVER  # no RC here
    assert m.load == 250 and m.battery_remaining == -1


def test_sys_status_without_a_vehicle_state_is_not_armable_and_arming_says_why():
    for m in (roundtrip(gcs_messages.sys_status(0.0, (1, 2, 3, 4, 5), has_state=False)),
              roundtrip(gcs_messages.build(mavlink.MAVLINK_MSG_ID_SYS_STATUS, snapshot(has_state=False), Commander(),
                                           gcs_messages.Origin()))):  # fmt: skip
        assert mavsdk_health(m) == dict.fromkeys(("gyro", "accel", "mag", "global", "local", "armable"), False)
        assert m.onboard_control_sensors_present & (1 << 28)  # the check exists, and fails
        assert m.onboard_control_sensors_health & mavlink.MAV_SYS_STATUS_SENSOR_ATTITUDE_STABILIZATION
    assert (m.errors_comm, m.errors_count1, m.errors_count4) == (0, 0, 0)
    m = roundtrip(gcs_messages.sys_status(0.0, (1, 2, 3, 4, 70000), has_state=False))
    assert (m.errors_comm, m.errors_count1, m.errors_count2, m.errors_count3, m.errors_count4) == (1, 2, 3, 4, 65535)
    assert gcs_messages.arming_check(True) == ""
    assert gcs_messages.arming_check(False) == "Arming denied: no vehicle state (plant link down)"


def test_gps_raw_int_is_a_3d_fix_at_the_true_position_and_velocity():
    origin = gcs_messages.Origin(47.397742, 8.545594, 488.0)
    s = snapshot()  # x 3, y −4, z −10 m; vx 1, vy 2 m/s
    gps = roundtrip(gcs_messages.build(mavlink.MAVLINK_MSG_ID_GPS_RAW_INT, s, Commander(), origin))
    gpi = roundtrip(gcs_messages.build(mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT, s, Commander(), origin))
    assert gps.fix_type == mavlink.GPS_FIX_TYPE_3D_FIX and gps.satellites_visible == 10
    assert (gps.lat, gps.lon, gps.alt) == (gpi.lat, gpi.lon, gpi.alt) and gps.alt == 498_000
    north, east = geodetic_to_ned(gps.lat * 1e-7, gps.lon * 1e-7, origin.lat, origin.lon)
    assert north == pytest.approx(3.0, abs=0.02) and east == pytest.approx(-4.0, abs=0.02)
    assert gps.vel == round(math.hypot(1.0, 2.0) * 100) == 224
    assert gps.cog == round(math.degrees(math.atan2(2.0, 1.0)) * 100)  # 63.43°: north-east-ish, clockwise
    assert (gps.eph, gps.epv, gps.alt_ellipsoid) == (100, 100, 498_000)
    assert gps.h_acc > 0 and gps.v_acc > 0 and gps.vel_acc > 0
    assert gps.time_usec == 1_234_000

    def fix(**kw):
        s = snapshot(state=VehicleState(**kw), time_ms=0)
        return roundtrip(gcs_messages.build(mavlink.MAVLINK_MSG_ID_GPS_RAW_INT, s, Commander(), origin))

    assert fix(vy=-1.0).cog == 27000 and fix(vx=-1.0).cog == 18000 and fix(vx=1.0, vz=5.0).cog == 0
    at_rest = fix(vz=-3.0)  # climbing straight up: no ground speed, no course
    assert at_rest.vel == 0 and at_rest.cog == 65535
    assert fix(vx=1e6).vel == 65534  # saturates below UINT16_MAX, which means "unknown"
    assert (fix().lat, fix().lon, fix().alt) == (473977420, 85455940, 488_000)


def test_home_position_from_local_coordinates_and_the_origin():
    origin = gcs_messages.Origin(47.397742, 8.545594, 488.0)
    m = roundtrip(gcs_messages.home_position(origin))
    assert (m.latitude, m.longitude, m.altitude) == (473977420, 85455940, 488_000)
    assert (m.x, m.y, m.z) == (0.0, 0.0, 0.0) and list(m.q) == [1.0, 0.0, 0.0, 0.0]
    m = roundtrip(gcs_messages.home_position(origin, 30.0, -40.0, -2.5, math.pi / 2, time_usec=5_000_000))
    assert (m.x, m.y, m.z) == (30.0, -40.0, -2.5) and m.altitude == 490_500 and m.time_usec == 5_000_000
    assert geodetic_to_ned(m.latitude * 1e-7, m.longitude * 1e-7, origin.lat, origin.lon) == pytest.approx(
        (30.0, -40.0), abs=0.02
    )
    assert list(m.q) == pytest.approx([math.sqrt(0.5), 0.0, 0.0, math.sqrt(0.5)])  # heading east
    assert (m.approach_x, m.approach_y, m.approach_z) == (0.0, 0.0, 0.0)


def test_streamed_home_and_relative_altitude_follow_the_home_in_the_snapshot():
    origin, c = gcs_messages.Origin(), Commander()
    s = snapshot(home=(3.0, -4.0, -2.0, 0.0))  # home 2 m above the origin; the vehicle at 10 m
    home = roundtrip(gcs_messages.build(mavlink.MAVLINK_MSG_ID_HOME_POSITION, s, c, origin))
    assert (home.x, home.y, home.z) == (3.0, -4.0, -2.0) and home.altitude == 490_000
    gpi = roundtrip(gcs_messages.build(mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT, s, c, origin))
    assert (home.latitude, home.longitude) == (gpi.lat, gpi.lon)  # the vehicle is above home
    assert gpi.relative_alt == 8_000 and gpi.alt == 498_000  # above home, and above mean sea level


def test_landed_states_of_takeoff_land_and_rtl():
    def vehicle(mode: str, armed: bool = True, final_descent: bool = False):
        """The commander's side landed_state reads (``landing``: LAND, or RTL's final descent)."""
        return SimpleNamespace(armed=armed, mode=Mode[mode], landing=mode == "LAND" or final_descent)

    ground, flying = VehicleState(), VehicleState(z=-2.0, vz=-0.5)
    states = {
        (mode, armed, where): gcs_messages.landed_state(vehicle(mode, armed), st)
        for mode in ("HOLD", "OFFBOARD", "TAKEOFF", "LAND", "RTL")
        for armed in (False, True)
        for where, st in (("ground", ground), ("air", flying))
    }
    on_ground, in_air = mavlink.MAV_LANDED_STATE_ON_GROUND, mavlink.MAV_LANDED_STATE_IN_AIR
    assert all(v == on_ground for (_, armed, _), v in states.items() if not armed)
    assert states["TAKEOFF", True, "ground"] == states["TAKEOFF", True, "air"] == mavlink.MAV_LANDED_STATE_TAKEOFF
    assert states["LAND", True, "air"] == mavlink.MAV_LANDED_STATE_LANDING
    assert states["LAND", True, "ground"] == on_ground  # touched down, about to disarm
    for mode in ("HOLD", "OFFBOARD", "RTL"):
        assert (states[mode, True, "ground"], states[mode, True, "air"]) == (on_ground, in_air)
    assert gcs_messages.in_air(vehicle("TAKEOFF"), ground) and gcs_messages.in_air(vehicle("LAND"), flying)
    assert not gcs_messages.in_air(vehicle("LAND"), ground) and not gcs_messages.in_air(vehicle("HOLD", False), flying)
    assert gcs_messages.landed_state(vehicle("HOLD"), VehicleState(vz=0.5)) == in_air  # sinking below the ground
    assert gcs_messages.landed_state(vehicle("RTL", final_descent=True), flying) == mavlink.MAV_LANDED_STATE_LANDING


def test_telemetry_never_raises_on_a_non_finite_or_huge_state():
    # The tick refuses non-finite states, but a builder must not raise on one either; the state arrives as
    # float32, so 3e38 is as large as it gets.
    c, origin = orbiting(), gcs_messages.Origin()
    for bad in (math.nan, math.inf, -math.inf, 3e38, -3e38):
        st = VehicleState(*[bad] * 12)
        s = snapshot(state=st, body_rates=(bad,) * 3, u1=bad, home=(bad,) * 4, load=bad)
        for mid in MessageStreams(0.001, 50.0).defaults:
            assert roundtrip(gcs_messages.build(mid, s, c, origin)).get_msgId() == mid


def test_gps_streams_at_5_hz_alongside_global_position():
    s = MessageStreams(0.001, 50.0)
    gps, gpi = mavlink.MAVLINK_MSG_ID_GPS_RAW_INT, mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT
    assert s.interval_us(gps) == 200_000
    ticks = [t for t in range(2000) if gps in s.due(t)]
    assert len(ticks) == 10 and all(gpi in s.due(t) for t in ticks)


def test_integer_parameters_go_as_int32_bytewise_as_px4_carries_them():
    """PX4's encoding (PARAM_ENCODE_BYTEWISE), which MAVSDK's set_param_int/get_param_int read: an integer
    parameter's bytes in the float field, typed INT32; a REAL32 as itself; a REAL32 set of an integer parameter taken
    as a number."""
    import struct

    from quadsitl import wire

    carried, kind = wire.param_to_wire(2, integer=True)
    assert kind == mavlink.MAV_PARAM_TYPE_INT32 and struct.pack("<f", carried) == struct.pack("<i", 2)
    assert wire.param_from_wire(carried, kind) == 2.0
    assert wire.param_to_wire(2.5, integer=False) == (2.5, mavlink.MAV_PARAM_TYPE_REAL32)
    assert wire.param_from_wire(1.0, mavlink.MAV_PARAM_TYPE_REAL32) == 1.0
    byte = struct.unpack("<f", bytes([200, 0, 0, 0]))[0]
    assert wire.param_from_wire(byte, mavlink.MAV_PARAM_TYPE_UINT8) == 200.0
