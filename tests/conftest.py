import os
import subprocess
import sys
from pathlib import Path

import pytest

# pymavlink's mavutil speaks MAVLink 2 with the common dialect only when told before it is imported.
os.environ.setdefault("MAVLINK20", "1")
os.environ.setdefault("MAVLINK_DIALECT", "common")

BIN = Path(sys.executable).parent


def run_cli(*args: str, timeout: float = 120, module: str | None = None) -> subprocess.CompletedProcess:
    """Run the installed ``quadsitl`` command (or ``python -m <module>``) and capture its output."""
    if module:
        cmd = [sys.executable, "-m", module, *args]
    else:
        exe = BIN / "quadsitl"
        cmd = [str(exe), *args] if exe.exists() else [sys.executable, "-m", "groundstation.cli", *args]
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    return subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, env=env)


@pytest.fixture(scope="session", autouse=True)
def compiled():
    """Compile every per-tick function into numba's cache once, before the processes the tests start need it
    (a fresh checkout has no cache: each process would otherwise compile on its own, several at a time)."""
    from autopilot.tick import warm_up
    from quadsitl.config import load_preset
    from sitl import process
    from sitl.plant import Plant

    warm_up()
    process.warm_up(Plant(load_preset("paper")))
    _warm_the_autopilots_loop()


def _warm_the_autopilots_loop() -> None:
    """The autopilot's compiled plant loop for both of its modes (its arguments' types differ)."""
    from autopilot import plant_loop
    from autopilot.process import Autopilot, build_parser
    from quadsitl.cli_util import with_state
    from quadsitl.config import load_preset

    for state in ("truth", "sensors"):
        args = build_parser().parse_args(["--no-zenoh", "--plant-listen", "127.0.0.1:0", "--gcs-listen", "127.0.0.1:0",
                                          "--api-listen", "127.0.0.1:0", "--state", state])  # fmt: skip
        args.home, args.signing_key = None, None
        ap = Autopilot(with_state(load_preset("x500"), args), args)
        try:
            plant_loop.warm_up(ap.tick_arguments())
        finally:
            ap.close()


@pytest.fixture
def cli():
    return run_cli
