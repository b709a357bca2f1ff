"""The autopilot's own flight logs, kept as PX4's logger keeps them by default (``SDLOG_MODE`` 0: from arming until
disarming): one ULog per flight, ``DIR/YYYY-MM-DD/HH_MM_SS.ulg`` named by the wall clock's UTC at arming, written as
the flight goes from the telemetry records the compiled tick batches (PX4's topics: :mod:`autopilot.flight_log`),
with the status texts said meanwhile stamped on the simulated clock. :mod:`autopilot.log_protocol` serves them.

Of each batch only the first row of each :func:`kept_ms` is kept, which holds the first row of every logged topic's
interval (each a multiple of it), and the kept rows are written at least every ``WRITE_EVERY`` simulated seconds and
when the vehicle disarms."""

from __future__ import annotations

import datetime
import math
from collections.abc import Callable
from pathlib import Path

import numpy as np

from autopilot import flight_log
from autopilot.tick import Batch
from quadsitl import telemetry, ulog
from quadsitl.telemetry import SENSORS


def kept_ms(sensing: bool) -> int:
    """[ms] The interval every logged topic's is a multiple of: 10 on the true state, 5 with sensor mode's
    sensor_combined (the log keeps no more rows than its topics take)."""
    return math.gcd(*(ms for name, ms in flight_log.INTERVAL_MS.items()
                      if sensing or name not in flight_log.SENSOR_TOPICS))  # fmt: skip


WRITE_EVERY = 1.0  # [s] simulated: what a crash of the process may lose
LEVELS = {level: name for name, level in ulog.LOG_LEVELS.items()}  # MAV_SEVERITY's numbers are ULog's levels


class OnboardLog:
    """Flight logs in ``directory``. ``definitions()``: a new log's definitions (topics, parameters as they are
    now, information: :func:`autopilot.flight_log.definitions`); ``f_max`` [N], ``home`` (lat, lon [deg], alt [m
    AMSL]) and the control ``period`` [s] as :func:`autopilot.flight_log.topics_of` takes them; ``streams``: the
    batch's streams logged (the truth's and the sensors' in sensor mode)."""

    def __init__(self, directory: Path, definitions: Callable[[], ulog.Log], f_max: float, home: tuple,
                 streams: tuple[str, ...], period: float) -> None:  # fmt: skip
        self.directory, self.definitions, self.f_max, self.home = directory, definitions, f_max, home
        self.period = period
        self.streams = ("status", *streams)
        self.kept_ms = kept_ms(SENSORS in streams)
        self.dtypes = {stream: telemetry.record_dtype(stream) for stream in self.streams}
        self.writer: ulog.Writer | None = None
        self.pending: list[dict[str, np.ndarray]] = []  # kept rows not yet written, as columns
        self.strings: list[tuple[int, str, str]] = []  # said, not yet written
        self.last_kept: float | None = None  # [s] the time of the last row kept in this log
        self.last_written: float | None = None  # [s] the time of the last row written

    def add(self, batch: Batch, rows: int) -> None:
        """The batch's first ``rows`` rows (each stream's the same ticks): a flight's rows logged, a log started at
        arming and closed at disarming."""
        if rows <= 0:
            return
        records = {}
        for stream in self.streams:
            at, _ = batch.regions[stream]
            records[stream] = np.frombuffer(batch.records, dtype=self.dtypes[stream], count=rows, offset=at)
        armed = records["status"]["armed"] > 0
        t = records["status"]["t"]
        edges = np.flatnonzero(armed[1:] != armed[:-1]) + 1
        for lo, hi in zip(np.concatenate([[0], edges]).tolist(), np.concatenate([edges, [rows]]).tolist()):
            if not armed[lo]:
                self.close(until=float(t[lo]))  # "Landed, disarmed" is said on the first tick disarmed
                continue
            if self.writer is None:
                self._open(float(t[lo]))
            self._keep({stream: r[lo:hi] for stream, r in records.items()})
        if self.writer is None:
            self.strings = []  # said on the ground
        elif self.pending and (self.last_written is None or float(t[-1]) - self.last_written >= WRITE_EVERY):
            self._write()

    @property
    def path(self) -> Path | None:
        """The log being written, if any."""
        return self.writer.path if self.writer is not None else None

    def say(self, t: float, severity: int, text: str) -> None:
        """A status text said at simulated time ``t`` [s]: logged when said in a flight, or just before it (the
        rows of the ticks around it are still in the batch: "Armed" goes into the flight's log)."""
        self.strings.append((round(t * 1e6), LEVELS.get(severity, "info"), text))

    def _open(self, t: float) -> None:
        stamp = datetime.datetime.now(datetime.UTC)
        folder = self.directory / stamp.strftime("%Y-%m-%d")
        folder.mkdir(parents=True, exist_ok=True)
        path, n = folder / stamp.strftime("%H_%M_%S.ulg"), 1
        while path.exists():  # two flights in one second (lockstep runs fast)
            n += 1
            path = folder / stamp.strftime(f"%H_%M_%S_{n}.ulg")
        log = self.definitions()
        log.start_us = round(t * 1e6)
        self.writer = ulog.Writer(path, log)
        self.last_kept = self.last_written = None

    def _keep(self, records: dict[str, np.ndarray]) -> None:
        """The rows that begin a ``kept_ms`` interval, copied (the batch's buffer is written again)."""
        columns = flight_log.record_columns(records)
        kept = flight_log.sampled(columns["t"], self.kept_ms, self.last_kept)
        if len(kept):
            self.pending.append({name: values[kept].copy() for name, values in columns.items()})
            self.last_kept = float(columns["t"][kept[-1]])

    def _write(self, until: float | None = None) -> None:
        """The kept rows and the strings said (``until`` [s]: those said until then) written."""
        if self.writer is None:
            return
        strings, self.strings = self.strings, []
        if until is not None:
            stop = round(until * 1e6)
            strings, self.strings = [s for s in strings if s[0] <= stop], [s for s in strings if s[0] > stop]
        topics: list[ulog.Topic] = []
        if self.pending:
            columns = {name: np.concatenate([p[name] for p in self.pending]) for name in self.pending[0]}
            topics = flight_log.topics_of(columns, self.f_max, self.home, before=self.last_written,
                                          period=self.period)  # fmt: skip
            self.last_written = float(columns["t"][-1])
        self.writer.append(topics, strings)
        self.writer.flush()
        self.pending = []

    def close(self, until: float | None = None) -> None:
        """The open log written to its end and closed: disarmed at ``until`` [s] (what is said later is not the
        flight's), or the process ending (None)."""
        if self.writer is not None:
            self._write(until)
            self.writer.close()
            self.writer = None
