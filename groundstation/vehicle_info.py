"""``quadsitl/<vehicle>/info``: who a vehicle is and where its home is, for maps of a fleet (JSON).

Each vehicle's local frame starts at its own home (PX4's convention: ``x``, ``y`` on Zenoh are metres from where
it started), so a map of several vehicles needs each one's home. The per-tick records do not carry it; the
launcher (``quadsitl up``) does, on this key, one document per vehicle, encoding
``application/json;quadsitl.info.v1``::

    {"system_id": 2, "home": {"latitude": 47.397742, "longitude": 8.545621, "altitude": 488.0},
     "preset": "paper", "vehicles": 3}

``system_id`` is the vehicle's MAVLink system id, ``home`` its home (degrees, metres above mean sea level),
``preset`` the airframe it flies and ``vehicles`` how many ``up`` started. It is put once a second (so a
subscriber that joins late has it within a second) and answers a Zenoh ``get`` on ``quadsitl/*/info`` at once.
:func:`encode_info` writes it; :func:`decode_info` checks it field by field (a dashboard refuses a bad one with
its reason and keeps the last good one).
"""

from __future__ import annotations

import json
import math

from quadsitl import telemetry

INFO = "info"  # the key quadsitl/<vehicle>/info
INFO_SCHEMA = 1
MAX_INFO_BYTES = 4096
MAX_FLEET = 64  # vehicles a document may say the fleet has (groundstation.fleet.MAX_VEHICLES)


def info_key(vehicle: str) -> str:
    return telemetry.key(vehicle, INFO)


def info_encoding():
    import zenoh

    return zenoh.Encoding.APPLICATION_JSON.with_schema(f"quadsitl.{INFO}.v{INFO_SCHEMA}")


def encode_info(system_id: int, home: tuple[float, float, float], preset: str = "", vehicles: int = 1) -> bytes:
    """The document (see the module's docstring) for one vehicle."""
    doc = {
        "system_id": int(system_id),
        "home": {"latitude": float(home[0]), "longitude": float(home[1]), "altitude": float(home[2])},
        "preset": str(preset),
        "vehicles": int(vehicles),
    }
    return json.dumps(doc, separators=(",", ":"), allow_nan=False).encode()


def decode_info(payload: bytes) -> dict:
    """An info document → {system_id, home: (lat, lon, alt), preset, vehicles}, checked. Raises ValueError naming
    what is wrong (too long, not JSON, a missing or mistyped field, a value out of range)."""
    doc = telemetry.json_object(payload, "info", MAX_INFO_BYTES)

    def integer(name: str, lo: int, hi: int, default: int | None = None) -> int:
        v = doc.get(name, default)
        if not isinstance(v, int) or isinstance(v, bool) or not lo <= v <= hi:
            raise ValueError(f"info: {name} = {v!r:.40}, expected an integer in {lo}..{hi}")
        return v

    system_id = integer("system_id", 1, 255)
    home = doc.get("home")
    if not isinstance(home, dict):
        raise ValueError(f"info: home = {home!r:.40}, expected an object of latitude, longitude, altitude")
    coords = []
    for name, lo, hi in (("latitude", -90.0, 90.0), ("longitude", -180.0, 180.0), ("altitude", -1000.0, 1e5)):
        v = home.get(name)
        if not isinstance(v, (int, float)) or isinstance(v, bool) or not math.isfinite(v) or not lo <= v <= hi:
            raise ValueError(f"info: home {name} = {v!r:.40}, expected a number in [{lo:g}, {hi:g}]")
        coords.append(float(v))
    preset = doc.get("preset", "")
    if not isinstance(preset, str) or len(preset) > 200:
        raise ValueError(f"info: preset = {preset!r:.40}, expected a string of at most 200 characters")
    return {
        "system_id": system_id,
        "home": tuple(coords),
        "preset": preset,
        "vehicles": integer("vehicles", 1, MAX_FLEET, 1),
    }


class InfoPublisher:
    """The launcher's side: on its Zenoh ``session`` (which :meth:`close` closes), put every vehicle's document
    once a second (:meth:`tick`) and answer a ``get`` at once. ``docs``: {vehicle name: encoded document}."""

    PERIOD = 1.0  # [s] wall between puts

    def __init__(self, session, docs: dict[str, bytes]) -> None:
        import zenoh

        self.session, self.docs, self.next = session, docs, 0.0
        enc = info_encoding()
        self.pubs = {name: session.declare_publisher(info_key(name), encoding=enc) for name in docs}
        self.queryable = session.declare_queryable(telemetry.key("*", INFO), self._answer)
        self._zenoh = zenoh

    def _answer(self, query) -> None:  # Zenoh's thread: only replies, never blocks
        for name, doc in self.docs.items():
            key = info_key(name)
            if self._zenoh.KeyExpr(key).intersects(query.key_expr):
                query.reply(key, doc, encoding=info_encoding())

    def tick(self, now: float) -> None:
        if now < self.next:
            return
        self.next = now + self.PERIOD
        for name, pub in self.pubs.items():
            pub.put(self.docs[name])

    def close(self) -> None:
        for p in self.pubs.values():
            p.undeclare()
        self.queryable.undeclare()
        self.session.close()
