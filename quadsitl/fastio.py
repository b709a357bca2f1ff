"""The C library's datagram calls and clock, callable from compiled code: so that a lockstep loop can receive,
tick and answer without coming back to Python between two ticks (:mod:`autopilot.plant_loop`,
:mod:`sitl.lockstep_loop`).

Each is a numba intrinsic that declares the libc function by name in the compiled module (``recvfrom``,
``sendto``, ``send``, ``poll``, ``epoll_wait``, ``clock_gettime``), so the machine code calls it directly, as C
would, and numba's on-disk cache keeps it (a ctypes function pointer would be a different address in every process,
which numba refuses to cache). Buffers are passed as addresses (``array.ctypes.data``); the caller keeps the arrays
alive.

Linux only (the socket address layout below is Linux's ``struct sockaddr_in``); with ``NUMBA_DISABLE_JIT=1`` none
of this exists, and the processes keep their Python loops (:data:`AVAILABLE`).
"""

from __future__ import annotations

import os
import platform
import select
import socket
import struct
import sys

import numpy as np

from quadsitl.cli_util import UsageError
from quadsitl.jit import DISABLED, jit

AVAILABLE = not DISABLED and sys.platform == "linux"
"""True when the compiled loops can run here: compiled code (not ``NUMBA_DISABLE_JIT``) on Linux."""

LOOPS_ENV = "QUADSITL_COMPILED_LOOPS"  # 0: the processes keep their Python loops (for comparison; 1 is the default)


def compiled_loops() -> bool:
    """Whether the plant and the autopilot serve their lockstep link in compiled code: where :data:`AVAILABLE`,
    unless ``$QUADSITL_COMPILED_LOOPS`` is 0 (the Python loops, which handle every datagram the same way)."""
    text = os.environ.get(LOOPS_ENV, "1")
    if text not in ("0", "1"):
        raise UsageError(f"${LOOPS_ENV} = {text!r}: expected 0 (Python loops) or 1 (compiled loops, the default)")
    return AVAILABLE and text == "1"


MSG_DONTWAIT = 0x40  # Linux's flag: a receive that returns at once (−1) when nothing is waiting
SOCKADDR_IN = 16  # bytes of a struct sockaddr_in (family, port, IPv4 address, padding)
CLOCK_MONOTONIC = 1
# A compiled loop's waits, counted in its stats (int64) by :func:`receive` (index 0 is the loop's own count):
# datagrams that came while polling, of which late (after half the budget); blocking waits, and the consecutive
# ones shorter than the budget (SpinThenBlock's "hot" count: :meth:`quadsitl.process_util.SpinThenBlock.tally`).
POLLED, LATE, BLOCKED, SHORT = 1, 2, 3, 4
RAN_OUT = -2  # receive(): polling found no datagram within its patience
POLLIN = 0x001  # poll(2)'s event: data to read


def pollfds(socks: list[socket.socket]) -> np.ndarray:
    """The ``struct pollfd`` array that :func:`any_readable` asks about ``socks``: int32 pairs (the descriptor; the
    requested events, POLLIN, in the low 16 bits and the returned ones in the high 16, as Linux's little-endian
    ``short events, revents`` lay out)."""
    out = np.zeros((len(socks), 2), dtype=np.int32)
    for i, sock in enumerate(socks):
        out[i] = sock.fileno(), POLLIN
    return out


# Linux's struct epoll_event in uint32 words (events, then the 64-bit data whose low word is the descriptor): packed on
# x86-64 (12 bytes), aligned to 8 elsewhere (16).
EPOLL_WORDS, EPOLL_FD_WORD = (3, 1) if platform.machine() in ("x86_64", "AMD64") else (4, 2)


class ReadySet:
    """An ``epoll(7)`` instance watching sockets for datagrams to read, for :func:`epoll_wait` in compiled code: one
    call tells which of many sockets have one, at a cost that grows with those that do, not with all of them (a
    ``poll(2)`` asks every socket every time: docs/performance.md#a-hosted-fleet-in-lockstep).

    ``fd``: the instance's descriptor; ``events``: room for one event per socket (uint32, EPOLL_WORDS each, the
    socket's descriptor in word EPOLL_FD_WORD: Python's ``select.epoll`` registers a descriptor as the event's data);
    ``slot``: int64, by descriptor, the socket's index in ``socks`` (−1 for any other)."""

    def __init__(self, socks: list[socket.socket]) -> None:
        fds = [sock.fileno() for sock in socks]
        self._epoll = select.epoll()
        for fd in fds:
            self._epoll.register(fd, select.EPOLLIN)
        self.fd = self._epoll.fileno()
        self.events = np.zeros(max(len(fds), 1) * EPOLL_WORDS, dtype=np.uint32)
        self.slot = np.full(max(fds, default=0) + 1, -1, dtype=np.int64)
        self.slot[fds] = np.arange(len(fds))

    def close(self) -> None:
        self._epoll.close()

    def __enter__(self) -> ReadySet:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def sockaddr(address: tuple[str, int]) -> np.ndarray:
    """An IPv4 (host, port) as the bytes of a Linux ``struct sockaddr_in``, to compare with what ``recvfrom``
    fills in and to give ``sendto``."""
    host, port = address[0], address[1]
    raw = struct.pack("=H", socket.AF_INET) + struct.pack("!H", port) + socket.inet_aton(host) + bytes(8)
    return np.frombuffer(raw, dtype=np.uint8).copy()


def address_of(raw: np.ndarray) -> tuple[str, int]:
    """The (host, port) of a ``struct sockaddr_in`` that ``recvfrom`` filled in."""
    data = raw.tobytes()
    return socket.inet_ntoa(data[4:8]), struct.unpack("!H", data[2:4])[0]


if AVAILABLE:
    from llvmlite import ir
    from numba import types
    from numba.core import cgutils
    from numba.extending import intrinsic

    _I32, _I64 = ir.IntType(32), ir.IntType(64)
    _PTR = ir.IntType(8).as_pointer()

    def _libc(builder, name: str, ret, params):
        return cgutils.get_or_insert_function(builder.module, ir.FunctionType(ret, params), name)

    def _ptr(builder, value):
        return builder.inttoptr(value, _PTR)

    @intrinsic
    def recvfrom(typingctx, fd, buf, size, flags, addr, addrlen):
        """recvfrom(fd, buf address, size, flags, sockaddr address, socklen_t address) → bytes or −1."""
        sig = types.int64(types.int64, types.intp, types.int64, types.int64, types.intp, types.intp)

        def codegen(context, builder, signature, args):
            fn = _libc(builder, "recvfrom", _I64, [_I32, _PTR, _I64, _I32, _PTR, _PTR])
            fd_, buf_, size_, flags_, addr_, len_ = args
            return builder.call(fn, [builder.trunc(fd_, _I32), _ptr(builder, buf_), size_, builder.trunc(flags_, _I32),
                                     _ptr(builder, addr_), _ptr(builder, len_)])  # fmt: skip

        return sig, codegen

    @intrinsic
    def sendto(typingctx, fd, buf, size, flags, addr, addrlen):
        """sendto(fd, buf address, size, flags, sockaddr address, its length) → bytes sent or −1."""
        sig = types.int64(types.int64, types.intp, types.int64, types.int64, types.intp, types.int64)

        def codegen(context, builder, signature, args):
            fn = _libc(builder, "sendto", _I64, [_I32, _PTR, _I64, _I32, _PTR, _I32])
            fd_, buf_, size_, flags_, addr_, len_ = args
            return builder.call(fn, [builder.trunc(fd_, _I32), _ptr(builder, buf_), size_, builder.trunc(flags_, _I32),
                                     _ptr(builder, addr_), builder.trunc(len_, _I32)])  # fmt: skip

        return sig, codegen

    @intrinsic
    def send(typingctx, fd, buf, size, flags):
        """send(fd, buf address, size, flags) on a connected socket → bytes sent or −1."""
        sig = types.int64(types.int64, types.intp, types.int64, types.int64)

        def codegen(context, builder, signature, args):
            fn = _libc(builder, "send", _I64, [_I32, _PTR, _I64, _I32])
            fd_, buf_, size_, flags_ = args
            return builder.call(fn, [builder.trunc(fd_, _I32), _ptr(builder, buf_), size_, builder.trunc(flags_, _I32)])

        return sig, codegen

    @intrinsic
    def poll(typingctx, fds, nfds, timeout_ms):
        """poll(struct pollfd address, their count, timeout [ms]: 0 returns at once) → how many are ready, or −1."""
        sig = types.int64(types.intp, types.int64, types.int64)

        def codegen(context, builder, signature, args):
            fn = _libc(builder, "poll", _I32, [_PTR, _I64, _I32])
            fds_, nfds_, timeout_ = args
            return builder.sext(builder.call(fn, [_ptr(builder, fds_), nfds_, builder.trunc(timeout_, _I32)]), _I64)

        return sig, codegen

    @intrinsic
    def epoll_wait(typingctx, epfd, events, maxevents, timeout_ms):
        """epoll_wait(epoll descriptor, struct epoll_event address, room for how many, timeout [ms]: 0 returns at
        once) → how many events it wrote, or −1."""
        sig = types.int64(types.int64, types.intp, types.int64, types.int64)

        def codegen(context, builder, signature, args):
            fn = _libc(builder, "epoll_wait", _I32, [_I32, _PTR, _I32, _I32])
            ep_, events_, max_, timeout_ = args
            return builder.sext(
                builder.call(
                    fn,
                    [
                        builder.trunc(ep_, _I32),
                        _ptr(builder, events_),
                        builder.trunc(max_, _I32),
                        builder.trunc(timeout_, _I32),
                    ],
                ),
                _I64,
            )

        return sig, codegen

    @jit
    def any_readable(fds: np.ndarray) -> bool:
        """Whether a datagram waits on any of the sockets of ``fds`` (:func:`pollfds`), without waiting."""
        return fds.shape[0] > 0 and poll(fds.ctypes.data, fds.shape[0], 0) > 0

    @intrinsic
    def sched_yield(typingctx):
        """sched_yield(): let another task waiting for this core run first (0, or −1)."""
        sig = types.int64()

        def codegen(context, builder, signature, args):
            fn = _libc(builder, "sched_yield", _I32, [])
            return builder.sext(builder.call(fn, []), _I64)

        return sig, codegen

    @intrinsic
    def monotonic_ns(typingctx):
        """CLOCK_MONOTONIC in integer nanoseconds (time.monotonic_ns's clock)."""
        sig = types.int64()

        def codegen(context, builder, signature, args):
            fn = _libc(builder, "clock_gettime", _I32, [_I32, _I64.as_pointer()])
            ts = cgutils.alloca_once(builder, _I64, size=2)
            builder.call(fn, [ir.Constant(_I32, CLOCK_MONOTONIC), ts])
            seconds = builder.load(ts)
            nanos = builder.load(builder.gep(ts, [ir.Constant(_I32, 1)]))
            return builder.add(builder.mul(seconds, ir.Constant(_I64, 1_000_000_000)), nanos)

        return sig, codegen

    @jit
    def receive(fd: int, rx: np.ndarray, sender: np.ndarray, length: np.ndarray, polling: bool, budget_ns: int,
                patience_ns: int, stats: np.ndarray) -> int:  # fmt: skip
        """One datagram from socket ``fd`` into ``rx`` (its sender's address into ``sender``, the address's length
        into ``length``, int32[1]) → its length. ``polling``: poll for up to ``patience_ns`` [ns], yielding the core
        between polls to any task waiting for it (RAN_OUT when none came); else block (−1 when the socket's receive
        timeout ends the wait). The wait is counted in ``stats`` (POLLED, LATE: after half of ``budget_ns``;
        BLOCKED, SHORT: a blocking wait shorter than ``budget_ns``; :class:`quadsitl.process_util.SpinThenBlock`)."""
        flags = MSG_DONTWAIT if polling else 0
        began = monotonic_ns()
        while True:
            length[0] = SOCKADDR_IN
            n = recvfrom(fd, rx.ctypes.data, rx.size, flags, sender.ctypes.data, length.ctypes.data)
            if n >= 0 or not polling:
                break
            sched_yield()  # a task waiting for this core (the peer itself, when both are on one) runs first
            if monotonic_ns() - began > patience_ns:
                return RAN_OUT
        took = monotonic_ns() - began
        if polling:
            stats[POLLED] += 1
            if took > budget_ns // 2:
                stats[LATE] += 1
        else:
            stats[BLOCKED] += 1
            stats[SHORT] = stats[SHORT] + 1 if took < budget_ns else 0
        return n
