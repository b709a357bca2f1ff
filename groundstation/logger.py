"""A Zenoh subscriber that logs a vehicle's telemetry into telemetry.csv rows.

It joins the four streams by tick and keeps the ticks flown in offboard (``offboard_tick`` ≥ 0), with
t = (tick − offboard_tick)·T so that t = 0 is the first tick flown under the reference trajectory. Samples
wait in Zenoh's FIFO channels until ``drain`` files them by tick; decoding happens in ``rows``.
"""

from __future__ import annotations

import threading

import zenoh

from quadsitl import telemetry


class TelemetryLogger:
    """Live: the status stream (armed, offboard start, the newest tick) is decoded as it arrives. The
    state, setpoint and actuator payloads are only filed by tick and decoded when :meth:`rows` is asked
    for: at 10,000 ticks/s the logger must not compete with the vehicle for the machine's two cores."""

    def __init__(self, session: zenoh.Session, vehicle: str, period: float) -> None:
        self.period = period
        self._raw: dict[str, dict[int, bytes]] = {s: {} for s in telemetry.STREAMS if s != "status"}
        self._flown: set[int] = set()  # ticks whose status says: armed, in this offboard flight
        self.last_tick = -1
        self.last_status: dict | None = None
        self.flight_start_tick = -1
        self.malformed = 0
        # The callbacks only append (one lock, no decoding): a Zenoh callback must never block.
        self._lock = threading.Lock()
        self._inbox: list[tuple[str, bytes]] = []
        self._subs = [
            (stream, session.declare_subscriber(telemetry.key(vehicle, stream), self._callback(stream)))
            for stream in telemetry.STREAMS
        ]

    def _callback(self, stream: str):
        inbox, lock = self._inbox, self._lock

        def cb(sample: zenoh.Sample) -> None:
            data = sample.payload.to_bytes()
            with lock:
                inbox.append((stream, data))

        return cb

    def _received(self) -> list[tuple[str, bytes]]:
        with self._lock:
            out = self._inbox[:]
            del self._inbox[:]
        return out

    def drain(self) -> None:
        """File what arrived by tick; follow the status stream."""
        for stream, data in self._received():
            try:
                recs = telemetry.records(stream, data)
            except ValueError:
                self.malformed += 1
                continue
            if stream != "status":
                size = telemetry.STREAMS[stream].size
                raw = self._raw[stream]
                for i, rec in enumerate(recs):
                    raw[rec[0]] = data[i * size : (i + 1) * size]
                continue
            for tick, _t, armed, mode, failsafe, start in recs:
                self.last_status = {"tick": tick, "armed": armed, "mode": mode, "failsafe": failsafe,
                                    "offboard_tick": start}  # fmt: skip
                self.last_tick = max(self.last_tick, tick)
                if start < 0 or not armed:
                    continue
                if self.flight_start_tick < 0:
                    self.flight_start_tick = start
                if start == self.flight_start_tick:  # a later offboard segment is not part of this flight
                    self._flown.add(tick)

    def complete(self) -> set[int]:
        """Flight ticks (counted from the flight's start) for which all four streams arrived."""
        start = self.flight_start_tick
        raw = self._raw.values()
        return {tick - start for tick in self._flown if all(tick in r for r in raw)}

    def rows(self) -> dict[int, list[float]]:
        """Flight tick → row in telemetry_csv.COLUMNS order, t = 0 at the flight's first tick."""
        start = self.flight_start_tick
        out: dict[int, list[float]] = {}
        for k in sorted(self.complete()):
            tick = k + start
            s, r, a = (telemetry.decode(stream, self._raw[stream][tick]) for stream in ("state", "setpoint",
                                                                                          "actuators"))  # fmt: skip
            out[k] = [
                k * self.period, s["x"], s["y"], s["z"], -s["z"], s["vx"], s["vy"], s["vz"], s["roll"], s["pitch"],
                s["yaw"], s["p"], s["q"], s["r"], r["altitude_ref"], r["roll_ref"], r["pitch_ref"], r["yaw_ref"],
                a["u1"], a["u2"], a["u3"], a["u4"], a["f1"], a["f2"], a["f3"], a["f4"],
            ]  # fmt: skip
        return out

    def flight_time(self) -> float:
        """Simulated seconds flown under the trajectory so far (−1 before the flight starts)."""
        if self.flight_start_tick < 0:
            return -1.0
        return (self.last_tick - self.flight_start_tick) * self.period

    def close(self) -> None:
        for _stream, sub in self._subs:
            sub.undeclare()
        self._subs = []
