"""The ground side starts without the compiler: the command line, the ground station, the dashboard, the logger,
replay and the router import no numba (half a second of every start), and the frame conversions they use are the
very functions the compiled code runs (quadsitl.compiled_frames compiles quadsitl.frames' own)."""

from __future__ import annotations

import inspect
import subprocess
import sys

import pytest

from quadsitl import compiled_frames, frames

GROUND = (
    "groundstation.cli",
    "groundstation.gcs",
    "groundstation.dashboard.server",
    "groundstation.logger",
    "groundstation.replay",
    "groundstation.router",
    "groundstation.vehicle_info",
    "groundstation.recording",
    "groundstation.launcher",
    "quadsitl.frames",
    "quadsitl.wire",
)


def compiler_modules(code: str) -> list[str]:
    """The numba and llvmlite modules a fresh interpreter has loaded after running ``code``."""
    probe = f"{code}\nimport sys\nprint(sorted(m for m in sys.modules if m.split('.')[0] in ('numba', 'llvmlite')))"
    done = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    return eval(done.stdout.strip().splitlines()[-1])


def test_the_ground_sides_modules_load_no_compiler():
    assert compiler_modules("".join(f"import {m}\n" for m in GROUND)) == []


@pytest.mark.parametrize(
    "argv",
    [
        ["--help"],
        ["up", "--help"],
        ["fly", "--vehicles", "0"],
        ["sim", "--wind", "5"],
        ["sweep", "paper-mass-mismatch", "--workers", "0"],
    ],
    ids=" ".join,
)
def test_the_command_line_answers_help_and_refusals_without_the_compiler(argv):
    code = f"from groundstation.cli import main\ntry:\n    main({argv!r})\nexcept SystemExit:\n    pass"
    assert compiler_modules(code) == []


def test_the_compiled_code_loads_the_compiler():
    """The probe can fail: the processes that fly load numba."""
    assert "numba" in compiler_modules("import quadsitl.codec")


def test_every_frame_conversion_is_compiled_from_its_one_source():
    plain = {name: f for name, f in vars(frames).items() if inspect.isfunction(f) and f.__module__ == frames.__name__}
    assert len(plain) >= 14
    for name, f in plain.items():
        assert getattr(compiled_frames, name).py_func is f, name
