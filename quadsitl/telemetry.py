"""Telemetry over Zenoh: the key schema, the encoding and the session configuration (DESIGN.md §5).

Keys (``<vehicle>`` defaults to ``v1``), one record per control tick on each:

    quadsitl/<vehicle>/state      tick, t, x, y, z, vx, vy, vz, roll, pitch, yaw, p, q, r
    quadsitl/<vehicle>/setpoint   tick, t, altitude_ref, roll_ref, pitch_ref, yaw_ref, x_ref, y_ref
    quadsitl/<vehicle>/actuators  tick, t, u1, u2, u3, u4, f1, f2, f3, f4
    quadsitl/<vehicle>/status     tick, t, armed, mode, failsafe, offboard_tick

Encoding: little-endian C structs (``struct`` formats below): ``tick`` uint64 (control ticks since the
plant started), ``t`` float64 simulated time [s], then float64 fields in SI units, radians, NED/FRD;
setpoint: ``x_ref``, ``y_ref`` the horizontal position reference in local NED [m] (x north, y east), NaN
while the horizontal position is not controlled (attitude setpoints, the paper's experiment);
status: ``armed`` uint8 (0/1), ``mode`` uint8 (:data:`MODES`: 0 hold, 1 offboard, 2 land, 3 takeoff,
4 rtl, 5 mission), ``failsafe`` uint8 (0 none, 1 setpoint stream lost), ``offboard_tick``
int64 (tick at which the current offboard flight started, −1 when not in an offboard flight). The Zenoh
encoding is ``application/octet-stream`` with schema ``quadsitl.<stream>.v3`` (:data:`SCHEMA_VERSION`).

Versions: v3 added x_ref and y_ref to the setpoint record (v2's was ``<Qd4d``); the other streams' records
are as in v2, and carry v3 too, so that one version names the whole set. v2 batched records; v1 carried
exactly one per sample.

A sample carries one or more records of consecutive ticks, concatenated (since v2).
The autopilot sends what it has every 5 ms of wall time (or after 512 ticks): at 1 kHz in real time that
is five records per sample, in a lockstep run at 20,000 ticks/s about a hundred. Every tick's record is
published; batching only spares the transport a message (and a wake-up of its thread, and of every
subscriber's) per tick, which at that rate cost more than the control loop itself. Split a payload with
:func:`records`.
"""

from __future__ import annotations

import argparse
import struct
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # the schema needs no Zenoh: pure modules (dashboard model, recordings) import it
    import zenoh

PREFIX = "quadsitl"
SCHEMA_VERSION = 3  # of every stream's record layout; in the Zenoh encoding's schema, quadsitl.<stream>.v3
STREAMS: dict[str, struct.Struct] = {
    "state": struct.Struct("<Qd12d"),
    "setpoint": struct.Struct("<Qd6d"),
    "actuators": struct.Struct("<Qd8d"),
    "status": struct.Struct("<QdBBBq"),
}
FIELDS: dict[str, tuple[str, ...]] = {
    "state": ("tick", "t", "x", "y", "z", "vx", "vy", "vz", "roll", "pitch", "yaw", "p", "q", "r"),
    "setpoint": ("tick", "t", "altitude_ref", "roll_ref", "pitch_ref", "yaw_ref", "x_ref", "y_ref"),
    "actuators": ("tick", "t", "u1", "u2", "u3", "u4", "f1", "f2", "f3", "f4"),
    "status": ("tick", "t", "armed", "mode", "failsafe", "offboard_tick"),
}
# The status record's ``mode``: the autopilot's flight modes (PX4's, DESIGN.md §8), as quadsitl.wire.Mode numbers them.
MODES: dict[int, str] = {0: "hold", 1: "offboard", 2: "land", 3: "takeoff", 4: "rtl", 5: "mission"}


def key(vehicle: str, stream: str) -> str:
    return f"{PREFIX}/{vehicle}/{stream}"


def encoding(stream: str) -> zenoh.Encoding:
    import zenoh

    return zenoh.Encoding.APPLICATION_OCTET_STREAM.with_schema(f"quadsitl.{stream}.v{SCHEMA_VERSION}")


def records(stream: str, payload: bytes) -> list[tuple]:
    """One sample → its records (tuples in FIELDS order). Raises ValueError on a malformed payload."""
    fmt = STREAMS[stream]
    if not payload or len(payload) % fmt.size:
        raise ValueError(f"{stream}: payload of {len(payload)} bytes, expected a multiple of {fmt.size}")
    return list(fmt.iter_unpack(payload))


def decode(stream: str, payload: bytes) -> dict[str, float]:
    """One sample → {field: value}. Raises ValueError on a malformed payload."""
    fmt = STREAMS[stream]
    if len(payload) != fmt.size:
        raise ValueError(f"{stream}: payload of {len(payload)} bytes, expected {fmt.size}")
    return dict(zip(FIELDS[stream], fmt.unpack(payload)))


def zenoh_config(
    mode: str = "peer",
    listen: Sequence[str] = (),
    connect: Sequence[str] = (),
    config_file: str | None = None,
) -> zenoh.Config:
    """A Zenoh configuration: from ``config_file`` (Zenoh's own JSON5 format) if given, else peer mode
    with multicast scouting off (it fails inside containers) and the given endpoints."""
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


def config_from_args(args: argparse.Namespace) -> zenoh.Config:
    return zenoh_config(args.zenoh_mode, args.zenoh_listen, args.zenoh_connect, args.zenoh_config)
