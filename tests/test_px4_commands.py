"""Commands answered as PX4 answers them, through ``quadsitl up``: a takeoff altitude below the minimum (MAVProxy's
``takeoff 5``) takes off to MIS_TAKEOFF_ALT with a warning instead of being refused, and GPS_GLOBAL_ORIGIN is
answered (MAVSDK's ``get_gps_global_origin``)."""

import math

import pytest

from tests.mavclient import M, armable_client


@pytest.fixture(scope="module")
def vehicle():
    with armable_client("--preset", "x500") as c:
        yield c


def test_a_takeoff_below_the_minimum_altitude_climbs_to_mis_takeoff_alt_and_says_so(vehicle):
    c = vehicle
    nan = math.nan
    ack = c.command(M.MAV_CMD_NAV_TAKEOFF, nan, nan, nan, nan, nan, nan, 5.0)  # MAVProxy's `takeoff 5`: 5 m AMSL
    assert ack.result == M.MAV_RESULT_ACCEPTED
    assert "Using minimum takeoff altitude: 2.50 m" in c.text_containing("minimum takeoff altitude")
    assert c.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == M.MAV_RESULT_ACCEPTED
    reached = c.wait("LOCAL_POSITION_NED", lambda m: m.z < -2.45, timeout=20)
    assert reached.z == pytest.approx(-2.5, abs=0.1)  # MIS_TAKEOFF_ALT above home, not 483 m below it


def test_gps_global_origin_is_the_local_frames_origin(vehicle):
    c = vehicle
    c.conn.mav.command_long_send(1, 1, M.MAV_CMD_REQUEST_MESSAGE, 0, M.MAVLINK_MSG_ID_GPS_GLOBAL_ORIGIN,
                                 0, 0, 0, 0, 0, 0)  # fmt: skip
    origin = c.wait("GPS_GLOBAL_ORIGIN", timeout=5)
    assert (origin.latitude, origin.longitude, origin.altitude) == (473977420, 85455940, 488000)  # PX4 SITL's home
