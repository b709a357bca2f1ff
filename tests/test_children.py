"""The launcher's children stopped together: ``Children.stop(names=...)`` sends each of the named processes its
SIGTERM first and then waits for all, so a fleet's autopilots and ground stations close their sessions at the
same time, not one after another; the processes it was not given go on."""

from __future__ import annotations

import subprocess
import sys
import time

from groundstation.launcher import Children

SLOW_TO_STOP = 1.5  # [s]: how long each child takes to end after its SIGTERM
CHILD = f"""
import signal, sys, time
signal.signal(signal.SIGTERM, lambda *_: (time.sleep({SLOW_TO_STOP}), sys.exit(0)))
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
        start = time.monotonic()
        children.stop(grace=10.0, names=["a", "b"])
        took = time.monotonic() - start
        assert children.procs["a"].returncode == 0 and children.procs["b"].returncode == 0  # ended by their handler
        assert took < 2 * SLOW_TO_STOP - 0.1, took  # together: one after another would take 2 × SLOW_TO_STOP
        assert children.procs["c"].poll() is None
    finally:
        for p in children.procs.values():
            p.kill()
            p.wait()
            p.stdout.close()
