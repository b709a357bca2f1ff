"""A Zenoh subscriber that logs a vehicle's telemetry into telemetry.csv rows.

It joins the four streams by tick and keeps the ticks flown in offboard (``offboard_tick`` ≥ 0), with
t = (tick − offboard_tick)·T so that t = 0 is the first tick flown under the reference trajectory. The
Zenoh callback only appends bytes to a list (it never blocks); decoding happens in ``drain``.
"""

from __future__ import annotations

import threading

import zenoh

from quadsitl import telemetry


class TelemetryLogger:
    def __init__(self, session: zenoh.Session, vehicle: str, period: float) -> None:
        self.period = period
        self._lock = threading.Lock()
        self._inbox: list[tuple[str, bytes]] = []
        self._partial: dict[int, dict[str, dict]] = {}
        self.rows: dict[int, list[float]] = {}  # flight tick → row in telemetry_csv.COLUMNS order
        self.last_tick = -1
        self.last_status: dict | None = None
        self.flight_start_tick = -1
        self.malformed = 0
        self._subs = [
            session.declare_subscriber(telemetry.key(vehicle, stream), self._callback(stream))
            for stream in telemetry.STREAMS
        ]

    def _callback(self, stream: str):
        def cb(sample: zenoh.Sample) -> None:
            data = sample.payload.to_bytes()
            with self._lock:
                self._inbox.append((stream, data))

        return cb

    def drain(self) -> None:
        """Decode what arrived and assemble complete ticks into rows."""
        with self._lock:
            inbox, self._inbox = self._inbox, []
        for stream, data in inbox:
            try:
                rec = telemetry.decode(stream, data)
            except ValueError:
                self.malformed += 1
                continue
            tick = int(rec["tick"])
            parts = self._partial.setdefault(tick, {})
            parts[stream] = rec
            if stream == "status":
                self.last_status = rec
                self.last_tick = max(self.last_tick, tick)
            if len(parts) == len(telemetry.STREAMS):
                del self._partial[tick]
                self._row(tick, parts)

    def _row(self, tick: int, p: dict[str, dict]) -> None:
        start = int(p["status"]["offboard_tick"])
        if start < 0 or not p["status"]["armed"]:
            return
        if self.flight_start_tick < 0:
            self.flight_start_tick = start
        if start != self.flight_start_tick:
            return  # a later offboard segment: not part of this flight
        s, r, a = p["state"], p["setpoint"], p["actuators"]
        t = (tick - start) * self.period
        self.rows[tick - start] = [
            t, s["x"], s["y"], s["z"], -s["z"], s["vx"], s["vy"], s["vz"], s["roll"], s["pitch"], s["yaw"],
            s["p"], s["q"], s["r"], r["altitude_ref"], r["roll_ref"], r["pitch_ref"], r["yaw_ref"],
            a["u1"], a["u2"], a["u3"], a["u4"], a["f1"], a["f2"], a["f3"], a["f4"],
        ]  # fmt: skip

    def flight_time(self) -> float:
        """Simulated seconds flown under the trajectory so far (−1 before the flight starts)."""
        if self.flight_start_tick < 0:
            return -1.0
        return (self.last_tick - self.flight_start_tick) * self.period

    def close(self) -> None:
        for sub in self._subs:
            sub.undeclare()
        self._subs = []
