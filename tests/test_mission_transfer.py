"""The mission protocol through ``quadsitl up``'s shell (autopilot.process → autopilot.mission_protocol): MAVSDK
uploads a mission, downloads the same items, sees its progress (MISSION_CURRENT) and clears it; a raw pymavlink
client's refused items and unknown mission type are answered. Flying missions comes with the executor (issue 15)."""

import asyncio
import math

import pytest
from mavsdk.asyncio import ComponentType, Configuration, Mavsdk
from mavsdk.asyncio.plugins.mission import MissionAsync, MissionItem, MissionPlan

from quadsitl.frames import ned_to_geodetic
from tests.mavclient import Client, M, quadsitl_up
from tests.mavsdk_client import autopilot

ORIGIN = (47.397742, 8.545594)


def plan() -> MissionPlan:
    items = []
    for north, east, alt, hold in (
        (10.0, 0.0, 5.0, 0.0),
        (10.0, 10.0, 6.0, 2.0),
        (0.0, 10.0, 5.0, 0.0),
        (0.0, 0.0, 4.0, 1.0),
    ):
        lat, lon = ned_to_geodetic(north, east, *ORIGIN)
        items.append(MissionItem(lat, lon, alt, 3.0, True, math.nan, math.nan, MissionItem.CameraAction.NONE, hold,
                                 math.nan, 1.0, math.nan, math.nan, MissionItem.VehicleAction.NONE))  # fmt: skip
    return MissionPlan(items)


def fields(p: MissionPlan) -> list[tuple[float, float, float, float]]:
    """Latitude, longitude, relative altitude and hold time of each item (MAVSDK reads a hold of 0 as NaN)."""
    return [(i.latitude_deg, i.longitude_deg, i.relative_altitude_m, 0.0 if math.isnan(i.loiter_time_s) else
             i.loiter_time_s) for i in p.mission_items]  # fmt: skip


async def transfer(port: int) -> dict:
    seen: dict = {}
    async with Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION)) as m:
        mission = MissionAsync(await autopilot(m, port))
        sent = plan()
        await mission.upload_mission(sent)
        got = await mission.download_mission()
        seen["sent"], seen["got"] = fields(sent), fields(got)
        seen["speeds"] = [i.speed_m_s for i in got.mission_items]
        seen["radii"] = [i.acceptance_radius_m for i in got.mission_items]
        progress = await asyncio.wait_for(anext(aiter(mission.subscribe_mission_progress())), 5)
        seen["progress"] = (progress.current, progress.total)
        await mission.clear_mission()
        seen["after_clear"] = len((await mission.download_mission()).mission_items)
    return seen


def test_mavsdk_uploads_downloads_and_clears_a_mission():
    with quadsitl_up() as v:
        seen = asyncio.run(asyncio.wait_for(transfer(v.api_port), 90))
        assert v.proc.poll() is None
    assert len(seen["got"]) == 4
    for sent, got in zip(seen["sent"], seen["got"]):
        assert got[:2] == pytest.approx(sent[:2], abs=1e-7)  # 1e-7 degrees: MISSION_ITEM_INT's resolution
        assert got[2:] == pytest.approx(sent[2:], abs=1e-6)
    assert seen["speeds"] == pytest.approx([3.0] * 4) and seen["radii"] == pytest.approx([1.0] * 4)
    assert seen["progress"] == (0, 4) and seen["after_clear"] == 0


def test_refused_items_and_other_mission_types_are_answered(tmp_path):
    with quadsitl_up() as v:
        c = Client(v.gcs_port)
        try:
            c.heartbeat()
            # an upload of a mission type MAVLink does not define: UNSUPPORTED with the type echoed, at once
            c.conn.mav.mission_count_send(1, 1, 2, 7)
            ack = c.wait("MISSION_ACK")
            assert (ack.type, ack.mission_type) == (M.MAV_MISSION_UNSUPPORTED, 7)
            # a mission whose second item is a command we do not fly: the upload ends with UNSUPPORTED
            c.conn.mav.mission_count_send(1, 1, 2, 0)
            assert c.wait("MISSION_REQUEST_INT", lambda r: r.seq == 0).mission_type == 0
            c.conn.mav.mission_item_int_send(1, 1, 0, 6, M.MAV_CMD_NAV_WAYPOINT, 1, 1, 0, 1, 0, math.nan,
                                             473977420, 85455940, 5.0, 0)  # fmt: skip
            c.wait("MISSION_REQUEST_INT", lambda r: r.seq == 1)
            c.conn.mav.mission_item_int_send(1, 1, 1, 2, M.MAV_CMD_DO_SET_SERVO, 0, 1, 1, 1500, 0, 0, 0, 0, 0.0, 0)
            assert c.wait("MISSION_ACK").type == M.MAV_MISSION_UNSUPPORTED
            # nothing was stored: a download counts 0
            c.conn.mav.mission_request_list_send(1, 1, 0)
            assert c.wait("MISSION_COUNT").count == 0
            # MISSION_CURRENT streams at 1 Hz: no mission (total 65535, state 1)
            cur = c.wait("MISSION_CURRENT", timeout=3)
            assert (cur.total, cur.mission_state) == (65535, 1)
        finally:
            c.close()


WAYPOINTS = """QGC WPL 110
0\t1\t3\t16\t0\t1\t0\t0\t47.397832\t8.545594\t5\t1
1\t0\t3\t16\t2\t1\t0\t0\t47.397832\t8.545727\t6\t1
2\t0\t3\t16\t0\t1\t0\t0\t47.397742\t8.545727\t5\t1
3\t0\t3\t20\t0\t0\t0\t0\t0\t0\t0\t1
"""


def test_mavproxy_wp_load_uploads_a_waypoint_file_and_wp_list_downloads_the_same_items(tmp_path):
    from tests.test_up_mavproxy import MAVProxy

    (tmp_path / "way.txt").write_text(WAYPOINTS)
    with quadsitl_up() as v:
        mp = MAVProxy(v.gcs_port, tmp_path)
        try:
            mp.expect(r"online system 1", 30)
            mp.send(f"wp load {tmp_path / 'way.txt'}")
            mp.expect(r"Sent all 4 waypoints")
            mp.expect(r"Got MISSION_ACK: TYPE_MISSION: ACCEPTED")
            mp.send("wp list")
            mp.expect(r"Requesting 4 waypoints")
            listed = [
                mp.expect(r"^(\d+) (\d+) ([-\d.]+) ([-\d.]+) ([-\d.]+) p1=([-\d.]+) p2=([-\d.]+)") for _ in range(4)
            ]
        finally:
            mp.close()
    sent = [line.split("\t") for line in WAYPOINTS.splitlines()[1:]]
    for row, got in zip(sent, listed):
        command, frame, lat, lon, alt, p1, p2 = (float(g) for g in got.groups())
        assert (command, frame) == (float(row[3]), float(row[2]))
        assert (lat, lon, alt) == pytest.approx((float(row[8]), float(row[9]), float(row[10])), abs=1e-7)
        assert (p1, p2) == (float(row[4]), float(row[5]))
