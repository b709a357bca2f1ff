"""The real-time set-up the bench's fleets run under, where the machine permits it: SCHED_FIFO at
:data:`benchmarks.floor.FIFO_PRIORITY` (as ``chrt -f``), and every core kept out of slow idle states (as ``quadsitl up
--cores-awake``); each with the one line that says why this machine cannot."""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator

from benchmarks.floor import FIFO_PRIORITY
from quadsitl.cli_util import UsageError
from quadsitl.process_util import hold_cores_awake


@contextlib.contextmanager
def fifo_scheduling(enabled: bool) -> Iterator[None]:
    """While entered (and ``enabled``), this process runs under SCHED_FIFO at FIFO_PRIORITY, so the processes it
    starts inherit it, as under ``chrt -f``; PermissionError without root or CAP_SYS_NICE."""
    if not enabled:
        yield
        return
    policy, param = os.sched_getscheduler(0), os.sched_getparam(0)
    os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(FIFO_PRIORITY))
    try:
        yield
    finally:
        os.sched_setscheduler(0, policy, param)


def raise_to_fifo(pid: int) -> None:
    """Every thread of process ``pid`` to SCHED_FIFO at FIFO_PRIORITY (threads it starts later inherit it)."""
    for tid in os.listdir(f"/proc/{pid}/task"):
        with contextlib.suppress(ProcessLookupError):  # a thread that has just ended
            os.sched_setscheduler(int(tid), os.SCHED_FIFO, os.sched_param(FIFO_PRIORITY))


def fifo_missing() -> str | None:
    """Why this machine cannot run a fleet under SCHED_FIFO (one line), or None when it can."""
    try:
        with fifo_scheduling(True):
            return None
    except (PermissionError, AttributeError, OSError) as exc:
        return f"SCHED_FIFO is not permitted here ({exc}): it needs root or CAP_SYS_NICE"


@contextlib.contextmanager
def cores_awake(enabled: bool) -> Iterator[None]:
    """While entered (and ``enabled``), every core is kept out of slow idle states, as ``quadsitl up --cores-awake``
    keeps them (:func:`quadsitl.process_util.hold_cores_awake`); UsageError where that is refused."""
    if not enabled:
        yield
        return
    fd = hold_cores_awake()
    try:
        yield
    finally:
        os.close(fd)


def awake_missing() -> str | None:
    """Why this machine cannot keep its cores awake for a fleet (one line), or None when it can."""
    try:
        with cores_awake(True):
            return None
    except UsageError as exc:
        return str(exc)
