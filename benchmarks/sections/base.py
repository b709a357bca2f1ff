"""What a section of ``quadsitl bench`` is (:class:`Section`) and what it is given (:class:`Context`)."""

from __future__ import annotations

import argparse
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from benchmarks.report import Report


@dataclass
class Context:
    """A bench run, as its sections see it: the ``report`` they add figures to, a scratch directory ``work`` (gone
    with the run), the command's options ``args``, the fleet sizes ``--fleet-sizes`` asked for, and what one section
    measured for those after it: the blocking ping-pong's round trips per second (``ping``) and ``lockstep_ratio``
    (``fly``'s tick rate over the fastest ping-pong's), once the lockstep section ran."""

    report: Report
    work: Path
    args: argparse.Namespace
    sizes: list[int] = field(default_factory=list)
    ping: float | None = None
    lockstep_ratio: float | None = None

    @property
    def full(self) -> bool:
        """``--full``: every section whole; else each in its quick form (the figures its goals need)."""
        return bool(self.args.full)


@dataclass(frozen=True)
class Section:
    """One section of the report, run by ``--only NAME`` or by default: ``run(context)`` adds its figures and returns
    its own keys of the JSON report. ``compiled``: its processes load the compiled equations, which are compiled into
    numba's cache once, before the first section that is not ``cold`` (a process compiling as it starts would miss
    the bench's wait for it); ``cold``: it measures that compilation itself, so it runs before. ``missing()``: what
    this machine lacks to run it and how to get it, or None (an optional section, skipped with one line saying so);
    ``absent``: the JSON keys it then leaves out; ``full_only``: it has no quick form, and a default run leaves it out
    (it runs with ``--full``, or named with ``--only``)."""

    name: str
    run: Callable[[Context], dict[str, object]]
    compiled: bool = True
    cold: bool = False
    missing: Callable[[], str | None] | None = None
    absent: tuple[str, ...] = ()
    full_only: bool = False
