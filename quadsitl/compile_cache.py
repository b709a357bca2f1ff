"""Where numba keeps the compiled equations, and whether they are there: plain Python, so that a launcher can tell
whether the first run will compile without loading the compiler itself."""

from __future__ import annotations

import hashlib
import os
import shutil
import time
from pathlib import Path

PACKAGES = ("quadsitl", "sitl", "autopilot")  # where compiled functions live (and what they call)
STALE_DAYS = 7


def cache_dir() -> Path:
    """Where numba keeps the compiled functions: ``$NUMBA_CACHE_DIR``, else ``quadsitl`` in the user's cache folder
    (``$XDG_CACHE_HOME`` when it is an absolute path, as the XDG base directory specification says; else
    ``~/.cache``), in a folder named by a hash of the packages' sources. A folder is marked each time it is used;
    folders of other sources (other versions, other checkouts) unused for STALE_DAYS are removed."""
    root = Path(__file__).resolve().parent.parent
    digest = hashlib.sha256()
    for package in PACKAGES:
        for path in sorted((root / package).rglob("*.py")):
            digest.update(path.relative_to(root).as_posix().encode())
            digest.update(path.read_bytes())
    xdg = os.environ.get("XDG_CACHE_HOME", "")
    user = Path(xdg) if os.path.isabs(xdg) else Path.home() / ".cache"
    base = Path(os.environ.get("NUMBA_CACHE_DIR") or user / "quadsitl") / "numba"
    folder = base / digest.hexdigest()[:16]
    folder.mkdir(parents=True, exist_ok=True)
    now = time.time()
    os.utime(folder, (now, now))
    for other in base.iterdir():
        if other != folder and now - other.stat().st_mtime > STALE_DAYS * 86400:
            shutil.rmtree(other, ignore_errors=True)
    return folder


def cached(function: str) -> bool:
    """Whether numba's cache for these sources holds ``function`` ("module.name", e.g. "plant_loop.serve"), compiled:
    False right after an install or a change to the equations, when the first run compiles
    (docs/performance.md#cold-start)."""
    return any(cache_dir().rglob(f"{function}-*.nbi"))


def compiling(command: str, sensing: bool = False) -> str:
    """What ``quadsitl <command>`` says, on any output, when it is about to compile (:func:`cached` says it must, or
    loading takes long): that the wait is the compiler's, once, and about how long it takes on a 2-core machine
    (docs/performance.md#cold-start); ``sensing``: ``sim``'s loop on sensors, several times longer."""
    took = "2 to 4 minutes on a 2-core machine" if sensing else "30 s to a minute on a 2-core machine"
    return f"quadsitl {command}: compiling the vehicle's equations, once after an install or a change ({took})"
