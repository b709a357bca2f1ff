"""Run a snippet twice, compiled and as plain Python (``NUMBA_DISABLE_JIT=1``), for tests that check the one
source gives the same numbers to the bit in both."""

import os
import subprocess
import sys


def outputs(code: str, timeout: float = 50.0) -> tuple[str, str]:
    """The standard output of ``code`` run compiled, then under ``NUMBA_DISABLE_JIT=1``."""
    runs = []
    for disabled in ("0", "1"):
        env = {**os.environ, "NUMBA_DISABLE_JIT": disabled}
        done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=timeout)
        assert done.returncode == 0, done.stderr
        runs.append(done.stdout)
    return runs[0], runs[1]
