"""The README's examples run as written: its Python example, and its MAVSDK example against ``quadsitl up`` (the
address alone moved to the test's free port), which takes off and lands."""

import re
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from tests.mavclient import quadsitl_up

README = Path(__file__).resolve().parent.parent / "README.md"


def python_blocks() -> list[str]:
    return re.findall(r"```python\n(.*?)```", README.read_text(encoding="utf-8"), re.S)


def test_the_python_example_runs(tmp_path):
    (example,) = [b for b in python_blocks() if "quadsitl.sim" in b]
    r = subprocess.run([sys.executable, "-c", example], capture_output=True, text=True, timeout=300, cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    rms = float(r.stdout.splitlines()[0])
    assert 0.0 < rms < 1.0  # PX4's cascade flies the circle within a metre


def highest_altitude(port: int, stop: threading.Event, seen: list[float]) -> None:
    """The highest relative altitude [m] in GLOBAL_POSITION_INT streamed to ``port``, into ``seen``."""
    from pymavlink import mavutil

    conn = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}")
    try:
        while not stop.is_set():
            m = conn.recv_match(type="GLOBAL_POSITION_INT", blocking=True, timeout=0.2)
            if m is not None:
                seen.append(m.relative_alt / 1000.0)
    finally:
        conn.close()


@pytest.mark.timeout(240)
def test_the_mavsdk_example_takes_off_and_lands():
    (example,) = [b for b in python_blocks() if "mavsdk" in b]
    seen: list[float] = []
    stop = threading.Event()
    with quadsitl_up("--preset", "x500") as v:
        watcher = threading.Thread(target=highest_altitude, args=(v.gcs_port, stop, seen), daemon=True)
        watcher.start()
        code = example.replace("udpin://0.0.0.0:14540", f"udpin://127.0.0.1:{v.api_port}")
        assert code != example
        r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=180)
        time.sleep(3.0)  # the landing goes on after the example's last command
        stop.set()
        watcher.join(5)
        assert v.proc.poll() is None
    assert r.returncode == 0, r.stderr
    assert max(seen) > 2.0  # MIS_TAKEOFF_ALT 2.5 m, reached within the example's 8 s
    assert seen[-1] < max(seen) - 0.5  # and on its way down


def test_the_readme_is_a_front_page():
    text = README.read_text(encoding="utf-8")
    assert len(text.splitlines()) < 90
    assert not re.search(r"\d[\d,]* ticks/s|round trips/s|µs", text)  # figures live in docs/performance.md
