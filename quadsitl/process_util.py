"""What every process shell needs: address parsing, clean exit on SIGTERM/SIGINT, dying with the parent."""

from __future__ import annotations

import ctypes
import signal
import sys

from quadsitl.cli_util import UsageError


def parse_address(option: str, text: str) -> tuple[str, int]:
    """'HOST:PORT' → (host, port), or a UsageError naming the option."""
    host, sep, port = text.rpartition(":")
    if not sep or not host or not port.isdigit() or not 0 <= int(port) <= 65535:
        raise UsageError(f"{option} {text!r}: expected HOST:PORT with PORT in 0..65535")
    return host, int(port)


def exit_on_signals() -> None:
    """Turn SIGTERM into SystemExit so ``finally`` blocks run (sockets and Zenoh sessions close)."""

    def handler(signum: int, _frame: object) -> None:
        raise SystemExit(128 + signum)

    signal.signal(signal.SIGTERM, handler)


def die_with_parent() -> None:
    """Linux: ask the kernel to SIGTERM this process when its parent dies (no orphans, even after
    ``kill -9`` of the launcher). A no-op elsewhere."""
    if sys.platform.startswith("linux"):
        try:
            libc = ctypes.CDLL("libc.so.6", use_errno=True)
            libc.prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG
        except OSError:
            pass
