"""What every process shell needs: address parsing, a clean stop on SIGINT and SIGTERM (also when started with
SIGINT ignored), dying with the parent."""

from __future__ import annotations

import contextlib
import ctypes
import errno
import functools
import gc
import io
import os
import random
import select
import signal
import socket
import struct
import sys
import time
from collections.abc import Callable, Collection, Sequence
from pathlib import Path

from quadsitl.cli_util import UsageError

PLANT_DIVERGED = 3
"""The plant process's exit status when its state left the bounds (:func:`sitl.plant.inside`); ``quadsitl fly``
then ends with the same status (docs/failures.md)."""


def parse_address(option: str, text: str) -> tuple[str, int]:
    """'HOST:PORT' → (host, port), or a UsageError naming the option."""
    host, sep, port = text.rpartition(":")
    if not sep or not host or not port.isdigit() or not 0 <= int(port) <= 65535:
        raise UsageError(f"{option} {text!r}: expected HOST:PORT with PORT in 0..65535")
    return host, int(port)


def parse_remote(option: str, text: str) -> tuple[str, int] | None:
    """'HOST:PORT' or 'none' (→ None)."""
    return None if text.lower() == "none" else parse_address(option, text)


PORTS_VARIABLE = "QUADSITL_PORTS"


def _pick_ports() -> tuple[int, int]:
    """[first, end) of the ports :func:`free_port` picks from: above PX4's (14540-14589, 18570-18599) and below Linux's
    default ephemeral range (32768-60999); or a part of that the environment's QUADSITL_PORTS ("FIRST-LAST") gives,
    so that runs started side by side (the test suite's workers) never pick a port another has picked and not bound
    yet: a stream's remote port is bound only when its client starts."""
    text = os.environ.get(PORTS_VARIABLE, "")
    if text:
        try:
            first, last = (int(x) for x in text.split("-"))
        except ValueError:
            raise ValueError(f"{PORTS_VARIABLE}={text!r}: expected FIRST-LAST, e.g. 20000-24000") from None
        if not 1024 <= first < last <= 65535:
            raise ValueError(f"{PORTS_VARIABLE}={text!r}: expected 1024 <= FIRST < LAST <= 65535")
        return first, last + 1
    return 20000, 32768


PICK_PORTS = _pick_ports()
EPHEMERAL_RANGE = "/proc/sys/net/ipv4/ip_local_port_range"
_pick = random.Random()  # its own state: picking a port never moves a seeded generator's


def ephemeral_range() -> tuple[int, int]:
    """[first, last] of the ports the OS hands to a socket bound to port 0 or connected unbound (Linux's
    ``ip_local_port_range``; its default where that is not readable)."""
    try:
        first, last = (int(x) for x in Path(EPHEMERAL_RANGE).read_text().split())
    except (OSError, ValueError):
        return 32768, 60999
    return first, last


def free_port(kind: int = socket.SOCK_DGRAM, avoid: Collection[int] = ()) -> int:
    """A port free on 127.0.0.1 now (UDP by default, TCP with SOCK_STREAM), for a process about to be started to bind.

    ``avoid``: ports that are free now but taken soon (a plan's ports its processes have not bound yet), never
    returned.

    It is picked at random from PICK_PORTS outside the ephemeral range, so that no socket that binds port 0 or
    connects, in any process, is handed it by the OS before the process it is for binds it (a port the OS had just
    said free, from the ephemeral range, was: two runs at once, one of them failed with "Address already in use").
    Where the ephemeral range covers PICK_PORTS, a port the OS says is free."""
    first, last = ephemeral_range()
    skip = set(avoid)
    outside = [p for p in range(*PICK_PORTS) if not first <= p <= last and p not in skip]
    for _ in range(64 if outside else 0):
        port = _pick.choice(outside)
        with socket.socket(socket.AF_INET, kind) as s:
            try:
                s.bind(("127.0.0.1", port))
            except OSError:
                continue  # in use: another
            return port
    for _ in range(64):
        with socket.socket(socket.AF_INET, kind) as s:
            s.bind(("127.0.0.1", 0))
            port = s.getsockname()[1]
        if port not in skip:
            return port
    raise OSError("no free port on 127.0.0.1")


def free_ports_apart(count: int, kind: int = socket.SOCK_DGRAM) -> list[int]:
    """``count`` ports free on 127.0.0.1 now (:func:`free_port`), no two the same: each is picked avoiding those
    before it, which are free too until their processes bind them."""
    ports: list[int] = []
    for _ in range(count):
        ports.append(free_port(kind, avoid=ports))
    return ports


def bind_tcp(
    option: str, value: str, host: str, port: int, choose: str, host_option: str | None = None
) -> socket.socket:
    """A listening TCP socket on host:port, or a UsageError naming the option and its value; a busy port
    says how to choose another (``choose`` follows the option's name in that hint). Other failures are
    blamed on ``host_option`` when the host has an option of its own."""
    sock = socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    try:
        sock.bind((host, port))
        sock.listen(128)
    except OSError as exc:
        sock.close()
        where = f"cannot listen on {host}:{port}: {exc.strerror or exc}"
        if exc.errno == errno.EADDRINUSE:
            raise UsageError(f"{option} {value}: {where}; choose another with {option} {choose}") from None
        raise UsageError(f"{host_option} {host}: {where}" if host_option else f"{option} {value}: {where}") from None
    return sock


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
    before every receive, a system call more per tick, which the lockstep loop cannot afford
    (docs/performance.md#in-lockstep)."""
    sock.settimeout(None)
    usec = 0 if seconds is None else max(1, round(seconds * 1e6))  # 0 = no timeout
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVTIMEO, struct.pack("ll", usec // 1_000_000, usec % 1_000_000))


SPIN_ENV = "QUADSITL_SPIN_US"  # the polling budget in µs (0: always block)
SPIN_BUDGET = 200e-6  # [s] waits shorter than this make a lockstep loop hot; hot, it polls this long, then blocks
PATIENCE = 2e-3  # [s] how long a hot loop polls before it blocks where nothing waits on its pace (SpinThenBlock)
HOT_AFTER = 8  # consecutive waits shorter than the budget that make a loop hot
SPIN_WINDOW = 256  # waits per verdict on whether polling pays
SPIN_MISSES = 32  # polls that ran out (or came late) in a window, beyond which polling stops for a while
SPIN_STRIKES = 2  # failing windows in a row that stop polling: a burst (another process's few ms) is not enough
SPIN_COOL = (0.25, 4.0)  # [s] how long it stops: doubling from the first to the second while it keeps failing
PACE_WINDOW = 0.1  # [s] wall: how long PaceGauge averages a peer's pace over
PACED_BELOW = 2.0  # [× real time] a peer whose ticks come slower than this is paced (PaceGauge)


def spin_budget() -> float:
    """The polling budget [s]: ``$QUADSITL_SPIN_US`` µs if set (0 turns polling off), else SPIN_BUDGET."""
    text = os.environ.get(SPIN_ENV)
    if not text:
        return SPIN_BUDGET
    try:
        value = float(text)
    except ValueError:
        value = -1.0
    if not 0.0 <= value <= 100_000.0:
        raise UsageError(f"${SPIN_ENV} = {text!r}: expected microseconds in [0, 100000] (0 = always block)")
    return value * 1e-6


class SpinThenBlock:
    """Receive for a lockstep loop: poll without blocking for up to ``budget`` seconds (``patience``, if longer),
    then block.

    A process that blocks in ``recv`` pays a wake-up when the datagram comes, and on a virtual machine the wake-up of a
    halted core, which costs more than the per-tick work of either side (docs/performance.md#in-lockstep). A loop that
    is hot (its last HOT_AFTER waits were each shorter than the budget: the other side answers within microseconds)
    polls instead and does not sleep. A loop that is paced (``--speed 1``, real time: a millisecond between datagrams)
    or whose peer has gone (free-wheeling) finds its wait longer than the budget and goes back to blocking, so it spends
    no CPU on polling. A paced loop that finds one datagram already waiting (it was late, behind a busy core) does not
    turn hot: it would poll the whole budget for the next one, a millisecond away, and in a real-time fleet under
    SCHED_FIFO hold a core its fleet-mates need.

    A loop whose peer answers within microseconds but now and then takes longer (a moment of Python there: a telemetry
    batch, a ground-station message, the scheduler giving its core to another process for a while) turns cold at each
    such moment with a budget of 200 µs. Turning hot again takes HOT_AFTER blocking waits, and where waking a process is
    slow (a Firecracker guest: docs/performance.md#in-lockstep) each of those waits is, so an unpaced lockstep run
    spends most of its time there. Such a loop is given ``patience`` (PATIENCE, 2 ms): it polls that long before it
    blocks. Only a loop that nothing paces gets it, as it costs CPU when the peer is late: the plant in an unpaced run
    (it knows its pace), and the autopilot while its plant's ticks come at PACED_BELOW × real time or faster (it
    measures their pace: :class:`PaceGauge`; a real-time plant catching up after a stall sends ticks back to back, and
    an autopilot made hot by them would otherwise poll through every millisecond after). A paced plant's wait for each
    answer is short too, so it turns hot; without patience it keeps polling at most a budget when an answer is late, and
    leaves the core to the processes a paced run serves (an idle-priority dashboard).

    Polling only pays while both processes have a core each. On a machine whose cores are taken by
    something else, a poller holds a core its peer needs, and the loop slows down instead: the polls
    then run out of budget. When more than SPIN_MISSES of SPIN_WINDOW polls do, polling stops for
    SPIN_COOL seconds (doubling while it keeps failing), and the loop blocks as it would without it.
    Only the waiting changes: every datagram is received and handled exactly as before, so lockstep
    results are unchanged.
    """

    def __init__(
        self,
        recv: Callable[..., object],
        into: bytearray | None = None,
        budget: float | None = None,
        patience: float | None = None,
    ) -> None:
        # ``recv`` is sock.recv or sock.recvfrom (a blocking socket, with SO_RCVTIMEO as needed); with a buffer
        # ``into``, sock.recv_into or sock.recvfrom_into, which read into it instead of making bytes. ``patience``
        # [s]: how long a hot loop polls (None: the budget; never less than the budget).
        args = (65535,) if into is None else (into, 0)
        self.poll = functools.partial(recv, *args, socket.MSG_DONTWAIT)
        self.block = functools.partial(recv, *args)
        self.budget = spin_budget() if budget is None else budget
        self.be_patient(patience)
        self.hot = False
        self._short = 0  # consecutive waits shorter than the budget
        self.polled = 0  # datagrams that came while polling
        self.blocked = 0  # waits that blocked
        self.cooled = 0  # times polling was stopped for not paying
        self._polls = self._misses = 0
        self._cool_until = 0.0
        self._cool = SPIN_COOL[0]
        self._strikes = 0  # failing windows in a row

    def be_patient(self, patience: float | None) -> None:
        """Poll for up to ``patience`` seconds when hot (None: the budget; never less than the budget; with polling
        off, a budget of 0, nothing polls)."""
        self.patience = self.budget if patience is None or self.budget <= 0 else max(patience, self.budget)

    def __call__(self):
        """What ``recv`` returns; raises as it does (BlockingIOError on SO_RCVTIMEO's timeout)."""
        start = time.perf_counter()
        if self.hot and start >= self._cool_until:
            end, poll = start + self.patience, self.poll
            while True:
                try:
                    out = poll()
                except (BlockingIOError, InterruptedError):
                    if time.perf_counter() < end:
                        continue
                    self._verdict(miss=True)
                    break
                self.polled += 1
                # A datagram that took more than half the budget to come was late: the peer had to wait for
                # a core. Counted as a miss, as is a poll that ran out of patience.
                self._verdict(miss=time.perf_counter() - start > 0.5 * self.budget)
                return out  # still hot
        self.blocked += 1
        try:
            return self.block()
        finally:
            self._short = self._short + 1 if time.perf_counter() - start < self.budget else 0
            self.hot = self._short >= HOT_AFTER

    def polling(self) -> bool:
        """True when the next wait polls: the loop is hot, polling is on and not stopped for a while."""
        return self.hot and self.budget > 0 and time.perf_counter() >= self._cool_until

    def tally(self, polled: int, late: int, ran_out: bool, blocked: int, short: int) -> None:
        """Waits made elsewhere with this budget, the way :meth:`__call__` makes them (a compiled loop,
        :mod:`autopilot.plant_loop`): ``polled`` datagrams came while polling, ``late`` of them after half the
        budget; ``ran_out``: a poll then found none within its patience (a miss, after which the loop is no longer
        hot and the next wait blocks); ``blocked`` waits blocked, the last ``short`` of them in a row each shorter
        than the budget."""
        self.polled += polled
        self._verdicts(polled, late)
        if ran_out:
            self._verdict(miss=True)
            self._short, self.hot = 0, False
        if blocked:
            self.blocked += blocked
            self._short = short
            self.hot = short >= HOT_AFTER

    @property
    def short(self) -> int:
        """Consecutive waits, up to now, each shorter than the budget."""
        return self._short

    def _verdict(self, miss: bool) -> None:
        """One poll (a miss: it ran out, or its datagram came late); the Python loops' per-receive path."""
        self._polls += 1
        self._misses += miss
        if self._polls >= SPIN_WINDOW:
            self._judge()

    def _verdicts(self, polls: int, late: int) -> None:
        """``polls`` polls in a row, the first ``late`` of them misses, counted window by window: the same as one
        :meth:`_verdict` each (a compiled loop reports tens of thousands at a time; one call each was a measurable
        share of a lockstep tick on each side: docs/performance.md#per-call)."""
        while polls > 0:
            n = min(polls, SPIN_WINDOW - self._polls)
            missed = min(max(late, 0), n)
            self._polls += n
            self._misses += missed
            polls -= n
            late -= missed
            if self._polls >= SPIN_WINDOW:
                self._judge()

    def _judge(self) -> None:
        """A full window of polls: polling goes on, or stops for a while when more than SPIN_MISSES missed."""
        if self._misses <= SPIN_MISSES:
            self._cool, self._strikes = SPIN_COOL[0], 0
        else:  # a failing window: polling stops after SPIN_STRIKES in a row, or at once if it failed since it resumed
            self._strikes += 1
            if self._strikes >= SPIN_STRIKES or self._cool > SPIN_COOL[0]:
                self._cool_until = time.perf_counter() + self._cool
                self._cool = min(2 * self._cool, SPIN_COOL[1])
                self._strikes = 0
                self.cooled += 1
        self._polls = self._misses = 0


class PaceGauge:
    """How fast a peer's ticks come, in multiples of real time, over windows of ``window`` seconds of wall time: how
    the autopilot knows what its plant knows, whether the run is paced (real time, ``--speed``), from the ticks'
    own numbers. A paced loop should not be patient (:class:`SpinThenBlock`): a real-time plant that falls behind
    (a stalled machine) catches up by sending its late ticks back to back, the autopilot's waits are then short and
    make it hot, and with patience it would poll (``sched_yield``) through every period between two paced ticks
    until polling stopped for not paying, hundreds of periods later."""

    def __init__(self, period: float, window: float = PACE_WINDOW) -> None:
        self.period = period  # [s] one tick of simulated time
        self.window = window
        self._since: tuple[int, float] | None = None  # (tick, wall) where the window began

    def update(self, tick: int, wall: float) -> float | None:
        """``tick``: the newest tick heard; ``wall``: now [s, monotonic] → the pace over the window this call ends
        [× real time: simulated over wall seconds], or None while the window is still open. A tick number that went
        back (a new plant run) reads as a negative pace."""
        if self._since is None:
            self._since = (tick, wall)
            return None
        tick0, wall0 = self._since
        if wall - wall0 < self.window:
            return None
        self._since = (tick, wall)
        return (tick - tick0) * self.period / (wall - wall0)

    @staticmethod
    def patience(pace: float) -> float | None:
        """The patience for a loop whose peer keeps ``pace``: PATIENCE unpaced (PACED_BELOW × real time or faster),
        none (the budget) paced."""
        return PATIENCE if pace >= PACED_BELOW else None


def wait_readable(sock: socket.socket, seconds: float) -> bool:
    """Wait up to ``seconds`` (microsecond resolution) for ``sock`` to have a datagram."""
    try:
        readable, _, _ = select.select([sock], [], [], max(seconds, 0.0))
    except InterruptedError:
        return False
    return bool(readable)


def readable_of(socks: Sequence[socket.socket], seconds: float) -> list[socket.socket]:
    """Wait up to ``seconds`` (microsecond resolution: select, where epoll and poll round up to whole milliseconds,
    too coarse for a 1 kHz schedule) for any of ``socks`` to have a datagram; those that do."""
    try:
        readable, _, _ = select.select(socks, [], [], max(seconds, 0.0))
    except InterruptedError:
        return []
    return readable


def quiet_garbage_collector() -> None:
    """Keep the cyclic garbage collector out of the per-tick loop: objects made so far (modules, presets)
    are frozen out of its view, and it runs only after 50,000 net allocations of container objects
    instead of 700. The loops make no reference cycles, so reference counting frees what they allocate;
    the collector stays on for anything else."""
    gc.collect()
    gc.freeze()
    gc.set_threshold(50_000, 50, 100)


def free_ports(n: int, kind: int = socket.SOCK_DGRAM, taken: set[int] | None = None) -> int:
    """The first of ``n`` consecutive ports that are free on 127.0.0.1 now (for a fleet's PORT + i plan), none of
    them in ``taken`` (ports picked before, not bound yet), which gets them."""
    taken = set() if taken is None else taken
    for _ in range(200):
        base = free_port(kind, avoid=taken)
        if taken.intersection(range(base, base + n)):
            continue
        socks = []
        try:
            for i in range(n):
                s = socket.socket(socket.AF_INET, kind)
                socks.append(s)
                s.bind(("127.0.0.1", base + i))
            taken.update(range(base, base + n))
            return base
        except OSError:
            continue
        finally:
            for s in socks:
                s.close()
    raise OSError(f"no {n} consecutive free ports on 127.0.0.1")


def children_of(pid: int) -> list[int]:
    """The live child processes of ``pid`` (Linux's /proc)."""
    out = []
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            try:
                fields = (d / "stat").read_text().rsplit(")", 1)[1].split()
            except OSError:
                continue
            if int(fields[1]) == pid:
                out.append(int(d.name))
    return out


def rss_mb(pid: int | str, field: str = "VmRSS") -> float:
    """Resident memory [MB] of a live process (``/proc/PID/status``'s VmRSS; ``pid`` "self": this one's): now, or its
    peak since it started its program (``field`` "VmHWM"). Not ``getrusage``'s peak, which also counts what the
    parent held when it forked the process (a bench that had compiled in-process gave each plant 2.4 GB)."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith(f"{field}:"):
            return int(line.split()[1]) / 1024.0
    return 0.0


def start_process(quiet_gc: bool = True) -> None:
    """What every process's main() does first: die with the parent, stop cleanly on SIGINT and SIGTERM
    (:func:`handle_stop_signals`) and, for the per-tick loops, keep the garbage collector quiet."""
    die_with_parent()
    handle_stop_signals()
    if quiet_gc:
        quiet_garbage_collector()


def clock_above_its_peers() -> bool:
    """Under a real-time policy (``chrt -f P quadsitl up ...``: every process inherits SCHED_FIFO or SCHED_RR at P),
    raise this process one priority above the others: the plant, whose clock every vehicle's period hangs on,
    then never waits behind an autopilot. True when it did; nothing under the default policy, or when the system
    refuses (no root or CAP_SYS_NICE)."""
    try:
        policy = os.sched_getscheduler(0)
        if policy not in (os.SCHED_FIFO, os.SCHED_RR):
            return False
        priority = os.sched_getparam(0).sched_priority
        if priority >= os.sched_get_priority_max(policy):
            return False
        os.sched_setscheduler(0, policy, os.sched_param(priority + 1))
    except (AttributeError, OSError):
        return False
    return True


TIMER_SLACK_NS = 1_000  # [ns] how late Linux may fire a real-time clock's timers (its default: 50,000)


def timers_on_time() -> bool:
    """Linux: let this thread's timers fire at most TIMER_SLACK_NS late (``prctl(PR_SET_TIMERSLACK)``; threads it starts
    afterwards inherit it). The kernel's default slack for a task under the default policy is 50 µs: it may fire a
    sleep's timer that much late to group wake-ups and save power, so a real-time clock's every tick would start about
    50 µs into its 1 ms period, a twentieth of the time its vehicles have to answer (measured:
    docs/performance.md#in-real-time). Under SCHED_FIFO the kernel already gives no slack. True when it was set; False
    elsewhere or when refused."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL("libc.so.6", use_errno=True)
        return libc.prctl(29, ctypes.c_ulong(TIMER_SLACK_NS), 0, 0, 0) == 0  # PR_SET_TIMERSLACK
    except (OSError, AttributeError):
        return False


CPU_LATENCY = "/dev/cpu_dma_latency"  # Linux's PM QoS request for every core's wake-up latency [µs, int32]
CORES_AWAKE_HELP = (f"while the run lasts, keep every core out of slow idle states (Linux's PM QoS, {CPU_LATENCY} at "
                    "0 µs: idle cores poll instead of halting), for real-time runs on virtual machines; needs root "
                    "or write access to that file")  # fmt: skip


def hold_cores_awake(path: str = CPU_LATENCY) -> int:
    """``--cores-awake``: keep every core out of the idle states it is slow to wake from (Linux's PM QoS: a wake-up
    latency of 0 µs written to ``path``, as ``cyclictest`` does) for as long as the returned file descriptor stays open;
    the kernel drops the request when it is closed or the process ends, however it ends. An idle core then polls instead
    of halting. On a virtual machine a halted virtual CPU is a thread its host must wake and schedule again, which can
    take longer than a 1 ms period (docs/performance.md#in-real-time); the price is that every idle core spins while the
    request is held. UsageError naming the option, the file and the reason when the request is refused (it needs root,
    or write access to the file)."""
    try:
        fd = os.open(path, os.O_WRONLY)
    except OSError as exc:
        why = "it needs root, or write access to it" if exc.errno in (errno.EACCES, errno.EPERM) else (
            "this system has no PM QoS interface there")  # fmt: skip
        raise UsageError(f"--cores-awake: cannot write {path} ({exc.strerror}): {why}") from None
    try:
        os.write(fd, struct.pack("=i", 0))
    except OSError as exc:
        os.close(fd)
        raise UsageError(f"--cores-awake: cannot write {path} ({exc.strerror})") from None
    return fd


class StopRequested(KeyboardInterrupt):
    """Raised in the main thread by SIGINT or SIGTERM once :func:`handle_stop_signals` has run. It is a
    KeyboardInterrupt, so every ``except KeyboardInterrupt`` (and every ``finally``) handles SIGTERM exactly as
    Ctrl-C; ``signum`` says which signal it was."""

    def __init__(self, signum: int) -> None:
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


def stop_status(exc: BaseException) -> int:
    """The exit status of a command interrupted before it finished its job, as shells report it: 128 + the
    signal's number (130 for SIGINT, 143 for SIGTERM). A command that runs until stopped (``up``,
    ``dashboard``, ``plant``, ``autopilot``, ``replay --loop``) exits 0 instead: the stop was its end."""
    if isinstance(exc, StopRequested):
        return 128 + exc.signum
    if isinstance(exc, SystemExit) and isinstance(exc.code, int):
        return exc.code
    return 128 + signal.SIGINT


def whole_lines() -> None:
    """Make this process write each line of stdout and stderr in one ``write``, flushed at its newline. Unbuffered
    (``PYTHONUNBUFFERED=1``, common in containers and CI), Python's ``print`` writes its text and its newline in two
    calls, and the children of ``fly``/``up``, which share the launcher's terminal, interleaved their lines: two
    autopilots of a fleet ending at once printed ``...0.25 s)autopilot: ...`` and then an empty line. Line buffering
    keeps what unbuffered output is for: every line out as soon as it ends."""
    for stream in (sys.stdout, sys.stderr):
        if isinstance(stream, io.TextIOWrapper) and stream.write_through:
            stream.reconfigure(line_buffering=True, write_through=False)


def run_stoppable(main: Callable[[], int], stopped: int | None = 0, name: str = "quadsitl") -> int:
    """Run a process's ``main()`` and return its exit status. A stop request that ``main`` did not handle
    itself, because it came during start-up (arguments, presets, sockets, compiling), before ``main``'s own
    ``try``, ends the process quietly, without a traceback: status ``stopped`` (0 for a command that runs until
    stopped), or, when ``stopped`` is None, 128 + the signal. Every process entry point goes through this
    (``python -m sitl``, ``-m autopilot``, ``-m groundstation``, the dashboard, replay, and ``quadsitl``). An error
    that escapes ``main`` after a stop request is taken as that stop's (the interrupted code reported it as its own)
    and printed as one line ``NAME: stopped; while stopping: ...``; ``name`` is also what a finalizer's failure after a
    stop is reported under (:func:`handle_stop_signals`)."""
    global _process_name
    _process_name = name
    whole_lines()
    try:
        return main()
    except StopRequested as exc:
        return stop_status(exc) if stopped is None else stopped
    except Exception as exc:
        signum = stop_requested()
        if signum is None:
            raise
        # The stop request interrupted code that reported it as an error of its own: CPython's import of ssl,
        # interrupted at one spot, raised "TypeError: expected a message argument" instead of the StopRequested
        # (a dashboard stopped as it started, ci on a96fa71). The process was asked to stop and stopped: the stop's
        # status, and one line instead of a traceback, so that a real error in a clean-up stays visible.
        print(f"{name}: stopped; while stopping: {type(exc).__name__}: {exc}", file=sys.stderr)
        return 128 + signum if stopped is None else stopped


def stop_requested() -> int | None:
    """The signal of this process's first stop request (SIGINT or SIGTERM), or None if it was never asked to stop."""
    return _stop_requested


STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)
FORCE_AFTER = 2.0  # [s] a second stop signal later than this after the first interrupts the clean-up too
LOST_STOP_AGAIN = 0.005  # [s] when a stop request raised where Python drops exceptions is raised again
_stop_requested_at: float | None = None
_stop_requested: int | None = None  # the signal of this process's first stop request
_process_name = "quadsitl"  # what this process calls itself on stderr (run_stoppable's name)


def handle_stop_signals() -> None:
    """Install this process's own handlers for SIGINT and SIGTERM, whatever it inherited: both raise
    :class:`StopRequested` in the main thread, so ``finally`` blocks run (children stopped, sockets and
    Zenoh sessions closed, logs flushed).

    Needed because a non-interactive shell (a CI script, a test harness, ``cmd &`` in a script) starts its
    background jobs with SIGINT ignored, and Python leaves an ignored SIGINT ignored: without this, Ctrl-C
    (or ``kill -INT``) would not stop ``quadsitl up &``. A signal that comes while a stop is already under way
    is ignored for FORCE_AFTER seconds (a launcher's SIGTERM to its children right after the terminal's
    SIGINT reached them all must not interrupt their clean-up); a later one interrupts the clean-up too."""
    global _stop_requested_at, _stop_requested
    _stop_requested_at = _stop_requested = None

    def handler(signum: int, _frame: object) -> None:
        global _stop_requested_at, _stop_requested
        now = time.monotonic()
        if _stop_requested_at is not None and now - _stop_requested_at < FORCE_AFTER:
            return
        _stop_requested_at = now
        if _stop_requested is None:
            _stop_requested = signum
        raise StopRequested(signum)

    for sig in STOP_SIGNALS:
        signal.signal(sig, handler)
    lost: int | None = None  # the signal of a StopRequested that was dropped, until raised again
    previous = sys.unraisablehook

    def unraisable(info: object) -> None:
        """A StopRequested raised where Python cannot raise (a finalizer, a ctypes callback: llvmlite's while numba
        loads compiled code) is only printed and dropped: the process went on as if never asked to stop. It is
        raised again a moment later, from SIGALRM, where the main thread then is."""
        nonlocal lost
        exc = getattr(info, "exc_value", None)
        if isinstance(exc, StopRequested):
            lost = exc.signum
            signal.setitimer(signal.ITIMER_REAL, LOST_STOP_AGAIN)
            return
        if _stop_requested is not None and exc is not None:
            # The stop interrupted an object's making (llvmlite's ValueRef, while numba loads compiled code), and its
            # finalizer then failed on what was never set: one line, as run_stoppable reports such an error.
            where = getattr(getattr(info, "object", None), "__qualname__", "a finalizer")
            print(f"{_process_name}: stopped; while stopping, in {where}: {type(exc).__name__}: {exc}",
                  file=sys.stderr)  # fmt: skip
            return
        previous(info)

    def again(_signum: int, _frame: object) -> None:
        nonlocal lost
        if lost is not None:
            signum, lost = lost, None
            raise StopRequested(signum)

    signal.signal(signal.SIGALRM, again)
    sys.unraisablehook = unraisable


def die_with_parent() -> None:
    """Linux: ask the kernel to SIGTERM this process when its parent dies (no orphans, even after
    ``kill -9`` of the launcher). A no-op elsewhere."""
    if sys.platform.startswith("linux"):
        try:
            libc = ctypes.CDLL("libc.so.6", use_errno=True)
            libc.prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG
        except OSError:
            pass


READY_ENV = "QUADSITL_READY_FD"  # a pipe's write end, inherited from a launcher that waits for this process


def say_ready() -> None:
    """Tell the launcher that started this process (``$QUADSITL_READY_FD``, :meth:`quadsitl.children.Children.start`)
    that it is ready: one byte on the pipe, which is then closed. Nothing without a launcher waiting."""
    fd = os.environ.pop(READY_ENV, None)
    if fd is None:
        return
    with contextlib.suppress(OSError, ValueError):
        os.write(int(fd), b"r")
        os.close(int(fd))
