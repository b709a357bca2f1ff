"""Stopping the long-running commands from scripts: a non-interactive shell starts its background jobs with
SIGINT ignored, and each command must still stop on SIGINT (and SIGTERM), children included, exit 0 when it
runs until stopped, 130 when a flight is cut short, and leave no process behind."""

from __future__ import annotations

import contextlib
import os
import shlex
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from groundstation.launcher import free_port
from quadsitl.process_util import StopRequested, run_stoppable
from tests.test_fly import alive, children_of, quadsitl


def signal_mask(pid: int, field: str) -> int:
    """The SigIgn/SigCgt mask of a process (bit n-1 stands for signal n); 0 once it is gone."""
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith(field + ":"):
                return int(line.split()[1], 16)
    except OSError:
        pass
    return 0


def catches(pid: int, sig: int) -> bool:
    return bool(signal_mask(pid, "SigCgt") >> (sig - 1) & 1)


def wait_until(predicate, timeout: float, what: str) -> None:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if predicate():
            return
        time.sleep(0.05)
    raise AssertionError(f"timed out after {timeout} s waiting for {what}")


def ignore_sigint() -> None:
    """What a non-interactive shell does in a background job before it runs the command."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)


@contextlib.contextmanager
def killed_at_exit(*procs: subprocess.Popen) -> Iterator[list[int]]:
    """Yields a list the test fills with pids to watch; on the way out (pass or fail) every one of them still
    alive, and each process given, is killed."""
    pids: list[int] = []
    try:
        yield pids
    finally:
        for pid in pids:
            if alive(pid):
                with contextlib.suppress(OSError):
                    os.kill(pid, signal.SIGKILL)
        for p in procs:
            if p.poll() is None:
                with contextlib.suppress(OSError):
                    os.killpg(p.pid, signal.SIGKILL)
                p.wait()


def test_a_scripts_background_jobs_start_with_sigint_ignored():
    """The premise of the tests below, checked with the shell they use: ``cmd &`` in ``bash -c``."""
    r = subprocess.run(["bash", "-c", "sleep 10 & pid=$!; sleep 0.3; grep SigIgn /proc/$pid/status; kill $pid"],
                       capture_output=True, text=True, timeout=10)  # fmt: skip
    assert int(r.stdout.split()[1], 16) >> (signal.SIGINT - 1) & 1, r.stdout


def test_up_started_by_a_script_stops_on_sigint_with_its_children(tmp_path):
    """``quadsitl up --dashboard &`` in a shell script, then ``kill -INT``: plant, autopilot and dashboard stop,
    ``up`` exits 0 (what the script's ``wait`` reports), nothing is left behind."""
    up = quadsitl("up", "--gcs-listen", f"127.0.0.1:{free_port()}", "--gcs-remote", "none",
                  "--api-listen", f"127.0.0.1:{free_port()}", "--api-remote", "none",
                  "--zenoh-listen", f"tcp/127.0.0.1:{free_port(socket.SOCK_STREAM)}",
                  "--dashboard", "--dashboard-port", "0")  # fmt: skip
    pidfile = tmp_path / "up.pid"
    script = f"{shlex.join(up)} & echo $! > {shlex.quote(str(pidfile))}; wait $!"
    sh = subprocess.Popen(["bash", "-c", script], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                          start_new_session=True)  # fmt: skip
    with killed_at_exit(sh) as watched:
        wait_until(lambda: pidfile.exists() and pidfile.read_text().strip(), 10, "the script's pid file")
        pid = int(pidfile.read_text())
        watched.append(pid)
        wait_until(lambda: len(children_of(pid)) == 3, 30, "plant, autopilot and dashboard")
        kids = children_of(pid)
        watched.extend(kids)
        wait_until(lambda: all(catches(p, signal.SIGINT) for p in [pid, *kids]), 20, "SIGINT handlers")
        out: list[str] = []
        threading.Thread(target=lambda: out.extend(sh.stdout), daemon=True).start()
        wait_until(lambda: any("Ctrl-C stops." in line for line in out), 60, "up's banner (it is running)")
        assert any("dashboard:" in line for line in out)
        time.sleep(1.0)  # flying
        os.kill(pid, signal.SIGINT)
        sh.wait(20)
        err = sh.stderr.read()
        assert sh.returncode == 0, err  # the status of `wait $!`: up's own
        assert "quadsitl up: stopping autopilot, plant, dashboard" in err
        assert "Traceback" not in err
        time.sleep(0.2)
        assert not [p for p in [pid, *kids] if alive(p)]


@pytest.mark.parametrize(
    "sig, after",
    [(signal.SIGINT, 0.0), (signal.SIGINT, 1.0), (signal.SIGTERM, 1.0)],
    ids=["SIGINT-in-start-up", "SIGINT-running", "SIGTERM-running"],
)
@pytest.mark.parametrize("command", ["plant", "autopilot", "dashboard"])
def test_each_process_command_started_with_sigint_ignored_stops_with_status_0(command, sig, after):
    """As soon as its handler is in place (still starting up: a stop request before the command's own
    handling must end it as quietly), or once it runs."""
    args = {
        "plant": ["--autopilot", f"127.0.0.1:{free_port()}", "--quiet"],  # free-wheels: no autopilot answers
        "autopilot": ["--plant-listen", f"127.0.0.1:{free_port()}", "--gcs-listen", "127.0.0.1:0", "--gcs-remote",
                      "none", "--api-listen", "127.0.0.1:0", "--api-remote", "none", "--no-zenoh"],
        "dashboard": ["--port", "0", "--zenoh-listen", f"tcp/127.0.0.1:{free_port(socket.SOCK_STREAM)}", "--quiet"],
    }[command]  # fmt: skip
    proc = subprocess.Popen(quadsitl(command, *args), stderr=subprocess.PIPE, text=True, preexec_fn=ignore_sigint,
                            start_new_session=True)  # fmt: skip
    with killed_at_exit(proc):
        wait_until(lambda: catches(proc.pid, signal.SIGINT) or proc.poll() is not None, 20, "a SIGINT handler")
        time.sleep(after)
        assert proc.poll() is None, proc.stderr.read()
        proc.send_signal(sig)
        _, err = proc.communicate(timeout=15)
        assert proc.returncode == 0, err
        assert "Traceback" not in err


def test_fly_started_with_sigint_ignored_is_interrupted_by_sigint(tmp_path):
    """A flight cut short is not a success (130, as shells report SIGINT), but it stops at once, stops its
    children, and keeps the telemetry logged so far."""
    fly = subprocess.Popen(quadsitl("fly", "--speed", "1", "--duration", "60", "--out", str(tmp_path), "--quiet"),
                           stderr=subprocess.PIPE, text=True, preexec_fn=ignore_sigint,
                           start_new_session=True)  # fmt: skip
    with killed_at_exit(fly) as watched:
        wait_until(lambda: len(children_of(fly.pid)) == 3, 30, "plant, autopilot and ground station")
        kids = children_of(fly.pid)
        watched.extend(kids)
        tlog = tmp_path / "flight.tlog"
        wait_until(lambda: tlog.exists() and tlog.stat().st_size > 0, 30, "the ground station's link")
        time.sleep(4.0)  # flying: armed at 2 s of the vehicle's clock (the log is written when the flight ends or is
        # interrupted; 2 s was too short on a loaded CI machine, which interrupted it before arming)
        fly.send_signal(signal.SIGINT)
        _, err = fly.communicate(timeout=20)
        assert fly.returncode == 130, err
        assert "interrupted" in err and "Traceback" not in err
        time.sleep(0.2)
        assert not [p for p in kids if alive(p)]
        assert len((tmp_path / "telemetry.csv").read_text().splitlines()) > 100  # saved up to the interruption


if sys.platform != "linux":  # /proc and PR_SET_PDEATHSIG
    pytestmark = pytest.mark.skip("Linux only")


def test_a_stop_that_main_did_not_catch_ends_the_process_quietly():
    def starting_up() -> int:
        raise StopRequested(signal.SIGTERM)  # as the handler does, before main's own try

    assert run_stoppable(starting_up) == 0  # a command that runs until stopped
    assert run_stoppable(starting_up, stopped=None) == 143  # a job cut short: 128 + SIGTERM
    assert run_stoppable(lambda: 7) == 7


INTERRUPTED_LIBRARY = """
import os, signal, sys
from quadsitl.process_util import StopRequested

def interrupted_library():
    try:
        os.kill(os.getpid(), signal.SIGNAL)
        for _ in range(10_000_000):  # the handler runs here
            pass
    except StopRequested:  # as CPython's import of ssl did once, interrupted at one spot
        raise TypeError("expected a message argument") from None
    return 3
"""
REPORTED_AS_ANOTHER_ERROR = (
    INTERRUPTED_LIBRARY
    + """
from quadsitl.process_util import handle_stop_signals, run_stoppable

def main():
    handle_stop_signals()
    if sys.argv[1] == "real":
        raise TypeError("a real error")
    return interrupted_library()

sys.exit(run_stoppable(main, stopped=None if sys.argv[2] == "job" else 0, name="quadsitl dashboard"))
"""
)


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
@pytest.mark.parametrize("kind", ["job", "server"])
def test_a_stop_that_the_interrupted_code_reports_as_another_error_is_still_a_stop(sig, kind):
    """A dashboard stopped as it started (ci on a96fa71): the SIGINT interrupted CPython's import of ssl, which
    raised a TypeError instead, and the process died with a traceback and status 1. Now the stop's status and one
    line; an error with no stop request behind it still gets its traceback."""
    code = REPORTED_AS_ANOTHER_ERROR.replace("signal.SIGNAL", f"signal.{sig.name}")
    r = subprocess.run([sys.executable, "-c", code, "interrupted", kind], capture_output=True, text=True, timeout=30)
    assert r.returncode == (128 + sig if kind == "job" else 0), (r.returncode, r.stderr)
    assert r.stderr == "quadsitl dashboard: stopped; while stopping: TypeError: expected a message argument\n"
    r = subprocess.run([sys.executable, "-c", code, "real", kind], capture_output=True, text=True, timeout=30)
    assert r.returncode == 1 and "Traceback" in r.stderr and "TypeError: a real error" in r.stderr, r.stderr


LOST_STOP = """
import os, signal, sys, time
from quadsitl.process_util import handle_stop_signals, run_stoppable

class Finalized:
    def __del__(self):  # Python prints and drops what a finalizer raises (llvmlite's do, while numba loads code)
        os.kill(os.getpid(), signal.SIGTERM)
        for _ in range(1000):  # the handler runs here, inside the finalizer
            pass

def main():
    handle_stop_signals()
    Finalized()
    time.sleep(10)  # not reached: the stop is raised again where the main thread is
    return 3

sys.exit(run_stoppable(main, stopped=None))
"""


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_a_stop_raised_where_python_drops_exceptions_is_raised_again(sig):
    """A stop signal whose StopRequested lands in a finalizer or a ctypes callback (an autopilot stopped while numba
    loaded its compiled code: it went on running, and a test's 10 s wait for its exit ran out) still stops the
    process, at once and with the signal's status, and without an 'Exception ignored' line."""
    code = LOST_STOP.replace("signal.SIGTERM", f"signal.{sig.name}")
    started = time.monotonic()
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=30)
    assert time.monotonic() - started < 8.0, "the stop was lost: the process slept on"
    assert r.returncode == 128 + sig, (r.returncode, r.stderr)
    assert "Exception ignored" not in r.stderr and "Traceback" not in r.stderr, r.stderr


HALF_MADE = """
import os, signal, sys, time
from quadsitl.process_util import handle_stop_signals, run_stoppable

class HalfMade:
    def __init__(self):
        os.kill(os.getpid(), signal.SIGTERM)  # the stop lands here, before the attribute is set (llvmlite's ValueRef)
        for _ in range(1000):
            pass
        self.handle = 1

    def __del__(self):
        del self.handle  # AttributeError: the finalizer of an object the stop interrupted

def main():
    handle_stop_signals()
    HalfMade()
    return 3

sys.exit(run_stoppable(main, stopped=0, name="quadsitl autopilot"))
"""


def test_a_finalizer_failing_on_an_object_the_stop_interrupted_is_one_line_not_a_traceback():
    """An autopilot stopped while numba loaded its compiled code: the stop interrupted llvmlite's ValueRef before it
    was whole, its finalizer then raised AttributeError, and Python printed 'Exception ignored' and a traceback
    (ci at e0544df). Stopped, with one line saying what failed while it stopped, under the process's own name (it was
    ``__main__.py`` under ``python -m autopilot``)."""
    r = subprocess.run([sys.executable, "-c", HALF_MADE], capture_output=True, text=True, timeout=30)
    assert r.returncode == 0, r.stderr
    assert "Traceback" not in r.stderr and "Exception ignored" not in r.stderr, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1, r.stderr
    assert lines[0].startswith("quadsitl autopilot: stopped; while stopping, in HalfMade.__del__: AttributeError")


COMMAND_REPORTED_AS_ANOTHER_ERROR = (
    INTERRUPTED_LIBRARY
    + """
import groundstation.cli as cli

def presets(args):
    if sys.argv[1] == "real":
        raise TypeError("a real error")
    return interrupted_library()

cli.run_presets = presets  # `quadsitl presets`, a command that is not a process of its own, is this one
sys.exit(cli.main(["presets"]))
"""
)


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_a_command_stopped_where_the_interrupted_code_reports_another_error_says_interrupted(sig):
    """The commands that are not processes of their own (fly, sim, sweep, ...) take the same rule as run_stoppable:
    a stop reported as another error is the stop (one line, 128 + the signal), and a real error keeps its
    traceback."""
    code = COMMAND_REPORTED_AS_ANOTHER_ERROR.replace("signal.SIGNAL", f"signal.{sig.name}")
    r = subprocess.run([sys.executable, "-c", code, "interrupted"], capture_output=True, text=True, timeout=30)
    assert r.returncode == 128 + sig, (r.returncode, r.stderr)
    assert r.stderr == "quadsitl presets: interrupted; while stopping: TypeError: expected a message argument\n"
    r = subprocess.run([sys.executable, "-c", code, "real"], capture_output=True, text=True, timeout=30)
    assert r.returncode == 1 and "Traceback" in r.stderr and "TypeError: a real error" in r.stderr, r.stderr
