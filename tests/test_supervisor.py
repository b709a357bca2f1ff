"""The one child-process supervisor (quadsitl.children), with real processes: ``stop`` escalates SIGTERM → grace →
SIGKILL, ``stop_all`` gives several children one grace period together, ``describe`` says how a child ended as the
launchers always said it, and ``supervise``/``run_supervised`` turn a child's end, a failure or a stop request into
the exit statuses and lines of ``up`` and ``fly``."""

from __future__ import annotations

import contextlib
import signal
import subprocess
import sys
import time

import pytest

from quadsitl.children import Children, describe, run_supervised, stop, stop_all, supervise
from quadsitl.process_util import PLANT_DIVERGED

pytestmark = pytest.mark.timeout(60)

# A child that says "ready" once its SIGTERM disposition is in place, then sleeps; IGNORE: it ignores SIGTERM.
IGNORE = """
import signal, time
signal.signal(signal.SIGTERM, signal.SIG_IGN)
print("ready", flush=True)
time.sleep(60)
"""
# A child that says "term" on SIGTERM and ends with status 0.
POLITE = """
import signal, sys, time
def term(*_):
    print("term", flush=True)
    sys.exit(0)
signal.signal(signal.SIGTERM, term)
print("ready", flush=True)
time.sleep(60)
"""
SLEEPER = "import time; time.sleep(60)"


@pytest.fixture
def spawn():
    """Start ``python -c CODE`` children (waiting for their "ready" line if they print one); every one left running
    is killed at the end."""
    procs: list[subprocess.Popen] = []

    def start(code: str, ready: bool = True) -> subprocess.Popen:
        proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
        procs.append(proc)
        if ready:
            assert proc.stdout.readline() == "ready\n"
        return proc

    yield start
    for proc in procs:
        if proc.poll() is None:
            proc.kill()
        proc.wait()
        proc.stdout.close()


def test_a_child_that_ignores_sigterm_is_killed_after_the_grace_period(spawn):
    proc = spawn(IGNORE)
    start = time.monotonic()
    status = stop(proc, grace=0.5)
    elapsed = time.monotonic() - start
    assert status == proc.returncode == -signal.SIGKILL
    assert 0.5 <= elapsed < 5.0  # the grace period was given, then no more
    assert describe("autopilot", status) == "the autopilot process was killed by signal 9 (SIGKILL)"


def test_a_child_that_ends_on_sigterm_is_not_killed_and_does_not_use_the_grace_period(spawn):
    proc = spawn(POLITE)
    start = time.monotonic()
    assert stop(proc, grace=20.0) == 0  # its own handler's status, not SIGKILL's
    assert time.monotonic() - start < 10.0
    assert proc.stdout.read() == "term\n"


def test_a_sleeping_child_ends_by_sigterm(spawn):
    proc = spawn(SLEEPER, ready=False)
    assert stop(proc) == -signal.SIGTERM
    assert describe("plant", proc.returncode) == "the plant process was killed by signal 15 (SIGTERM)"


def test_grace_0_kills_at_once_without_sigterm(spawn):
    proc = spawn(POLITE)
    assert stop(proc, grace=0) == -signal.SIGKILL
    assert proc.stdout.read() == ""  # it never saw a SIGTERM


def test_a_child_that_already_ended_keeps_its_status(spawn):
    proc = spawn("import sys; sys.exit(7)", ready=False)
    proc.wait(30)
    assert stop(proc, grace=5.0) == 7
    assert describe("gcs", 7) == "the gcs process exited with status 7"


def test_stop_all_gives_its_children_one_grace_period_together(spawn):
    procs = [spawn(IGNORE) for _ in range(3)]
    start = time.monotonic()
    stop_all(procs, grace=1.0)
    elapsed = time.monotonic() - start
    assert [p.returncode for p in procs] == [-signal.SIGKILL] * 3
    assert 1.0 <= elapsed < 2.5  # one after another would take three grace periods


def _children(spawn, **named: str) -> Children:
    children = Children()
    for name, code in named.items():
        children.procs[name] = spawn(code, ready=False)
    return children


def test_supervise_names_the_child_that_failed_and_returns_1(spawn, capsys):
    children = _children(spawn, autopilot=SLEEPER, plant="import sys; sys.exit(1)")
    assert supervise(children, "quadsitl up", period=0.01) == 1
    said = capsys.readouterr().err
    assert said == "quadsitl up: error: the plant process exited with status 1; stopping the others\n"
    assert children.procs["autopilot"].poll() is None  # stopping the others is the caller's tail (run_supervised)


def test_supervise_hands_a_diverged_plant_to_its_handler(spawn, capsys):
    children = _children(spawn, autopilot=SLEEPER, plant=f"import sys; sys.exit({PLANT_DIVERGED})")
    said = []
    assert supervise(children, "quadsitl up", diverged=lambda name: said.append(name) or 42, period=0.01) == 42
    assert said == ["plant"] and capsys.readouterr().err == ""
    # without a handler, a diverged plant is a failure like any other
    assert supervise(children, "quadsitl up", period=0.01) == 1


def test_supervise_ends_when_finished_and_reports_an_optional_child_once(spawn, capsys):
    children = _children(spawn, dashboard="import os, signal; os.kill(os.getpid(), signal.SIGKILL)",
                         gcs="import time; time.sleep(0.5)")  # fmt: skip
    ticks = []
    status = supervise(children, "quadsitl fly", done="gcs", finished=lambda: children.procs["gcs"].poll() == 0,
                       tick=lambda: ticks.append(1), period=0.01)  # fmt: skip
    assert status is None and len(ticks) > 1
    assert capsys.readouterr().err == ("quadsitl fly: warning: the dashboard process was killed by signal 9 (SIGKILL); "
                                       "the others go on\n")  # fmt: skip


def test_run_supervised_stops_every_child_after_closing_what_the_run_opened(spawn, capsys):
    children = _children(spawn, autopilot=SLEEPER, plant=SLEEPER)
    order = []

    def run(stack: contextlib.ExitStack) -> int:
        stack.callback(lambda: order.append(("closed", children.procs["plant"].poll())))
        raise RuntimeError("the dashboard did not start")

    assert run_supervised(children, "quadsitl up", run, interrupted=lambda exc: 0) == 1
    assert capsys.readouterr().err == "quadsitl up: error: the dashboard did not start; stopping the others\n"
    assert order == [("closed", None)]  # closed while the children still ran
    assert [p.returncode for p in children.procs.values()] == [-signal.SIGTERM] * 2


def test_run_supervised_hands_a_stop_request_to_the_command(spawn):
    children = _children(spawn, plant=SLEEPER)

    def run(stack: contextlib.ExitStack) -> int:
        raise KeyboardInterrupt

    assert run_supervised(children, "quadsitl fly", run, interrupted=lambda exc: 130) == 130
    assert children.procs["plant"].returncode == -signal.SIGTERM
    assert run_supervised(children, "quadsitl fly", lambda stack: 3, interrupted=lambda exc: 130) == 3
