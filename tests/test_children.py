"""The launcher's children stopped together: ``Children.stop(names=...)`` sends each of the named processes its
SIGTERM first and then waits for all, so a fleet's autopilots and ground stations close their sessions at the
same time, not one after another; the processes it was not given go on. And children that share the launcher's
stderr write whole lines, also unbuffered."""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time

from quadsitl.children import Children

SLOW_TO_STOP = 1.5  # [s]: how long each child takes to end after its SIGTERM
CHILD = f"""
import signal, sys, time
def stop(*_):
    print("term", time.monotonic(), flush=True)
    time.sleep({SLOW_TO_STOP})
    print("exit", time.monotonic(), flush=True)
    sys.exit(0)
signal.signal(signal.SIGTERM, stop)
print("ready", flush=True)
time.sleep(120)
"""


def test_the_named_children_are_stopped_together_and_the_others_go_on():
    children = Children()
    try:
        for name in ("a", "b", "c"):
            children.procs[name] = subprocess.Popen([sys.executable, "-c", CHILD], stdout=subprocess.PIPE, text=True)
        for p in children.procs.values():
            assert p.stdout.readline() == "ready\n"  # its handler is in place
        children.stop(grace=10.0, names=["a", "b"])
        assert children.procs["a"].returncode == 0 and children.procs["b"].returncode == 0  # ended by their handler
        said = {n: dict(line.split() for line in children.procs[n].stdout.read().splitlines()) for n in ("a", "b")}
        # together: each had its SIGTERM before either had ended (one after another, b's would come after a's exit)
        assert max(float(said[n]["term"]) for n in said) < min(float(said[n]["exit"]) for n in said), said
        assert children.procs["c"].poll() is None
    finally:
        for p in children.procs.values():
            p.kill()
            p.wait()
            p.stdout.close()


LINES = 3000
WRITER = f"""
import sys, time
from quadsitl.process_util import whole_lines
if sys.argv[2] == "whole":
    whole_lines()
while time.time() < float(sys.argv[3]):  # both start writing at once
    pass
for i in range({LINES}):
    print(sys.argv[1] * 40, i, file=sys.stderr)
"""


def interleaved_lines(mode: str) -> tuple[list[str], list[str]]:
    """Two unbuffered children (PYTHONUNBUFFERED=1, as containers and CI set it) printing to one shared stderr, as a
    fleet's autopilots share the launcher's → (every line, the lines that are not one child's whole line)."""
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    start = str(time.time() + 1.0)
    with tempfile.TemporaryFile("w+") as shared:
        argv = [sys.executable, "-c", WRITER]
        procs = [subprocess.Popen([*argv, tag, mode, start], stderr=shared, env=env) for tag in "ab"]
        for proc in procs:
            assert proc.wait(timeout=60) == 0
        shared.seek(0)
        lines = shared.read().splitlines()
    whole = {f"{tag * 40} {i}" for tag in "ab" for i in range(LINES)}
    return lines, [line for line in lines if line not in whole]


def test_children_sharing_an_unbuffered_stderr_write_whole_lines():
    """``run_stoppable`` (every process) and ``quadsitl`` call ``whole_lines()``: each line one write, so lines of two
    children never mix. Without it, Python writes a line's text and its newline in two calls: the control run shows
    the lines mixing on the same machine (two autopilots of ``fly --vehicles 2`` printed
    ``...0.25 s)autopilot: ...`` once)."""
    lines, broken = interleaved_lines("whole")
    assert len(lines) == 2 * LINES and not broken, broken[:5]
    for _ in range(5):  # the control: a race, so tried a few times
        lines, broken = interleaved_lines("raw")
        if broken:
            break
    assert broken, "unbuffered children never mixed their lines here: the test above proves nothing"
