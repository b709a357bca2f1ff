"""The mission protocol's state machine (autopilot/mission_protocol.py): pure, driven by hand with a fake clock."""

from __future__ import annotations

import math

import pytest
from pymavlink.dialects.v20 import common as mavlink

from autopilot import mission_protocol as mp
from autopilot.mission_protocol import MissionItem, MissionProtocol, Out

GCS = (255, 190)
OTHER = (254, 1)
LAT, LON = 47.397742, 8.545594


def item_fields(seq: int, *, command: int = 16, frame: int = 6, current: int = 0, legacy: bool = False, **kw) -> dict:
    """A MISSION_ITEM_INT's fields (or a MISSION_ITEM's, ``legacy``) by pymavlink's names: a waypoint 10 m
    north-east per seq, 10 m above home."""
    lat, lon = LAT + 1e-4 * seq, LON + 1e-4 * seq
    f = {
        "seq": seq,
        "frame": frame,
        "command": command,
        "current": current,
        "autocontinue": 1,
        "param1": 0.0,
        "param2": 1.0,
        "param3": 0.0,
        "param4": math.nan,
        "x": lat if legacy else round(lat * 1e7),
        "y": lon if legacy else round(lon * 1e7),
        "z": 10.0,
        "mission_type": 0,
    }
    f.update(kw)
    return f


def kinds(outs: list[Out]) -> list[str]:
    return [o.kind for o in outs]


def only(outs: list[Out], kind: str) -> Out:
    assert kinds(outs).count(kind) == 1, kinds(outs)
    return next(o for o in outs if o.kind == kind)


def ack_type(outs: list[Out]) -> int:
    return only(outs, "MISSION_ACK").fields["type"]


def upload(p: MissionProtocol, n: int, sender=GCS, t: float = 0.0, **kw) -> list[Out]:
    """Upload n waypoints the nominal way; returns the last answer."""
    out = p.on_count(sender, n, 0, t)
    for s in range(n):
        assert only(out, "MISSION_REQUEST_INT").fields["seq"] == s
        out = p.on_item(sender, item_fields(s, current=int(s == 0), **kw), t)
    return out


# ---- upload -----------------------------------------------------------------------------------------


def test_nominal_upload_requests_each_item_from_the_sender_then_accepts():
    p = MissionProtocol()
    out = p.on_count(GCS, 3, 0, 0.0)
    assert out == [Out("MISSION_REQUEST_INT", GCS, {"seq": 0, "mission_type": 0})]
    out = p.on_item(GCS, item_fields(0, current=1), 0.01)
    assert out[0].fields["seq"] == 1 and out[0].target == GCS
    out = p.on_item(GCS, item_fields(1), 0.02)
    assert out[0].fields["seq"] == 2
    out = p.on_item(GCS, item_fields(2), 0.03)
    assert ack_type(out) == mp.ACCEPTED and only(out, "MISSION_ACK").target == GCS
    assert only(out, "MISSION_CURRENT").fields == {"seq": 0, "total": 3, "mission_state": 2, "mission_mode": 0}
    assert [it.seq for it in p.items] == [0, 1, 2]
    assert p.items[1].x == round((LAT + 1e-4) * 1e7) and p.items[1].z == 10.0
    assert p.mission_state == mp.STATE_NOT_STARTED and not p.upload_in_progress


def test_lost_requests_are_re_sent_every_250_ms_and_the_upload_completes():
    p = MissionProtocol()
    p.on_count(GCS, 2, 0, 0.0)  # this request is "lost"
    assert p.tick(0.1) == [] and p.tick(0.24) == []
    again = p.tick(0.25)
    assert again == [Out("MISSION_REQUEST_INT", GCS, {"seq": 0, "mission_type": 0})]
    assert p.tick(0.3) == [] and kinds(p.tick(0.5)) == ["MISSION_REQUEST_INT"]
    out = p.on_item(GCS, item_fields(0), 0.6)
    assert out[0].fields["seq"] == 1
    assert p.tick(0.8) == []  # 0.2 s after the last request
    assert p.tick(0.85)[0].fields["seq"] == 1
    assert ack_type(p.on_item(GCS, item_fields(1), 0.9)) == mp.ACCEPTED


def test_a_repeated_count_before_any_item_re_requests_item_0():
    p = MissionProtocol()
    p.on_count(GCS, 2, 0, 0.0)
    assert p.on_count(GCS, 2, 0, 0.5) == [Out("MISSION_REQUEST_INT", GCS, {"seq": 0, "mission_type": 0})]
    assert p.on_item(GCS, item_fields(1), 0.6) == []  # still waiting for item 0
    assert p.on_item(GCS, item_fields(0), 0.7)[0].fields["seq"] == 1


def test_duplicate_and_out_of_order_items_are_ignored_and_the_wanted_one_re_requested():
    p = MissionProtocol()
    p.on_count(GCS, 3, 0, 0.0)
    p.on_item(GCS, item_fields(0), 0.1)
    assert p.on_item(GCS, item_fields(0), 0.2) == []  # duplicate: no error, no extra request
    assert p.on_item(GCS, item_fields(2), 0.25) == []  # ahead of the wanted one: ignored
    assert p.tick(0.36)[0].fields["seq"] == 1  # the timer asks again for the wanted one
    p.on_item(GCS, item_fields(1), 0.4)
    out = p.on_item(GCS, item_fields(2), 0.5)
    assert ack_type(out) == mp.ACCEPTED and len(p.items) == 3


def test_timeout_cancels_the_upload_and_keeps_the_old_mission():
    p = MissionProtocol()
    upload(p, 2)
    old = p.items
    p.on_count(GCS, 4, 0, 10.0)
    p.on_item(GCS, item_fields(0), 10.1)
    for t in (10.5, 12.0, 15.0):
        assert kinds(p.tick(t)) == ["MISSION_REQUEST_INT"]
    out = p.tick(15.2)  # 5.1 s after the last item
    assert ack_type(out) == mp.OPERATION_CANCELLED and only(out, "MISSION_ACK").target == GCS
    assert "STATUSTEXT" in kinds(out)
    assert p.items == old and not p.upload_in_progress and p.tick(16.0) == []


def test_half_an_upload_never_replaces_the_stored_mission_and_a_cancel_from_the_client_drops_it():
    p = MissionProtocol()
    upload(p, 2)
    old, version = p.items, p.version
    p.on_count(GCS, 3, 0, 1.0)
    p.on_item(GCS, item_fields(0, z=50.0), 1.1)
    assert p.items == old
    assert p.on_ack(GCS, mp.OPERATION_CANCELLED, 0, 1.2) == []
    assert not p.upload_in_progress and p.items == old and p.version == version
    assert p.tick(1.5) == []


def test_a_second_client_starting_an_upload_is_refused_and_the_first_continues():
    p = MissionProtocol()
    p.on_count(GCS, 2, 0, 0.0)
    p.on_item(GCS, item_fields(0), 0.1)
    out = p.on_count(OTHER, 5, 0, 0.2)
    assert out == [Out("MISSION_ACK", OTHER, {"type": mp.ERROR, "mission_type": 0})]
    assert p.on_item(OTHER, item_fields(1, z=99.0), 0.3) == []  # the other client's items are not taken
    out = p.on_item(GCS, item_fields(1), 0.4)
    assert ack_type(out) == mp.ACCEPTED and len(p.items) == 2 and p.items[1].z == 10.0


def test_the_partner_restarting_its_upload_with_a_new_count_restarts_it():
    p = MissionProtocol()
    p.on_count(GCS, 3, 0, 0.0)
    p.on_item(GCS, item_fields(0), 0.1)
    assert p.on_count(GCS, 2, 0, 0.2)[0].fields["seq"] == 0
    assert ack_type(upload(p, 2, t=0.3)) == mp.ACCEPTED and len(p.items) == 2


def test_a_stale_upload_does_not_block_another_client():
    p = MissionProtocol()
    p.on_count(GCS, 3, 0, 0.0)
    out = p.on_count(OTHER, 1, 0, 6.0)  # no tick ran in between
    assert ack_type([o for o in out if o.target == GCS]) == mp.OPERATION_CANCELLED
    assert only(out, "MISSION_REQUEST_INT").target == OTHER


def test_count_zero_clears_and_too_many_is_no_space():
    p = MissionProtocol()
    upload(p, 2)
    out = p.on_count(GCS, mp.MAX_ITEMS + 1, 0, 1.0)
    assert ack_type(out) == mp.NO_SPACE and len(p.items) == 2 and not p.upload_in_progress
    assert kinds(p.on_count(GCS, mp.MAX_ITEMS, 0, 1.1)) == ["MISSION_REQUEST_INT"]
    out = p.on_count(GCS, 0, 0, 1.2)
    assert ack_type(out) == mp.ACCEPTED and p.items == () and p.mission_state == mp.STATE_NO_MISSION
    assert only(out, "MISSION_CURRENT").fields["total"] == mp.UINT16_MAX


def test_a_lost_final_ack_is_sent_again_when_the_last_item_comes_again():
    p = MissionProtocol()
    upload(p, 2)
    assert ack_type(p.on_item(GCS, item_fields(1), 1.0)) == mp.ACCEPTED
    assert ack_type(p.on_item(GCS, item_fields(0), 1.1)) == mp.ERROR  # no transfer
    assert ack_type(p.on_item(OTHER, item_fields(1), 1.2)) == mp.ERROR


def test_the_item_marked_current_becomes_current_and_the_same_mission_again_keeps_progress():
    p = MissionProtocol()
    p.on_count(GCS, 3, 0, 0.0)
    for s in range(3):
        out = p.on_item(GCS, item_fields(s, current=int(s == 1)), 0.1)
    assert p.current == 1 and only(out, "MISSION_CURRENT").fields["seq"] == 1
    p.current, p.mission_state, version = 2, mp.STATE_PAUSED, p.version
    out = upload(p, 3, t=1.0)  # the same plan (current flag on seq 0 now): nothing changes but the ACK
    assert kinds(out) == ["MISSION_ACK"] and p.current == 2 and p.mission_state == mp.STATE_PAUSED
    assert p.version == version
    upload(p, 3, t=2.0, z=20.0)
    assert p.current == 0 and p.mission_state == mp.STATE_NOT_STARTED and p.version == version + 1


def test_legacy_mission_item_is_taken_in_float_degrees_and_answered_with_legacy_requests():
    p = MissionProtocol()
    p.on_count(GCS, 2, 0, 0.0)
    out = p.on_item(GCS, item_fields(0, frame=3, legacy=True), 0.1, legacy=True)
    assert out == [Out("MISSION_REQUEST", GCS, {"seq": 1, "mission_type": 0})]
    assert kinds(p.tick(0.4)) == ["MISSION_REQUEST"]
    assert ack_type(p.on_item(GCS, item_fields(1, frame=3, legacy=True), 0.5, legacy=True)) == mp.ACCEPTED
    assert p.items[0].x == round(LAT * 1e7) and p.items[0].y == round(LON * 1e7) and p.items[0].frame == 3


def test_an_unsupported_ack_from_the_partner_switches_the_request_kind():
    p = MissionProtocol()
    p.on_count(GCS, 1, 0, 0.0)
    assert kinds(p.on_ack(GCS, mp.UNSUPPORTED, 0, 0.1)) == ["MISSION_REQUEST"]
    assert kinds(p.on_ack(GCS, mp.UNSUPPORTED, 0, 0.2)) == ["MISSION_REQUEST_INT"]


def test_busy_flying_refuses_uploads_and_clears_but_not_downloads_or_set_current():
    p = MissionProtocol()
    upload(p, 3)
    p.busy_flying = True
    assert ack_type(p.on_count(GCS, 2, 0, 1.0)) == mp.DENIED
    assert ack_type(p.on_count(GCS, 0, 0, 1.0)) == mp.DENIED
    assert ack_type(p.on_clear_all(GCS, 0, 1.0)) == mp.DENIED
    assert len(p.items) == 3 and not p.upload_in_progress
    assert only(p.on_request_list(GCS, 0, 1.1), "MISSION_COUNT").fields["count"] == 3
    assert kinds(p.on_set_current(GCS, 2, 1.2)) == ["MISSION_CURRENT"] and p.current == 2


# ---- item validation ----------------------------------------------------------------------------------


BAD_ITEMS = [
    ({"command": 17}, mp.UNSUPPORTED),  # LOITER_UNLIM
    ({"command": 201}, mp.UNSUPPORTED),  # DO_SET_ROI
    ({"frame": 1}, mp.UNSUPPORTED_FRAME),  # LOCAL_NED
    ({"frame": 10}, mp.UNSUPPORTED_FRAME),  # GLOBAL_TERRAIN_ALT
    ({"frame": 2}, mp.UNSUPPORTED_FRAME),  # a waypoint needs a position
    ({"param1": -1.0}, mp.INVALID_PARAM1),
    ({"param1": math.inf}, mp.INVALID_PARAM1),
    ({"param2": -0.5}, mp.INVALID_PARAM2),
    ({"param4": math.inf}, mp.INVALID_PARAM4),
    ({"x": 900_000_001}, mp.INVALID_PARAM5_X),
    ({"y": -1_800_000_001}, mp.INVALID_PARAM6_Y),
    ({"z": math.inf}, mp.INVALID_PARAM7),
    ({"command": 22, "z": math.nan}, mp.INVALID_PARAM7),  # a takeoff needs its altitude (a waypoint keeps its own)
    ({"command": 19, "param1": math.nan}, mp.INVALID_PARAM1),  # loiter time needs a time
    ({"command": 93, "frame": 2, "param1": -1.0}, mp.INVALID_PARAM1),  # delay until a time of day
    ({"command": 178, "frame": 2, "param1": 1.0, "param2": math.nan}, mp.INVALID_PARAM2),
    ({"command": 178, "frame": 2, "param1": 7.0, "param2": 5.0}, mp.INVALID_PARAM1),
]


@pytest.mark.parametrize(("change", "code"), BAD_ITEMS)
def test_a_refused_item_ends_the_upload_with_its_error_and_keeps_the_old_mission(change, code):
    p = MissionProtocol()
    upload(p, 1)
    old = p.items
    p.on_count(GCS, 3, 0, 1.0)
    p.on_item(GCS, item_fields(0), 1.1)
    out = p.on_item(GCS, item_fields(1, **change), 1.2)
    assert ack_type(out) == code and only(out, "MISSION_ACK").target == GCS
    assert not p.upload_in_progress and p.items == old
    assert p.tick(2.0) == []


@pytest.mark.parametrize(
    ("x", "y", "code"),
    [(math.nan, LON, mp.INVALID_PARAM5_X), (91.0, LON, mp.INVALID_PARAM5_X), (LAT, math.inf, mp.INVALID_PARAM6_Y)],
)
def test_a_legacy_item_with_a_bad_position_is_refused(x, y, code):
    with pytest.raises(mp.ItemRefusedError) as e:
        mp.parse_item(item_fields(0, frame=3, legacy=True, x=x, y=y), legacy=True)
    assert e.value.code == code


def test_every_supported_command_and_frame_is_taken():
    cases = [
        (16, 6, {"param1": 2.0, "param2": 3.0, "param4": 90.0}),
        (16, 0, {"param1": math.nan, "param2": math.nan}),  # NaN: the defaults
        (16, 3, {}),
        (16, 5, {}),
        (22, 6, {"param4": math.nan}),
        (21, 6, {}),
        (19, 6, {"param1": 5.0}),
        (20, 2, {"x": 0, "y": 0, "z": 0.0}),
        (20, 3, {"x": 0, "y": 0, "z": math.nan}),  # as some waypoint files write it: x, y, z ignored
        (93, 2, {"param1": 3.0, "param2": -1.0, "param3": -1.0, "param4": -1.0}),
        (178, 2, {"param1": 1.0, "param2": 5.0, "param3": -1.0, "param4": 0.0}),  # as MAVSDK sends it
        (178, 2, {"param1": 1.0, "param2": -1.0}),
    ]
    p = MissionProtocol()
    p.on_count(GCS, len(cases), 0, 0.0)
    for s, (command, frame, kw) in enumerate(cases):
        out = p.on_item(GCS, item_fields(s, command=command, frame=frame, **kw), 0.1)
        assert "MISSION_ACK" not in kinds(out) or ack_type(out) == mp.ACCEPTED, (command, frame, out)
    assert len(p.items) == len(cases) and p.items[8].z == 0.0


def test_an_item_of_another_mission_type_during_upload_is_an_error_but_the_upload_goes_on():
    p = MissionProtocol()
    p.on_count(GCS, 1, 0, 0.0)
    assert ack_type(p.on_item(GCS, item_fields(0, mission_type=1), 0.1)) == mp.ERROR
    assert ack_type(p.on_item(GCS, item_fields(0), 0.2)) == mp.ACCEPTED


# ---- other mission types ------------------------------------------------------------------------------


@pytest.mark.parametrize("mission_type", [3, 7])
def test_unknown_types_are_unsupported_with_the_type_echoed(mission_type):
    p = MissionProtocol()
    upload(p, 1)
    ack = Out("MISSION_ACK", GCS, {"type": mp.UNSUPPORTED, "mission_type": mission_type})
    name = f"Mission type {mission_type}"
    for out, what in ((p.on_count(GCS, 3, mission_type, 1.0), "upload"),
                      (p.on_request_list(GCS, mission_type, 1.0), "download")):  # fmt: skip
        assert out[0] == ack and out[1].kind == "STATUSTEXT"  # the ack, and why: MAVSDK says only ERROR
        assert out[1].fields["text"] == f"{name} {what} refused: not supported"
    assert p.on_clear_all(GCS, mission_type, 1.0) == [ack]
    assert len(p.items) == 1 and not p.upload_in_progress


# ---- the geofence (mission_type 1) ----------------------------------------------------------------------

FENCE = 1


def vertex(seq: int, east: float, north: float, n: int = 4, command: int = mp.FENCE_POLYGON_INCLUSION) -> dict:
    """A polygon vertex ``east``, ``north`` [m] from (LAT, LON), of a polygon of ``n`` vertices."""
    lat, lon = LAT + north / 111_320.0, LON + east / (111_320.0 * math.cos(math.radians(LAT)))
    return item_fields(seq, command=command, frame=5, param1=float(n), param2=0.0, x=round(lat * 1e7),
                       y=round(lon * 1e7), z=0.0, mission_type=FENCE)  # fmt: skip


def circle(seq: int, radius: float, command: int = mp.FENCE_CIRCLE_INCLUSION) -> dict:
    return item_fields(seq, command=command, frame=5, param1=radius, param2=0.0, z=0.0, mission_type=FENCE)


def upload_fence(p: MissionProtocol, items: list[dict]) -> list[Out]:
    """Upload ``items`` of their mission type (the geofence's, or the rally points')."""
    kind = items[0]["mission_type"]
    out = p.on_count(GCS, len(items), kind, 0.0)
    for f in items:
        assert only(out, "MISSION_REQUEST_INT").fields == {"seq": f["seq"], "mission_type": kind}
        out = p.on_item(GCS, f, 0.0)
    return out


SQUARE = [vertex(0, -10, -10), vertex(1, 10, -10), vertex(2, 10, 10), vertex(3, -10, 10)]


def test_a_geofence_is_uploaded_downloaded_and_cleared_beside_the_mission():
    p = MissionProtocol()
    upload(p, 2)
    items = [*SQUARE, circle(4, 30.0, mp.FENCE_CIRCLE_EXCLUSION)]
    out = upload_fence(p, items)
    assert out == [Out("MISSION_ACK", GCS, {"type": mp.ACCEPTED, "mission_type": FENCE})]
    assert len(p.fence) == 5 and p.fence_version == 1 and len(p.items) == 2  # the mission untouched
    assert p.on_request_list(GCS, FENCE, 1.0) == [Out("MISSION_COUNT", GCS, {"count": 5, "mission_type": FENCE})]
    for f in items:
        (o,) = p.on_request(GCS, f["seq"], FENCE, 1.0)
        got = o.fields
        assert (got["command"], got["param1"], got["x"], got["y"], got["mission_type"]) == (
            f["command"], f["param1"], f["x"], f["y"], FENCE)  # fmt: skip
    assert p.on_ack(GCS, mp.ACCEPTED, FENCE, 1.0) == []
    p.busy_flying = True  # a fence may change while a mission flies; the mission may not
    assert ack_type(p.on_clear_all(GCS, FENCE, 2.0)) == mp.ACCEPTED and p.fence == () and p.fence_version == 2
    assert len(p.items) == 2
    p.busy_flying = False
    upload_fence(p, SQUARE)
    assert ack_type(p.on_clear_all(GCS, mp.MISSION_TYPE_ALL, 3.0)) == mp.ACCEPTED
    assert p.fence == () and p.items == ()


@pytest.mark.parametrize(
    ("items", "code", "why"),
    [
        ([vertex(0, 0, 0, n=2), vertex(1, 10, 0, n=2)], mp.ERROR, "at least 3 vertices"),  # PX4's answer
        ([circle(0, 0.0)], mp.INVALID_PARAM1, "radius must be a number > 0"),
        ([circle(0, -5.0)], mp.INVALID_PARAM1, "radius"),
        ([circle(0, math.nan)], mp.INVALID_PARAM1, "radius"),
        (
            [vertex(0, -10, -10), vertex(1, 10, 10), vertex(2, 10, -10), vertex(3, -10, 10)],
            mp.ERROR,
            "crosses itself",
        ),  # a bow tie
        ([vertex(0, -10, -10), vertex(1, 10, -10), vertex(2, 10, 10)], mp.ERROR, "has not 4 vertices"),
        ([*SQUARE[:3], vertex(3, -10, 10, command=mp.FENCE_POLYGON_EXCLUSION)], mp.ERROR, "has not 4 vertices"),
        ([item_fields(0, mission_type=FENCE)], mp.UNSUPPORTED, "not a geofence item"),  # a waypoint
        (
            [vertex(0, 0, 0, n=3), vertex(1, 10, 0, n=3), {**vertex(2, 0, 10, n=3), "frame": 2}],
            mp.UNSUPPORTED_FRAME,
            "not a global frame",
        ),
    ],
)
def test_a_malformed_geofence_is_refused_and_the_stored_one_kept(items, code, why):
    p = MissionProtocol()
    upload_fence(p, SQUARE)
    kept = p.fence
    out = p.on_count(GCS, len(items), FENCE, 1.0)
    for f in items:
        if kinds(out) != ["MISSION_REQUEST_INT"]:
            break
        out = p.on_item(GCS, f, 1.0)
    assert only(out, "MISSION_ACK").fields == {"type": code, "mission_type": FENCE}
    assert why in only(out, "STATUSTEXT").fields["text"]
    assert p.fence == kept and p.fence_version == 1 and not p.upload_in_progress


def test_a_geofence_beyond_its_limit_is_no_space():
    p = MissionProtocol()
    assert ack_type(p.on_count(GCS, mp.MAX_FENCE_ITEMS + 1, FENCE, 0.0)) == mp.NO_SPACE


RALLY = 2


def rally_point(seq: int, east: float, north: float, **kw) -> dict:
    lat, lon = LAT + north / 111_320.0, LON + east / (111_320.0 * math.cos(math.radians(LAT)))
    fields = {"param1": 0.0, "param2": 0.0, "x": round(lat * 1e7), "y": round(lon * 1e7), "z": 10.0, **kw}
    return item_fields(seq, command=mp.RALLY_POINT, frame=6, mission_type=RALLY, **fields)


def test_rally_points_are_uploaded_downloaded_and_cleared_and_checked_against_the_fence():
    said = []

    def outside(items):  # the shell's check: here, any point north of 50 m is outside
        far = [it.seq for it in items if it.lat > LAT + 50 / 111_320.0]
        said.append(len(items))
        return f"Rally point {far[0]} is outside the geofence" if far else ""

    p = MissionProtocol(rally_check=outside)
    out = upload_fence(p, [rally_point(0, 10, 10), rally_point(1, -20, 30)])  # the same steps, type 2
    assert out == [Out("MISSION_ACK", GCS, {"type": mp.ACCEPTED, "mission_type": RALLY})]
    assert len(p.rally) == 2 and p.rally_version == 1 and said == [2]
    assert p.on_request_list(GCS, RALLY, 1.0) == [Out("MISSION_COUNT", GCS, {"count": 2, "mission_type": RALLY})]
    (o,) = p.on_request(GCS, 1, RALLY, 1.0)
    assert (o.fields["command"], o.fields["z"], o.fields["mission_type"]) == (mp.RALLY_POINT, 10.0, RALLY)
    out = upload_fence(p, [rally_point(0, 0, 0), rally_point(1, 0, 80)])
    assert only(out, "MISSION_ACK").fields == {"type": mp.ERROR, "mission_type": RALLY}
    assert only(out, "STATUSTEXT").fields["text"] == "Rally point 1 is outside the geofence"
    assert len(p.rally) == 2 and p.rally_version == 1  # kept
    out = upload_fence(p, [rally_point(0, 0, 0, z=math.inf)])
    assert ack_type(out) == mp.INVALID_PARAM7
    assert ack_type(p.on_clear_all(GCS, RALLY, 2.0)) == mp.ACCEPTED and p.rally == () and p.rally_version == 2


# ---- download -----------------------------------------------------------------------------------------


def test_download_in_any_order_and_several_at_once():
    p = MissionProtocol()
    upload(p, 4)
    out = p.on_request_list(GCS, 0, 1.0)
    assert out == [Out("MISSION_COUNT", GCS, {"count": 4, "mission_type": 0})]
    got = {}
    for seq in (2, 0, 3, 1, 1):  # any order, one twice
        (o,) = p.on_request(GCS, seq, 0, 1.1)
        assert o.kind == "MISSION_ITEM_INT" and o.target == GCS
        got[seq] = o.fields
    assert [got[s]["current"] for s in range(4)] == [1, 0, 0, 0]
    assert all(f["autocontinue"] == 1 and f["frame"] == 6 and f["command"] == 16 for f in got.values())
    assert got[3]["x"] == round((LAT + 3e-4) * 1e7) and got[3]["z"] == 10.0 and math.isnan(got[3]["param4"])
    assert p.on_ack(GCS, mp.ACCEPTED, 0, 1.2) == []
    assert p.on_request(GCS, 0, 0, 1.3) == []  # ended: requests are ignored


def test_download_current_flag_follows_the_current_item():
    p = MissionProtocol()
    upload(p, 3)
    p.set_current(2)
    p.on_request_list(GCS, 0, 1.0)
    assert [p.on_request(GCS, s, 0, 1.0)[0].fields["current"] for s in range(3)] == [0, 0, 1]


def test_download_seq_beyond_the_count_is_invalid_sequence_and_ends_it():
    p = MissionProtocol()
    upload(p, 2)
    p.on_request_list(GCS, 0, 1.0)
    assert ack_type(p.on_request(GCS, 2, 0, 1.1)) == mp.INVALID_SEQUENCE
    assert p.on_request(GCS, 0, 0, 1.2) == []


def test_download_of_an_empty_mission_and_requests_outside_a_download():
    p = MissionProtocol()
    assert p.on_request(GCS, 0, 0, 0.0) == []
    assert p.on_request_list(GCS, 0, 0.0)[0].fields["count"] == 0
    assert ack_type(p.on_request(GCS, 0, 0, 0.1)) == mp.INVALID_SEQUENCE


def test_legacy_download_gives_mission_item_in_float_degrees_and_legacy_frames():
    p = MissionProtocol()
    upload(p, 2)
    p.on_request_list(GCS, 0, 1.0)
    (o,) = p.on_request(GCS, 1, 0, 1.1, legacy=True)
    assert o.kind == "MISSION_ITEM" and o.fields["frame"] == 3
    assert o.fields["x"] == pytest.approx(LAT + 1e-4, abs=1e-9) and o.fields["y"] == pytest.approx(LON + 1e-4)


def test_a_download_is_not_confused_by_another_clients_upload():
    p = MissionProtocol()
    upload(p, 3)
    p.on_request_list(OTHER, 0, 1.0)
    first = p.on_request(OTHER, 0, 0, 1.0)[0].fields
    upload(p, 2, t=1.1, z=40.0)  # GCS replaces the mission while OTHER downloads
    assert len(p.items) == 2 and p.items[0].z == 40.0
    rest = [p.on_request(OTHER, s, 0, 1.2)[0].fields for s in (1, 2)]
    assert [f["z"] for f in [first, *rest]] == [10.0, 10.0, 10.0]  # the mission it was told the count of
    assert p.on_request_list(OTHER, 0, 1.3)[0].fields["count"] == 2


def test_downloads_time_out_and_are_bounded():
    p = MissionProtocol()
    upload(p, 1)
    p.on_request_list(GCS, 0, 0.0)
    p.tick(5.1)
    assert p.on_request(GCS, 0, 0, 5.2) == []
    for i in range(mp.MAX_DOWNLOADS + 3):
        p.on_request_list((i + 1, 1), 0, 6.0 + i)
    assert len(p._downloads) == mp.MAX_DOWNLOADS
    assert p.on_request((1, 1), 0, 0, 20.0) == []  # the least recently active was dropped
    assert kinds(p.on_request((mp.MAX_DOWNLOADS + 3, 1), 0, 0, 20.0)) == ["MISSION_ITEM_INT"]


# ---- clear and current --------------------------------------------------------------------------------


@pytest.mark.parametrize("mission_type", [0, 255])
def test_clear_all(mission_type):
    p = MissionProtocol()
    upload(p, 2)
    out = p.on_clear_all(GCS, mission_type, 1.0)
    assert only(out, "MISSION_ACK").fields == {"type": mp.ACCEPTED, "mission_type": mission_type}
    assert p.items == () and p.current == 0 and p.mission_state == mp.STATE_NO_MISSION
    assert p.on_request_list(GCS, 0, 1.1)[0].fields["count"] == 0


def test_set_current_in_and_out_of_range():
    p = MissionProtocol()
    assert kinds(p.on_set_current(GCS, 0, 0.0)) == ["STATUSTEXT"]  # no mission
    upload(p, 3)
    out = p.on_set_current(GCS, 2, 1.0)
    assert out == [Out("MISSION_CURRENT", None, {"seq": 2, "total": 3, "mission_state": 2, "mission_mode": 0})]
    assert kinds(p.on_set_current(GCS, 3, 1.1)) == ["STATUSTEXT"] and p.current == 2


def test_do_set_mission_current():
    p = MissionProtocol()
    assert p.do_set_mission_current(0) == (mp.RESULT_FAILED, [])
    upload(p, 3)
    result, out = p.do_set_mission_current(1)
    assert result == mp.RESULT_ACCEPTED and only(out, "MISSION_CURRENT").fields["seq"] == 1
    assert p.do_set_mission_current(1)[0] == mp.RESULT_ACCEPTED  # sent even when unchanged
    assert p.do_set_mission_current(3) == (mp.RESULT_FAILED, []) and p.current == 1
    p.mission_state = mp.STATE_COMPLETE
    result, out = p.do_set_mission_current(-1, reset=True)
    assert result == mp.RESULT_ACCEPTED and p.current == 1 and p.mission_state == mp.STATE_PAUSED


def test_addressed_to():
    assert mp.addressed_to(1, 1, 1, 1) and mp.addressed_to(1, 0, 1, 1) and mp.addressed_to(1, 190, 1, 1)
    assert not mp.addressed_to(2, 1, 1, 1) and not mp.addressed_to(1, 2, 1, 1)


# ---- items and pymavlink ------------------------------------------------------------------------------


def test_mission_item_converts_to_and_from_both_item_messages():
    it = mp.parse_item(item_fields(4, current=1, param1=2.5, param4=45.0))
    assert it == MissionItem(
        4, 6, 16, 1, 1, 2.5, 1.0, 0.0, 45.0, round((LAT + 4e-4) * 1e7), round((LON + 4e-4) * 1e7), 10.0
    )
    assert mp.parse_item(it.message_fields()) == it
    legacy = it.message_fields(legacy=True)
    assert legacy["frame"] == 3 and isinstance(legacy["x"], float)
    assert mp.parse_item(legacy, legacy=True) == MissionItem(**{**it.__dict__, "frame": 3})
    assert it.lat == pytest.approx(LAT + 4e-4) and it.lon == pytest.approx(LON + 4e-4)


def _round_trip(out: Out):
    """Encode ``out`` with pymavlink's own message class and decode it again."""
    cls = getattr(mavlink, f"MAVLink_{out.kind.lower()}_message")
    kw = out.kwargs()
    if out.kind == "STATUSTEXT":
        kw = {**kw, "text": kw["text"].encode(), "id": 0, "chunk_seq": 0}
    assert set(kw) == set(cls.fieldnames), (out.kind, set(kw) ^ set(cls.fieldnames))
    mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    buf = cls(**kw).pack(mav)
    msg = mavlink.MAVLink(None).decode(bytearray(buf))
    assert msg.get_type() == out.kind
    return msg, kw


def test_every_message_it_sends_encodes_with_pymavlink():
    p = MissionProtocol()
    outs: list[Out] = []
    outs += p.on_count(GCS, 2, 0, 0.0)
    outs += p.on_item(GCS, item_fields(0, current=1), 0.1)
    outs += p.on_item(GCS, item_fields(1), 0.2)
    outs += p.on_request_list(GCS, 0, 0.3)
    outs += p.on_request(GCS, 0, 0, 0.4)
    outs += p.on_request(GCS, 1, 0, 0.4, legacy=True)
    outs += p.on_set_current(GCS, 9, 0.5)
    p.on_count(GCS, 1, 0, 1.0)
    outs += p.on_ack(GCS, mp.UNSUPPORTED, 0, 1.1)
    outs += p.tick(10.0)
    assert set(kinds(outs)) == {
        "MISSION_REQUEST_INT",
        "MISSION_REQUEST",
        "MISSION_ACK",
        "MISSION_CURRENT",
        "MISSION_COUNT",
        "MISSION_ITEM_INT",
        "MISSION_ITEM",
        "STATUSTEXT",
    }
    for out in outs:
        msg, kw = _round_trip(out)
        for name, value in kw.items():
            got = getattr(msg, name)
            if name == "text":
                assert got == value.decode()
            elif isinstance(value, float) and math.isnan(value):
                assert math.isnan(got)
            elif isinstance(value, float):
                assert got == pytest.approx(value, rel=1e-6), (out.kind, name)
            else:
                assert got == value, (out.kind, name)
