"""The autopilot's plant link served by compiled code: receive the plant's datagram, fly the tick, send the answer,
and again, without coming back to Python between two ticks (:func:`serve`).

Each tick the Python loop of :mod:`autopilot.process` paid for what the tick itself does not need: a receive and a
send through Python's socket objects, the call into the compiled tick (numba checks the type of each of its
sixteen arguments on every call), a few clock reads and comparisons. In a lockstep run that was about as much time
as the tick's own work. :func:`serve` does the same per tick, in the same order, on the same compiled tick
(:func:`autopilot.tick.autopilot_tick` or :func:`~autopilot.tick.sensor_tick`), and gives the loop back to
Python whenever Python has something to do:

- the tick reports more than an answer (telemetry messages or an event due, a full batch, ...): :data:`SENT`,
  its answer already sent, so the plant integrates and sends the next tick while Python does the rest of this
  one (Python's work changes nothing the answer says, and ran after the answer went out before too);
- the tick has no answer (a datagram pymavlink must parse, a refused one, ...), or its answer must wait for an
  offboard setpoint (``limit_tick``, :mod:`autopilot.offboard_lockstep`): :data:`TICKED`, the answer not sent,
  for Python to finish the tick as it always has;
- a datagram from another sender than the plant the link is locked to: :data:`STRANGER`, the datagram in ``rx``
  and its sender in ``addr``;
- the wall-clock moment ``deadline_ns`` has passed (Python's wall-clock work, the next telemetry batch):
  :data:`DUE`;
- a datagram waits on a ground-station socket (asked every ``ground_every_ns`` between ticks, without waiting):
  :data:`GROUND`. Python reads those sockets only then, not on a timer: in real time a timer would bring the loop
  back to Python every other tick, for nothing most of the time;
- no datagram came within the wait (``spin_ns`` of polling, or the socket's receive timeout when blocking):
  :data:`QUIET`.

So every datagram is handled exactly as the Python loop handles it, and lockstep runs are unchanged to the bit
(tested: :mod:`tests.test_plant_loop`). The wait is the one :class:`quadsitl.process_util.SpinThenBlock` chooses:
polling for ``spin_ns`` while the loop is hot, a blocking receive otherwise; what the waits found goes back to it
in ``stats`` (:meth:`~quadsitl.process_util.SpinThenBlock.tally`).
"""

from __future__ import annotations

import numpy as np

from autopilot import tick as kernel
from quadsitl import fastio
from quadsitl.jit import borrowed, jit

TICKED, STRANGER, DUE, QUIET, SENT, GROUND = 0, 1, 2, 3, 4, 5
ANSWERED_ONLY = 7  # fly_one's: the answer sent, nothing left for Python (never returned to Python)
READABLE = 6  # serve_group's: a datagram waits on the plant socket of a vehicle whose datagrams Python reads
# serve_group's: ctl's columns (a row per vehicle) and out's entries
CTL_DEADLINE, CTL_LIMIT, CTL_COMPILED, CTL_GROUND_EVERY, CTL_HELD, CTL_HELD_LENGTH, CTL_HELD_FLAGS, CTL_SIZE = range(8)
VEHICLE, LENGTH, FLAGS, NEXT, OUT_SIZE = range(5)
# stats (int64): ticks answered here, the waits (quadsitl.fastio.receive's counts), the last tick's duration [ns],
# and when the ground-station sockets are next asked (CLOCK_MONOTONIC [ns]; the caller sets it, the loop moves it).
ANSWERED, TICK_NS, NEXT_GROUND, STATS_SIZE = 0, 5, 6, 7
POLLED, LATE, BLOCKED, SHORT = fastio.POLLED, fastio.LATE, fastio.BLOCKED, fastio.SHORT
NO_LIMIT = np.iinfo(np.int64).max

if fastio.AVAILABLE:
    from numba.extending import overload

    def fly_datagram(rx: np.ndarray, length: int, targs: tuple) -> int:
        """The tick of the datagram rx[:length]: :func:`autopilot.tick.autopilot_tick` (``targs``: its arguments
        after the datagram) or, in sensor mode, :func:`autopilot.tick.sensor_tick` (its arguments)."""
        raise NotImplementedError  # compiled code only: the overload below

    @overload(fly_datagram, jit_options={"cache": True})
    def _fly_datagram(rx, length, targs):
        if len(targs) == 15:  # the state mode's arguments (autopilot_tick), else the sensor mode's
            return lambda rx, length, targs: kernel.autopilot_tick(rx, length, *targs)
        return lambda rx, length, targs: kernel.sensor_tick(rx, length, *targs)

    @jit
    def send_frames(frames: tuple, links: tuple) -> bool:
        """The telemetry datagrams the tick built (``frames``: :attr:`autopilot.stream_frames.StreamFrames.out`) to
        each link's destinations (``links``: :attr:`Destinations.out`) → False when a send failed (counted in its
        destination's errors, for Python to deal with)."""
        lens, datagrams = frames[2], frames[1]
        addrs, fds, of_link, errors, count = links
        ok = True
        for d in range(count[0]):
            n = lens[of_link[d]]
            if n > 0:
                sent = fastio.sendto(fds[d], datagrams[of_link[d]].ctypes.data, n, 0, addrs[d].ctypes.data,
                                     fastio.SOCKADDR_IN)  # fmt: skip
                if sent < 0:
                    errors[d] += 1
                    ok = False
        return ok

    @jit(inline=True)
    def fly_one(fd: int, n: int, rx: np.ndarray, addr: np.ndarray, addrlen: np.ndarray, peer: np.ndarray,
                tx: np.ndarray, io: np.ndarray, targs: tuple, stats: np.ndarray, links: tuple,
                limit_tick: int) -> tuple:  # fmt: skip
        """The datagram rx[:n] just received on ``fd`` from ``addr`` (:func:`serve`'s and :func:`serve_group`'s
        arguments) → (STRANGER: not the locked plant's; TICKED: no answer sent (none, or past ``limit_tick``); SENT: the
        answer sent and work left for Python; ANSWERED_ONLY: the answer sent and nothing else; the tick's flags, the
        clock [ns] once done). The answer goes to the plant, then the tick's telemetry frames to ``links``."""
        now = fastio.monotonic_ns()
        if addrlen[0] != fastio.SOCKADDR_IN:
            return STRANGER, 0, now
        for i in range(8):  # family, port, IPv4 address
            if addr[i] != peer[i]:
                return STRANGER, 0, now
        flags = fly_datagram(rx, n, targs)
        if not flags & kernel.ANSWER or io[kernel.TICK] > limit_tick:
            return TICKED, flags, now
        fastio.sendto(fd, tx.ctypes.data, io[kernel.TX_LEN], 0, peer.ctypes.data, fastio.SOCKADDR_IN)
        stats[ANSWERED] += 1
        if flags & kernel.FRAMES and links[4][0] >= 0 and send_frames(targs[-1], links):
            flags &= ~kernel.FRAMES
        end = fastio.monotonic_ns()
        stats[TICK_NS] = end - now
        return (SENT if flags != kernel.ANSWER else ANSWERED_ONLY), flags, end

    @jit
    def serve(fd: int, rx: np.ndarray, addr: np.ndarray, addrlen: np.ndarray, peer: np.ndarray, tx: np.ndarray,
              io: np.ndarray, targs: tuple, deadline_ns: int, polling: bool, budget_ns: int, patience_ns: int,
              hot_after: int, limit_tick: int, stats: np.ndarray, links: tuple, ground: np.ndarray,
              ground_every_ns: int) -> tuple:  # fmt: skip
        """Serve the plant on socket ``fd`` until Python has something to do (the module's docstring) → (status,
        the datagram's length or −1, the tick's flags: with SENT, the answer among them was sent). Datagrams are
        read into ``rx``, their sender into ``addr`` (``addrlen``: its length, int32[1]); ``peer`` is the locked
        plant's address (:func:`quadsitl.fastio.sockaddr`); ``tx`` and ``io`` are the tick's answer buffer and
        bookkeeping (also in ``targs``).

        ``polling``: each wait polls for up to ``patience_ns`` [ns]; else it blocks in the receive (the socket's
        own timeout ends it: QUIET), and once ``hot_after`` consecutive waits were each shorter than the budget
        the loop goes back to Python (DUE), which then polls. ``deadline_ns``: CLOCK_MONOTONIC [ns]. ``ground``:
        the ground-station sockets (:func:`quadsitl.fastio.pollfds`), asked from stats[NEXT_GROUND] on, then every
        ``ground_every_ns``.

        The telemetry frames a tick built (FRAMES) go to the ground-station links' destinations (``links``:
        :attr:`Destinations.out`) after the answer; with no destination list (count −1: one Python cannot give
        here), or when a send fails, the tick's flags keep FRAMES and Python sends them."""
        rx, addr, addrlen, peer, tx, io, targs, stats, links, ground = borrowed(
            (rx, addr, addrlen, peer, tx, io, targs, stats, links, ground)
        )  # quadsitl.jit.borrowed
        while True:
            n = fastio.receive(fd, rx, addr, addrlen, polling, budget_ns, patience_ns, stats)
            if n == fastio.RAN_OUT or n < 0:
                return QUIET, -1, 0
            status, flags, end = fly_one(fd, n, rx, addr, addrlen, peer, tx, io, targs, stats, links, limit_tick)
            if status != ANSWERED_ONLY:
                return status, n, flags
            if end >= deadline_ns or (not polling and stats[SHORT] == hot_after):
                return DUE, -1, 0
            if end >= stats[NEXT_GROUND]:
                stats[NEXT_GROUND] = end + ground_every_ns
                if fastio.any_readable(ground):
                    return GROUND, -1, 0

    @jit(nogil=True)  # it waits on the socket: a host's other vehicles fly meanwhile
    def serve_unlocked(fd: int, rx: np.ndarray, addr: np.ndarray, addrlen: np.ndarray, peer: np.ndarray,
                       tx: np.ndarray, io: np.ndarray, targs: tuple, deadline_ns: int, polling: bool, budget_ns: int,
                       patience_ns: int, hot_after: int, limit_tick: int, stats: np.ndarray, links: tuple,
                       ground: np.ndarray, ground_every_ns: int) -> tuple:  # fmt: skip
        """:func:`serve` without Python's lock while it runs, for a process hosting several vehicles' loops in
        threads (:mod:`autopilot.host`); a process of one vehicle keeps the lock, as it always has."""
        return serve(fd, rx, addr, addrlen, peer, tx, io, targs, deadline_ns, polling, budget_ns, patience_ns,
                     hot_after, limit_tick, stats, links, ground, ground_every_ns)  # fmt: skip

    @jit(nogil=True)  # it waits on the sockets: the host's other threads run meanwhile
    def serve_group(vehicles: object, ctl: np.ndarray, epfd: int, events: np.ndarray, slot: np.ndarray,
                    out: np.ndarray, quiet_ns: int, spin_ns: int) -> int:  # fmt: skip
        """:func:`serve` for several vehicles of one host at once, in one thread, without Python's lock
        (:mod:`autopilot.group`): an ``epoll_wait`` on the vehicles' plant sockets, then each datagram waiting served
        as :func:`serve` serves it, without a thread woken for each vehicle. → a status of :func:`serve`'s, or READABLE
        (the vehicle's plant socket has a datagram for Python to read), for the vehicle out[VEHICLE] (the length and
        flags in out[LENGTH], out[FLAGS]); QUIET with out[VEHICLE] −1 when nothing came for ``quiet_ns``.

        Answers come first: a tick that leaves Python work once its answer is out (SENT) holds its vehicle (its next
        datagram waits) while the others' waiting datagrams are answered, and a deadline (DUE) is given back only
        when no datagram waits, so that one vehicle's trip to Python does not make its group-mates' answers late.

        ``vehicles``: numba's typed List of :func:`group_entry` tuples; ``ctl`` (int64, a row per vehicle):
        CTL_DEADLINE (CLOCK_MONOTONIC [ns]: the vehicle's DUE), CTL_LIMIT (``limit_tick``), CTL_COMPILED (0: the
        vehicle's datagrams go to Python, READABLE), CTL_GROUND_EVERY [ns], CTL_HELD (1: a SENT waits for Python, its
        length and flags in CTL_HELD_LENGTH, CTL_HELD_FLAGS); ``epfd``, ``events``, ``slot``: a
        :class:`quadsitl.fastio.ReadySet` of the plant sockets, in the same order. Datagrams are served in the order
        their sockets became readable; Python's turns are taken in turn from out[NEXT] on. ``spin_ns`` > 0: when no
        datagram waits, ask again without blocking (yielding the core between asks) for up to that long before it
        blocks, as a vehicle alone does in an unpaced lockstep run (:class:`quadsitl.process_util.SpinThenBlock`):
        waking a blocked thread costs more than a vehicle's tick."""
        k = len(vehicles)
        began = fastio.monotonic_ns()
        wait_ms = 0
        while True:
            ready = fastio.epoll_wait(epfd, events.ctypes.data, k, 0 if spin_ns > 0 else wait_ms)
            if ready == 0 and wait_ms > 0 and spin_ns > 0:
                spun = fastio.monotonic_ns()
                while ready == 0 and fastio.monotonic_ns() - spun < spin_ns:
                    fastio.sched_yield()
                    ready = fastio.epoll_wait(epfd, events.ctypes.data, k, 0)
                if ready == 0:
                    ready = fastio.epoll_wait(epfd, events.ctypes.data, k, wait_ms)
            served = 0
            for j in range(ready if ready > 0 else 0):
                i = slot[events[j * fastio.EPOLL_WORDS + fastio.EPOLL_FD_WORD]]
                if ctl[i, CTL_HELD]:  # its Python work goes first
                    continue
                if ctl[i, CTL_COMPILED] == 0:
                    return _picked(out, i, k, READABLE, -1, 0)
                fd, rx, addr, addrlen, peer, tx, io, targs, stats, links, ground = borrowed(vehicles[i])
                addrlen[0] = fastio.SOCKADDR_IN
                n = fastio.recvfrom(fd, rx.ctypes.data, rx.size, fastio.MSG_DONTWAIT, addr.ctypes.data,
                                    addrlen.ctypes.data)  # fmt: skip
                if n < 0:
                    continue
                served += 1
                status, flags, end = fly_one(fd, n, rx, addr, addrlen, peer, tx, io, targs, stats, links,
                                             ctl[i, CTL_LIMIT])  # fmt: skip
                if status == SENT:  # Python's work once the others are answered
                    ctl[i, CTL_HELD], ctl[i, CTL_HELD_LENGTH], ctl[i, CTL_HELD_FLAGS] = 1, n, flags
                elif status != ANSWERED_ONLY:
                    return _picked(out, i, k, status, n, flags)
                elif end >= stats[NEXT_GROUND]:
                    stats[NEXT_GROUND] = end + ctl[i, CTL_GROUND_EVERY]
                    if fastio.any_readable(ground):
                        return _picked(out, i, k, GROUND, -1, 0)
            if served:
                wait_ms = 0  # more may have come meanwhile: answered before anything else
                continue
            now = fastio.monotonic_ns()
            wait_ns = began + quiet_ns - now
            for j in range(k):
                i = (out[NEXT] + j) % k
                if ctl[i, CTL_HELD]:
                    ctl[i, CTL_HELD] = 0
                    return _picked(out, i, k, SENT, ctl[i, CTL_HELD_LENGTH], ctl[i, CTL_HELD_FLAGS])
                if now >= ctl[i, CTL_DEADLINE]:
                    return _picked(out, i, k, DUE, -1, 0)
                wait_ns = min(wait_ns, ctl[i, CTL_DEADLINE] - now)
            if wait_ns <= 0:
                out[VEHICLE] = -1
                return QUIET
            wait_ms = (wait_ns + 999_999) // 1_000_000

    @jit(inline=True)
    def _picked(out: np.ndarray, i: int, k: int, status: int, n: int, flags: int) -> int:
        """serve_group's answer: ``status`` for vehicle ``i`` of ``k`` (the next call starts with the one after it)."""
        out[VEHICLE], out[LENGTH], out[FLAGS], out[NEXT] = i, n, flags, (i + 1) % k
        return status


def group_entry(fd: int, rx: np.ndarray, addr: np.ndarray, addrlen: np.ndarray, peer: np.ndarray,
                tx: np.ndarray, io: np.ndarray, targs: tuple, stats: np.ndarray, links: tuple,
                ground: np.ndarray) -> tuple:  # fmt: skip
    """One vehicle of :func:`serve_group`: :func:`serve`'s arguments that are the vehicle's own, in one tuple."""
    return (fd, rx, addr, addrlen, peer, tx, io, targs, stats, links, ground)


MAX_DESTINATIONS = 16  # ground-station destinations the compiled loop sends the telemetry frames to


class Destinations:
    """Where :func:`serve` sends the telemetry frames the ticks build (``out``): each destination's IPv4 address,
    the socket (of its link) it goes from, the link's index (its datagram), and the sends that failed. With none
    set (:meth:`set` with None: a destination the compiled loop cannot reach, IPv6 or too many), Python sends."""

    def __init__(self) -> None:
        self.addrs = np.zeros((MAX_DESTINATIONS, fastio.SOCKADDR_IN), dtype=np.uint8)
        self.fds = np.zeros(MAX_DESTINATIONS, dtype=np.int64)
        self.of_link = np.zeros(MAX_DESTINATIONS, dtype=np.int64)
        self.errors = np.zeros(MAX_DESTINATIONS, dtype=np.int64)
        self.count = np.array([-1], dtype=np.int64)
        self.out = (self.addrs, self.fds, self.of_link, self.errors, self.count)
        self.entries: list[tuple[int, tuple[str, int]]] = []  # (link index, address), in the arrays' order

    def set(self, entries: list[tuple[int, int, tuple[str, int]]] | None) -> None:
        """The destinations: (link index, socket fd, IPv4 address) each; None: Python sends."""
        self.errors[:] = 0
        if entries is None or len(entries) > MAX_DESTINATIONS:
            self.entries, self.count[0] = [], -1
            return
        for i, (link, fd, address) in enumerate(entries):
            self.addrs[i] = fastio.sockaddr(address)
            self.fds[i], self.of_link[i] = fd, link
        self.entries = [(link, address) for link, _, address in entries]
        self.count[0] = len(entries)

    def failed(self) -> list[tuple[int, tuple[str, int]]]:
        """The destinations a send to failed since the last call: (link index, address) each."""
        out = [self.entries[i] for i in np.flatnonzero(self.errors[: max(self.count[0], 0)])]
        self.errors[:] = 0
        return out


def _copied(value: object) -> object:
    if isinstance(value, np.ndarray):
        return value.copy()
    if isinstance(value, tuple):
        return tuple(_copied(v) for v in value)
    return value


def group_list(entries: list[tuple]) -> object:
    """numba's typed List of :func:`group_entry` tuples, for :func:`serve_group`."""
    from numba.typed import List

    out = List()
    for entry in entries:
        out.append(entry)
    return out


def warm_up(targs: tuple, unlocked: bool = False) -> None:
    """Compile (or load from numba's cache) :func:`serve` (``unlocked``: :func:`serve_unlocked`) for these tick
    arguments (the autopilot's own, copied:
    nothing of its state is touched) before the first tick: one made-up ODOMETRY datagram served on a loopback
    socket."""
    if not fastio.AVAILABLE:
        return
    import socket
    import time

    from quadsitl import codec
    from quadsitl.process_util import set_receive_timeout

    targs = _copied(targs)
    tx, io = targs[-4], targs[-3]
    frame, n = kernel.made_up_datagram(False, codec.FRAME_MAX)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind(("127.0.0.1", 0))
        set_receive_timeout(sock, 0.1)
        peer = fastio.sockaddr(sock.getsockname())
        rx, addr, addrlen = np.zeros(65535, dtype=np.uint8), np.zeros_like(peer), np.zeros(1, dtype=np.int32)
        for polling in (True, False):
            sock.sendto(frame[:n].tobytes(), sock.getsockname())
            served = serve_unlocked if unlocked else serve
            served(sock.fileno(), rx, addr, addrlen, peer, tx, io, targs, 0, polling, 1000, 1000, 8, NO_LIMIT,
                   np.zeros(STATS_SIZE, dtype=np.int64), Destinations().out, fastio.pollfds([sock]), 0)  # fmt: skip
        if unlocked:  # a host's vehicles may also be served in groups (autopilot.group)
            sock.sendto(frame[:n].tobytes(), sock.getsockname())
            entry = group_entry(
                sock.fileno(),
                rx,
                addr,
                addrlen,
                peer,
                tx,
                io,
                targs,
                np.zeros(STATS_SIZE, dtype=np.int64),
                Destinations().out,
                fastio.pollfds([sock]),
            )
            ctl = np.zeros((1, CTL_SIZE), dtype=np.int64)
            ctl[0, :CTL_HELD] = time.monotonic_ns() + 10**8, NO_LIMIT, 1, 0
            with fastio.ReadySet([sock]) as ready:
                serve_group(group_list([entry]), ctl, ready.fd, ready.events, ready.slot,
                            np.zeros(OUT_SIZE, dtype=np.int64), 10**8, 0)  # fmt: skip
