"""The processes compile at LLVM's -O2 (quadsitl.jit.favour_compile_time), the rest at numba's -O3: the level
changes how long the first run waits, never a result. The paper's closed loop (its backstepping law with the
errata, on the rk4 dynamics) compiled at each level flies the same bits."""

import hashlib
import os
import subprocess
import sys

import pytest

from quadsitl.jit import DISABLED, PROCESS_OPT

# Compiled afresh in each process (plain numba.njit, no cache): the level applies to every function it inlines.
LOOP = """
import hashlib, sys
import numba, numpy as np
from quadsitl.jit import favour_compile_time
favour_compile_time()
from autopilot.backstepping import backstepping
from autopilot.control_params import control_array
from quadsitl.config import load_preset
from quadsitl.param_arrays import vehicle_array
from sitl import dynamics, integrators

@numba.njit
def fly(x, ref, v, c, h, n):
    s = (x[0], x[1], x[2], x[3], x[4], x[5], x[6], x[7], x[8], x[9], x[10], x[11])
    r = (ref[0], ref[1], ref[2], ref[3])
    last = (0.0, 0.0, 0.0, 0.0)
    out = np.empty((n, 12))
    for k in range(n):
        u, _, omega_r = backstepping(s, r, last, v, c)
        last = (u[0], u[1], u[2], u[3])
        s = integrators.rk4(s, last, omega_r, v, dynamics.CALM, h)
        for i in range(12):
            out[k, i] = s[i]
    return out

p = load_preset("paper")
v = vehicle_array(p.vehicle)
c = control_array(p.poles(), p.sim.period, p.controller.pd_kp, p.controller.pd_kd)
x = np.zeros(12)
out = fly(x, np.array([2.0, 0.2, -0.1, 0.5]), v, c, p.sim.period, 3000)
digest = hashlib.sha256(out.tobytes()).hexdigest()
print(int(numba.config.OPT), digest, float(np.ptp(out[:, 2])), float(np.ptp(out[:, 8])))
"""


def level_and_flight(opt: str | None) -> tuple[int, str, float, float]:
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_OPT"}
    if opt is not None:
        env["NUMBA_OPT"] = opt
    done = subprocess.run([sys.executable, "-c", LOOP], env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    level, digest, climb, turn = done.stdout.split()
    return int(level), digest, float(climb), float(turn)


@pytest.mark.skipif(DISABLED, reason="compares two compiles: needs the compiler on")
def test_the_process_level_flies_the_same_bits_as_numbas_default():
    level, digest, climb, turn = level_and_flight(None)
    assert level == PROCESS_OPT == 2  # not the user's choice: the processes' own
    default, reference, *_ = level_and_flight("3")
    assert default == 3  # the user's NUMBA_OPT wins over the processes' level
    assert climb > 1.0 and turn > 0.3  # the loop flew the step: climbed and turned
    assert digest == reference, "the paper's loop compiled at -O2 and -O3 differs"
    assert hashlib.sha256(b"").hexdigest() not in (digest, reference)
