"""What the dashboard knows about each vehicle: pure, no I/O (the server feeds it Zenoh samples).

For each vehicle seen on ``quadsitl/<vehicle>/<stream>`` (:mod:`quadsitl.telemetry`, schema v3) it keeps

* the latest record of every stream (for ``/api/vehicles`` and the status panel), decoding only the last
  record of each sample;
* a plot series decimated in simulated time: the ticks that are multiples of ``decimation`` (one every
  ``1/plot_rate`` simulated seconds), picked out of each sample by offset without decoding the rest, and
  joined across the four streams by tick. The full-rate stream stays on Zenoh; the page gets at most
  ``plot_rate`` rows per simulated second whatever the run's speed;
* the stored mission (``quadsitl/<vehicle>/mission``, JSON): where each item flies and which is current,
  for the map; a malformed document is counted and the last good one kept;
* the tick rate and real-time factor, from the status records' ticks and simulated times against the wall
  clock over the last ``RATE_WINDOW`` seconds: the time each record was published (its Zenoh timestamp, the
  publisher's clock), or, for a publisher that does not stamp, when it came;
* for the fleet view: who the vehicle is and where its home is (``quadsitl/<vehicle>/info``,
  :mod:`groundstation.vehicle_info`, put by ``quadsitl up``; a bad document is refused with its reason, kept
  for the page, and the last good one stays), and a trail of its local x, y at ``TRAIL_RATE`` points per
  simulated second, picked from the state samples by offset as the plot rows are.

The fleet's common frame: north and east metres from the home of the first vehicle (in natural order of
names: v1, v2, …, v10) whose home is known, the fleet's *origin*; a vehicle's place on the fleet map is its home's
offset from the origin (:func:`quadsitl.frames.geodetic_to_ned`) plus its local x, y. A vehicle whose home is not
known has no offset: the page draws it at its local x, y from the origin, marked as such.

Rows carry display units: metres, degrees (angles and their errors), newtons and newton-metres; x, y and
x_ref, y_ref stay in local NED metres (x north, y east) for the page's x–y map, x_ref and y_ref NaN (null in
JSON) while the horizontal position is not controlled.
A vehicle whose ticks jump back (a new run, a replay that loops) starts a new ``generation``: its series
is cleared so that the page never draws two runs as one line.
"""

from __future__ import annotations

import math
import re
import struct
from collections import deque
from dataclasses import dataclass, field

from groundstation.vehicle_info import INFO, decode_info
from quadsitl import telemetry
from quadsitl.frames import geodetic_to_ned, wrap_pi

RATE_WINDOW = 2.0  # [s] wall: tick rate and real-time factor are averaged over this
STALE_AFTER = 1.0  # [s] wall without telemetry: the link shows as stale
MAX_VEHICLES = 64  # more names than this are ignored (and counted): a stranger must not exhaust memory
MAX_PENDING = 4096  # decimated ticks waiting for their other streams (a sample of 64 ticks holds a few)
TRAIL_RATE = 5.0  # fleet-map trail points per simulated second (at most the plot rate): 100 over a 20 s window
MODES = telemetry.MODES  # 0 hold, 1 offboard, 2 land, 3 takeoff, 4 rtl, 5 mission
FAILSAFES = {
    0: "none", 1: "setpoint stream lost", 2: "plant link lost", 3: "ground station lost", 4: "estimator failed",
    5: "controller failed", 6: "motor failure", 7: "geofence", 8: "battery",
}  # fmt: skip

# A row of the plot series, in this order (the page receives columns by these names).
ROW_FIELDS = (
    "t", "altitude", "altitude_ref", "roll", "roll_ref", "pitch", "pitch_ref", "yaw", "yaw_ref",
    "e_altitude", "e_roll", "e_pitch", "e_yaw", "u1", "u2", "u3", "u4", "f1", "f2", "f3", "f4", "x", "y",
    "x_ref", "y_ref",
)  # fmt: skip
_TICK = struct.Struct("<Q")
_XY = struct.Struct("<2d")  # x, y of a state record, at byte _STATE_AT_X
_STATE_AT_X = telemetry.STATE_AT_X
assert telemetry.OFFSETS["state"]["y"] == _STATE_AT_X + telemetry.FLOAT64
_STATE_SIZE = telemetry.STREAMS["state"].size


def natural(name: str) -> tuple:
    """A sort key that puts v2 before v10."""
    return tuple((0, int(p), "") if p.isdigit() else (1, 0, p) for p in re.split(r"(\d+)", name) if p)


def plot_row(state: tuple, setpoint: tuple, actuators: tuple) -> tuple[float, ...]:
    """One tick's records (in telemetry.FIELDS order) → a row in ROW_FIELDS order, display units.
    Errors are reference − measured; the yaw error is wrapped to (−180°, 180°]."""
    _tick, t, x, y, z, _vx, _vy, _vz, roll, pitch, yaw = state[:11]
    _, _, alt_ref, roll_ref, pitch_ref, yaw_ref, x_ref, y_ref = setpoint
    altitude, deg = -z, math.degrees  # NED: z down
    return (
        t, altitude, alt_ref, deg(roll), deg(roll_ref), deg(pitch), deg(pitch_ref), deg(yaw), deg(yaw_ref),
        alt_ref - altitude, deg(roll_ref - roll), deg(pitch_ref - pitch), deg(wrap_pi(yaw_ref - yaw)),
        *actuators[2:10], x, y, x_ref, y_ref,
    )  # fmt: skip


@dataclass
class Vehicle:
    name: str
    plot_rate: float
    window: float
    latest: dict[str, tuple] = field(default_factory=dict)
    rows: deque = field(default_factory=deque)  # (seq, row)
    seq: int = 0  # rows ever appended (across generations)
    generation: int = 0
    decimation: int = 0  # ticks between plotted rows; 0 until the period is known
    period: float = 0.0  # [s] simulated, the control period, learnt from the records
    last_wall: float = -math.inf
    samples: int = 0
    malformed: int = 0
    _pending: dict[int, dict[str, tuple]] = field(default_factory=dict)
    _rate: deque = field(default_factory=deque)  # (when [s], tick, t) of status records: sent, or else received
    _rate_clock: str = "wall"  # whose clock _rate's times are: "sent" (the publisher's) or "wall" (this process's)
    _stream_tick: dict[str, int] = field(default_factory=dict)  # the newest tick of each stream
    mission: dict | None = None  # the last mission document (quadsitl.telemetry.decode_mission), None before one
    info: dict | None = None  # the last good info document (groundstation.vehicle_info.decode_info)
    info_error: str | None = None  # why the newest info document was refused (None once a good one came)
    info_refused: int = 0
    trail: deque = field(default_factory=deque)  # (seq, t, x, y): local NED metres, TRAIL_RATE per second
    trail_seq: int = 0
    full_wall: float = -math.inf  # [s] wall: when a full-rate sample last came (the overview's are then ignored)
    _slow_tick: dict[str, int] = field(default_factory=dict)  # the newest tick of each stream's overview

    # ---- ingest ---------------------------------------------------------------------------------------

    def ingest(self, stream: str, payload: bytes, wall: float, slow: bool = False, sent: float | None = None) -> None:
        """A sample of ``stream``: full rate (consecutive ticks), or with ``slow`` the overview's one record of it
        (quadsitl/<vehicle>/slow/overview, :data:`quadsitl.telemetry.SLOW`), taken only while no full-rate sample
        has come for STALE_AFTER: its record is a plot row and a trail point of its own, whatever its tick. ``sent``:
        when it was published [s, the publisher's clock], if the sample says; the rates use it instead of ``wall``."""
        if slow and wall - self.full_wall <= STALE_AFTER:
            return
        fmt = telemetry.STREAMS[stream]
        size = len(payload)
        if not size or size % fmt.size:
            self.malformed += 1
            return
        n = size // fmt.size
        last = fmt.unpack_from(payload, size - fmt.size)
        if not math.isfinite(last[1]):  # a record without a time; NaN fields are "not known" (a replayed tlog)
            self.malformed += 1
            return
        first_tick = _TICK.unpack_from(payload, telemetry.AT_TICK)[0]
        if slow and n != 1:
            self.malformed += 1
            return
        self.samples += 1
        self.last_wall = wall
        ticks = self._slow_tick if slow else self._stream_tick  # each source's own: they interleave on a switch
        if first_tick < ticks.get(stream, -1) - 1:  # ticks went back: a new run, same name
            self._restart()
        ticks[stream] = last[0]
        if not slow:
            self.full_wall = wall
        if stream == "status":
            clock = "sent" if sent is not None else "wall"
            if clock != self._rate_clock:  # the rates never mix the publisher's clock with this one
                self._rate.clear()
                self._rate_clock = clock
            stamp = wall if sent is None else sent
            self._rate.append((stamp, last[0], last[1]))
            while len(self._rate) > 2 and stamp - self._rate[1][0] >= RATE_WINDOW:
                self._rate.popleft()
        self.latest[stream] = last
        if not self.decimation:
            self._learn_period(last)
            if not self.decimation:
                return
        if slow:
            self._join(first_tick, stream, last)
            if stream == "state" and (not self.trail or last[1] - self.trail[-1][1] >= 1.0 / TRAIL_RATE - 1e-9):
                self.trail_seq += 1
                self.trail.append((self.trail_seq, last[1], last[2], last[3]))
                while self.trail[0][1] < last[1] - self.window:
                    self.trail.popleft()
            return
        d = self.decimation
        k = -(-first_tick // d) * d  # the first multiple of d at or after the sample's first tick
        while k < first_tick + n:
            rec = fmt.unpack_from(payload, (k - first_tick) * fmt.size)
            self._join(k, stream, rec)
            k += d
        if stream == "state":
            self._trail(payload, first_tick, n, last[1])

    def _trail(self, payload: bytes, first_tick: int, n: int, t_last: float) -> None:
        """Every ``trail_every``-th plotted tick's x, y into the trail; older than the window out."""
        d = self.decimation * max(1, round(self.plot_rate / TRAIL_RATE))
        k = -(-first_tick // d) * d
        while k < first_tick + n:
            x, y = _XY.unpack_from(payload, (k - first_tick) * _STATE_SIZE + _STATE_AT_X)
            self.trail_seq += 1
            self.trail.append((self.trail_seq, k * self.period, x, y))
            k += d
        trail = self.trail
        while trail and trail[0][1] < t_last - self.window:
            trail.popleft()

    def ingest_overview(self, payload: bytes, wall: float, sent: float | None = None) -> None:
        """An overview sample (quadsitl/<vehicle>/slow/overview, :func:`quadsitl.telemetry.split_overview`): each
        stream's record as :meth:`ingest` takes it with ``slow``, counted as the one sample it is."""
        records = telemetry.split_overview(payload)
        if records is None:
            self.malformed += 1
            return
        before = self.samples
        for stream, record in records.items():
            self.ingest(stream, record, wall, True, sent)
        self.samples = min(self.samples, before + 1)

    def ingest_info(self, payload: bytes, wall: float) -> None:
        """A ``quadsitl/<vehicle>/info`` document: kept when well formed; otherwise refused, its reason kept for
        the page (``info_error``) and the last good one kept."""
        try:
            self.info = decode_info(payload)
        except ValueError as exc:
            self.malformed += 1
            self.info_refused += 1
            self.info_error = str(exc)
            return
        self.info_error = None
        self.samples += 1
        self.last_wall = max(self.last_wall, wall)

    def ingest_mission(self, payload: bytes, wall: float) -> None:
        """A mission document: kept when it is well formed (counted as malformed and ignored otherwise)."""
        try:
            self.mission = telemetry.decode_mission(payload)
        except ValueError:
            self.malformed += 1
            return
        self.samples += 1
        self.last_wall = max(self.last_wall, wall)

    def _learn_period(self, rec: tuple) -> None:
        tick, t = rec[0], rec[1]
        if tick > 0 and t > 0:
            self.period = t / tick
            self.decimation = max(1, round(1.0 / (self.plot_rate * self.period)))

    def _restart(self) -> None:
        self.generation += 1
        self.rows.clear()
        self._pending.clear()
        self._rate.clear()
        self._stream_tick.clear()
        self._slow_tick.clear()
        self.trail.clear()

    def _join(self, tick: int, stream: str, rec: tuple) -> None:
        got = self._pending.setdefault(tick, {})
        got[stream] = rec
        if len(got) < len(telemetry.STREAMS):
            if len(self._pending) > MAX_PENDING:  # a stream that never completes a tick must not grow this
                del self._pending[min(self._pending)]
            return
        del self._pending[tick]
        self.seq += 1
        self.rows.append((self.seq, plot_row(got["state"], got["setpoint"], got["actuators"])))
        t_now = self.rows[-1][1][0]
        while self.rows and self.rows[0][1][0] < t_now - self.window:
            self.rows.popleft()

    # ---- views ----------------------------------------------------------------------------------------

    def rates(self) -> tuple[float | None, float | None]:
        """(ticks per wall second, simulated seconds per wall second) over the last RATE_WINDOW."""
        if len(self._rate) < 2:
            return None, None
        (w0, k0, t0), (w1, k1, t1) = self._rate[0], self._rate[-1]
        if w1 - w0 < 0.2:
            return None, None
        return (k1 - k0) / (w1 - w0), (t1 - t0) / (w1 - w0)

    def summary(self, wall: float) -> dict:
        """The vehicle as ``/api/vehicles`` lists it: latest records by field name, status, rates."""
        age = wall - self.last_wall
        rate, rtf = self.rates()
        if age > STALE_AFTER:
            rate, rtf = 0.0, 0.0
        out: dict = {"name": self.name}
        for stream in ("state", "setpoint", "actuators"):
            rec = self.latest.get(stream)
            out[stream] = dict(zip(telemetry.FIELDS[stream][1:], rec[1:])) if rec else None
        st = self.latest.get("status")
        out["status"] = (
            {
                "tick": st[0],
                "t": st[1],
                "armed": bool(st[2]),
                "mode": MODES.get(st[3], f"unknown ({st[3]})"),
                "failsafe": FAILSAFES.get(st[4], f"unknown ({st[4]})"),
                "offboard_tick": st[5],
                **{f: (None if math.isnan(st[6 + i]) else st[6 + i]) for i, f in enumerate(telemetry.BATTERY_FIELDS)},
            }
            if st
            else None
        )
        out["link"] = {
            "telemetry": "live" if age <= STALE_AFTER else "stale",
            "age_s": round(age, 3),
            "samples": self.samples,
            "malformed": self.malformed,
        }
        m = self.mission
        out["mission"] = None if m is None else {**m, "state_name": telemetry.MISSION_STATES[m["state"]]}
        out["tick_rate"] = rate
        out["real_time_factor"] = rtf
        out["period"] = self.period or None
        out["generation"] = self.generation
        info = self.info
        out["system_id"] = info["system_id"] if info else None
        out["home"] = dict(zip(("latitude", "longitude", "altitude"), info["home"])) if info else None
        out["preset"] = info["preset"] if info else None
        out["info_error"] = self.info_error
        return out

    def trail_since(self, seq: int) -> list[tuple]:
        """Trail points (t, x, y) appended after ``seq`` (the whole trail if ``seq`` is older than it)."""
        trail = self.trail
        if not trail or trail[-1][0] <= seq:
            return []
        if trail[0][0] > seq:
            return [p[1:] for p in trail]
        return [p[1:] for p in trail if p[0] > seq]

    def fleet_entry(self, wall: float, offset: tuple[float, float, float] | None) -> dict:
        """The vehicle as the fleet view shows it: who, status, link, rates and its pose now (local x, y [m],
        altitude [m], yaw [deg]); ``offset`` (north, east, up [m] of its home from the fleet's origin) or None
        when its home is not known. No plot rows, no trail (the server adds the trail's new points)."""
        age = wall - self.last_wall
        live = age <= STALE_AFTER
        rate, rtf = self.rates() if live else (0.0, 0.0)
        st, s = self.latest.get("status"), self.latest.get("state")
        pose = None if s is None else [round(s[2], 3), round(s[3], 3), round(-s[4], 3), round(math.degrees(s[10]), 2)]
        info = self.info
        if info is not None:
            home_note = None
        elif self.info_error:
            home_note = f"home unknown: {self.info_error}"
        else:
            home_note = f"home unknown: nothing on {telemetry.PREFIX}/{self.name}/{INFO} yet"
        return {
            "name": self.name,
            "system_id": info["system_id"] if info else None,
            "preset": info["preset"] if info else None,
            "fleet_size": info["vehicles"] if info else None,
            "offset": None if offset is None else [round(v, 3) for v in offset],
            "home_note": home_note,
            "armed": None if st is None else bool(st[2]),
            "mode": None if st is None else MODES.get(st[3], f"unknown ({st[3]})"),
            "failsafe": None if st is None else FAILSAFES.get(st[4], f"unknown ({st[4]})"),
            "t": None if st is None else st[1],
            "link": "live" if live else "stale",
            "age_s": round(age, 3),
            "malformed": self.malformed,
            "tick_rate": None if rate is None else round(rate, 1),
            "real_time_factor": None if rtf is None else round(rtf, 3),
            "pose": pose,
            "generation": self.generation,
        }

    def rows_since(self, seq: int) -> list[tuple]:
        """Rows appended after ``seq`` (all rows of the window if ``seq`` is older than the window)."""
        rows = self.rows
        if not rows or rows[-1][0] <= seq:
            return []
        if rows[0][0] > seq:
            return [r for _, r in rows]
        return [r for s, r in rows if s > seq]


class Fleet:
    """Every vehicle seen, by name."""

    def __init__(self, plot_rate: float = 50.0, window: float = 20.0) -> None:
        self.plot_rate = plot_rate
        self.window = window
        self.vehicles: dict[str, Vehicle] = {}
        self.ignored = 0  # samples on keys that are not telemetry, or beyond MAX_VEHICLES

    def ingest(self, key: str, payload: bytes, wall: float, sent: float | None = None) -> None:
        """A Zenoh sample on ``key`` (``quadsitl/<vehicle>/<stream>``, or the overview's
        ``quadsitl/<vehicle>/slow/overview``) received at ``wall`` [s] (published at ``sent`` [s, the publisher's
        clock], if it says)."""
        parts = key.split("/")
        slow = len(parts) == 4 and parts[2] == telemetry.SLOW and parts[3] == telemetry.OVERVIEW
        if slow:
            parts = [parts[0], parts[1], telemetry.OVERVIEW]
        mission = len(parts) == 3 and parts[2] == telemetry.MISSION
        info = len(parts) == 3 and parts[2] == INFO
        if (len(parts) != 3 or parts[0] != telemetry.PREFIX
                or (parts[2] not in telemetry.STREAMS and not mission and not info and not slow)):  # fmt: skip
            self.ignored += 1
            return
        v = self.vehicles.get(parts[1])
        if v is None:
            if len(self.vehicles) >= MAX_VEHICLES:
                self.ignored += 1
                return
            v = self.vehicles[parts[1]] = Vehicle(parts[1], self.plot_rate, self.window)
        if mission:
            v.ingest_mission(payload, wall)
        elif info:
            v.ingest_info(payload, wall)
        elif slow:
            v.ingest_overview(payload, wall, sent)
        else:
            v.ingest(parts[2], payload, wall, False, sent)

    def ordered(self) -> list[Vehicle]:
        """The vehicles in natural order of their names (v1, v2, …, v10)."""
        return [self.vehicles[k] for k in sorted(self.vehicles, key=natural)]

    def summaries(self, wall: float) -> list[dict]:
        out = [v.summary(wall) for v in self.ordered()]
        offsets = self.offsets()
        for s in out:
            off = offsets.get(s["name"])
            s["offset"] = None if off is None else [round(x, 3) for x in off]
        return out

    def origin(self) -> Vehicle | None:
        """The fleet's origin: the first vehicle, in natural order, whose home is known (None: no home known)."""
        return next((v for v in self.ordered() if v.info is not None), None)

    def offsets(self) -> dict[str, tuple[float, float, float]]:
        """{name: (north, east, up) [m] of its home from the origin's} for every vehicle whose home is known."""
        o = self.origin()
        if o is None:
            return {}
        lat0, lon0, alt0 = o.info["home"]
        out = {}
        for name, v in self.vehicles.items():
            if v.info is not None:
                lat, lon, alt = v.info["home"]
                out[name] = (*geodetic_to_ned(lat, lon, lat0, lon0), alt - alt0)
        return out

    def fleet_view(self, wall: float) -> dict:
        """The fleet view without trails: the origin and every vehicle's :meth:`Vehicle.fleet_entry`."""
        o, offsets = self.origin(), self.offsets()
        origin = None if o is None else {"name": o.name, **dict(zip(("latitude", "longitude", "altitude"),
                                                                    o.info["home"]))}  # fmt: skip
        return {"origin": origin, "vehicles": [v.fleet_entry(wall, offsets.get(v.name)) for v in self.ordered()]}
