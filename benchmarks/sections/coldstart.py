"""0. cold start: the compiler's cost, paid once. A short ``quadsitl fly`` with numba's cache empty (as right after
installing, or after any change to the equations), then the same again with the cache it left. It has no quick form:
a default run leaves it out."""

from __future__ import annotations

import os
import subprocess
import sys
import time

from benchmarks.sections.base import Context, Section


def run(ctx: Context) -> dict[str, object]:
    """Both runs' wall times [s], the second against the first; ``first_run_s``."""
    r, workdir = ctx.report, ctx.work
    r.section("0. cold start: quadsitl fly --duration 1, end to end, with numba's cache empty and then filled")
    env = {**os.environ, "NUMBA_CACHE_DIR": str(workdir / "numba-cache")}
    walls = []
    for _ in range(2):
        start = time.monotonic()
        subprocess.run([sys.executable, "-m", "groundstation.cli", "fly", "--preset", "paper", "--duration", "1",
                        "--out", str(workdir / "cold"), "--no-figures", "--quiet"], check=True, timeout=600,
                       env=env)  # fmt: skip
        walls.append(time.monotonic() - start)
    r.add("first run after install (compiles)", walls[0], "s")
    r.add("second run (from numba's cache)", walls[1], "s", walls[0], "first run")
    return {"first_run_s": walls[0]}


# on a cache of its own (NUMBA_CACHE_DIR)
SECTION = Section("coldstart", run, compiled=False, cold=True, absent=("first_run_s",), full_only=True)
