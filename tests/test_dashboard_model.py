"""The dashboard's pure model: decimation, the join across streams, runs that restart, rates, and input
that must not hurt it (malformed payloads, strangers' keys, too many vehicles)."""

import json
import math

import pytest

from groundstation.dashboard.model import MAX_PENDING, MAX_VEHICLES, ROW_FIELDS, Fleet, plot_row
from quadsitl import telemetry

T = 0.001


def records(stream: str, ticks, **values) -> bytes:
    """A schema-v4 sample of consecutive ticks; fields not given are tick-dependent so they can be checked (the
    status record's are 0)."""
    fmt, fields = telemetry.STREAMS[stream], telemetry.FIELDS[stream]
    out = []
    for k in ticks:
        rec = [k, k * T]
        for f in fields[2:]:
            rec.append(values.get(f, 0 if stream == "status" else k * 1e-3))
        out.append(fmt.pack(*rec))
    return b"".join(out)


def feed(fleet: Fleet, ticks, wall: float, vehicle: str = "v1", **status) -> None:
    st = {"armed": 1, "mode": 1, "failsafe": 0, "offboard_tick": 0, **status}
    for stream in ("state", "setpoint", "actuators"):
        fleet.ingest(f"quadsitl/{vehicle}/{stream}", records(stream, ticks), wall)
    fleet.ingest(f"quadsitl/{vehicle}/status", records("status", ticks, **st), wall)


def test_rows_are_every_nth_tick_joined_across_streams_in_display_units():
    fleet = Fleet(plot_rate=50.0, window=20.0)  # T = 1 ms → one row every 20 ticks
    for first in range(1, 1001, 7):  # samples of 7 ticks, not aligned with the decimation
        feed(fleet, range(first, first + 7), wall=first * T)
    v = fleet.vehicles["v1"]
    assert v.decimation == 20 and v.period == pytest.approx(T)
    rows = v.rows_since(0)
    ticks = [round(r[0] / T) for r in rows]
    assert ticks == list(range(20, 1001, 20))  # every multiple, none twice, none from a partial join
    r = dict(zip(ROW_FIELDS, rows[-1]))
    k = 1000
    assert r["altitude"] == pytest.approx(-k * 1e-3)  # −z
    assert r["roll"] == pytest.approx(math.degrees(k * 1e-3))
    assert r["e_altitude"] == pytest.approx(r["altitude_ref"] - r["altitude"])
    assert r["u1"] == pytest.approx(k * 1e-3) and r["f4"] == pytest.approx(k * 1e-3)
    # the x–y map's columns: metres in local NED, not converted
    assert (r["x"], r["y"], r["x_ref"], r["y_ref"]) == pytest.approx((k * 1e-3,) * 4)
    # a page that saw up to row 40 gets only the newer ones
    seq_40 = v.rows[39][0]
    assert [round(x[0] / T) for x in v.rows_since(seq_40)] == list(range(820, 1001, 20))
    assert v.rows_since(v.seq) == []


def test_the_window_keeps_only_the_last_seconds_of_simulated_time():
    fleet = Fleet(plot_rate=10.0, window=1.0)
    for first in range(1, 5001, 50):
        feed(fleet, range(first, first + 50), wall=first * T)
    ts = [r[0] for r in fleet.vehicles["v1"].rows_since(0)]
    assert ts[-1] == pytest.approx(5.0) and ts[0] >= 4.0 - 1e-9 and len(ts) == 11


def test_a_run_that_restarts_under_the_same_name_starts_a_new_generation():
    fleet = Fleet()
    feed(fleet, range(1, 2001), wall=1.0)
    v = fleet.vehicles["v1"]
    assert v.generation == 0 and len(v.rows) == 100
    feed(fleet, range(1, 101), wall=2.0)  # ticks back to the start: a new fly, a looping replay
    assert v.generation == 1
    assert [round(r[0] / T) for r in v.rows_since(0)] == list(range(20, 101, 20))


def test_tick_rate_and_real_time_factor_follow_the_wall_clock():
    fleet = Fleet()
    wall = 0.0
    for first in range(1, 30001, 100):  # 100 ticks every 10 ms of wall time: 10,000 ticks/s, 10×
        feed(fleet, range(first, first + 100), wall=wall)
        wall += 0.01
    s = fleet.summaries(wall - 0.01)[0]
    assert s["tick_rate"] == pytest.approx(10000, rel=0.01)
    assert s["real_time_factor"] == pytest.approx(10.0, rel=0.01)
    assert s["link"]["telemetry"] == "live"
    stale = fleet.summaries(wall + 5.0)[0]
    assert stale["link"]["telemetry"] == "stale" and stale["tick_rate"] == 0.0


def test_rates_use_the_publication_time_so_a_backlog_taken_at_once_is_no_burst():
    """A dashboard starved of CPU takes 1.5 s of samples in one drain, every one received at the same moment, then
    drains every 0.25 s again. The rates follow when the samples were sent (the Zenoh timestamp), so after every
    drain they read the vehicle's pace, 2× real time; by the receiving times the backlog's old simulated times sat
    at the start of the window, and the same samples read 3.9-13.6× (CI's starved dashboard showed 3.7)."""
    stamped, unstamped = Fleet(), Fleet()
    drains: dict[float, list] = {}
    for i, first in enumerate(range(1, 6001, 100)):  # 100 ticks (0.1 s simulated) published every 50 ms: 2×
        sent = i * 0.05
        received = 1.5 if sent < 1.5 else math.ceil(sent / 0.25 + 1e-9) * 0.25
        drains.setdefault(received, []).append((records("status", range(first, first + 100)), sent))
    seen: list[tuple] = []
    for received, samples in sorted(drains.items()):
        for status, sent in samples:
            stamped.ingest("quadsitl/v1/status", status, received, 1000.0 + sent)
            unstamped.ingest("quadsitl/v1/status", status, received)
        seen.append((stamped.vehicles["v1"].rates(), unstamped.vehicles["v1"].rates()))
    for (rate, rtf), _ in seen:
        assert rtf == pytest.approx(2.0, rel=1e-9) and rate == pytest.approx(2000, rel=1e-9)
    assert max(rtf or 0.0 for _, (_, rtf) in seen) > 3.0  # what the receiving times alone make of them
    # a publisher that stops stamping (a session of the user's own configuration): the window starts again on this
    # process's clock, never a difference between the two clocks
    stamped.ingest("quadsitl/v1/status", records("status", range(6001, 6101)), 7.0)
    assert stamped.vehicles["v1"].rates() == (None, None)


def test_status_names_mode_and_failsafe():
    fleet = Fleet()
    feed(fleet, range(1, 10), wall=0.0, armed=0, mode=2, failsafe=8, offboard_tick=-1, battery_v=15.2,
         battery_a=17.5, battery_mah=900.0, battery_j=5e4, battery_remaining=0.06)  # fmt: skip
    st = fleet.summaries(0.0)[0]["status"]
    assert st == {"tick": 9, "t": pytest.approx(0.009), "armed": False, "mode": "land", "failsafe": "battery",
                  "offboard_tick": -1, "battery_v": 15.2, "battery_a": 17.5, "battery_mah": 900.0,
                  "battery_j": 5e4, "battery_remaining": 0.06}  # fmt: skip
    nan = float("nan")
    feed(fleet, range(10, 12), wall=0.0, battery_v=nan, battery_a=nan, battery_mah=nan, battery_j=nan,
         battery_remaining=nan)  # fmt: skip
    st = fleet.summaries(0.0)[0]["status"]  # no battery (an ideal supply): null in JSON, never NaN
    assert [st[f] for f in telemetry.BATTERY_FIELDS] == [None] * 5


@pytest.mark.parametrize(("number", "name"), [(0, "hold"), (1, "offboard"), (2, "land"), (3, "takeoff"), (4, "rtl"),
                                              (5, "mission"), (6, "posctl"), (7, "altctl"), (8, "stabilized"),
                                              (9, "orbit"), (10, "follow"), (11, "unknown (11)")])  # fmt: skip
def test_every_mode_number_of_the_status_stream_has_its_name(number, name):
    fleet = Fleet()
    feed(fleet, range(1, 3), wall=0.0, mode=number)
    assert fleet.summaries(0.0)[0]["status"]["mode"] == name


def test_an_uncontrolled_horizontal_position_reaches_the_page_as_nan():
    """x_ref, y_ref NaN (attitude setpoints): rows carry NaN (null in JSON, no setpoint on the map)."""
    fleet = Fleet(plot_rate=50.0)
    for stream in ("state", "actuators"):
        fleet.ingest(f"quadsitl/v1/{stream}", records(stream, range(1, 41)), 0.0)
    fleet.ingest("quadsitl/v1/setpoint", records("setpoint", range(1, 41), x_ref=math.nan, y_ref=math.nan), 0.0)
    fleet.ingest("quadsitl/v1/status", records("status", range(1, 41), armed=1, mode=1), 0.0)
    (row,) = fleet.vehicles["v1"].rows_since(0)[-1:]
    r = dict(zip(ROW_FIELDS, row))
    assert math.isnan(r["x_ref"]) and math.isnan(r["y_ref"]) and r["x"] == pytest.approx(0.040)


def test_bad_input_is_counted_and_ignored():
    fleet = Fleet()
    feed(fleet, range(1, 101), wall=0.0)
    v = fleet.vehicles["v1"]
    rows = len(v.rows)
    fleet.ingest("quadsitl/v1/state", b"\x00" * 13, 0.1)  # not a whole record
    fleet.ingest("quadsitl/v1/state", b"", 0.1)
    no_time = telemetry.STREAMS["state"].pack(101, float("nan"), *([0.0] * 12))
    fleet.ingest("quadsitl/v1/state", no_time, 0.1)
    assert v.malformed == 3 and len(v.rows) == rows
    # NaN fields are "not known" (a replayed tlog has no u1..u4): kept, and shown as gaps (null in JSON)
    unknown = telemetry.STREAMS["actuators"].pack(120, 0.120, *([float("nan")] * 8))
    fleet.ingest("quadsitl/v1/actuators", unknown, 0.1)
    assert v.malformed == 3 and math.isnan(fleet.summaries(0.1)[0]["actuators"]["u1"])
    fleet.ingest("quadsitl/v1/telemetry", b"x" * 8, 0.1)  # unknown stream
    fleet.ingest("someone/else/state", b"x" * 8, 0.1)
    fleet.ingest("quadsitl/v1/state/extra", b"x" * 8, 0.1)
    assert fleet.ignored == 3
    for i in range(MAX_VEHICLES + 10):
        feed(fleet, range(1, 3), wall=0.2, vehicle=f"x{i}")
    assert len(fleet.vehicles) == MAX_VEHICLES and fleet.ignored == 3 + 4 * 11


def test_a_stream_that_never_completes_a_tick_does_not_grow_memory():
    fleet = Fleet()
    fleet.ingest("quadsitl/v1/state", records("state", range(1, 100001)), 0.0)
    v = fleet.vehicles["v1"]
    assert len(v._pending) <= MAX_PENDING + 1 and len(v.rows) == 0


def test_yaw_error_wraps_across_pi():
    state = (1, T, 0, 0, 0, 0, 0, 0, 0, 0, math.radians(179), 0, 0, 0)
    setpoint = (1, T, 0, 0, 0, math.radians(-179), math.nan, math.nan)
    row = dict(zip(ROW_FIELDS, plot_row(state, setpoint, (1, T, 0, 0, 0, 0, 0, 0, 0, 0))))
    assert row["e_yaw"] == pytest.approx(2.0)


def test_the_mission_document_is_kept_for_the_map_and_a_bad_one_is_counted_and_ignored():
    fleet = Fleet()
    items = [{"seq": 0, "command": 22, "x": None, "y": None, "altitude": 5.0},
             {"seq": 1, "command": 16, "x": 12.0, "y": -4.0, "altitude": 5.0}]  # fmt: skip
    fleet.ingest("quadsitl/v1/mission", telemetry.encode_mission(2, 1, 3, items), 0.0)  # before any telemetry
    feed(fleet, range(1, 41), wall=0.0)
    (s,) = fleet.summaries(0.0)
    assert s["mission"]["current"] == 1 and s["mission"]["state_name"] == "active" and s["mission"]["total"] == 2
    assert s["mission"]["items"][1] == {"seq": 1, "command": 16, "x": 12.0, "y": -4.0, "altitude": 5.0}
    assert len(fleet.vehicles["v1"].rows) == 2  # the plan is not a plot row
    good = fleet.vehicles["v1"].mission
    bad = [b"{", b"[]", b'{"version": 1}', telemetry.encode_mission(2, 5, 3, items),  # current beyond the plan
           telemetry.encode_mission(2, 1, 9, items),  # no such MISSION_STATE
           telemetry.encode_mission(2, 1, 3, items).replace(b"12.0", b"1e99"),
           telemetry.encode_mission(2, 1, 3, items).replace(b'"total":2', b'"total":3'),
           b" " * (telemetry.MAX_MISSION_BYTES + 1), b"\xff\xfe"]  # fmt: skip
    for payload in bad:
        fleet.ingest("quadsitl/v1/mission", payload, 0.1)
    v = fleet.vehicles["v1"]
    assert v.malformed == len(bad) and v.mission == good
    fleet.ingest("quadsitl/v1/mission", telemetry.encode_mission(3, 0, 1, []), 0.2)  # cleared
    cleared = fleet.summaries(0.2)[0]["mission"]
    assert cleared["items"] == [] and cleared["state_name"] == "none" and cleared["fence"] == cleared["rally"] == []


def test_the_mission_document_carries_the_geofence_and_rally_points_and_refuses_bad_ones():
    fence = [{"kind": 1, "size": 3, "x": -20.0, "y": -20.0}, {"kind": 1, "size": 3, "x": 20.0, "y": 0.0},
             {"kind": 1, "size": 3, "x": -20.0, "y": 20.0}, {"kind": 4, "size": 5.5, "x": 1.0, "y": 2.0}]  # fmt: skip
    rally = [{"x": 40.0, "y": 10.0}]
    doc = telemetry.decode_mission(telemetry.encode_mission(1, 0, 2, [], (), fence, rally))
    assert doc["fence"] == fence and doc["rally"] == rally
    old = telemetry.encode_mission(1, 0, 2, []).replace(b',"fence":[],"rally":[]', b"")  # an older vehicle's
    assert b"fence" not in old and telemetry.decode_mission(old)["fence"] == []
    for bad in ([{**fence[0], "kind": 9}], [{**fence[0], "x": 1e99}], ["x"]):
        with pytest.raises(ValueError, match="mission: "):
            telemetry.decode_mission(telemetry.encode_mission(1, 0, 2, [], (), [], []).replace(
                b'"fence":[]', b'"fence":' + json.dumps(bad).encode()))  # fmt: skip


def slow(fleet: Fleet, tick: int, wall: float, vehicle: str = "v1", x: float | None = None) -> None:
    """The overview of tick ``tick``: each stream's record, in one sample on quadsitl/<vehicle>/slow/overview."""
    out = b""
    for stream in ("state", "setpoint", "actuators"):
        rec = records(stream, [tick])
        if stream == "state" and x is not None:
            rec = rec[:16] + telemetry.STREAMS["state"].pack(tick, tick * T, x, *[0.0] * 11)[16:]
        out += rec
    out += records("status", [tick], armed=1, mode=1, failsafe=0, offboard_tick=0)
    assert list(telemetry.split_overview(out)) == list(telemetry.STREAMS)
    fleet.ingest(f"quadsitl/{vehicle}/slow/overview", out, wall)


def test_the_overview_alone_keeps_a_vehicle_on_the_map_with_rows_trail_and_rates():
    """A vehicle followed only through its overview (20 records a second per stream, the dashboard's view of a
    fleet's vehicles nobody shows): its latest records, a plot row and a trail point per overview tick (at most
    TRAIL_RATE a simulated second), rates, and a new run still noticed."""
    from groundstation.dashboard.model import TRAIL_RATE

    fleet = Fleet()
    for i in range(1, 41):  # 2 s of wall, 50 ms apart, in real time
        slow(fleet, 50 * i, 0.05 * i, x=0.1 * i)
    v = fleet.vehicles["v1"]
    assert v.latest["state"][0] == 2000 and v.latest["status"][3] == 1 and v.malformed == 0
    assert v.samples == 40  # Zenoh's samples: one an overview
    assert [r[1][0] for r in v.rows][:3] == pytest.approx([0.05, 0.1, 0.15])  # a row per overview tick
    assert len(v.rows) == 40
    trail = v.trail_since(0)
    assert len(trail) == round(2.0 * TRAIL_RATE) and trail[-1] == pytest.approx((1.85, 3.7, 0.0))  # t, x, y
    rate, rtf = v.rates()
    assert rate == pytest.approx(1000.0) and rtf == pytest.approx(1.0)
    gen = v.generation
    slow(fleet, 10, 2.1)  # ticks went back: a new run under the same name
    assert v.generation == gen + 1 and len(v.rows) == 1
    # an overview sample of any other length is not one (here, two states), nor a stream's own key under slow/
    fleet.ingest("quadsitl/v1/slow/overview", records("state", [60, 61]), 2.2)
    assert v.malformed == 1 and v.latest["state"][0] == 10
    ignored = fleet.ignored
    fleet.ingest("quadsitl/v1/slow/state", records("state", [60]), 2.2)
    assert fleet.ignored == ignored + 1 and v.latest["state"][0] == 10


def test_the_overview_is_ignored_while_the_full_rate_comes_and_taken_again_when_it_stops():
    fleet = Fleet()
    feed(fleet, range(0, 100), 1.0)
    v = fleet.vehicles["v1"]
    rows, samples = len(v.rows), v.samples
    slow(fleet, 99, 1.5)  # the same vehicle's overview, while its full rate comes: a duplicate, dropped
    assert (len(v.rows), v.samples) == (rows, samples)
    feed(fleet, range(100, 200), 1.6)  # the full rate goes on: no new run, its rows as before
    assert v.generation == 0 and len(v.rows) == 2 * rows
    slow(fleet, 3000, 1.6 + 1.01)  # a second without the full rate (the page stopped showing it): the overview
    assert v.latest["state"][0] == 3000 and len(v.rows) == 2 * rows + 1 and v.generation == 0
