"""The launcher's children stopped together: ``Children.stop(names=...)`` sends each of the named processes its
SIGTERM first and then waits for all, so a fleet's autopilots and ground stations close their sessions at the
same time, not one after another; the processes it was not given go on."""

from __future__ import annotations

import subprocess
import sys

from groundstation.launcher import Children

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
