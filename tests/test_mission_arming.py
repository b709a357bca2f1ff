"""AUTO.MISSION selected on the ground, then armed, as PX4 (and QGroundControl's "start mission" on a disarmed vehicle)
does, through ``quadsitl up --preset x500`` and a raw pymavlink ground station: the mode is taken, the vehicle stays on
the ground, and arming starts the mission (it takes off); arming in AUTO.MISSION without a mission is refused, naming
why. `quadsitl fly` starts its missions this way, at the tick its plant holds the clock at."""

import pytest

from quadsitl.frames import ned_to_geodetic
from quadsitl.wire import Mode
from tests.mavclient import M, armable_client

ORIGIN = (47.397742, 8.545594)


def mode_of(c) -> tuple[bool, int]:
    hb = c.wait("HEARTBEAT", lambda m: m.autopilot == M.MAV_AUTOPILOT_PX4)
    return bool(hb.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED), hb.custom_mode


@pytest.mark.timeout(120)
def test_mission_mode_selected_on_the_ground_waits_for_arming_and_then_flies():
    with armable_client("--preset", "x500") as c:
        # no mission: the mode is refused, and so would arming in it be
        ack = c.command(M.MAV_CMD_DO_SET_MODE, M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 4, 4)
        assert ack.result == M.MAV_RESULT_DENIED and "no mission uploaded" in c.text_containing("no mission")
        lat, lon = ned_to_geodetic(6.0, 0.0, *ORIGIN)
        items = [(M.MAV_CMD_NAV_TAKEOFF, 0.0, 0.0, 4.0), (M.MAV_CMD_NAV_WAYPOINT, lat, lon, 4.0)]
        assert c.upload_mission(items).type == M.MAV_MISSION_ACCEPTED
        ack = c.command(M.MAV_CMD_DO_SET_MODE, M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 4, 4)
        assert ack.result == M.MAV_RESULT_ACCEPTED
        # the mission cleared while the mode stays: arming in it is refused, naming why
        c.texts.clear()
        c.conn.mav.mission_clear_all_send(1, 1, M.MAV_MISSION_TYPE_MISSION)
        assert c.wait("MISSION_ACK").type == M.MAV_MISSION_ACCEPTED
        assert c.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == M.MAV_RESULT_DENIED
        assert c.text_containing("Arming denied") == "Arming denied: Mission denied: no mission uploaded"
        assert c.upload_mission(items).type == M.MAV_MISSION_ACCEPTED
        c.pump(1.0)
        armed, custom = mode_of(c)
        assert not armed and custom == Mode.MISSION.px4_custom_mode
        assert c.wait("LOCAL_POSITION_NED").z > -0.05  # still on the ground: nothing starts disarmed
        current = c.wait("MISSION_CURRENT")
        assert current.seq == 0 and getattr(current, "mission_state", 2) in (0, 2)  # not started
        assert c.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == M.MAV_RESULT_ACCEPTED
        c.wait("LOCAL_POSITION_NED", lambda m: m.z < -3.0, timeout=20)  # arming started it: it takes off
        c.wait("MISSION_ITEM_REACHED", lambda m: m.seq == 1, timeout=30)
        armed, custom = mode_of(c)
        assert armed and custom == Mode.MISSION.px4_custom_mode
