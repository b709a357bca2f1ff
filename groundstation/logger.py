"""A Zenoh subscriber that logs a vehicle's telemetry into telemetry.csv rows.

It joins the four streams by tick and keeps the ticks flown in offboard (``offboard_tick`` ≥ 0), with
t = (tick − offboard_tick)·T so that t = 0 is the first tick flown under the reference trajectory; or, for a
mission (``start="armed"``), the ticks flown armed from the first armed tick on, t = 0 at arming. Samples
wait in Zenoh's FIFO channels until ``drain`` files them (numpy views of the samples: no Python per record); joining and
decoding happen in ``rows``.
"""

from __future__ import annotations

import time

import numpy as np
import zenoh

from quadsitl import telemetry

# the streams, and sensor mode's: the plant's ground truth (laid out as the state) and the sensors
DTYPES = {stream: telemetry.record_dtype(stream) for stream in (*telemetry.STREAMS, *telemetry.SENSING)}
STATUS_FIELDS = ("tick", "armed", "mode", "failsafe", "offboard_tick")
CHANNEL = 1 << 20  # samples per stream that may wait for drain()


def by_tick(chunks: list[np.ndarray], stream: str, ticks: np.ndarray, names: tuple[str, ...]) -> list[np.ndarray]:
    """The fields ``names`` of a stream's records (``chunks`` as they arrived) at ``ticks``: the newest record of a
    tick that came twice, NaN for a tick that never came."""
    recs = joined_records(chunks, DTYPES[stream])[::-1]
    if len(recs) == 0:
        return [np.full(len(ticks), np.nan) for _ in names]
    _, first = np.unique(recs["tick"], return_index=True)
    kept = recs[first]
    at = np.minimum(np.searchsorted(kept["tick"], ticks), len(kept) - 1)
    found = kept["tick"][at] == ticks
    return [np.where(found, kept[name][at], np.nan) for name in names]


def joined_records(chunks: list[np.ndarray], dtype: np.dtype) -> np.ndarray:
    """The records of ``chunks`` (contiguous arrays of ``dtype``, as received) in one array. Their bytes joined:
    ``np.concatenate`` promotes the structured dtype of each pair of chunks in Python (numpy 2), many times slower
    for a flight's samples (docs/performance.md#a-flights-files)."""
    return np.frombuffer(b"".join(chunks), dtype=dtype)


class TelemetryLogger:
    """Live: the status stream (armed, offboard start, the newest tick) is followed as it arrives, a sample
    (up to hundreds of ticks) at a time with numpy. The state, setpoint and actuator samples are only kept,
    and joined by tick when :meth:`rows` is asked for: at tens of thousands of ticks per second the logger
    must not compete with the vehicle for the machine's two cores."""

    def __init__(self, session: zenoh.Session, vehicle: str, period: float, start: str = "offboard") -> None:
        if start not in ("offboard", "armed"):
            raise ValueError(f"start {start!r}: expected 'offboard' or 'armed'")
        self.period = period
        self.start = start
        self.last_armed_tick = -1
        self._raw: dict[str, list[np.ndarray]] = {s: [] for s in telemetry.STREAMS if s != "status"}
        self._flown: list[np.ndarray] = []  # ticks whose status says: armed, in this offboard flight
        self.last_tick = -1
        self.last_status: dict | None = None
        self.flight_start_tick = -1
        self.malformed = 0
        self._published: list[tuple[int, float]] = []  # (a status batch's last tick, its publication time [s])
        # Each stream's samples wait in a FIFO channel inside Zenoh (no Python runs when one arrives, so the
        # logger wakes no thread per sample); drain() takes them. A full channel holds Zenoh back, and with it a
        # vehicle whose publishers wait (fly's) or drop (up's): the capacity covers minutes of samples.
        # sensor mode: the ground truth beside the estimate, and what the estimator took
        self._sensing: dict[str, list[np.ndarray]] = {s: [] for s in telemetry.SENSING}
        self._battery: list[np.ndarray] = []  # a battery's status records (none kept for an ideal supply)
        self._subs = [
            (stream, session.declare_subscriber(telemetry.key(vehicle, stream), zenoh.handlers.FifoChannel(CHANNEL)))
            for stream in (*telemetry.STREAMS, *telemetry.SENSING, telemetry.MISSION)
        ]
        self.mission: dict | None = None  # the newest mission document (quadsitl.telemetry.decode_mission)
        self.mission_reached: list[tuple[int, float]] = []  # its (seq, simulated time [s]) reached

    def _received(self) -> list[tuple[str, bytes, zenoh.Timestamp | None]]:
        out = []
        for stream, sub in self._subs:
            while (sample := sub.try_recv()) is not None:
                out.append((stream, sample.payload.to_bytes(), sample.timestamp))
        return out

    def drain(self) -> int:
        """File what arrived; follow the status stream. Returns how many samples arrived."""
        received = self._received()
        for stream, data, stamp in received:
            if stream == telemetry.MISSION:
                try:
                    self.mission = telemetry.decode_mission(data)
                    self.mission_reached = self.mission["reached"]
                except ValueError:
                    self.malformed += 1
                continue
            size = DTYPES[stream].itemsize
            if not data or len(data) % size:
                self.malformed += 1
                continue
            recs = np.frombuffer(data, dtype=DTYPES[stream])
            if stream in self._sensing:
                self._sensing[stream].append(recs)
                continue
            if stream != "status":
                self._raw[stream].append(recs)
                continue
            if np.isfinite(recs["battery_remaining"]).any():
                self._battery.append(recs)
            self.last_status = {name: int(recs[-1][name]) for name in STATUS_FIELDS}
            self.last_tick = max(self.last_tick, int(recs["tick"].max()))
            if stamp is not None:  # the publisher's clock when the batch went out (the autopilot's, on its machine)
                self._published.append((int(recs["tick"][-1]), stamp.get_time().timestamp()))
            start, armed = recs["offboard_tick"], recs["armed"] != 0
            if self.start == "armed":
                self._follow_armed(recs["tick"], armed)
                continue
            if self.flight_start_tick < 0:
                flying = np.flatnonzero((start >= 0) & armed)
                if flying.size:
                    self.flight_start_tick = int(start[flying[0]])
            if self.flight_start_tick >= 0:  # a later offboard segment is not part of this flight
                self._flown.append(recs["tick"][(start == self.flight_start_tick) & armed])
        return len(received)

    def _follow_armed(self, ticks: np.ndarray, armed: np.ndarray) -> None:
        """A mission's flight: every armed tick from the first one on."""
        if self.flight_start_tick < 0 and armed.any():
            self.flight_start_tick = int(ticks[np.flatnonzero(armed)[0]])
        if self.flight_start_tick >= 0:
            kept = ticks[armed & (ticks >= self.flight_start_tick)]
            self._flown.append(kept)
            if kept.size:
                self.last_armed_tick = max(self.last_armed_tick, int(kept.max()))

    def _joined(self) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """The flight's ticks for which all four streams arrived, sorted, and each stream's records for them
        (the newest record of a tick that came twice)."""
        flown = np.unique(np.concatenate(self._flown)) if self._flown else np.zeros(0, dtype=np.uint64)
        latest = {}
        for stream, chunks in self._raw.items():
            recs = joined_records(chunks, DTYPES[stream])
            ticks = recs["tick"][::-1]  # the newest first, so that unique keeps it
            _, first = np.unique(ticks, return_index=True)
            latest[stream] = recs[::-1][first]
            flown = np.intersect1d(flown, latest[stream]["tick"], assume_unique=True)
        return flown, {s: r[np.searchsorted(r["tick"], flown)] for s, r in latest.items()}

    def complete(self) -> set[int]:
        """Flight ticks (counted from the flight's start) for which all four streams arrived, and in sensor mode the
        truth's and the sensors': a record still on its way must not become a row's NaN."""
        flown, _ = self._joined()
        for chunks in self._sensing.values():  # sensor mode: theirs too (their columns would be NaN without them)
            if chunks:
                flown = np.intersect1d(flown, np.concatenate([r["tick"] for r in chunks]))
        return set((flown.astype(np.int64) - self.flight_start_tick).tolist())

    def wait_for(self, ticks: int, quiet: float) -> bool:
        """Drain until the flight's first ``ticks`` ticks have arrived in every stream, or until ``quiet`` [s, wall]
        passes without one more of them: telemetry that keeps filling the flight (a loaded machine delivering a
        backlog) is waited for; a tick that never comes is not, though the vehicle may go on publishing later ones.
        Whether they all came."""
        wanted = set(range(ticks))
        have, last = len(wanted & self.complete()), time.monotonic()
        while have < ticks:
            asked = time.monotonic()  # before the drain: quiet only if a drain that began after it brought nothing
            if self.drain() and (now := len(wanted & self.complete())) > have:
                have, last = now, time.monotonic()
                continue
            if asked - last >= quiet:
                return False
            time.sleep(0.02)
        return True

    def absent(self, ticks: int) -> dict[str, int]:
        """How many of the flight's first ``ticks`` ticks each stream lacks (status: as flown in this flight)."""
        wanted = np.arange(ticks, dtype=np.int64) + self.flight_start_tick
        flown = np.concatenate(self._flown) if self._flown else np.zeros(0, dtype=np.uint64)
        got = {s: joined_records(c, DTYPES[s])["tick"] for s, c in self._raw.items()} | {"status": flown}
        return {s: int(ticks - np.isin(wanted, t.astype(np.int64)).sum()) for s, t in got.items()}

    def rows(self) -> dict[int, list[float]]:
        """Flight tick → row in telemetry_csv.COLUMNS order (sensor mode's and the battery's after them, when there
        are any: telemetry_csv.names_of), t = 0 at the flight's first tick."""
        flown, recs = self._joined()
        s, r, a = recs["state"], recs["setpoint"], recs["actuators"]
        k = flown.astype(np.int64) - self.flight_start_tick
        columns = [k * self.period, s["x"], s["y"], s["z"], -s["z"], s["vx"], s["vy"], s["vz"], s["roll"],
                   s["pitch"], s["yaw"], s["p"], s["q"], s["r"], r["altitude_ref"], r["roll_ref"], r["pitch_ref"],
                   r["yaw_ref"], r["x_ref"], r["y_ref"], a["u1"], a["u2"], a["u3"], a["u4"], a["f1"], a["f2"], a["f3"],
                   a["f4"]]  # fmt: skip
        if any(self._sensing.values()):  # sensor mode: the truth's and the sensors' (telemetry_csv.SENSING_COLUMNS)
            for stream, chunks in self._sensing.items():
                columns += by_tick(chunks, stream, flown, telemetry.layout(stream)[1][2:])
        if self._battery:  # a battery: its columns last (telemetry_csv.BATTERY_COLUMNS)
            columns += by_tick(self._battery, "status", flown, telemetry.BATTERY_FIELDS)
        table = np.column_stack(columns) if len(k) else np.zeros((0, len(columns)))
        return dict(zip(k.tolist(), table.tolist()))

    def reached(self) -> list[dict]:
        """The mission items reached in this flight, as the vehicle's mission document says (exact: the tick after
        which each was reached, not when the ground station heard of it): {"seq", "t"}, t [s] from the flight's
        start."""
        if self.flight_start_tick < 0:
            return []
        start = self.flight_start_tick * self.period
        return [{"seq": seq, "t": round(t - start, 6)} for seq, t in self.mission_reached if t >= start]

    def flight_time(self, tick: int | None = None) -> float:
        """Simulated seconds flown under the trajectory at ``tick`` (default: the newest tick seen; −1 before the
        flight starts)."""
        if self.flight_start_tick < 0:
            return -1.0
        return ((self.last_tick if tick is None else tick) - self.flight_start_tick) * self.period

    def pace(self, first_tick: int, last_tick: int) -> tuple[int, float] | None:
        """How fast the vehicle went from ``first_tick`` to ``last_tick``: (ticks, wall seconds) between the
        publication times of two status batches, the first that ends at or after first_tick and the last that ends at
        or before last_tick (the autopilot stamps each batch as it goes out: the figure is the vehicle's own pace,
        without this logger's delays). None without two such batches, or without timestamps."""
        inside = [(tick, t) for tick, t in self._published if first_tick <= tick <= last_tick]
        if len(inside) < 2 or inside[-1][1] <= inside[0][1]:
            return None
        return inside[-1][0] - inside[0][0], inside[-1][1] - inside[0][1]

    def close(self) -> None:
        for _stream, sub in self._subs:
            sub.undeclare()
        self._subs = []
