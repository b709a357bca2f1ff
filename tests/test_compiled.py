"""The compiled equations (quadsitl.jit) against the same source run as ordinary Python, and bad input
refused before anything is compiled."""

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from quadsitl.jit import DISABLED
from tests import compiled_cases


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """compiled_cases.compute() with the compiler off: the reference implementation (the same source)."""
    path = tmp_path_factory.mktemp("reference") / "cases.npz"
    subprocess.run([sys.executable, "-m", "tests.compiled_cases", str(path)], check=True, timeout=600,
                   env={**os.environ, "NUMBA_DISABLE_JIT": "1"})  # fmt: skip
    with np.load(path) as data:
        return dict(data)


@pytest.mark.skipif(DISABLED, reason="compares compiled code with Python: needs the compiler on")
def test_compiled_equals_the_reference_to_1e_12(reference):
    compiled = compiled_cases.compute()
    assert set(compiled) == set(reference)
    for name, ref in reference.items():
        got = compiled[name]
        assert got.shape == ref.shape, name
        assert np.all(np.isfinite(got) == np.isfinite(ref)), name
        scale = np.maximum(1.0, np.abs(ref))
        worst = np.nanmax(np.abs(got - ref) / scale) if ref.size else 0.0
        assert worst <= 1e-12, f"{name}: compiled and Python differ by {worst:.3g} (relative)"
    # the per-tick frames are the same bytes
    assert np.array_equal(compiled["ticks/answers"], reference["ticks/answers"])
    # and the cases are not trivial: the closed loop moved, the paper's step was flown
    assert np.ptp(reference["paper/backstepping/state"][:, 2]) > 1.0
    assert np.ptp(reference["ticks/values"][:, 2]) > 0.0


PAPER_TOML = Path(__file__).resolve().parent.parent / "quadsitl" / "presets" / "paper.toml"


@pytest.mark.parametrize(
    ("command", "line", "replacement", "message"),
    [
        ("sim", "mass = 2.0", "mass = nan", "vehicle.mass = nan: expected a finite number > 0"),
        ("sim", "period = 0.001", "period = inf", "sim.period = inf: expected a number in [1e-5, 0.1] s"),
        ("fly", "max_thrust = 10000.0", "max_thrust = 1e400", "actuators.max_thrust = inf: expected a finite"),
        ("up", "gains = [10.0, 10.0,", "gains = [10.0, nan,", "controller.gains = [10.0, nan, 10.0"),
        ("sim", "gravity = 9.8", "gravity = -9.8", "vehicle.gravity = -9.8"),
    ],
)
def test_values_the_compiled_code_cannot_take_are_refused_before_anything_compiles(
    tmp_path, command, line, replacement, message
):
    text = "\n".join(replacement + row[len(line):] if row.startswith(line) else row
                     for row in PAPER_TOML.read_text().splitlines())  # fmt: skip
    preset = tmp_path / "bad.toml"
    preset.write_text(text + "\n")
    cache = tmp_path / "cache"
    env = {**os.environ, "NUMBA_CACHE_DIR": str(cache)}
    r = subprocess.run([sys.executable, "-m", "groundstation.cli", command, "--preset", str(preset)],
                       capture_output=True, text=True, timeout=60, env=env)  # fmt: skip
    assert r.returncode == 2
    assert r.stderr.count("\n") == 1 and message in r.stderr and "Traceback" not in r.stderr, r.stderr
    assert not [p for p in cache.rglob("*") if p.is_file()], "something was compiled before the refusal"


def test_cli_gains_that_are_not_finite_are_refused_before_anything_compiles(tmp_path):
    cache = tmp_path / "cache"
    for option in ("--gains", "--poles"):
        r = subprocess.run([sys.executable, "-m", "groundstation.cli", "sim", option, "nan,1,1,1,1,1,1,1"],
                           capture_output=True, text=True, timeout=60,
                           env={**os.environ, "NUMBA_CACHE_DIR": str(cache)})  # fmt: skip
        assert r.returncode == 2 and "expected 8 comma-separated finite numbers" in r.stderr, r.stderr
    assert not [p for p in cache.rglob("*") if p.is_file()]


@pytest.mark.skipif(DISABLED, reason="compares the machine code called two ways")
def test_the_specialized_entry_is_the_dispatched_function_to_the_bit():
    """Plant.step and the controllers call their machine code without numba's dispatch (quadsitl.jit.specialized):
    over a flight of random commands, states and references, the same numbers to the bit as the call through the
    dispatcher, in the same arrays."""
    from autopilot import backstepping, pd
    from autopilot.factory import make_controller
    from quadsitl.config import load_preset
    from sitl.plant import Plant, step_arrays

    rng = np.random.default_rng(7)
    preset = load_preset("paper")
    fast, slow = Plant(preset), Plant(preset)
    assert fast._step is not step_arrays  # the machine code itself, not the dispatcher
    for _ in range(500):
        commanded = tuple(rng.uniform(0.0, 8.0, 4))
        omega_r = None if rng.random() < 0.5 else float(rng.normal(0.0, 50.0))
        fast.step(commanded, omega_r)
        slow.commanded[:] = commanded
        step_arrays(slow.x, slow.motors, slow.commanded, slow.out, slow.v, slow.a, slow.air, slow.air_rng, slow.period,
                    slow.substeps, slow.method, np.nan if omega_r is None else omega_r)  # fmt: skip
        assert np.array_equal(fast.x, slow.x) and np.array_equal(fast.out, slow.out)
        assert np.array_equal(fast.motors, slow.motors)
    for module, kind in ((backstepping, "backstepping"), (pd, "pd")):
        ctl, twin = make_controller(preset, kind), make_controller(preset, kind)
        assert ctl._step is not module.step_arrays  # the machine code itself, not the dispatcher
        twin._step = module.step_arrays
        for _ in range(200):
            state, reference = rng.normal(0.0, 0.5, 12), (rng.uniform(0.5, 5.0), *rng.normal(0.0, 0.2, 3))
            assert ctl.step(state, reference) == twin.step(state, reference), kind
            assert np.array_equal(ctl.mem, twin.mem), kind
