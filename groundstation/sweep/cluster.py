"""A sweep's chunks on a Dask distributed cluster: ``quadsitl sweep SPEC --cluster tcp://HOST:PORT``.

The user starts a scheduler (``dask scheduler``) and workers (``dask worker tcp://HOST:PORT``) on machines with
quadsitl installed. Each chunk of trial numbers (:func:`groundstation.sweep.run.chunks`) is one task,
:func:`groundstation.sweep.run.fly`, exactly what a local worker process runs; the results come back as they
complete and are assembled by :func:`groundstation.sweep.run.assemble`, as a local run's: the same table, to the
bit, checked to hold every trial exactly once.

A worker lost mid-sweep (its process killed, its machine gone) takes the tasks it was running with it; the
scheduler runs them again on the others, up to ``distributed.scheduler.allowed-failures`` lost workers per task
(a scheduler setting, default 3): beyond that the sweep fails with one line. A scheduler set to allow none is
warned about before the sweep starts. A result already received is released at once: a worker lost later does
not make the scheduler fly its chunk again.

``distributed`` is imported only here, and this module only by ``--cluster``: the other commands and a local
sweep do not pay for it.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import re
import time
import uuid
import warnings
from collections.abc import Callable, Iterator

from groundstation.sweep.run import ChunkResult, SweepError, SweepResult, assemble, chunks, fly, warm_up
from groundstation.sweep.spec import SweepSpec
from quadsitl.cli_util import UsageError

CONNECT_TIMEOUT = 5.0  # [s] for the scheduler to answer, and then for a first worker to be there
ADDRESS = re.compile(r"^(?:tcp://)?(\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9._-]+):(\d{1,5})$")


class ClusterError(SweepError):
    """The cluster did not run the sweep (unreachable, no workers, a chunk lost too often): one line, exit 1."""


def parse_address(option: str, text: str) -> str:
    """``tcp://HOST:PORT`` (or ``HOST:PORT``; HOST a name, an IPv4 address or a bracketed IPv6 one) → the
    scheduler's address as Dask spells it, or a UsageError naming the option and the value."""
    m = ADDRESS.match(text.strip())
    if not m or not 1 <= int(m.group(2)) <= 65535:
        raise UsageError(
            f"{option} {text!r}: expected a Dask scheduler's address tcp://HOST:PORT with PORT in 1..65535 "
            "(what `dask scheduler` prints as 'Scheduler at')"
        )
    return f"tcp://{m.group(1)}:{int(m.group(2))}"


def prepare(spec: SweepSpec | None = None) -> dict[str, str]:
    """Run on every worker before the sweep: compile the batch engine there (or load it from numba's cache), the
    version ``spec`` flies, so that compiling is not counted as flying, and say which versions of what the results
    depend on it has."""
    warm_up(spec)
    return versions()


def versions() -> dict[str, str]:
    """The versions a trial's bits depend on: quadsitl, numpy, numba, Python."""
    import platform
    from importlib import metadata

    import numba
    import numpy

    try:
        quadsitl = metadata.version("quadsitl")
    except metadata.PackageNotFoundError:  # pragma: no cover - run from a checkout not installed
        quadsitl = "not installed"
    return {
        "quadsitl": quadsitl,
        "numpy": numpy.__version__,
        "numba": numba.__version__,
        "python": platform.python_version(),
    }


def run_on_cluster(
    spec: SweepSpec,
    address: str,
    chunk: int | None = None,
    progress: Callable[[float], None] | None = None,
    warn: Callable[[str], None] | None = None,
    option: str = "--cluster",
) -> SweepResult:
    """Fly every trial of ``spec`` on the Dask scheduler at ``address`` (``tcp://HOST:PORT``), one task per
    chunk (``chunk`` trials each; by default about four per worker thread, as a local run per process).
    ``progress`` is called with the simulated vehicle-seconds done after each chunk, as they complete; ``warn``
    with one line when the workers' versions differ from this machine's or the scheduler lets a lost worker
    fail a chunk. The result's ``where`` (summary.json) holds ``cluster`` (the address) and ``workers`` (the
    Dask workers there at the start). A :class:`ClusterError` naming ``option`` when the scheduler does not
    answer within :data:`CONNECT_TIMEOUT` s, has no worker, goes away, or loses a chunk's workers more often
    than it allows."""
    warn = warn or (lambda line: None)
    with _quiet_distributed(), _connect(address, option) as client:
        try:
            client.wait_for_workers(1, timeout=CONNECT_TIMEOUT)
        except (OSError, TimeoutError, asyncio.TimeoutError):
            raise ClusterError(
                f"{option} {address}: the scheduler has no worker (none joined within "
                f"{CONNECT_TIMEOUT:g} s); start some with `dask worker {address}`"
            ) from None
        try:
            workers = _prepare_workers(client, spec, address, option, warn)
            parts = chunks(spec.trials, max(1, sum(workers.values())), chunk)
            start = time.monotonic()  # the flights only: every worker has the engine compiled
            results = _fly_chunks(client, spec, parts, address, option, progress)
            wall = time.monotonic() - start
            lost = set(workers) - set(client.nthreads())
        except (OSError, TimeoutError, asyncio.TimeoutError) as exc:  # CommClosedError is an OSError
            raise ClusterError(f"{option} {address}: lost the scheduler mid-sweep ({_reason(exc)})") from None
    if lost:
        warn(f"{len(lost)} of the {len(workers)} workers left mid-sweep ({', '.join(sorted(lost))}); the scheduler "
             "flew the chunks they held again on the others")  # fmt: skip
    return assemble(spec, results, wall, {"cluster": address, "workers": len(workers)})


@contextlib.contextmanager
def _quiet_distributed() -> Iterator[None]:
    """distributed's log lines on stderr (a worker lost, a result gathered again, a reconnection) silenced while
    the sweep runs: what matters is told in one line, by a warning or a :class:`ClusterError`."""
    import distributed  # noqa: F401 - configures its loggers (each its own handler) when first imported

    loggers = [log for name, log in logging.root.manager.loggerDict.items()
               if name.split(".")[0] == "distributed" and isinstance(log, logging.Logger)]  # fmt: skip
    levels = [log.level for log in loggers]
    for log in loggers:
        log.setLevel(logging.CRITICAL)
    try:
        yield
    finally:
        for log, level in zip(loggers, levels):
            log.setLevel(level)


def _connect(address: str, option: str):  # -> distributed.Client
    """A client of the scheduler at ``address``, once :func:`_probe` found one there."""
    from distributed import Client
    from distributed.versions import VersionMismatchWarning

    _probe(address, option)
    try:
        with warnings.catch_warnings():
            # distributed's table of every package that differs between here, the scheduler and the workers:
            # what matters to the results is checked by _prepare_workers, in one line
            warnings.simplefilter("ignore", VersionMismatchWarning)
            return Client(address, timeout=CONNECT_TIMEOUT, set_as_default=False)
    except (OSError, TimeoutError, asyncio.TimeoutError) as exc:
        raise ClusterError(f"{option} {address}: the scheduler stopped answering ({_reason(exc)})") from None


def _probe(address: str, option: str) -> None:
    """A :class:`ClusterError` unless a Dask scheduler answers at ``address`` within :data:`CONNECT_TIMEOUT` s.
    distributed's client waits for ever on a server that accepts the connection and says nothing (a web server,
    the dashboard's port): asked here first, with a deadline, what answers there is named."""
    from distributed.comm import connect

    async def identity() -> object:
        comm = await connect(address, timeout=CONNECT_TIMEOUT)
        try:
            await comm.write({"op": "identity"})
            return await comm.read()
        finally:
            comm.abort()

    try:
        reply = asyncio.run(asyncio.wait_for(identity(), CONNECT_TIMEOUT))
    except (OSError, TimeoutError, asyncio.TimeoutError) as exc:
        why = "" if "timed out" in str(exc).lower() or not str(exc) else f" ({_reason(exc)})"
        raise ClusterError(
            f"{option} {address}: no Dask scheduler answered within {CONNECT_TIMEOUT:g} s{why}; start one there "
            "with `dask scheduler`, or check the address"
        ) from None
    except Exception as exc:  # something else answered, what Dask cannot read
        reply = type(exc).__name__
    kind = reply.get("type") if isinstance(reply, dict) else None
    if kind != "Scheduler":
        what = f"a Dask {kind.lower()}, not the scheduler" if isinstance(kind, str) else (
            f"not a Dask scheduler ({reply} reading its reply)")  # fmt: skip
        raise ClusterError(
            f"{option} {address}: what answers there is {what}; give the address `dask scheduler` prints as "
            "'Scheduler at'"
        )


def _prepare_workers(client, spec: SweepSpec, address: str, option: str, warn: Callable[[str], None]) -> dict[str, int]:
    """Compile the engine on every worker (:func:`prepare`), warn in one line about versions that differ from
    this machine's and a scheduler that allows no lost worker; the workers' threads {address: nthreads}. A
    :class:`ClusterError` when a worker cannot (quadsitl not installed there, or another version)."""
    mine = versions()
    for worker, theirs in sorted(client.run(prepare, spec, on_error="return").items()):
        if isinstance(theirs, BaseException):  # quadsitl missing there, or another version without this module
            raise ClusterError(
                f"{option} {address}: worker {worker} could not load quadsitl's batch engine "
                f"({type(theirs).__name__}: {_reason(theirs)}); install quadsitl, this version, in the workers' "
                "environment"
            )
        differ = [f"{k} {theirs.get(k)} (here {v})" for k, v in mine.items() if theirs.get(k) != v]
        if differ:
            warn(f"worker {worker} has {', '.join(differ)}: its trials may differ from a local run's")
            break
    try:
        allowed = client.run_on_scheduler(_allowed_failures)
    except Exception:  # a scheduler that does not run functions sent to it: its setting is unknown
        allowed = None
    if allowed == 0:
        warn(
            f"the scheduler at {address} has distributed.scheduler.allowed-failures = 0: a lost worker fails "
            "the sweep (start it with DASK_DISTRIBUTED__SCHEDULER__ALLOWED_FAILURES=3)"
        )
    return dict(client.nthreads())


def _fly_chunks(
    client, spec: SweepSpec, parts: list, address: str, option: str, progress: Callable[[float], None] | None
) -> list[ChunkResult]:
    """One task per chunk; their results as they complete, each released once here."""
    from distributed import KilledWorker, as_completed

    tag = uuid.uuid4().hex[:8]
    futures = [
        client.submit(fly, spec, part, key=f"quadsitl-sweep-{tag}-{int(part[0])}-{int(part[-1])}", pure=False)
        for part in parts
    ]
    part_of = {f.key: part for f, part in zip(futures, parts)}
    results: list[ChunkResult] = []
    done = 0.0
    for future in as_completed(futures, loop=client.loop):
        part = part_of[future.key]
        try:
            results.append(future.result())
        except KilledWorker as exc:
            raise ClusterError(
                f"{option} {address}: trials {int(part[0])}..{int(part[-1])} were lost with "
                f"{exc.allowed_failures + 1} workers (the scheduler's distributed.scheduler.allowed-failures is "
                f"{exc.allowed_failures}): the sweep is not complete"
            ) from None
        except (OSError, TimeoutError, asyncio.TimeoutError, asyncio.CancelledError):
            raise  # the scheduler went away: run_on_cluster says so
        except Exception as exc:  # raised by fly on the worker: the same trials fly alone with --workers 1
            raise ClusterError(
                f"{option} {address}: trials {int(part[0])}..{int(part[-1])} failed on a worker "
                f"({type(exc).__name__}: {_reason(exc)})"
            ) from None
        future.release()  # its result is here: a worker lost from now on does not fly it again
        done += len(part) * spec.duration
        if progress is not None:
            progress(done)
    return results


def _allowed_failures(dask_scheduler) -> int:  # the argument's name is how run_on_scheduler passes the Scheduler
    return int(dask_scheduler.allowed_failures)


def _reason(exc: BaseException) -> str:
    """An exception as a few words on one line."""
    text = " ".join(str(exc).split()) or type(exc).__name__
    return text if len(text) <= 160 else text[:157] + "..."
