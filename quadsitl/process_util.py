"""What every process shell needs: address parsing, clean exit on SIGTERM/SIGINT, dying with the parent."""

from __future__ import annotations

import ctypes
import errno
import gc
import select
import signal
import socket
import struct
import sys

from quadsitl.cli_util import UsageError


def parse_address(option: str, text: str) -> tuple[str, int]:
    """'HOST:PORT' → (host, port), or a UsageError naming the option."""
    host, sep, port = text.rpartition(":")
    if not sep or not host or not port.isdigit() or not 0 <= int(port) <= 65535:
        raise UsageError(f"{option} {text!r}: expected HOST:PORT with PORT in 0..65535")
    return host, int(port)


def parse_remote(option: str, text: str) -> tuple[str, int] | None:
    """'HOST:PORT' or 'none' (→ None)."""
    return None if text.lower() == "none" else parse_address(option, text)


def bind_udp(option: str, text: str) -> socket.socket:
    """A UDP socket bound to the option's HOST:PORT, or a UsageError that names the option, the address
    and, for a busy port, how to choose another."""
    address = parse_address(option, text)
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        sock.bind(address)
    except OSError as exc:
        sock.close()
        hint = f"; choose another with {option} HOST:PORT" if exc.errno == errno.EADDRINUSE else ""
        raise UsageError(f"{option} {text}: cannot bind: {exc.strerror}{hint}") from None
    return sock


def set_receive_timeout(sock: socket.socket, seconds: float | None) -> None:
    """Make ``recv`` on a blocking socket give up after ``seconds`` (None: never; raising BlockingIOError), with the
    kernel's SO_RCVTIMEO instead of Python's socket timeout: Python implements its timeout with a poll()
    before every receive, a system call the lockstep loop cannot afford at 10,000 ticks/s."""
    sock.settimeout(None)
    usec = 0 if seconds is None else max(1, round(seconds * 1e6))  # 0 = no timeout
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVTIMEO, struct.pack("ll", usec // 1_000_000, usec % 1_000_000))


def wait_readable(sock: socket.socket, seconds: float) -> bool:
    """Wait up to ``seconds`` (microsecond resolution) for ``sock`` to have a datagram."""
    try:
        readable, _, _ = select.select([sock], [], [], max(seconds, 0.0))
    except InterruptedError:
        return False
    return bool(readable)


def quiet_garbage_collector() -> None:
    """Keep the cyclic garbage collector out of the per-tick loop: objects made so far (modules, presets)
    are frozen out of its view, and it runs only after 50,000 net allocations of container objects
    instead of 700. The loops make no reference cycles, so reference counting frees what they allocate;
    the collector stays on for anything else."""
    gc.collect()
    gc.freeze()
    gc.set_threshold(50_000, 50, 100)


def start_process(quiet_gc: bool = True) -> None:
    """What every process's main() does first: die with the parent, exit cleanly on SIGTERM and, for the
    per-tick loops, keep the garbage collector quiet."""
    die_with_parent()
    exit_on_signals()
    if quiet_gc:
        quiet_garbage_collector()


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
