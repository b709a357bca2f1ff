"""Automatic disarming as PX4's (COM_DISARM_PRFLT, COM_DISARM_LAND), through ``quadsitl up --preset x500``: a vehicle
armed and left on the ground disarms by itself, and so does one that lands in offboard (it stayed armed before)."""

import math
import time

import pytest

from tests.mavclient import Client, M, armable_client

VELOCITY_ONLY = 0b0000_1111_1100_0111  # SET_POSITION_TARGET_LOCAL_NED: vx, vy, vz


@pytest.fixture(scope="module")
def vehicle():
    with armable_client("--preset", "x500") as c:
        yield c


def armed(c: Client) -> bool:
    return bool(c.wait("HEARTBEAT", lambda m: m.autopilot == M.MAV_AUTOPILOT_PX4).base_mode
                & M.MAV_MODE_FLAG_SAFETY_ARMED)  # fmt: skip


def test_armed_and_left_on_the_ground_it_disarms_after_com_disarm_prflt(vehicle):
    c = vehicle
    assert c.param_set("COM_DISARM_PRFLT", 2.0).param_value == 2.0
    assert c.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == M.MAV_RESULT_ACCEPTED
    armed_at = time.monotonic()
    c.pump(1.0)
    assert armed(c)  # not before its time
    text = c.text_containing("auto preflight disarming", timeout=10)
    waited = time.monotonic() - armed_at
    assert "COM_DISARM_PRFLT 2 s" in text and 1.5 < waited < 5.0
    c.pump(0.3)
    assert not armed(c)


def test_a_vehicle_landed_in_offboard_disarms_after_com_disarm_land(vehicle):
    c = vehicle
    nan = math.nan
    assert c.command(M.MAV_CMD_NAV_TAKEOFF, nan, nan, nan, nan, nan, nan, nan).result == M.MAV_RESULT_ACCEPTED
    assert c.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == M.MAV_RESULT_ACCEPTED
    c.wait("LOCAL_POSITION_NED", lambda m: m.z < -2.4, timeout=20)

    def down() -> None:  # 1 m/s down, as MAVSDK's offboard_velocity_ned.py ends
        c.conn.mav.set_position_target_local_ned_send(0, 1, 1, M.MAV_FRAME_LOCAL_NED, VELOCITY_ONLY, 0, 0, 0,
                                                      0, 0, 1.0, 0, 0, 0, 0, 0)  # fmt: skip

    end = time.monotonic() + 30
    down()
    c.command(M.MAV_CMD_DO_SET_MODE, 1, 6, 0)  # PX4 offboard
    landed = None
    while time.monotonic() < end and landed is None:
        down()
        c.pump(0.05)
        landed = next((t for t in c.texts if "Landed, disarmed" in t), None)
    assert landed is not None, c.texts[-5:]
    assert not armed(c)
    assert c.wait("LOCAL_POSITION_NED").z > -0.1  # on the ground
