"""The first run after an install compiles the equations for a minute or more: each command says so when it is about
to, on whatever its output is (a pipe here, as under CI or a script), with an estimate, and the warm runs after it do
not (docs/performance.md#cold-start). Each cold run is stopped as soon as it has said it: the compile itself is not
waited for."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from quadsitl.compile_cache import compiling

pytestmark = pytest.mark.timeout(120)


def said_while_cold(argv: list[str], cache: Path, stream: str, within: float = 60.0) -> list[str]:
    """The lines ``quadsitl <argv>`` prints on ``stream`` ("stdout" or "stderr", a pipe) with an empty numba cache,
    until one says it compiles or ``within`` [s] passes; the command (and the processes it started) stopped then."""
    env = {**os.environ, "NUMBA_CACHE_DIR": str(cache), "PYTHONUNBUFFERED": "1"}
    proc = subprocess.Popen([sys.executable, "-m", "groundstation.cli", *argv], env=env, text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, start_new_session=True)  # fmt: skip
    lines: list[str] = []
    found = threading.Event()

    def read() -> None:
        for line in getattr(proc, stream):
            lines.append(line.rstrip("\n"))
            if "compiling" in line:
                found.set()
                return

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    try:
        found.wait(within)
    finally:
        os.killpg(proc.pid, signal.SIGKILL)  # the launcher and its children: the compile is not waited for
        proc.wait()
    return lines


def test_fly_says_it_compiles_on_its_first_run_even_into_a_pipe(tmp_path):
    began = time.monotonic()
    lines = said_while_cold(["fly", "--out", str(tmp_path / "out"), "--no-figures"], tmp_path / "cache", "stdout")
    assert compiling("fly") in lines and time.monotonic() - began < 30  # said first, before the processes compile
    assert "30 s to a minute" in compiling("fly")


def test_sim_says_it_compiles_on_its_first_run_even_into_a_pipe(tmp_path):
    lines = said_while_cold(["sim", "--out", str(tmp_path / "out"), "--no-figures"], tmp_path / "cache", "stderr")
    assert f"{compiling('sim')} ..." in lines


def test_sim_on_sensors_says_its_longer_estimate(tmp_path):
    argv = ["sim", "--preset", "x500", "--state", "sensors", "--out", str(tmp_path / "out"), "--no-figures"]
    lines = said_while_cold(argv, tmp_path / "cache", "stderr")
    assert f"{compiling('sim', sensing=True)} ..." in lines and "2 to 4 minutes" in lines[-1]


def test_warm_runs_do_not_say_it(tmp_path):
    """The suite compiled fly's processes and sim's truth loop first (tests/conftest.py)."""
    fly = subprocess.run([sys.executable, "-m", "groundstation.cli", "fly", "--duration", "0.5", "--no-figures",
                          "--out", str(tmp_path / "fly")], capture_output=True, text=True, timeout=100)  # fmt: skip
    assert fly.returncode == 0, fly.stderr
    assert "compiling" not in fly.stdout + fly.stderr


@pytest.mark.parametrize(("xdg", "numba_dir", "under"), [
    ("XDG", "", "XDG/quadsitl/numba"),  # the user's cache folder, as the XDG specification names it
    ("XDG", "NUMBA", "NUMBA/numba"),  # numba's own variable first
    ("relative/dir", "", "HOME/.cache/quadsitl/numba"),  # a relative XDG_CACHE_HOME is to be ignored
])  # fmt: skip
def test_the_compiled_code_goes_where_the_environment_says(tmp_path, xdg, numba_dir, under):
    def at(name: str) -> str:
        return str(tmp_path / name) if name in ("XDG", "NUMBA", "HOME") else name

    env = {**os.environ, "XDG_CACHE_HOME": at(xdg), "NUMBA_CACHE_DIR": at(numba_dir), "HOME": at("HOME")}
    r = subprocess.run([sys.executable, "-c", "from quadsitl.compile_cache import cache_dir; print(cache_dir())"],
                       capture_output=True, text=True, env=env, timeout=60)  # fmt: skip
    assert r.returncode == 0, r.stderr
    folder = Path(r.stdout.strip())
    assert folder.parent == tmp_path / under.split("/", 1)[0] / under.split("/", 1)[1] and folder.is_dir()


def test_up_compiles_the_autopilot_and_the_plant_at_once_and_fails_if_either_half_fails(tmp_path, monkeypatch):
    """``quadsitl up``'s compile before a fleet starts (launcher.compile_once): the autopilot's code and the plant's in
    a process each, both running at once (each logs its start and end through a wrapper of this Python)."""
    from groundstation import launcher

    log, wrapper = tmp_path / "log", tmp_path / "python"
    wrapper.write_text(f'#!/bin/sh\necho start >> "{log}"\n"{sys.executable}" "$@"\nrc=$?\necho end >> "{log}"\n'
                       "exit $rc\n")  # fmt: skip
    wrapper.chmod(0o755)
    monkeypatch.setattr(sys, "executable", str(wrapper))
    launcher.compile_once(None, (False,), ("lockstep",))
    assert log.read_text().split() == ["start", "start", "end", "end"]
    with pytest.raises(RuntimeError, match="compiling the equations failed"):
        launcher.compile_once(None, (False,), ("no such clock",))  # the plant's half fails, the autopilot's does not


SHARED = ("autopilot.tick._frames", "autopilot.tick.answer_again", "quadsitl.codec.decode_state",
          "autopilot.stream_frames.encode")  # fmt: skip
COUNT = """
import importlib, json, sys
from quadsitl.jit import favour_compile_time
favour_compile_time()
from autopilot import tick
getattr(tick, sys.argv[1])(False)
out = {}
for name in sys.argv[2:] + ["autopilot.tick.control_tick"]:
    module, _, function = name.rpartition(".")
    f = getattr(importlib.import_module(module), function)
    out[name] = (len(f.signatures), sum(f._cache_hits.values()), sum(f._cache_misses.values()))
print(json.dumps(out))
"""


@pytest.mark.timeout(400)
def test_the_share_a_helper_compiles_is_what_the_autopilots_tick_then_loads(tmp_path):
    """Before a fleet starts, one process compiles a share of the autopilot's tick (autopilot.tick.warm_up_share), then
    the plant's, while the other compiles the tick's bulk, control_tick first (launcher.compile_once): each part of the
    share, compiled from Python, must have the argument types the tick's own compile looks up, or the autopilot's
    compiler compiles it again."""
    import json

    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "cache")}

    def run(entry: str) -> dict:
        r = subprocess.run([sys.executable, "-c", COUNT, entry, *SHARED], env=env, capture_output=True, text=True,
                           timeout=380)  # fmt: skip
        assert r.returncode == 0, r.stderr
        return json.loads(r.stdout)

    share = run("warm_up_share")
    assert all(share[name] == [1, 0, 1] for name in SHARED), share  # compiled, once each
    assert share["autopilot.tick.control_tick"] == [0, 0, 0]  # the bulk is left to the autopilot
    tick = run("warm_up")
    assert all(tick[name][2] == 0 and tick[name][1] >= 1 for name in SHARED), tick  # loaded, none compiled again
    assert tick["autopilot.tick.control_tick"] == [1, 0, 1]  # compiled first, from Python: the tick found it
