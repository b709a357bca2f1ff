"""``quadsitl up`` and a raw pymavlink client: the position commands as COMMAND_LONG and COMMAND_INT with NaN
parameters, global position targets, QGroundControl's SET_MODE, and refused inputs (each answered and said,
the vehicle flying on as before)."""

import math
import time

import numpy as np
import pytest

from quadsitl.frames import geodetic_to_ned, ned_to_geodetic
from tests.mavclient import Client, M, armable_client

NAN = math.nan
HOLD, RTL = (4 << 16) | (3 << 24), (4 << 16) | (5 << 24)
ORIGIN = (47.397742, 8.545594, 488.0)  # PX4 SITL's default home: the local origin


@pytest.fixture
def client():
    with armable_client("--speed", "4") as c:
        yield c


def command_int(c: Client, cmd: int, frame: int, params=(NAN,) * 4, x: int = 0, y: int = 0, z: float = NAN):
    c.conn.mav.command_int_send(1, 1, frame, cmd, 0, 0, *params, x, y, z)
    return c.wait("COMMAND_ACK", lambda m: m.command == cmd)


def position(c: Client) -> tuple[float, float, float]:
    p = c.wait("LOCAL_POSITION_NED")
    return p.x, p.y, -p.z


def settle(c: Client, target: tuple[float, float, float], tolerance: float, timeout: float = 30.0) -> None:
    c.wait("LOCAL_POSITION_NED", lambda p: math.dist((p.x, p.y, -p.z), target) < tolerance, timeout)


def test_commands_long_and_int_with_nan_parameters_and_refusals(client):
    c = client
    c.param_set("GF_MAX_HOR_DIST", 100.0)
    assert c.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == M.MAV_RESULT_ACCEPTED
    # takeoff as COMMAND_INT with an AMSL altitude (frame GLOBAL): 488 + 3 m
    assert command_int(c, M.MAV_CMD_NAV_TAKEOFF, 0, z=491.0).result == M.MAV_RESULT_ACCEPTED
    c.wait("HEARTBEAT", lambda m: m.custom_mode == HOLD, 20)
    assert position(c) == pytest.approx((0.0, 0.0, 3.0), abs=0.1)
    # a second takeoff while flying, and NaN or infinite parameters where a number is needed, are refused
    assert c.command(M.MAV_CMD_NAV_TAKEOFF, NAN, NAN, NAN, NAN, NAN, NAN, NAN).result == M.MAV_RESULT_DENIED
    c.text_containing("Takeoff denied: already flying")
    # goto as COMMAND_LONG (lat/lon in degrees, AMSL): 10 m east, 4 m up. Its params are float32: at 47° the
    # latitude is rounded to ~4e-6° (0.4 m), which is why MAVSDK sends COMMAND_INT; the vehicle flies there.
    lat, lon = ned_to_geodetic(0.0, 10.0, ORIGIN[0], ORIGIN[1])
    ack = c.command(M.MAV_CMD_DO_REPOSITION, -1, 1, 0, NAN, lat, lon, 492.0)
    assert ack.result == M.MAV_RESULT_ACCEPTED
    x, y = geodetic_to_ned(float(np.float32(lat)), float(np.float32(lon)), ORIGIN[0], ORIGIN[1])
    settle(c, (x, y, 4.0), 0.05)
    assert math.hypot(x, y - 10.0) < 0.5
    # goto as COMMAND_INT, frame GLOBAL_RELATIVE_ALT_INT, only the altitude changes (x, y = INT32_MAX: none)
    ack = command_int(c, M.MAV_CMD_DO_REPOSITION, 6, (NAN, 1, 0, NAN), 2**31 - 1, 2**31 - 1, 6.0)
    assert ack.result == M.MAV_RESULT_ACCEPTED
    settle(c, (x, y, 6.0), 0.05)
    # refused: beyond the geofence, a latitude off the globe, an infinite yaw, an unknown frame
    far_lat, far_lon = ned_to_geodetic(500.0, 0.0, ORIGIN[0], ORIGIN[1])
    far = round(far_lat * 1e7), round(far_lon * 1e7)
    refusals = [
        (command_int(c, M.MAV_CMD_DO_REPOSITION, 5, (NAN, 1, 0, NAN), *far, 494.0), "GF_MAX_HOR_DIST"),
        (c.command(M.MAV_CMD_DO_REPOSITION, -1, 1, 0, NAN, 95.0, lon, NAN), "latitude 95 deg"),
        (c.command(M.MAV_CMD_DO_REPOSITION, -1, 1, 0, math.inf, NAN, NAN, NAN), "yaw inf"),
        (command_int(c, M.MAV_CMD_DO_REPOSITION, 1, (NAN, 1, 0, NAN), 0, 0, 5.0), "frame 1"),
        (c.command(M.MAV_CMD_DO_CHANGE_SPEED, 1, 1000.0, -1), "Change speed: 1000 m/s"),
    ]  # fmt: skip
    for ack, said in refusals:
        assert ack.result == M.MAV_RESULT_DENIED, said
        c.text_containing(said)
    assert position(c) == pytest.approx((x, y, 6.0), abs=0.05)  # nothing moved
    # all-NaN reposition: stop here (it is already stopped); a speed change, then back home by SET_MODE (QGC)
    assert c.command(M.MAV_CMD_DO_REPOSITION, NAN, 1, NAN, NAN, NAN, NAN, NAN).result == M.MAV_RESULT_ACCEPTED
    assert c.command(M.MAV_CMD_DO_CHANGE_SPEED, 1, 3.0, -1).result == M.MAV_RESULT_ACCEPTED
    c.param_set("RTL_RETURN_ALT", 8.0)
    c.conn.mav.set_mode_send(1, M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, RTL)
    c.wait("HEARTBEAT", lambda m: m.custom_mode == RTL, 5)
    peak = 0.0  # it climbs to RTL_RETURN_ALT first, then flies home and lands

    def landed(m) -> bool:
        nonlocal peak
        if m.get_type() == "LOCAL_POSITION_NED":
            peak = max(peak, -m.z)
        return m.get_type() == "HEARTBEAT" and not m.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED

    c.wait_any(landed, 60)
    assert peak == pytest.approx(8.0, abs=0.3)
    assert position(c) == pytest.approx((0.0, 0.0, 0.0), abs=0.1)  # landed at home
    assert c.latest["SYS_STATUS"].errors_count2 >= 1  # the geofence refusal is counted with the other refusals


def test_global_position_targets_and_refused_position_targets(client):
    c = client
    lat, lon = ned_to_geodetic(-6.0, 4.0, ORIGIN[0], ORIGIN[1])
    mask = 2552  # position + yaw

    def target(frame: int, alt: float, lat: float = lat, lon: float = lon, mask: int = mask) -> None:
        c.conn.mav.set_position_target_global_int_send(0, 1, 1, frame, mask, round(lat * 1e7), round(lon * 1e7),
                                                       alt, 0, 0, 0, 0, 0, 0, 0.5, 0)  # fmt: skip

    def stream(seconds: float, bad: dict | None = None, **kw) -> None:
        """``kw``'s target at 20 Hz, each preceded by the ``bad`` one (a refused target does not keep the stream
        fresh: a client sending only refused setpoints loses offboard control, the failsafe lands)."""
        for _ in range(round(seconds / 0.05)):
            if bad is not None:
                target(**bad)
            target(**kw)
            c.pump(0.05)

    stream(0.3, frame=6, alt=5.0)  # 5 m above home
    assert c.command(M.MAV_CMD_DO_SET_MODE, 1, 6, 0).result == M.MAV_RESULT_ACCEPTED
    assert c.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == M.MAV_RESULT_ACCEPTED
    for _ in range(400):
        target(frame=6, alt=5.0)
        c.pump(0.05)
        p = c.latest.get("LOCAL_POSITION_NED")
        if p is not None and math.dist((p.x, p.y, -p.z), (-6.0, 4.0, 5.0)) < 0.05:
            break
    assert position(c) == pytest.approx((-6.0, 4.0, 5.0), abs=0.05)
    assert c.latest["ATTITUDE"].yaw == pytest.approx(0.5, abs=0.01)
    # AMSL (frame 5) the same point 2 m higher
    stream(8.0, frame=5, alt=ORIGIN[2] + 7.0)
    assert position(c) == pytest.approx((-6.0, 4.0, 7.0), abs=0.05)
    refused = [
        (dict(frame=7, alt=5.0), "frame 7"),
        (dict(frame=6, alt=5.0, lat=95.0), "lat_int = 9.5e+08"),
        (dict(frame=6, alt=5000.0), "altitude 5000 m"),
        (dict(frame=6, alt=5.0, mask=2048 | 512), "force setpoints"),
    ]
    for bad, said in [*refused, (dict(frame=6, alt=NAN), "alt = nan: expected a finite number")]:
        stream(0.5, bad, frame=5, alt=ORIGIN[2] + 7.0)
        end = time.monotonic() + 10  # the refusal comes within a few setpoints; a loaded machine may take longer
        while not any(said in text for text in c.texts) and time.monotonic() < end:
            stream(0.25, bad, frame=5, alt=ORIGIN[2] + 7.0)
        assert any(said in text for text in c.texts), (said, c.texts)
    assert position(c) == pytest.approx((-6.0, 4.0, 7.0), abs=0.05)  # the valid target flies on
    assert c.latest["HEARTBEAT"].custom_mode == 6 << 16  # still offboard
