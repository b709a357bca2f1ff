"""Child processes started, watched and stopped one way, by ``fly``, ``up``, a fleet's flight and the bench.

- :func:`stop` ends one process (SIGTERM, a grace period, then SIGKILL), :func:`stop_all` several together;
- :class:`Children` holds a launcher's processes by name, says which one failed and stops them;
- :func:`supervise` watches them until the run is done or one fails, and :func:`run_supervised` is the tail every
  launcher ends with: its exit status, a failure or a stop request said on stderr, every child stopped.
"""

from __future__ import annotations

import contextlib
import os
import select
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Collection, Iterable
from dataclasses import dataclass, field

from quadsitl.process_util import PLANT_DIVERGED, READY_ENV

GRACE = 3.0  # [s] a launcher's children's time to end after SIGTERM (they close their Zenoh sessions) before SIGKILL


def start_module(*args: str, **popen: object) -> subprocess.Popen:
    """``python -m ARGS`` as a child process, with this interpreter; ``popen``: :class:`subprocess.Popen`'s options."""
    return subprocess.Popen([sys.executable, "-m", *args], **popen)


def stop_all(procs: Iterable[subprocess.Popen], grace: float = GRACE) -> None:
    """Stop ``procs`` together: SIGTERM to each that runs, then ``grace`` seconds for all of them to end, then SIGKILL
    to those that have not (and each reaped). ``grace`` 0: SIGKILL at once, no SIGTERM (a process that has nothing
    left to say)."""
    procs = list(procs)
    if grace > 0:
        for p in procs:
            if p.poll() is None:
                p.terminate()
        end = time.monotonic() + grace
        for p in procs:
            with contextlib.suppress(subprocess.TimeoutExpired):
                p.wait(max(0.0, end - time.monotonic()))
    for p in procs:
        if p.poll() is None:
            p.kill()
            p.wait()


def stop(proc: subprocess.Popen, grace: float = GRACE) -> int:
    """Stop ``proc`` as :func:`stop_all` does (SIGTERM, ``grace`` seconds, SIGKILL); returns its status as
    :attr:`subprocess.Popen.returncode` gives it (-N: ended by signal N)."""
    stop_all([proc], grace)
    return proc.returncode


def describe(name: str, status: int) -> str:
    """How the child ``name`` ended, from its status (``Popen.returncode``): its exit status, or the signal."""
    if status < 0:
        return f"the {name} process was killed by signal {-status} ({signal.Signals(-status).name})"
    return f"the {name} process exited with status {status}"


@dataclass
class Children:
    """A launcher's child processes: ``procs`` {name: process}, started in ``env`` (None: this process's
    environment). ``optional`` children (a viewer) may end without failing the run: each is reported once, and
    ``reported`` holds those that were."""

    procs: dict[str, subprocess.Popen] = field(default_factory=dict)
    env: dict[str, str] | None = None
    optional: tuple[str, ...] = ("dashboard",)  # a viewer: its end is reported, and the vehicle flies on
    reported: set[str] = field(default_factory=set)
    readiness: dict[str, int] = field(default_factory=dict)  # name → the read end of its ready pipe

    def start(self, name: str, args: list[str], ready: bool = False) -> None:
        """Start ``python -m ARGS`` as the child ``name``; with ``ready``, one that says when it is ready
        (:func:`quadsitl.process_util.say_ready`), for :meth:`wait_ready`."""
        if not ready:
            self.procs[name] = start_module(*args, env=self.env)
            return
        read, write = os.pipe()
        env = {**(os.environ if self.env is None else self.env), READY_ENV: str(write)}
        try:
            self.procs[name] = start_module(*args, env=env, pass_fds=(write,))
        finally:
            os.close(write)
        self.readiness[name] = read

    def wait_ready(self, timeout: float) -> bool:
        """Wait until every child started with ``ready`` has said so → True; False when one ended first (or closed
        its pipe without a word), or after ``timeout`` seconds."""
        waiting, end = dict(self.readiness), time.monotonic() + timeout
        try:
            while waiting and time.monotonic() < end:
                readable, _, _ = select.select(list(waiting.values()), [], [], 0.1)
                for name in [n for n, fd in waiting.items() if fd in readable]:
                    if not os.read(waiting.pop(name), 1):
                        return False  # the pipe closed without a word: the child ended
            return not waiting
        finally:
            for fd in self.readiness.values():
                with contextlib.suppress(OSError):
                    os.close(fd)
            self.readiness.clear()

    def first_failure(self, done: str | Collection[str], prog: str = "quadsitl") -> tuple[str, int] | None:
        """(name, status) of a child that exited when it should not have; ``done`` (a name or several) may exit
        with 0. An optional child that ends is reported once on stderr (as ``prog``) and is not a failure."""
        done = (done,) if isinstance(done, str) else done
        for name, p in self.procs.items():
            rc = p.poll()
            if rc is None or (name in done and rc == 0):
                continue
            if name in self.optional:
                if name not in self.reported:
                    self.reported.add(name)
                    print(f"{prog}: warning: {describe(name, rc)}; the others go on", file=sys.stderr, flush=True)
                continue
            return name, rc
        return None

    def stop(self, grace: float = GRACE, names: Iterable[str] | None = None) -> None:
        """Stop the processes ``names`` (default: all) together (:func:`stop_all`): SIGTERM to each, then ``grace``
        seconds for all of them to end, then SIGKILL."""
        stop_all(self.procs.values() if names is None else [self.procs[n] for n in names], grace)


def supervise(children: Children, prog: str, *, done: str | Collection[str] = (),
              finished: Callable[[], bool] | None = None, diverged: Callable[[str], int] | None = None,
              tick: Callable[[], None] | None = None, period: float = 0.05) -> int | None:  # fmt: skip
    """Watch ``children`` every ``period`` [s] until ``finished()`` says the run is over (→ None) or a child fails (→
    the command's exit status). A plant that ended with PLANT_DIVERGED (it said why) → ``diverged(its name)``; any
    other failure is said on stderr as ``prog`` (naming the child and how it ended) → 1. ``done``: the children that
    may end with status 0; ``tick()``: called once a period (a fleet's info publisher)."""
    while True:
        if tick is not None:
            tick()
        failure = children.first_failure(done=done, prog=prog)
        if failure and diverged is not None and failure[0].startswith("plant") and failure[1] == PLANT_DIVERGED:
            return diverged(failure[0])
        if failure:
            print(f"{prog}: error: {describe(*failure)}; stopping the others", file=sys.stderr)
            return 1
        if finished is not None and finished():
            return None
        time.sleep(period)


def run_supervised(children: Children, prog: str, run: Callable[[contextlib.ExitStack], int],
                   interrupted: Callable[[KeyboardInterrupt], int]) -> int:  # fmt: skip
    """``run(stack)``'s exit status, every child stopped however it ends, after what ``run`` put on ``stack`` (a
    Zenoh session) is closed. A RuntimeError is said on stderr as ``prog`` → 1; a stop request (SIGINT or SIGTERM:
    KeyboardInterrupt, :class:`quadsitl.process_util.StopRequested`) → ``interrupted(it)``."""
    stack = contextlib.ExitStack()
    try:
        return run(stack)
    except KeyboardInterrupt as exc:
        return interrupted(exc)
    except RuntimeError as exc:
        print(f"{prog}: error: {exc}; stopping the others", file=sys.stderr)
        return 1
    finally:
        stack.close()
        children.stop()
