"""The dashboard's fleet view, without a browser: who each vehicle is and where its home is
(``quadsitl/<vehicle>/info``, groundstation.vehicle_info), homes turned into one frame's offsets, trails decimated
and kept to the window, 20+ vehicles, a vehicle whose home is unknown or whose info is hostile, and the server's
update: only the pose and new trail points of every vehicle, plot rows only for the one shown."""

from __future__ import annotations

import json
import math
import random
import socket
import time

import pytest

from groundstation.dashboard.model import MAX_VEHICLES, TRAIL_RATE, Fleet, natural
from groundstation.dashboard.server import Dashboard, _json_safe
from groundstation.fleet import plan_fleet
from groundstation.vehicle_info import MAX_INFO_BYTES, InfoPublisher, decode_info, encode_info, info_key
from quadsitl import telemetry
from quadsitl.frames import ned_to_geodetic
from tests.test_dashboard_model import T, records

HOME = (47.397742, 8.545594, 488.0)


def fly(fleet: Fleet, name: str, ticks, wall: float, x=0.0, y=0.0, yaw=0.0) -> None:
    """A sample of every stream of ``ticks`` for ``name``: at local (x, y), 2 m up, heading ``yaw`` [rad]."""
    st = telemetry.STREAMS["state"]
    state = b"".join(st.pack(k, k * T, x, y, -2.0, 0, 0, 0, 0, 0, yaw, 0, 0, 0) for k in ticks)
    fleet.ingest(f"quadsitl/{name}/state", state, wall)
    fleet.ingest(f"quadsitl/{name}/setpoint", records("setpoint", ticks), wall)
    fleet.ingest(f"quadsitl/{name}/actuators", records("actuators", ticks), wall)
    fleet.ingest(f"quadsitl/{name}/status", records("status", ticks, armed=1, mode=3, failsafe=0, offboard_tick=-1),
                 wall)  # fmt: skip


def test_the_info_document_round_trips_and_hostile_ones_are_refused_with_their_reason():
    doc = decode_info(encode_info(7, HOME, "x500", 12))
    assert doc == {"system_id": 7, "home": HOME, "preset": "x500", "vehicles": 12}
    assert decode_info(b'{"system_id": 3, "home": {"latitude": 1, "longitude": 2, "altitude": 3}}')["vehicles"] == 1
    good = json.loads(encode_info(7, HOME))
    bad = {
        b"{": "not JSON",
        b"\xff\xfe": "not JSON",
        b"[1, 2]": "expected an object, got list",
        b" " * (MAX_INFO_BYTES + 1): f"at most {MAX_INFO_BYTES}",
        json.dumps({**good, "system_id": 0}).encode(): "system_id = 0, expected an integer in 1..255",
        json.dumps({**good, "system_id": 256}).encode(): "system_id = 256",
        json.dumps({**good, "system_id": True}).encode(): "system_id = True",
        json.dumps({**good, "system_id": "2"}).encode(): "system_id = '2'",
        json.dumps({**good, "home": [47, 8, 400]}).encode(): "home = [47, 8, 400], expected an object",
        json.dumps({**good, "home": {**good["home"], "latitude": 91}}).encode(): "home latitude = 91",
        json.dumps({**good, "home": {**good["home"], "longitude": None}}).encode(): "home longitude = None",
        json.dumps({**good, "home": {**good["home"], "altitude": 1e9}}).encode(): "home altitude = 1000000000.0",
        b'{"system_id": 1, "home": {"latitude": NaN, "longitude": 8, "altitude": 0}}': "home latitude = nan",
        json.dumps({**good, "preset": ["x"]}).encode(): "preset = ['x']",
        json.dumps({**good, "vehicles": 65}).encode(): "vehicles = 65",
    }
    for payload, reason in bad.items():
        with pytest.raises(ValueError) as err:
            decode_info(payload)
        assert str(err.value).startswith("info: ") and reason in str(err.value), (payload[:40], str(err.value))


def test_twenty_five_vehicles_on_one_map_homes_become_offsets_from_the_first():
    """25 vehicles on `up`'s grid (4 m apart, 5 columns), their info and telemetry arriving in any order: the
    origin is v1's home, every vehicle's offset is its grid place (geodetic → north, east by quadsitl.frames), the
    table is in natural order with each one's system id, and each pose is local x, y plus its offset."""
    plan = plan_fleet(25, preset="paper", home=HOME, spacing=4.0, first_system_id=11)
    fleet = Fleet()
    order = list(plan)
    random.Random(3).shuffle(order)
    for v in order:
        fly(fleet, v.name, range(1, 101), 0.0, x=0.5 * v.index, y=-1.0, yaw=math.radians(10 * v.index))
        fleet.ingest(info_key(v.name), encode_info(v.system_id, v.home, "paper", 25), 0.0)
    view = fleet.fleet_view(0.0)
    assert view["origin"] == {"name": "v1", "latitude": HOME[0], "longitude": HOME[1], "altitude": HOME[2]}
    entries = view["vehicles"]
    assert [e["name"] for e in entries] == [f"v{i}" for i in range(1, 26)]  # v2 before v10
    for e, v in zip(entries, plan):
        assert e["system_id"] == v.system_id and e["fleet_size"] == 25 and e["home_note"] is None
        assert e["offset"] == [pytest.approx(v.offset[0], abs=1e-3), pytest.approx(v.offset[1], abs=1e-3), 0.0]
        assert e["pose"] == [pytest.approx(0.5 * v.index), -1.0, 2.0, pytest.approx(10 * v.index)]
        assert e["armed"] is True and e["mode"] == "takeoff" and e["failsafe"] == "none" and e["link"] == "live"
    assert entries[24]["offset"][:2] == [pytest.approx(16.0, abs=1e-3), pytest.approx(16.0, abs=1e-3)]
    # /api/vehicles carries the same: system id, home, offset
    s = {x["name"]: x for x in fleet.summaries(0.0)}
    assert s["v7"]["system_id"] == 17 and s["v7"]["home"]["latitude"] == pytest.approx(plan[6].home[0])
    assert s["v7"]["offset"][:2] == [pytest.approx(4.0, abs=1e-3), pytest.approx(4.0, abs=1e-3)]


def test_a_vehicle_without_a_home_is_drawn_from_the_origin_and_says_why():
    fleet = Fleet()
    fly(fleet, "v1", range(1, 41), 0.0)
    fly(fleet, "v2", range(1, 41), 0.0)
    fly(fleet, "v3", range(1, 41), 0.0)
    assert fleet.fleet_view(0.0)["origin"] is None  # no home known at all: every vehicle from its own home
    lat, lon = ned_to_geodetic(-6.0, 9.0, HOME[0], HOME[1])
    fleet.ingest("quadsitl/v3/info", encode_info(3, (lat, lon, HOME[2] + 2.0)), 0.0)
    fleet.ingest("quadsitl/v2/info", encode_info(2, HOME), 0.0)
    v1, v2, v3 = fleet.fleet_view(0.0)["vehicles"]
    # v1 has none: the origin is the next one in order that has one (v2), v1 has no offset and says so
    assert fleet.fleet_view(0.0)["origin"]["name"] == "v2"
    assert v1["offset"] is None and v1["system_id"] is None
    assert v1["home_note"] == "home unknown: nothing on quadsitl/v1/info yet"
    assert v2["offset"] == [0.0, 0.0, 0.0]
    assert v3["offset"] == [pytest.approx(-6.0, abs=1e-3), pytest.approx(9.0, abs=1e-3), 2.0]
    # a hostile document for v1: refused, its reason kept for the page, counted; v3's bad one keeps the good one
    fleet.ingest("quadsitl/v1/info", b'{"system_id": 999}', 0.1)
    fleet.ingest("quadsitl/v3/info", b"\x00" * 100, 0.1)
    v1, _, v3 = fleet.fleet_view(0.1)["vehicles"]
    assert v1["home_note"] == "home unknown: info: system_id = 999, expected an integer in 1..255"
    assert fleet.vehicles["v1"].malformed == 1 and fleet.vehicles["v1"].info_refused == 1
    assert v3["system_id"] == 3 and v3["offset"][0] == pytest.approx(-6.0, abs=1e-3) and v3["home_note"] is None
    assert fleet.summaries(0.1)[2]["info_error"].startswith("info: not JSON")
    # the next good document clears the refusal
    fleet.ingest("quadsitl/v1/info", encode_info(1, (*ned_to_geodetic(3.0, 0.0, HOME[0], HOME[1]), HOME[2])), 0.2)
    v1 = fleet.fleet_view(0.2)["vehicles"][0]
    assert v1["home_note"] is None and fleet.fleet_view(0.2)["origin"]["name"] == "v1"
    assert v1["offset"] == [0.0, 0.0, 0.0]


def test_the_trail_is_decimated_kept_to_the_window_and_cleared_by_a_new_run():
    fleet = Fleet(plot_rate=50.0, window=4.0)
    for first in range(1, 10001, 7):  # 10 s in samples of 7 ticks, not aligned with the trail's step
        ticks = range(first, first + 7)
        st = telemetry.STREAMS["state"]
        fleet.ingest("quadsitl/v1/state", b"".join(st.pack(k, k * T, k * 1e-3, -k * 1e-3, *[0.0] * 10)
                                                   for k in ticks), first * T)  # fmt: skip
        fleet.ingest("quadsitl/v1/status", records("status", ticks), first * T)
    v = fleet.vehicles["v1"]
    step = round(1 / (TRAIL_RATE * T))  # 200 ticks
    pts = v.trail_since(0)
    # the last sample ends at tick 10003: the window keeps t ≥ 6.003 s, every 200th tick of it
    assert step == 200 and [round(t / T) for t, _, _ in pts] == list(range(6200, 10001, step))
    assert all(x == pytest.approx(t) and y == pytest.approx(-t) for t, x, y in pts)  # local x, y at that tick
    seq = v.trail_seq
    fleet.ingest("quadsitl/v1/state", telemetry.STREAMS["state"].pack(10200, 10.2, 1, 2, *[0.0] * 10), 10.2)
    assert v.trail_since(seq) == [(pytest.approx(10.2), 1.0, 2.0)] and v.trail_since(v.trail_seq) == []
    fly(fleet, "v1", range(1, 3), 11.0)  # ticks back to the start: a new run, the old trail goes
    assert v.generation == 1 and v.trail_since(0) == []


def updates_of(dash: Dashboard, cursors: dict, selected: str | None = None) -> tuple[dict, int]:
    msg = dash.update(cursors, selected)
    return msg, len(json.dumps(_json_safe(msg), separators=(",", ":")))


def test_the_stream_sends_every_vehicle_a_pose_and_new_trail_points_and_rows_only_for_the_one_shown():
    """20 vehicles, 20 s each: the fleet view's first update carries each vehicle's whole trail (100 points), the
    next ones only what is new; the plot rows go out only for the selected vehicle. Sizes are the JSON the page
    gets."""
    plan = plan_fleet(20, preset="paper", home=HOME)
    dash = Dashboard.__new__(Dashboard)  # the update builder alone: no Zenoh session
    dash.fleet = Fleet()
    for first in range(1, 20001, 500):
        for v in plan:
            fly(dash.fleet, v.name, range(first, first + 500), first * T, x=first * 1e-4)
    for v in plan:
        dash.fleet.ingest(info_key(v.name), encode_info(v.system_id, v.home, "paper", 20), 20.0)
    cursors: dict = {}
    first, size_first = updates_of(dash, cursors)
    assert first["vehicle"] is None  # the fleet view: no plot rows at all
    entries = first["fleet"]["vehicles"]
    assert len(entries) == 20 and all(e["trail"]["reset"] for e in entries)
    assert {len(e["trail"]["t"]) for e in entries} == {100}  # 20 s at TRAIL_RATE
    assert size_first < 80_000  # ≈ 3.5 KB a vehicle with its whole trail
    for v in plan:
        fly(dash.fleet, v.name, range(20001, 20251), 20.25)  # a quarter of a second of flight
    nxt, size_next = updates_of(dash, cursors)
    assert {len(e["trail"]["t"]) for e in nxt["fleet"]["vehicles"]} == {1}  # 20.2 s; 20.0 was sent before
    assert not any(e["trail"]["reset"] for e in nxt["fleet"]["vehicles"])
    assert size_next < 10_000  # ≈ 400 bytes a vehicle
    # one vehicle shown: its rows and full summary, the others still only a pose
    shown, _ = updates_of(dash, {}, "v3")
    assert shown["vehicle"]["name"] == "v3" and shown["vehicle"]["system_id"] == 3
    assert len(shown["vehicle"]["rows"]["t"]) == 250  # the window's 1000 rows, thinned to MAX_ROWS
    assert "rows" not in shown["fleet"]["vehicles"][0]
    assert updates_of(dash, {}, "nosuch")[0]["vehicle"] is None  # a name the fleet lacks: nothing, no error


def test_more_names_than_the_dashboard_follows_are_ignored_also_on_the_info_key():
    fleet = Fleet()
    for i in range(MAX_VEHICLES + 3):
        fleet.ingest(info_key(f"x{i}"), encode_info(1, HOME), 0.0)
    assert len(fleet.vehicles) == MAX_VEHICLES and fleet.ignored == 3
    assert sorted(["v10", "v2", "v1", "a", "v1b"], key=natural) == ["a", "v1", "v1b", "v2", "v10"]


@pytest.mark.timeout(30)
def test_the_launchers_info_publisher_puts_once_a_second_and_answers_a_get():
    """What ``quadsitl up`` runs: a late subscriber has every vehicle's document within a second, and a ``get``
    on quadsitl/*/info (the dashboard's, as it starts) has them at once."""
    import zenoh

    from groundstation.launcher import free_port

    endpoint = f"tcp/127.0.0.1:{free_port(socket.SOCK_STREAM)}"
    docs = {v.name: encode_info(v.system_id, v.home, "paper", 3) for v in plan_fleet(3, preset="paper")}
    pub = InfoPublisher(zenoh.open(telemetry.zenoh_config(listen=[endpoint])), docs)
    sub_session = zenoh.open(telemetry.zenoh_config(connect=[endpoint]))
    try:
        got: dict[str, bytes] = {}
        sub = sub_session.declare_subscriber(
            "quadsitl/*/*", lambda s: got.update({str(s.key_expr): s.payload.to_bytes()})
        )
        end = time.monotonic() + 10
        while len(got) < 3 and time.monotonic() < end:
            pub.tick(time.monotonic())
            time.sleep(0.05)
        assert got == {info_key(n): d for n, d in docs.items()}
        replies = {str(r.ok.key_expr): r.ok.payload.to_bytes() for r in sub_session.get("quadsitl/*/info", timeout=5)}
        assert replies == got
        assert [str(r.ok.key_expr) for r in sub_session.get("quadsitl/v2/info", timeout=5)] == ["quadsitl/v2/info"]
        sub.undeclare()
    finally:
        sub_session.close()
        pub.close()


@pytest.mark.timeout(60)
def test_only_a_vehicle_a_page_shows_is_followed_at_the_full_rate():
    """Real Zenoh sessions: the dashboard follows every vehicle through its overview, and matches a vehicle's
    full-rate publishers only while a page shows it (so the others' autopilots send nothing at the full rate)."""
    import zenoh

    from groundstation.launcher import free_port

    endpoint = f"tcp/127.0.0.1:{free_port(socket.SOCK_STREAM)}"
    pub_session = zenoh.open(telemetry.zenoh_config(listen=[endpoint]))
    dash_session = zenoh.open(telemetry.zenoh_config(connect=[endpoint]))
    try:
        full = {v: pub_session.declare_publisher(telemetry.key(v, "state")) for v in ("v1", "v2")}
        overview = {v: telemetry.Overview(pub_session, v) for v in ("v1", "v2")}
        dash = Dashboard(dash_session, Fleet())

        def matching(v: str, want: bool) -> bool:
            deadline = time.monotonic() + 5
            while full[v].matching_status.matching != want and time.monotonic() < deadline:
                time.sleep(0.02)
            return full[v].matching_status.matching == want

        deadline = time.monotonic() + 5
        while set(dash.fleet.vehicles) != {"v1", "v2"} and time.monotonic() < deadline:
            for i, o in enumerate(overview.values()):
                o.due = -math.inf
                o.offer(lambda s, i=i: records(s, [100 + i], **({"armed": 1, "mode": 0, "failsafe": 0,
                                                                  "offboard_tick": -1} if s == "status" else {})),
                        time.monotonic())  # fmt: skip
            time.sleep(0.05)
            dash.drain()
        assert set(dash.fleet.vehicles) == {"v1", "v2"}  # both on the map through their overviews
        assert dash.fleet.vehicles["v2"].latest["state"][0] == 101
        assert matching("v1", False) and matching("v2", False)  # no page: nobody takes the full rate
        assert dash.watch("v2") and dash.watch("v2")  # two pages show v2
        assert matching("v2", True) and matching("v1", False)
        dash.unwatch("v2")
        assert matching("v2", True)  # one page still shows it
        dash.unwatch("v2")
        assert matching("v2", False)
        for bad in ("", "*", "**", "a/b", "v$1", "v?", "v#"):
            assert not dash.watch(bad) and bad not in dash.watched
        assert matching("v1", False)
    finally:
        dash_session.close()
        pub_session.close()


def test_the_overview_ends_on_the_last_record_even_when_nothing_new_comes():
    """Real Zenoh sessions: an offer inside the overview's period is owed, and put once the period is over (a
    lockstep clock held once landed offers nothing new; the overview must still show the landing), or at once when
    forced (an autopilot that stops)."""
    import zenoh

    from groundstation.launcher import free_port

    endpoint = f"tcp/127.0.0.1:{free_port(socket.SOCK_STREAM)}"
    pub_session = zenoh.open(telemetry.zenoh_config(listen=[endpoint]))
    sub_session = zenoh.open(telemetry.zenoh_config(connect=[endpoint]))
    try:
        sub = sub_session.declare_subscriber(f"{telemetry.PREFIX}/*/{telemetry.SLOW}/*", zenoh.handlers.FifoChannel(64))
        overview = telemetry.Overview(pub_session, "v1")
        deadline = time.monotonic() + 10
        while not overview.pub.matching_status.matching:
            assert time.monotonic() < deadline, "the subscriber was not found"
            time.sleep(0.02)
        newest = {s: records(s, [1]) for s in ("setpoint", "actuators")}
        assert not overview.offer(newest.get, 999.0) and not overview.owed  # a stream without a record yet
        newest |= {"state": records("state", [1]), "status": records("status", [1], armed=1, mode=0, failsafe=0,
                                                                         offboard_tick=-1)}  # fmt: skip
        t = 1000.0  # wall seconds, as the autopilot passes them
        assert overview.offer(newest.get, t) and not overview.owed
        newest["state"] = records("state", [2])
        assert not overview.offer(newest.get, t + 0.01) and overview.owed  # inside the period: owed
        assert not overview.catch_up(newest.get, t + 0.02)  # still inside it
        assert overview.catch_up(newest.get, t + telemetry.SLOW_PERIOD + 0.001) and not overview.owed
        assert not overview.catch_up(newest.get, t + 1.0)  # nothing owed: nothing put
        newest["state"] = records("state", [3])
        assert not overview.offer(newest.get, t + telemetry.SLOW_PERIOD + 0.01)
        assert overview.offer(newest.get, t + telemetry.SLOW_PERIOD + 0.02, force=True)
        got, deadline = [], time.monotonic() + 5
        while len(got) < 3 and time.monotonic() < deadline:
            sample = sub.try_recv()
            if sample is None:
                time.sleep(0.01)
                continue
            assert str(sample.key_expr) == telemetry.overview_key("v1")
            got.append(telemetry.split_overview(sample.payload.to_bytes()))
        # One sample a put, every stream's newest record in it
        assert [g["state"] for g in got] == [records("state", [k]) for k in (1, 2, 3)]
        assert all(g["status"] == newest["status"] and g["setpoint"] == newest["setpoint"] for g in got)
    finally:
        sub_session.close()
        pub_session.close()
