"""The ground station's telemetry logger without Zenoh: what it waits for after a flight, what it says a stream
lacks, how it joins its samples and measures the flight's pace."""

from __future__ import annotations

import time
from types import SimpleNamespace

import numpy as np
import pytest

from groundstation.logger import DTYPES, TelemetryLogger, joined_records
from groundstation.telemetry_csv import COLUMNS, SENSING_COLUMNS, names_of
from quadsitl import telemetry

STREAMS = [s for s in telemetry.STREAMS if s != "status"]


class NoSession:
    """A Zenoh session stand-in whose subscribers never receive: the logger is made as the ground station makes it,
    and each test hands it samples itself."""

    def declare_subscriber(self, _key: str, _handler: object) -> SimpleNamespace:
        return SimpleNamespace(try_recv=lambda: None)


def new_logger() -> TelemetryLogger:
    return TelemetryLogger(NoSession(), "v1", 0.001)


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
    logger = new_logger()
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


def test_the_pace_is_measured_between_batches_inside_the_flight():
    logger = new_logger()
    logger._published = [(90, 0.9), (104, 1.0), (160, 1.5), (208, 1.9), (260, 2.5)]  # (last tick, publication [s])
    assert logger.pace(100, 250) == (104, pytest.approx(0.9))  # from the batch ending at 104 to the one at 208
    assert logger.pace(100, 150) is None  # one batch only: no pace


def test_the_logger_joins_its_samples_keeping_a_ticks_newest_record_and_only_ticks_every_stream_has():
    """rows() from samples as drain() files them (arrays on the received bytes): each stream's records joined, a
    tick sent twice taken from its newest sample, a tick one stream lacks left out (finish() calls it missing)."""

    def sample(stream: str, ticks, x: float = 0.0) -> np.ndarray:
        r = np.zeros(len(ticks), dtype=DTYPES[stream])
        r["tick"] = ticks
        if stream == "state":
            r["x"] = x
        return np.frombuffer(r.tobytes(), dtype=DTYPES[stream])  # read-only, as received

    logger = new_logger()
    logger.flight_start_tick = 100
    logger._flown = [np.arange(100, 110, dtype=np.uint64)]
    logger._raw = {s: [sample(s, range(100, 105)), sample(s, range(105, 110))] for s in STREAMS}
    logger._raw["state"].append(sample("state", [104], x=7.0))  # tick 104 again, newer
    logger._raw["actuators"][1] = sample("actuators", [105, 106, 108, 109])  # tick 107 never came
    rows = logger.rows()
    assert sorted(rows) == [0, 1, 2, 3, 4, 5, 6, 8, 9] and logger.complete() == set(rows)
    assert rows[4][0] == pytest.approx(0.004) and rows[4][1] == 7.0 and rows[3][1] == 0.0  # t, x
    chunks = logger._raw["setpoint"]
    assert (joined_records(chunks, DTYPES["setpoint"]) == np.concatenate(chunks)).all()
    assert joined_records([], DTYPES["state"]).shape == (0,)


@pytest.mark.parametrize("late_stream", telemetry.SENSING)
def test_on_sensors_the_logger_waits_for_the_truth_and_the_sensors_still_on_their_way(late_stream):
    """The truth's and the sensors' records come on streams of their own: the last of them may still be on their way
    when the other four streams are complete. Waited for, so that no row's columns are NaN for a record that was
    coming (a telemetry.csv that differed from run to run at its last rows)."""
    every = ("status", *STREAMS)
    other = tuple(s for s in telemetry.SENSING if s != late_stream)
    late = logger_fed([(0.0, range(100, 200), every + other), (0.0, range(100, 150), (late_stream,)),
                       (0.3, range(150, 200), (late_stream,))])  # fmt: skip
    began = time.monotonic()
    assert late.wait_for(100, quiet=1.0)
    assert time.monotonic() - began > 0.25  # it waited for the late stream's last records
    rows = late.rows()
    assert sorted(rows) == list(range(100))
    table = np.array([rows[k] for k in range(100)])
    names = names_of(table.shape[1])  # the status's zeros say a battery: its columns last
    assert names[len(COLUMNS) : len(COLUMNS) + len(SENSING_COLUMNS)] == SENSING_COLUMNS and not np.isnan(table).any()
