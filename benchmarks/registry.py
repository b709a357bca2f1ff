"""The registry of ``quadsitl bench``'s sections (:mod:`benchmarks.sections`, one module each), in the order a run
measures them (:data:`SECTIONS`); each module's ``SECTION`` (:class:`benchmarks.sections.base.Section`) names it for
``--only`` and says how to run it."""

from __future__ import annotations

from collections.abc import Sequence

from benchmarks.sections import batch, coldstart, costs, dashboard, fanout, fleet, lockstep, realtime
from benchmarks.sections.base import Section

SECTIONS: tuple[Section, ...] = tuple(
    m.SECTION for m in (coldstart, lockstep, costs, fanout, realtime, dashboard, batch, fleet)
)
PARTS = tuple(s.name for s in SECTIONS)  # the names --only takes


def selected(parts: Sequence[str]) -> list[Section]:
    """The sections named in ``parts``, in the registry's order."""
    return [s for s in SECTIONS if s.name in parts]


def unavailable(sections: Sequence[Section]) -> dict[str, tuple[str, tuple[str, ...]]]:
    """{name: (what it lacks and how to get it, the JSON keys it leaves out)} for each of ``sections`` that cannot run
    on this machine."""
    return {s.name: (why, s.absent) for s in sections if s.missing is not None and (why := s.missing())}


def left_out(sections: Sequence[Section], full: bool, named: bool) -> dict[str, tuple[str, tuple[str, ...]]]:
    """{name: (why, the JSON keys it leaves out)} for each of ``sections`` that has no quick form, in a run without
    ``full`` (``--full``) whose sections were not ``named`` (``--only``): the default run leaves those out."""
    if full or named:
        return {}
    return {s.name: (f"it runs with --full or --only {s.name}", s.absent) for s in sections if s.full_only}
