"""Log download over MAVLink, as PX4's ``MavlinkLogHandler`` serves it (https://mavlink.io/en/services/ftp.html is
the other way; this is the LOG_* protocol QGroundControl's Log Download and MAVSDK's ``log_files`` use).

- LOG_REQUEST_LIST (start, end): the logs in the directory, oldest first, are numbered 0..n−1 as listed now, and a
  LOG_ENTRY goes out for each of ids start..end (0xFFFF: to the last): its size [bytes] and time_utc (the file's
  modification time [s]). With no logs, one LOG_ENTRY with num_logs 0 (as PX4 before v1.15 and ArduPilot answer;
  MAVSDK reports it as no log files).
- LOG_REQUEST_DATA (id, ofs, count): LOG_DATA of up to 90 bytes each from ofs, until count bytes or the size
  listed, on the link that asked. As PX4: nothing for an id not listed, before any listing, or an ofs past the end.
- LOG_REQUEST_END: the data stops. LOG_ERASE: every log is deleted, except the one being written (the vehicle is
  armed), which stays listed.

The data goes out a burst at a time (:meth:`LogServer.pump`), within a wall-clock budget, so the control loop
keeps its ticks."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

DATA_LEN = 90  # [bytes] LOG_DATA.data
ALL = 0xFFFF  # LOG_REQUEST_LIST.end: to the last log


@dataclass(frozen=True)
class Entry:
    """A listed log: its file, and its size [bytes] and modification time [s UTC] when listed."""

    path: Path
    size: int
    time_utc: int


@dataclass
class _Transfer:
    entry_id: int
    offset: int  # [bytes] the next LOG_DATA's
    end: int  # [bytes] where this request's data stops
    link: Any


class LogServer:
    """The logs in ``directory`` (``*.ulg`` in its dated folders; None: no logs kept), listed and sent.
    ``open_log()``: the log being written, if any (not erased)."""

    def __init__(self, directory: Path | None, open_log: Callable[[], Path | None]) -> None:
        self.directory, self.open_log = directory, open_log
        self.listed: list[Entry] | None = None  # as the last LOG_REQUEST_LIST numbered them
        self.transfer: _Transfer | None = None
        self.file = None  # the last transfer's file, open
        self.file_id = -1  # its id

    def logs(self) -> list[Path]:
        """The log files, oldest first (their names are their UTC dates and times)."""
        if self.directory is None or not self.directory.is_dir():
            return []
        return sorted(p for p in self.directory.glob("*/*.ulg") if p.is_file())

    def on_request_list(self, start: int, end: int) -> list[dict[str, int]]:
        """LOG_REQUEST_LIST → the LOG_ENTRY messages' fields."""
        self.listed = []
        for path in self.logs():
            try:
                st = path.stat()
            except OSError:  # erased meanwhile
                continue
            self.listed.append(Entry(path, st.st_size, int(st.st_mtime)))
        n = len(self.listed)
        if n == 0:
            return [{"id": 0, "num_logs": 0, "last_log_num": 0, "time_utc": 0, "size": 0}]
        last = n - 1 if end == ALL else min(end, n - 1)
        return [{"id": i, "num_logs": n, "last_log_num": last, "time_utc": self.listed[i].time_utc,
                 "size": self.listed[i].size} for i in range(start, last + 1)]  # fmt: skip

    def on_request_data(self, entry_id: int, ofs: int, count: int, link: Any) -> bool:
        """LOG_REQUEST_DATA → whether data will go out (False: as PX4, the request is dropped unanswered)."""
        if self.listed is None or entry_id >= len(self.listed):
            self.stop()
            return False
        entry = self.listed[entry_id]
        if ofs >= entry.size:
            self.stop()
            return False
        if self.file is None or self.file_id != entry_id:
            self._close_file()
            try:
                self.file = open(entry.path, "rb")  # noqa: SIM115 -- kept open across requests, closed by stop()
            except OSError:  # erased meanwhile
                self.transfer = None
                return False
            self.file_id = entry_id
        self.transfer = _Transfer(entry_id, ofs, min(entry.size, ofs + count), link)
        return True

    def on_erase(self) -> None:
        """LOG_ERASE: every log but the one being written deleted, their emptied folders too."""
        self.stop()
        keep = self.open_log()
        for path in self.logs():
            if path != keep:
                path.unlink(missing_ok=True)
        for folder in self.directory.glob("*/") if self.directory is not None and self.directory.is_dir() else ():
            if folder.is_dir() and not any(folder.iterdir()):
                folder.rmdir()
        self.listed = None

    def stop(self) -> None:
        """LOG_REQUEST_END, or a request dropped: no more data."""
        self.transfer = None
        self._close_file()

    def _close_file(self) -> None:
        if self.file is not None:
            self.file.close()
            self.file, self.file_id = None, -1

    @property
    def sending(self) -> bool:
        return self.transfer is not None

    def pump(self, budget: float, most: int) -> tuple[Any, list[dict[str, Any]]]:
        """The next burst of LOG_DATA messages' fields (at most ``most``, within ``budget`` [s] of wall time), and
        the link they go on."""
        t = self.transfer
        if t is None or self.file is None:
            return None, []
        out = []
        deadline = time.perf_counter() + budget
        self.file.seek(t.offset)
        while t.offset < t.end and len(out) < most and time.perf_counter() < deadline:
            data = self.file.read(min(DATA_LEN, t.end - t.offset))
            if not data:  # the file shrank
                break
            out.append({"id": t.entry_id, "ofs": t.offset, "count": len(data), "data": data.ljust(DATA_LEN, b"\0")})
            t.offset += len(data)
        link = t.link
        if t.offset >= t.end or not out:
            self.transfer = None  # the file stays open for the next chunk's request
        return link, out
