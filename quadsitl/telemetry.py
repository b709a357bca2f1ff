"""Telemetry over Zenoh: the key schema, the encoding and the session configuration (DESIGN.md §5).

Keys (``<vehicle>`` defaults to ``v1``), one record per control tick on each:

    quadsitl/<vehicle>/state      tick, t, x, y, z, vx, vy, vz, roll, pitch, yaw, p, q, r
    quadsitl/<vehicle>/setpoint   tick, t, altitude_ref, roll_ref, pitch_ref, yaw_ref, x_ref, y_ref
    quadsitl/<vehicle>/actuators  tick, t, u1, u2, u3, u4, f1, f2, f3, f4
    quadsitl/<vehicle>/status     tick, t, armed, mode, failsafe, offboard_tick, battery_v, battery_a, battery_mah,
                                  battery_j, battery_remaining

and in sensor mode (``--state sensors``, where ``state`` is the estimate flown) two more:

    quadsitl/<vehicle>/truth      the plant's ground truth, laid out as the state
    quadsitl/<vehicle>/sensors    tick, t, accel_x/y/z, gyro_x/y/z, mag_x/y/z, baro_alt, estimator_flags, vel_ratio,
                                  pos_horiz_ratio, pos_vert_ratio, mag_ratio, pos_horiz_accuracy, pos_vert_accuracy

Encoding: little-endian C structs (``struct`` formats below): ``tick`` uint64 (control ticks since the
plant started), ``t`` float64 simulated time [s], then float64 fields in SI units, radians, NED/FRD;
setpoint: ``x_ref``, ``y_ref`` the horizontal position reference in local NED [m] (x north, y east), NaN
while the horizontal position is not controlled (attitude setpoints, the paper's experiment);
status: ``armed`` uint8 (0/1), ``mode`` uint8 (:data:`MODES`: 0 hold, 1 offboard, 2 land, 3 takeoff,
4 rtl, 5 mission, 6 posctl, 7 altctl, 8 stabilized, 9 orbit, 10 follow), ``failsafe`` uint8 (0 none, 1 setpoint stream
lost, 2 plant link lost, 3 ground station lost, 4 estimator failed, 5 controller failed, 6 motor failure, 7 geofence,
8 battery, 9 manual control lost), ``offboard_tick``
int64 (tick at which the current offboard flight started, −1 when not in an offboard flight), then the battery as
the autopilot knows it (docs/battery.md): voltage [V], current [A], charge drawn [mAh], energy drawn [J], the share
of its charge left (0..1), all float64, NaN without a battery (an ideal supply); sensors: the newest samples the
estimator took (FRD, calibrated: accelerometer [m/s²], gyro [rad/s], magnetometer [gauss]; barometric altitude
[m AMSL]) and ESTIMATOR_STATUS's fields (its flags as a float64, the test ratios, the 1σ accuracies [m]), all
float64 (:data:`SENSORS_FIELDS`: a stream added beside v4's, whose records it leaves as they were). The Zenoh
encoding is ``application/octet-stream`` with schema ``quadsitl.<stream>.v4`` (:data:`SCHEMA_VERSION`).

One more key is not per tick: ``quadsitl/<vehicle>/mission`` carries the stored mission as the dashboard draws
it, JSON (``application/json`` with schema ``quadsitl.mission.v1``), published when the plan, its current
item or its state changes and once a second (so a subscriber that joins late has it within a second)::

    {"version": 3, "current": 1, "state": 3, "total": 4,
     "items": [{"seq": 0, "command": 22, "x": null, "y": null, "altitude": 5.0}, ...],
     "reached": [[0, 4.213], [1, 9.87]],
     "fence": [{"kind": 1, "size": 4, "x": -20.0, "y": -20.0}, ...], "rally": [{"x": 40.0, "y": 10.0}]}

``version`` counts replacements of the stored mission; ``state`` is MAVLink's MISSION_STATE (1 none, 2 not
started, 3 active, 4 paused, 5 complete); each item's ``x``, ``y`` (local NED [m], x north, y east of the
origin) and ``altitude`` [m] are where the item flies, null where it has no place of its own (a takeoff or
landing where the vehicle is, a delay, a speed change; a return to launch has home's x, y). ``reached`` lists each
MISSION_ITEM_REACHED since the vehicle last armed (or the stored mission was replaced), in order: the item and the
simulated time [s] of the tick after which it was reached (absent in documents of older autopilots: an empty list).
``fence`` is the geofence's items in order (``kind`` 1 inclusion polygon, 2 exclusion polygon, 3 inclusion circle,
4 exclusion circle; ``size`` a polygon's vertex count, a circle's radius [m]; ``x``, ``y`` a vertex or a centre) and
``rally`` the rally points (both absent in older documents: empty).
:func:`encode_mission` and :func:`decode_mission` write and check it.

And the overview, for maps of a fleet: ``quadsitl/<vehicle>/slow/overview`` carries the newest state, setpoint,
actuators and status records of one tick, concatenated in that order, at most 20 times a second of wall time
(:class:`Overview`, :func:`split_overview`; schema ``quadsitl.overview.v4``).

Versions: v4 added the battery to the status record (v3's was ``<QdBBBq``); v3 added x_ref and y_ref to the
setpoint record (v2's was ``<Qd4d``); the other streams' records are as they were, and carry the newest version
too, so that one version names the whole set. v2 batched records; v1 carried
exactly one per sample.

A sample carries one or more records of consecutive ticks, concatenated (since v2).
The autopilot sends what it has every ``BATCH_WALL`` of wall time (``FAST_BATCH_WALL`` in a run faster than twice
real time), or once ``BATCH_TICKS`` ticks are waiting (:mod:`autopilot.telemetry_out`): in real time a few records
per sample, in a fast lockstep run many; a large one through Zenoh's shared memory (:mod:`quadsitl.zenoh_shm`).
Every tick's record is published; batching only spares the transport a message (and a wake-up of its thread, and of
every subscriber's) per tick. Split a payload with :func:`records`.
"""

from __future__ import annotations

import argparse
import json
import math
import re
import struct
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from quadsitl import zenoh_shm

if TYPE_CHECKING:  # the schema needs no Zenoh: pure modules (dashboard model, recordings) import it
    import numpy as np
    import zenoh

PREFIX = "quadsitl"
SCHEMA_VERSION = 4  # of every stream's record layout; in the Zenoh encoding's schema, quadsitl.<stream>.v4
STREAMS: dict[str, struct.Struct] = {
    "state": struct.Struct("<Qd12d"),
    "setpoint": struct.Struct("<Qd6d"),
    "actuators": struct.Struct("<Qd8d"),
    "status": struct.Struct("<QdBBBq5d"),
}
FIELDS: dict[str, tuple[str, ...]] = {
    "state": ("tick", "t", "x", "y", "z", "vx", "vy", "vz", "roll", "pitch", "yaw", "p", "q", "r"),
    "setpoint": ("tick", "t", "altitude_ref", "roll_ref", "pitch_ref", "yaw_ref", "x_ref", "y_ref"),
    "actuators": ("tick", "t", "u1", "u2", "u3", "u4", "f1", "f2", "f3", "f4"),
    "status": (
        "tick",
        "t",
        "armed",
        "mode",
        "failsafe",
        "offboard_tick",
        "battery_v",
        "battery_a",
        "battery_mah",
        "battery_j",
        "battery_remaining",
    ),
}
# Where each field of a record is [bytes from the record's start], from the layouts above (little-endian, packed: no
# padding). Every writer takes its offsets from here: the compiled tick's (autopilot.tick) read these as globals.
FIELD_CODES = {"Q": "<u8", "d": "<f8", "B": "u1", "q": "<i8"}  # struct's code → numpy's type


# In sensor mode the autopilot flies on its estimate: the state stream is that estimate, and two more streams go out
# beside it, a record per tick each. Not in STREAMS: a truth-mode run has neither.
# - quadsitl/<vehicle>/truth: the plant's ground truth, laid out as the state's (tick, t, x, y, z, vx, vy, vz, roll,
#   pitch, yaw, p, q, r).
# - quadsitl/<vehicle>/sensors: what the estimator took and how it is (autopilot.estimator.report): the newest
#   accelerometer [m/s²], gyro [rad/s] and magnetometer [gauss] samples (FRD, calibrated), the barometric altitude
#   [m AMSL]; then ESTIMATOR_STATUS's fields: its flags (a float64 holding the integer), the velocity, horizontal
#   and vertical position and magnetometer test ratios, the horizontal and vertical position accuracy [m, 1σ].
TRUTH = "truth"
TRUTH_RECORD = STREAMS["state"]
SENSORS = "sensors"
SENSORS_RECORD = struct.Struct("<Qd17d")
SENSORS_FIELDS = ("tick", "t", "accel_x", "accel_y", "accel_z", "gyro_x", "gyro_y", "gyro_z", "mag_x", "mag_y",
                  "mag_z", "baro_alt", "estimator_flags", "vel_ratio", "pos_horiz_ratio", "pos_vert_ratio",
                  "mag_ratio", "pos_horiz_accuracy", "pos_vert_accuracy")  # fmt: skip
SENSING = (TRUTH, SENSORS)  # the streams of sensor mode, in the order they follow STREAMS'


def layout(stream: str) -> tuple[struct.Struct, tuple[str, ...]]:
    """A stream's record (its struct and its fields' names): STREAMS' and FIELDS', or sensor mode's."""
    if stream == TRUTH:
        return TRUTH_RECORD, FIELDS["state"]
    if stream == SENSORS:
        return SENSORS_RECORD, SENSORS_FIELDS
    return STREAMS[stream], FIELDS[stream]


def _codes(stream: str) -> list[str]:
    """The struct codes of a record's fields, one per field ("<Qd12d" → Q, d, d, ... d)."""
    codes = re.findall(r"(\d*)([QdBq])", layout(stream)[0].format)
    return [code for count, code in codes for _ in range(int(count or 1))]


def _offsets(stream: str) -> dict[str, int]:
    codes, fields = _codes(stream), layout(stream)[1]
    assert len(codes) == len(fields), stream
    return {f: struct.calcsize("<" + "".join(codes[:i])) for i, f in enumerate(fields)}


OFFSETS: dict[str, dict[str, int]] = {stream: _offsets(stream) for stream in (*STREAMS, SENSORS)}
FLOAT64 = struct.calcsize("<d")  # [bytes] a float64 field: consecutive ones are this far apart
AT_TICK, AT_T = OFFSETS["state"]["tick"], OFFSETS["state"]["t"]  # the same in every record
assert all((o["tick"], o["t"]) == (AT_TICK, AT_T) for o in OFFSETS.values())
assert all(set(_codes(s)[2:]) == {"d"} for s in ("state", "setpoint", "actuators", SENSORS))  # after t: float64s
STATE_AT_X, STATE_AT_P = OFFSETS["state"]["x"], OFFSETS["state"]["p"]  # x..yaw, then p, q, r
SETPOINT_AT_REF = OFFSETS["setpoint"]["altitude_ref"]  # altitude_ref..y_ref
ACTUATORS_AT_U = OFFSETS["actuators"]["u1"]  # u1..u4, f1..f4
STATUS_AT_ARMED, STATUS_AT_MODE, STATUS_AT_FAILSAFE, STATUS_AT_OFFBOARD_TICK, STATUS_AT_BATTERY = (
    OFFSETS["status"][f] for f in ("armed", "mode", "failsafe", "offboard_tick", "battery_v"))  # fmt: skip
BATTERY_FIELDS = FIELDS["status"][6:]  # battery_v .. battery_remaining, float64s in a row
SENSORS_AT_VALUES = OFFSETS[SENSORS]["accel_x"]  # accel_x .. pos_vert_accuracy


def record_dtype(stream: str) -> np.dtype:
    """A record of ``stream`` (STREAMS', or sensor mode's: :func:`layout`) as a numpy structured type: its fields at
    their offsets (the same bytes)."""
    import numpy as np

    record, fields = layout(stream)
    size = record.size
    dtype = np.dtype({"names": list(fields), "formats": [FIELD_CODES[c] for c in _codes(stream)],
                      "offsets": list(_offsets(stream).values()), "itemsize": size})  # fmt: skip
    assert dtype.itemsize == size
    return dtype


# The status record's ``mode``: the autopilot's flight modes (PX4's, DESIGN.md §8), as quadsitl.wire.Mode numbers them.
MODES: dict[int, str] = {
    0: "hold",
    1: "offboard",
    2: "land",
    3: "takeoff",
    4: "rtl",
    5: "mission",
    6: "posctl",
    7: "altctl",
    8: "stabilized",
    9: "orbit",
    10: "follow",
}


MISSION = "mission"  # the key quadsitl/<vehicle>/mission: the stored mission, JSON (not a per-tick stream)
MISSION_SCHEMA = 1
MAX_MISSION_BYTES = 256 * 1024  # [bytes] a mission document longer than this is refused
MISSION_STATES: dict[int, str] = {0: "unknown", 1: "none", 2: "not started", 3: "active", 4: "paused", 5: "complete"}


def key(vehicle: str, stream: str) -> str:
    return f"{PREFIX}/{vehicle}/{stream}"


# The overview: every publisher of the streams also puts the newest record of each, the four in one sample, on
# quadsitl/<vehicle>/slow/overview, at most every SLOW_PERIOD seconds of wall time. A map of a fleet subscribes to
# that (quadsitl/*/slow/*) and takes the full rate only of the vehicle it shows: a publisher sends a sample only
# where a subscriber matches, so the other vehicles' full-rate streams never leave their process. One sample, not
# one per stream: a map gets the four records of one tick together (docs/telemetry.md#the-overview).
SLOW = "slow"
OVERVIEW = "overview"
SLOW_PERIOD = 0.05  # [s] wall: 20 samples a second
OVERVIEW_SIZE = sum(record.size for record in STREAMS.values())  # [bytes] the four records, in STREAMS' order


def overview_key(vehicle: str) -> str:
    return f"{PREFIX}/{vehicle}/{SLOW}/{OVERVIEW}"


def split_overview(payload: bytes) -> dict[str, bytes] | None:
    """An overview sample's record of each stream (STREAMS' order, each its record's size); None when the payload
    is not OVERVIEW_SIZE bytes long."""
    if len(payload) != OVERVIEW_SIZE:
        return None
    out, at = {}, 0
    for stream, record in STREAMS.items():
        out[stream] = payload[at : at + record.size]
        at += record.size
    return out


class Overview:
    """The overview's publisher of one vehicle (see SLOW): :meth:`offer` the newest records as often as you like;
    they are put at most every SLOW_PERIOD wall seconds. An offer turned away is owed: :meth:`catch_up` puts the
    newest records once the period is over, so the overview ends on the vehicle's last record even when its clock
    stops (a lockstep plant holding it once landed) and nothing new is offered."""

    def __init__(self, session: zenoh.Session, vehicle: str) -> None:
        import zenoh

        self.pub = session.declare_publisher(overview_key(vehicle), encoding=overview_encoding(),
                                             congestion_control=zenoh.CongestionControl.DROP)  # fmt: skip
        self.due = -math.inf
        self.owed = False  # an offer was turned away since the last put

    def offer(self, newest: Callable[[str], bytes | None], now: float, force: bool = False) -> bool:
        """Put ``newest(stream)`` of every stream (one record each) as one sample if SLOW_PERIOD has passed since the
        last put, or with ``force`` (``now``: wall seconds, monotonic); True when it did. While a stream has no
        record yet (None), nothing is put, nor owed."""
        records = [newest(stream) for stream in STREAMS]
        if not all(records):
            return False
        if now < self.due and not force:
            self.owed = True
            return False
        self.due, self.owed = now + SLOW_PERIOD, False
        self.pub.put(b"".join(records))  # type: ignore[arg-type]
        return True

    def catch_up(self, newest: Callable[[str], bytes | None], now: float) -> bool:
        """Put what an offer turned away, once SLOW_PERIOD has passed since the last put; True when it did."""
        return self.owed and self.offer(newest, now)


def encoding(stream: str) -> zenoh.Encoding:
    import zenoh

    return zenoh.Encoding.APPLICATION_OCTET_STREAM.with_schema(f"quadsitl.{stream}.v{SCHEMA_VERSION}")


def overview_encoding() -> zenoh.Encoding:
    import zenoh

    return zenoh.Encoding.APPLICATION_OCTET_STREAM.with_schema(f"quadsitl.{OVERVIEW}.v{SCHEMA_VERSION}")


def mission_encoding() -> zenoh.Encoding:
    import zenoh

    return zenoh.Encoding.APPLICATION_JSON.with_schema(f"quadsitl.{MISSION}.v{MISSION_SCHEMA}")


def encode_mission(version: int, current: int, state: int, items: Sequence[dict],
                   reached: Sequence[tuple[int, float]] = (), fence: Sequence[dict] = (),
                   rally: Sequence[dict] = ()) -> bytes:  # fmt: skip
    """The mission document (see the module's docstring): ``items`` are dicts of seq, command, x, y, altitude
    (NaN or None where unknown; NaN goes out as null); ``reached`` (seq, simulated time [s]) pairs; ``fence`` the
    geofence's items, dicts of kind (1 inclusion polygon, 2 exclusion polygon, 3 inclusion circle, 4 exclusion
    circle), size (a polygon's vertex count, a circle's radius [m]), x, y [m, NED]; ``rally`` the rally points' x,
    y [m, NED]."""

    def num(v: float | None) -> float | None:
        return None if v is None or not math.isfinite(v) else round(float(v), 3)

    doc = {
        "version": int(version),
        "current": int(current),
        "state": int(state),
        "total": len(items),
        "items": [
            {"seq": int(i["seq"]), "command": int(i["command"]), "x": num(i["x"]), "y": num(i["y"]),
             "altitude": num(i["altitude"])}
            for i in items
        ],
        "reached": [[int(seq), round(float(t), 6)] for seq, t in reached],
        "fence": [{"kind": int(f["kind"]), "size": num(f["size"]), "x": num(f["x"]), "y": num(f["y"])} for f in fence],
        "rally": [{"x": num(r["x"]), "y": num(r["y"])} for r in rally],
    }  # fmt: skip
    return json.dumps(doc, separators=(",", ":"), allow_nan=False).encode()


def json_object(payload: bytes, what: str, limit: int) -> dict:
    """A JSON document's object, or a ValueError naming ``what`` it was: longer than ``limit`` bytes, not JSON, not
    an object."""
    if len(payload) > limit:
        raise ValueError(f"{what}: {len(payload)} bytes, at most {limit}")
    try:
        doc = json.loads(payload)
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ValueError(f"{what}: not JSON ({exc})") from None
    if not isinstance(doc, dict):
        raise ValueError(f"{what}: expected an object, got {type(doc).__name__}")
    return doc


def decode_mission(payload: bytes) -> dict:
    """A mission document → the dict :func:`encode_mission` wrote, checked field by field. Raises ValueError
    naming what is wrong (too long, not JSON, a missing or mistyped field, a value out of range)."""
    doc = json_object(payload, "mission", MAX_MISSION_BYTES)

    def integer(obj: dict, name: str, lo: int, hi: int) -> int:
        v = obj.get(name)
        if not isinstance(v, int) or isinstance(v, bool) or not lo <= v <= hi:
            raise ValueError(f"mission: {name} = {v!r}, expected an integer in {lo}..{hi}")
        return v

    def number(obj: dict, name: str) -> float | None:
        v = obj.get(name)
        if v is None:
            return None
        if not isinstance(v, (int, float)) or isinstance(v, bool) or not math.isfinite(v) or abs(v) > 1e7:
            raise ValueError(f"mission: item {name} = {v!r}, expected a number of metres within ±1e7, or null")
        return float(v)

    items = doc.get("items")
    if not isinstance(items, list):
        raise ValueError(f"mission: items = {items!r:.40}, expected a list")
    out = {
        "version": integer(doc, "version", 0, 2**53),
        "state": integer(doc, "state", 0, max(MISSION_STATES)),
        "total": integer(doc, "total", len(items), len(items)),
        "items": [],
    }
    out["current"] = integer(doc, "current", 0, max(len(items) - 1, 0))
    for item in items:
        if not isinstance(item, dict):
            raise ValueError(f"mission: an item is {type(item).__name__}, expected an object")
        out["items"].append({"seq": integer(item, "seq", 0, 65535), "command": integer(item, "command", 0, 65535),
                             "x": number(item, "x"), "y": number(item, "y"),
                             "altitude": number(item, "altitude")})  # fmt: skip
    reached = doc.get("reached", [])
    if not isinstance(reached, list):
        raise ValueError(f"mission: reached = {reached!r:.40}, expected a list")
    out["reached"] = []
    for r in reached:
        ok = isinstance(r, list) and len(r) == 2 and isinstance(r[0], int) and not isinstance(r[0], bool)
        ok = ok and 0 <= r[0] <= 65535 and isinstance(r[1], (int, float)) and not isinstance(r[1], bool)
        if not ok or not math.isfinite(r[1]):
            raise ValueError(f"mission: reached {r!r:.40}, expected [item, simulated time [s]]")
        out["reached"].append((r[0], float(r[1])))
    fence, rally = doc.get("fence", []), doc.get("rally", [])  # absent from an older vehicle's: none
    for name, value in (("fence", fence), ("rally", rally)):
        if not isinstance(value, list) or not all(isinstance(f, dict) for f in value):
            raise ValueError(f"mission: {name} = {value!r:.40}, expected a list of objects")
    out["fence"] = [{"kind": integer(f, "kind", 1, 4), "size": number(f, "size"), "x": number(f, "x"),
                     "y": number(f, "y")} for f in fence]  # fmt: skip
    out["rally"] = [{"x": number(r, "x"), "y": number(r, "y")} for r in rally]
    return out


def records(stream: str, payload: bytes) -> list[tuple]:
    """One sample → its records (tuples in its fields' order: :func:`layout`). Raises ValueError on a malformed
    payload."""
    fmt = layout(stream)[0]
    if not payload or len(payload) % fmt.size:
        raise ValueError(f"{stream}: payload of {len(payload)} bytes, expected a multiple of {fmt.size}")
    return list(fmt.iter_unpack(payload))


def decode(stream: str, payload: bytes) -> dict[str, float]:
    """One sample → {field: value}. Raises ValueError on a malformed payload."""
    fmt, fields = layout(stream)
    if len(payload) != fmt.size:
        raise ValueError(f"{stream}: payload of {len(payload)} bytes, expected {fmt.size}")
    return dict(zip(fields, fmt.unpack(payload)))


def zenoh_config(
    mode: str = "peer",
    listen: Sequence[str] = (),
    connect: Sequence[str] = (),
    config_file: str | None = None,
    shared_memory: bool = False,
) -> zenoh.Config:
    """A Zenoh configuration: from ``config_file`` (Zenoh's own JSON5 format) if given, else peer mode
    with multicast scouting off (it fails inside containers), every sample stamped with its publication time
    (the dashboard's rates: a subscriber that falls behind and takes a backlog at once would otherwise see a burst),
    and the given endpoints; Zenoh's shared memory on, set up as the session opens, for the sessions that publish the
    telemetry batches or copy each as it comes (``shared_memory``, where the process may lock it:
    :mod:`quadsitl.zenoh_shm`), else off."""
    import zenoh

    conf = zenoh.Config.from_file(str(Path(config_file))) if config_file else zenoh.Config()
    if mode:
        conf.insert_json5("mode", f'"{mode}"')
    if listen:
        conf.insert_json5("listen/endpoints", _json_list(listen))
    if connect:
        conf.insert_json5("connect/endpoints", _json_list(connect))
    if not config_file:
        conf.insert_json5("scouting/multicast/enabled", "false")
        conf.insert_json5("timestamping/enabled", "true")
        zenoh_shm.configure(conf, shared_memory)
    return conf


def _json_list(items: Sequence[str]) -> str:
    return "[" + ",".join(f'"{i}"' for i in items) + "]"


def add_zenoh_arguments(p: argparse.ArgumentParser, vehicle: bool = True) -> None:
    """The Zenoh options every process that touches telemetry takes (``--vehicle`` unless it sees all)."""
    if vehicle:
        p.add_argument(
            "--vehicle", default="v1", help="vehicle name in the Zenoh keys quadsitl/<vehicle>/... (default: v1)"
        )
    p.add_argument("--zenoh-mode", choices=("peer", "client", "router"), default="peer", help="default: peer")
    p.add_argument(
        "--zenoh-listen",
        action="append",
        default=[],
        metavar="ENDPOINT",
        help="Zenoh endpoint to listen on, e.g. tcp/127.0.0.1:7447 (repeatable)",
    )
    p.add_argument(
        "--zenoh-connect",
        action="append",
        default=[],
        metavar="ENDPOINT",
        help="Zenoh endpoint to connect to (repeatable)",
    )
    p.add_argument("--zenoh-config", metavar="FILE", help="a Zenoh JSON5 configuration file (TLS, access control)")


def config_from_args(args: argparse.Namespace, shared_memory: bool = False) -> zenoh.Config:
    return zenoh_config(args.zenoh_mode, args.zenoh_listen, args.zenoh_connect, args.zenoh_config, shared_memory)
