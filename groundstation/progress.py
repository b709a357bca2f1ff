"""Progress of a long run on stderr: simulated time done / total, real-time factor, ETA.

On a terminal it is a ``rich`` progress bar; anywhere else (a pipe, a CI log) it is a plain line at
most every ``interval`` wall seconds, and, if any such line was printed, a last one when the run ends:

    gcs: flight t = 12.00 / 30 s, 6.1× real time, ETA 3 s
    gcs: flight t = 30.00 / 30 s, 6.0× real time, done in 5.0 s

Runs shorter than ``interval`` wall seconds print nothing in plain mode. ``update`` is cheap enough to
call from a loop running at any rate: it reads the clock and returns unless ``refresh`` seconds
(0.1 s: 10 Hz) have passed since the last refresh.
"""

from __future__ import annotations

import sys
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import TextIO


def format_eta(seconds: float) -> str:
    """'7 s', '4:05' (min:s) or '1:02:03' (h:min:s)."""
    s = max(0, round(seconds))
    if s < 60:
        return f"{s} s"
    h, rest = divmod(s, 3600)
    m, sec = divmod(rest, 60)
    return f"{h}:{m:02d}:{sec:02d}" if h else f"{m}:{sec:02d}"


class FlightProgress:
    """Simulated seconds done out of ``total_s``; wall time counts from construction.

    ``enabled=False`` (``--quiet``) makes every method a no-op. ``interactive`` chooses the rich bar
    (True) or plain lines (False); by default, the bar when ``stream`` is a terminal. ``rich`` is
    imported only for the bar.
    """

    def __init__(
        self,
        total_s: float,
        enabled: bool = True,
        *,
        label: str = "flight",
        stream: TextIO | None = None,
        clock: Callable[[], float] = time.monotonic,
        interactive: bool | None = None,
        interval: float = 2.0,
        refresh: float = 0.1,
    ) -> None:
        self.total = float(total_s)
        self.enabled = enabled
        self.label = label
        self.stream = sys.stderr if stream is None else stream
        self.clock = clock
        self.interval = interval
        self.refresh = refresh
        self.start = clock()
        self.done_s = 0.0
        self.printed = 0  # plain lines printed
        self._last_refresh = -float("inf")
        self._last_line = self.start
        self._bar = None
        self._task = None
        self._closed = not enabled
        if not enabled:
            return
        if interactive is None:
            isatty = getattr(self.stream, "isatty", None)
            interactive = bool(isatty and isatty())
        self.interactive = interactive  # the bar starts at the first update: an error before leaves no trace

    # ---- the numbers -----------------------------------------------------------------------------

    def rate(self, now: float) -> float:
        """Real-time factor: simulated seconds per wall second so far (0 before any wall time)."""
        wall = now - self.start
        return self.done_s / wall if wall > 0 else 0.0

    def eta(self, now: float) -> float | None:
        """Wall seconds left at the rate so far (None while the rate is unknown)."""
        rtf = self.rate(now)
        return max(self.total - self.done_s, 0.0) / rtf if rtf > 0 else None

    def line(self, now: float, final: bool = False) -> str:
        """The plain progress line."""
        head = f"{self.label} t = {self.done_s:.2f} / {self.total:g} s, {self.rate(now):.1f}× real time"
        if final:
            return f"{head}, done in {now - self.start:.1f} s"
        eta = self.eta(now)
        return f"{head}, ETA {'?' if eta is None else format_eta(eta)}"

    # ---- reporting -------------------------------------------------------------------------------

    def update(self, sim_s: float) -> None:
        """``sim_s`` simulated seconds done (clamped to [0, total])."""
        if self._closed:
            return
        self.done_s = min(max(sim_s, 0.0), self.total)
        now = self.clock()
        if now - self._last_refresh < self.refresh:
            return
        self._last_refresh = now
        if self.interactive:
            if self._bar is None:
                self._start_bar()
            self._refresh_bar(now)
        elif now - self._last_line >= self.interval:
            self._last_line = now
            self._print(self.line(now))

    def close(self, completed: bool = True) -> None:
        """End the display. A completed run gets its last numbers: the bar's final state, or (plain
        mode, only if a line was printed) a closing line. Idempotent."""
        if self._closed:
            return
        self._closed = True
        now = self.clock()
        if self._bar is not None:
            if completed:
                self._refresh_bar(now, final=True)
            self._bar.stop()
            self._bar = None
        elif completed and self.printed:
            self._print(self.line(now, final=True))

    def __enter__(self) -> FlightProgress:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        self.close(completed=exc_type is None)

    def _print(self, text: str) -> None:
        self.printed += 1
        print(text, file=self.stream, flush=True)

    # ---- the rich bar ----------------------------------------------------------------------------

    def _start_bar(self) -> None:
        from rich.console import Console
        from rich.progress import BarColumn, Progress, TextColumn

        self._bar = Progress(
            TextColumn("{task.description}"),
            BarColumn(),
            TextColumn("{task.completed:.2f} / {task.total:g} s"),
            TextColumn("{task.fields[rtf]}"),
            TextColumn("{task.fields[eta]}"),
            console=Console(file=self.stream),
            refresh_per_second=10,
        )
        self._task = self._bar.add_task(self.label, total=self.total or 1.0, rtf="", eta="")
        self._bar.start()

    def _refresh_bar(self, now: float, final: bool = False) -> None:
        rtf = self.rate(now)
        if final:
            eta = f"done in {now - self.start:.1f} s"
        else:
            left = self.eta(now)
            eta = "ETA ?" if left is None else f"ETA {format_eta(left)}"
        self._bar.update(self._task, completed=self.done_s, rtf=f"{rtf:.1f}× real time" if rtf else "", eta=eta)


@contextmanager
def announce_if_slow(
    line: str, enabled: bool = True, after: float = 1.0, stream: TextIO | None = None
) -> Iterator[None]:
    """Print ``line`` (with " ...") on ``stream`` (stderr) if the block is still running ``after`` wall seconds on,
    and how long it took when it ends: for a wait that is long once (compiling) and short afterwards."""
    out = stream or sys.stderr
    start = time.monotonic()
    said = threading.Event()

    def say() -> None:
        said.set()
        print(f"{line} ...", file=out, flush=True)

    timer = threading.Timer(after, say)
    timer.daemon = True
    if enabled:
        timer.start()
    try:
        yield
    finally:
        timer.cancel()
        if said.is_set():
            print(f"{line}: done in {time.monotonic() - start:.1f} s", file=out, flush=True)
