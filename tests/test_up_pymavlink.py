"""``quadsitl up`` driven by a raw pymavlink client, the way a script or a ground station does it:
parameters, commands, message intervals, offboard flight and landing. Nothing of the project's own
ground-station code is used on the client side."""

import math
import time

import pytest

from tests.mavclient import Client, M, armable_client


@pytest.fixture
def client():
    with armable_client() as c:
        yield c


def for_a_while(c: Client, seconds: float, each=None) -> None:
    """Pump the link (calling ``each()`` every 50 ms) until ``seconds`` have passed on the wall clock and on the
    vehicle's (its ATTITUDE's time_boot_ms): the vehicle runs at 1x real time, but a loaded machine may hold it back,
    and what the test then asserts needs the flight's time, not the wall's."""
    end, t0 = time.monotonic() + seconds, c.latest["ATTITUDE"].time_boot_ms
    give_up = end + 30.0
    while time.monotonic() < end or c.latest["ATTITUDE"].time_boot_ms - t0 < 1000 * seconds:
        assert time.monotonic() < give_up, "the vehicle's clock stopped"
        if each is not None:
            each()
        c.pump(0.05)


def fly_setpoints(c: Client, seconds: float, **ref) -> None:
    """Stream setpoints ``ref`` for ``seconds`` of the vehicle's time (and at least that long on the wall clock)."""
    for_a_while(c, seconds, lambda: c.setpoint(**ref))


def test_parameters_list_read_set_and_refuse(client):
    c = client
    hb = c.heartbeat()
    assert hb.autopilot == M.MAV_AUTOPILOT_PX4 and hb.type == M.MAV_TYPE_QUADROTOR
    assert c.conn.flightmode == "LOITER"  # pymavlink decodes PX4's auto/loiter custom mode

    c.conn.mav.param_request_list_send(1, 1)
    params = {}
    end = time.monotonic() + 10
    while time.monotonic() < end:
        m = c.conn.recv_match(type="PARAM_VALUE", blocking=True, timeout=0.5)
        if m is not None:
            params[m.param_index] = m
            if len(params) == m.param_count:
                break
    count = {m.param_count for m in params.values()}
    assert len(count) == 1 and len(params) == count.pop() >= 30
    names = {m.param_id: m for m in params.values()}
    assert len(names) == len(params)
    assert {f"BS_K{i}" for i in range(1, 9)} <= set(names)
    assert names["BS_K1"].param_value == 10.0 and names["VM_MASS"].param_value == 2.0
    assert names["VM_IXX"].param_value == 1.25 and names["COM_OF_LOSS_T"].param_value == 1.0

    # read by name (index −1) and by index
    c.conn.mav.param_request_read_send(1, 1, b"VM_IZZ", -1)
    m = c.wait("PARAM_VALUE", lambda m: m.param_id == "VM_IZZ")
    assert m.param_value == pytest.approx(2.2) and m.param_index == names["VM_IZZ"].param_index
    c.conn.mav.param_request_read_send(1, 1, b"", names["BS_K5"].param_index)
    assert c.wait("PARAM_VALUE", lambda m: m.param_index == names["BS_K5"].param_index).param_id == "BS_K5"

    # accepted: echoed with the new value, and read back
    assert c.param_set("BS_K1", 8.0).param_value == 8.0
    c.conn.mav.param_request_read_send(1, 1, b"BS_K1", -1)
    assert c.wait("PARAM_VALUE", lambda m: m.param_id == "BS_K1").param_value == 8.0

    # out of range: the echo carries the unchanged value, and a STATUSTEXT says why
    echo = c.param_set("VM_MASS", -1.0)
    assert echo.param_value == 2.0 and echo.param_index == names["VM_MASS"].param_index
    assert "expected a number in (0, 10000] kg" in c.text_containing("VM_MASS = -1")

    # gains that break (41)–(44): refused, naming the condition
    assert c.param_set("BS_K2", 2000.0).param_value == 10.0
    assert "(41)" in c.text_containing("BS_K2 = 2000")

    # the count and the indices never change
    c.conn.mav.param_request_read_send(1, 1, b"BS_K2", -1)
    m = c.wait("PARAM_VALUE", lambda m: m.param_id == "BS_K2")
    assert m.param_count == len(params) and m.param_index == names["BS_K2"].param_index


def test_commands_versions_and_message_intervals(client):
    c = client
    c.heartbeat()
    assert c.command(M.MAV_CMD_DO_SET_SERVO, 1, 1500).result == M.MAV_RESULT_UNSUPPORTED
    ack = c.command(M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_AUTOPILOT_VERSION)
    assert ack.result == M.MAV_RESULT_ACCEPTED
    ver = c.wait("AUTOPILOT_VERSION")
    assert ver.capabilities & M.MAV_PROTOCOL_CAPABILITY_MAVLINK2
    assert c.command(M.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES, 1).result == M.MAV_RESULT_ACCEPTED
    c.wait("AUTOPILOT_VERSION")
    assert c.command(M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_HOME_POSITION).result == M.MAV_RESULT_ACCEPTED
    home = c.wait("HOME_POSITION")
    assert (home.latitude, home.longitude, home.altitude) == (473977420, 85455940, 488000)

    # ATTITUDE at 10 Hz instead of 50 Hz; then off; then the default again
    att = M.MAVLINK_MSG_ID_ATTITUDE
    assert c.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, att, 100_000).result == M.MAV_RESULT_ACCEPTED
    assert c.command(M.MAV_CMD_GET_MESSAGE_INTERVAL, att).result == M.MAV_RESULT_ACCEPTED
    assert c.wait("MESSAGE_INTERVAL", lambda m: m.message_id == att).interval_us == 100_000

    def rate(msg_type: str, seconds: float = 2.0) -> float:
        """Messages of ``msg_type`` per second of the vehicle's time (their time_boot_ms), over ``seconds`` of wall
        time: a loaded machine that holds the vehicle or this test back changes how many come, not their interval."""
        stamps = [m.time_boot_ms for m in received(msg_type, seconds)]
        return (len(stamps) - 1) / ((stamps[-1] - stamps[0]) / 1000) if len(stamps) > 2 else 0.0

    def received(msg_type: str, seconds: float) -> list:
        """The messages of ``msg_type`` that come in ``seconds`` of wall time, after 0.3 s for a change to apply."""
        c.pump(0.3)
        got, end = [], time.monotonic() + seconds
        while time.monotonic() < end:
            m = c.conn.recv_match(blocking=True, timeout=0.05)
            if m is not None and m.get_type() == msg_type:
                got.append(m)
        return got

    assert 5 <= rate("ATTITUDE") <= 15 and 25 <= rate("ATTITUDE_QUATERNION") <= 75
    assert c.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, att, -1).result == M.MAV_RESULT_ACCEPTED
    assert received("ATTITUDE", 1.0) == []
    assert c.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, att, 0).result == M.MAV_RESULT_ACCEPTED
    assert rate("ATTITUDE") >= 25
    ack = c.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, M.MAVLINK_MSG_ID_ODOMETRY, 1000)
    assert ack.result == M.MAV_RESULT_DENIED
    # a command addressed to another system is not ours to answer
    c.conn.mav.command_long_send(7, 1, M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, 0, 0)
    c.pump(0.5)
    assert not [a for a in c.acks if a.command == M.MAV_CMD_NAV_TAKEOFF][1:]


def test_one_sequence_for_every_message_on_the_link_so_no_loss_is_reported(client):
    """The streams the compiled tick builds (ATTITUDE ... GPS_RAW_INT) and the messages pymavlink packs (HEARTBEAT,
    SYS_STATUS, COMMAND_ACK, ...) share the link's one sequence number: pymavlink (as MAVProxy and QGroundControl)
    counts no message lost, and messages of both kinds arrive."""
    c = client
    c.conn.mav_loss = c.conn.mav_count = 0
    assert c.command(M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_GLOBAL_POSITION_INT).result == M.MAV_RESULT_ACCEPTED
    seen: set[str] = set()
    end = time.monotonic() + 2.5
    while time.monotonic() < end:
        m = c.conn.recv_match(blocking=True, timeout=0.05)
        if m is not None:
            seen.add(m.get_type())
    compiled = {"ATTITUDE", "ATTITUDE_QUATERNION", "LOCAL_POSITION_NED", "ATTITUDE_TARGET", "GLOBAL_POSITION_INT",
                "GPS_RAW_INT"}  # fmt: skip
    assert compiled <= seen and {"HEARTBEAT", "SYS_STATUS", "EXTENDED_SYS_STATE", "SERVO_OUTPUT_RAW"} <= seen
    assert c.conn.mav_count > 300 and c.conn.mav_loss == 0, (c.conn.mav_count, c.conn.mav_loss)


def test_offboard_flight_with_telemetry_mass_mismatch_and_landing(client):
    c = client
    c.heartbeat()
    # Pre-arm check: offboard needs a setpoint stream, both to switch to it and to arm in it.
    ack = c.command(M.MAV_CMD_DO_SET_MODE, M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 6, 0)
    assert ack.result == M.MAV_RESULT_DENIED
    c.text_containing("Offboard denied: no setpoint stream")
    fly_setpoints(c, 0.3, altitude=3.0)
    assert c.command(M.MAV_CMD_DO_SET_MODE, M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 6, 0).result == M.MAV_RESULT_ACCEPTED
    for_a_while(c, 1.6)  # the stream goes stale while disarmed in offboard (1 s on the vehicle's and the wall's clock)
    assert c.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == M.MAV_RESULT_DENIED
    c.text_containing("Arming denied: no offboard setpoint stream")

    ref = dict(altitude=3.0, roll=0.1, pitch=-0.1, yaw=0.5)
    fly_setpoints(c, 0.3, **ref)
    assert c.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == M.MAV_RESULT_ACCEPTED
    fly_setpoints(c, 3.0, **ref)
    hb = c.heartbeat()
    assert hb.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED and c.conn.flightmode == "OFFBOARD", c.texts
    att, pos = c.latest["ATTITUDE"], c.latest["LOCAL_POSITION_NED"]
    assert (att.roll, att.pitch, att.yaw) == pytest.approx((0.1, -0.1, 0.5), abs=2e-3)
    assert pos.z == pytest.approx(-3.0, abs=2e-3)
    assert c.latest["GLOBAL_POSITION_INT"].relative_alt == pytest.approx(3000, abs=5)
    assert c.latest["EXTENDED_SYS_STATE"].landed_state == M.MAV_LANDED_STATE_IN_AIR
    q = c.latest["ATTITUDE_QUATERNION"]
    assert math.hypot(q.q1, q.q2, q.q3, q.q4) == pytest.approx(1.0, abs=1e-6)
    assert c.latest["POSITION_TARGET_LOCAL_NED"].z == pytest.approx(-3.0)
    servo = c.latest["SERVO_OUTPUT_RAW"]
    assert all(1000 <= getattr(servo, f"servo{i}_raw") <= 2000 for i in range(1, 5))

    # The autopilot's model is a parameter: a 20 % heavier model mass makes the backstepping (no
    # integral action) hover above the reference by e1 = (m − m̂)·g / (m̂·k1·k2) = 0.4·9.8/(2.4·100) m.
    assert c.param_set("VM_MASS", 2.4).param_value == pytest.approx(2.4)
    fly_setpoints(c, 2.0, **ref)
    assert -c.latest["LOCAL_POSITION_NED"].z - 3.0 == pytest.approx(0.4 * 9.8 / (2.4 * 100), abs=2e-3)

    # Disarming in the air is refused unless forced; LAND descends and disarms on touchdown.
    assert c.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 0).result == M.MAV_RESULT_DENIED
    assert c.command(M.MAV_CMD_NAV_LAND).result == M.MAV_RESULT_ACCEPTED
    hb = c.wait("HEARTBEAT", lambda m: m.get_srcComponent() == 1 and not m.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED,
                timeout=10)  # fmt: skip
    assert c.conn.flightmode == "LAND"
    c.wait("EXTENDED_SYS_STATE", lambda m: m.landed_state == M.MAV_LANDED_STATE_ON_GROUND)
    assert c.latest["LOCAL_POSITION_NED"].z > -0.05
    c.text_containing("Landed, disarmed")


def test_health_gps_home_and_capabilities(client):
    """What MAVSDK and QGroundControl read before they fly: SYS_STATUS's sensor and pre-arm bits, the GPS, home
    (via REQUEST_MESSAGE, also as COMMAND_INT), AUTOPILOT_VERSION's capabilities; then GPS_RAW_INT in flight
    against LOCAL_POSITION_NED and GLOBAL_POSITION_INT of the same tick."""
    from quadsitl.frames import geodetic_to_ned

    c = client
    c.heartbeat()
    status = c.wait_armable()
    bits = (M.MAV_SYS_STATUS_SENSOR_3D_GYRO | M.MAV_SYS_STATUS_SENSOR_3D_ACCEL | M.MAV_SYS_STATUS_SENSOR_3D_MAG
            | M.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE | M.MAV_SYS_STATUS_SENSOR_GPS | M.MAV_SYS_STATUS_PREARM_CHECK
            | M.MAV_SYS_STATUS_SENSOR_ATTITUDE_STABILIZATION | M.MAV_SYS_STATUS_SENSOR_Z_ALTITUDE_CONTROL)  # fmt: skip
    for field in ("present", "enabled", "health"):
        assert getattr(status, f"onboard_control_sensors_{field}") & bits == bits, field

    assert c.command(M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_AUTOPILOT_VERSION).result == M.MAV_RESULT_ACCEPTED
    caps = c.wait("AUTOPILOT_VERSION").capabilities
    assert caps & M.MAV_PROTOCOL_CAPABILITY_MISSION_INT and caps & M.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
    assert c.command(M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_HOME_POSITION).result == M.MAV_RESULT_ACCEPTED
    home = c.wait("HOME_POSITION")
    assert (home.latitude, home.longitude, home.altitude) == (473977420, 85455940, 488000)
    assert (home.x, home.y, home.z) == (0.0, 0.0, 0.0)
    # the same request as COMMAND_INT (advertised): MAVSDK sends some commands that way
    c.conn.mav.command_int_send(1, 1, 0, M.MAV_CMD_REQUEST_MESSAGE, 0, 0, M.MAVLINK_MSG_ID_HOME_POSITION, 0, 0, 0,
                                0, 0, 0)  # fmt: skip
    assert c.wait("COMMAND_ACK", lambda m: m.command == M.MAV_CMD_REQUEST_MESSAGE).result == M.MAV_RESULT_ACCEPTED
    c.wait("HOME_POSITION")
    gps = c.wait("GPS_RAW_INT")
    assert (gps.fix_type, gps.satellites_visible) == (M.GPS_FIX_TYPE_3D_FIX, 10)
    assert (gps.lat, gps.lon, gps.alt) == (home.latitude, home.longitude, home.altitude)  # at rest, at home

    # Fly offboard, pitched 0.1 rad down: the vehicle climbs to 2 m and accelerates north (no position loop).
    ref = dict(altitude=2.0, pitch=-0.1, yaw=0.3)
    fly_setpoints(c, 0.3, **ref)
    assert c.command(M.MAV_CMD_DO_SET_MODE, 1, 6, 0).result == M.MAV_RESULT_ACCEPTED
    assert c.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == M.MAV_RESULT_ACCEPTED
    fly_setpoints(c, 2.0, **ref)
    seen: dict[str, dict[int, object]] = {"GPS_RAW_INT": {}, "GLOBAL_POSITION_INT": {}, "LOCAL_POSITION_NED": {}}
    end = time.monotonic() + 10
    while time.monotonic() < end:
        c.setpoint(**ref)
        m = c.conn.recv_match(blocking=True, timeout=0.05)
        if m is None or m.get_type() not in seen:
            continue
        ms = m.time_usec // 1000 if m.get_type() == "GPS_RAW_INT" else m.time_boot_ms
        seen[m.get_type()][ms] = m
        common = set(seen["GPS_RAW_INT"]) & set(seen["GLOBAL_POSITION_INT"]) & set(seen["LOCAL_POSITION_NED"])
        # ticks half a metre north at least (under load the real-time plant may lag the 2 s flown above)
        common = {ms for ms in common if seen["LOCAL_POSITION_NED"][ms].x > 0.5}
        if len(common) >= 3:
            break
    assert len(common) >= 3, {k: sorted(v)[-5:] for k, v in seen.items()}  # GPS ticks are also 10 and 50 Hz ticks
    for ms in common:
        gps, gpi, pos = (seen[k][ms] for k in ("GPS_RAW_INT", "GLOBAL_POSITION_INT", "LOCAL_POSITION_NED"))
        assert (gps.lat, gps.lon, gps.alt) == (gpi.lat, gpi.lon, gpi.alt)
        north, east = geodetic_to_ned(gps.lat * 1e-7, gps.lon * 1e-7, 47.397742, 8.545594)
        assert (north, east) == pytest.approx((pos.x, pos.y), abs=0.02) and pos.x > 0.5  # 1e-7 deg ≈ 1.1 cm
        assert gps.alt == pytest.approx(488_000 - 1000 * pos.z, abs=1) and gpi.relative_alt == pytest.approx(
            2000, abs=20
        )
        assert gps.vel == pytest.approx(100 * math.hypot(pos.vx, pos.vy), abs=1) and gps.vel > 50
        assert gps.cog == pytest.approx(math.degrees(math.atan2(pos.vy, pos.vx)) % 360 * 100, abs=2)
    c.wait("EXTENDED_SYS_STATE", lambda m: m.landed_state == M.MAV_LANDED_STATE_IN_AIR)


def test_a_busy_port_names_the_port_and_the_option(cli):
    import socket

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as busy:
        busy.bind(("127.0.0.1", 0))
        port = busy.getsockname()[1]
        r = cli("up", "-q", "--gcs-listen", f"127.0.0.1:{port}", "--api-listen", "127.0.0.1:0", "--no-zenoh",
                timeout=60)  # fmt: skip
    # refused by `up` itself, before it starts anything: one line, exit status 2
    assert r.returncode == 2
    assert r.stderr.strip() == (
        f"quadsitl up: error: --gcs-listen 127.0.0.1:{port}: cannot bind: Address already in use; "
        "choose another with --gcs-listen HOST:PORT"
    )


def test_setpoint_validation_normalises_near_unit_quaternions_and_refuses_the_rest(client):
    from quadsitl.frames import euler_to_quaternion

    c = client
    c.heartbeat()
    q = [1.04 * x for x in euler_to_quaternion(0.1, 0.0, 0.0)]  # 8 % off unit length: normalised

    def stream(quat, seconds: float, z: float = -1.0) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            c.conn.mav.set_attitude_target_send(0, 1, 1, 71, quat, 0, 0, 0, 0)
            c.conn.mav.set_position_target_local_ned_send(0, 1, 1, M.MAV_FRAME_LOCAL_NED, 0b110111111011, 0, 0, z,
                                                          0, 0, 0, 0, 0, 0, 0, 0)  # fmt: skip
            c.pump(0.05)

    stream(q, 0.3)
    assert c.command(M.MAV_CMD_DO_SET_MODE, 1, 6, 0).result == M.MAV_RESULT_ACCEPTED
    assert c.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == M.MAV_RESULT_ACCEPTED
    stream(q, 2.0)
    assert c.latest["ATTITUDE"].roll == pytest.approx(0.1, abs=2e-3)
    stream([2.0 * x for x in q], 1.0)  # far from unit length: refused, 0.1 rad stays in force
    c.text_containing("not a unit quaternion")
    stream(list(euler_to_quaternion(1.45, 0.0, 0.0)), 1.0)  # 83° > ATT_TILT_MAX (80°)
    c.text_containing("beyond ATT_TILT_MAX")
    stream(q, 1.0, z=-5000.0)  # above SP_ALT_MAX
    c.text_containing("Position setpoint refused: altitude 5000 m")
    assert c.latest["ATTITUDE"].roll == pytest.approx(0.1, abs=2e-3)
    assert c.latest["LOCAL_POSITION_NED"].z == pytest.approx(-1.0, abs=5e-3)
    assert c.latest["SYS_STATUS"].errors_count2 > 10
