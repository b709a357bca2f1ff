"""The ground station's telemetry logger without Zenoh: what it waits for after a flight, and what it says a
stream lacks."""

from __future__ import annotations

import time

import numpy as np

from groundstation.logger import DTYPES, TelemetryLogger
from quadsitl import telemetry

STREAMS = [s for s in telemetry.STREAMS if s != "status"]


def payload(stream: str, ticks: range) -> bytes:
    """A sample of ``stream`` as the autopilot publishes it: records for ``ticks``, flown offboard from tick 100."""
    r = np.zeros(len(ticks), dtype=DTYPES[stream])
    r["tick"] = list(ticks)
    if stream == "status":
        r["armed"], r["offboard_tick"] = 1, 100
    return r.tobytes()


def logger_fed(parts: list[tuple[float, range, tuple[str, ...]]], then: tuple[str, ...] = ()) -> TelemetryLogger:
    """A logger whose samples arrive on a timeline: each part (due [s after now], ticks, streams) arrives when due;
    after the last part, the streams ``then`` go on at every drain, for ever, with ticks after the flight's."""
    logger = TelemetryLogger.__new__(TelemetryLogger)  # drain() and what it files, without a session
    logger.period, logger.start, logger.flight_start_tick, logger.last_tick = 0.001, "offboard", -1, -1
    logger._raw, logger._flown, logger._truth, logger._published = {s: [] for s in STREAMS}, [], [], []
    logger.malformed, logger.last_status = 0, None
    start, pending = time.monotonic(), list(parts)
    next_tick = [10_000]

    def received() -> list:
        due = [p for p in pending if time.monotonic() - start >= p[0]]
        for p in due:
            pending.remove(p)
        if not pending and then:
            due.append((0.0, range(next_tick[0], next_tick[0] + 1), then))
            next_tick[0] += 1
        return [(s, payload(s, ticks), None) for _, ticks, streams in due for s in streams]

    logger._received = received
    return logger


def test_after_the_flight_the_logger_waits_while_telemetry_keeps_coming_not_for_a_stream_that_stopped():
    every = ("status", *STREAMS)
    # A backlog delivered slowly: five parts 0.15 s apart, 0.6 s in all, twice the quiet time waited for.
    slow = logger_fed([(0.15 * i, range(100 + 20 * i, 120 + 20 * i), every) for i in range(5)])
    began = time.monotonic()
    assert slow.wait_for(100, quiet=0.3)
    assert time.monotonic() - began > 0.55  # it waited for the last part
    assert slow.complete() == set(range(100)) and slow.absent(100) == dict.fromkeys([*STREAMS, "status"], 0)
    # The actuators stop after tick 159 while the other streams go on for ever: the wait ends once the quiet time
    # passes without another of the flight's ticks (no hang on the samples that keep coming), and says what lacks.
    others = ("status", "state", "setpoint")
    stopped = logger_fed([(0.0, range(100, 160), every), (0.0, range(160, 200), others)], then=others)
    began = time.monotonic()
    assert not stopped.wait_for(100, quiet=0.3)
    assert time.monotonic() - began > 0.25  # it waited the quiet time
    assert stopped.complete() == set(range(60))
    assert stopped.absent(100) == {"state": 0, "setpoint": 0, "actuators": 40, "status": 0}
