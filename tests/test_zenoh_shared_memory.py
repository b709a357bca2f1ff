"""Telemetry batches through Zenoh's shared memory (quadsitl/zenoh_shm.py): an autopilot puts its large batches from
a pool, so that a subscriber on the same host with shared memory on maps them instead of reading them through its
socket, while one with it off gets the same bytes; everything is set up when the sessions open, never in the middle
of a flight (under SCHED_FIFO that cost a fleet its deadlines); a process that may not lock memory (a container's
64 kB RLIMIT_MEMLOCK, no CAP_IPC_LOCK) flies without it instead of aborting. And the batches' period: a run faster
than twice real time batches FAST_BATCH_WALL, a slower one BATCH_WALL (autopilot/telemetry_out.py)."""

import json
import os
import queue
import resource
import shlex
import shutil
import signal
import time
from pathlib import Path

import numpy as np
import pytest
import zenoh

from autopilot import tick as kernel
from autopilot.telemetry_out import BATCH_TICKS, BATCH_WALL, FAST_BATCH_WALL, FAST_ROWS, ZenohOut
from quadsitl import telemetry, zenoh_shm
from tests.mavclient import quadsitl_up
from tests.test_fly import children_of

STATE = telemetry.STREAMS["state"].size


def locked_kb(pid: int) -> int:
    """The process's memory locked into RAM [kB] (VmLck)."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmLck:"):
            return int(line.split()[1])
    raise AssertionError(f"no VmLck in /proc/{pid}/status")


def thread_names(pid: int) -> list[str]:
    names = []
    for tid in os.listdir(f"/proc/{pid}/task"):
        try:
            names.append(Path(f"/proc/{pid}/task/{tid}/comm").read_text().strip())
        except OSError:
            continue
    return names


def processes(v) -> dict[int, str]:
    """``quadsitl up``'s process and its children → their command lines."""
    return {
        pid: Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()
        for pid in (v.proc.pid, *children_of(v.proc.pid))
    }


def subscribe_state(session: zenoh.Session, got: queue.Queue) -> None:
    """Every state sample into ``got``: (its bytes, whether it came through shared memory, its publication time)."""

    def cb(s: zenoh.Sample) -> None:
        got.put((s.payload.to_bytes(), s.payload.as_shm() is not None, s.timestamp.get_time().timestamp()))

    session.declare_subscriber("quadsitl/v1/state", cb)


def take(got: queue.Queue, n: int, v, timeout: float = 60.0) -> list[tuple[bytes, bool, float]]:
    out, end = [], time.monotonic() + timeout
    while len(out) < n:
        assert time.monotonic() < end, f"{len(out)} of {n} state samples in {timeout} s"
        try:
            out.append(got.get(timeout=1))
        except queue.Empty:
            assert v.proc.poll() is None, "quadsitl up ended"
    return out


def ticks(payload: bytes) -> np.ndarray:
    return np.frombuffer(payload, dtype=telemetry.record_dtype("state"))["tick"]


@pytest.mark.timeout(150)
def test_large_batches_reach_a_shared_memory_subscriber_through_it_and_one_without_as_bytes():
    with quadsitl_up("--speed", "0") as v:  # lockstep as fast as it goes: batches of up to BATCH_TICKS
        shm_q: queue.Queue = queue.Queue()
        plain_q: queue.Queue = queue.Queue()
        with (
            zenoh.open(telemetry.zenoh_config(connect=[v.zenoh], shared_memory=True)) as shared,
            zenoh.open(telemetry.zenoh_config(connect=[v.zenoh])) as plain,
        ):
            subscribe_state(shared, shm_q)
            subscribe_state(plain, plain_q)
            first = take(shm_q, 1, v)
            procs = processes(v)
            autopilot = next(pid for pid, cmd in procs.items() if " -m autopilot " in cmd)
            plant = next(pid for pid, cmd in procs.items() if " -m sitl " in cmd)
            locked = locked_kb(autopilot)
            # set up when its session opened and its pool was made: the pool and Zenoh's own segments are locked
            assert locked * 1024 >= zenoh_shm.POOL_BYTES, locked
            assert any(n.startswith("Watchdog") for n in thread_names(autopilot)), thread_names(autopilot)
            shm = first + take(shm_q, 40, v)
            plain_q.queue.clear()
            plain_samples = take(plain_q, 20, v)
            # nothing more locked in the middle of the flight, however many batches went through the pool
            assert locked_kb(autopilot) == locked
            # the plant publishes no batches: its session keeps shared memory off, and locks nothing
            assert locked_kb(plant) < 1024, locked_kb(plant)
            assert not [n for n in thread_names(plant) if n.startswith("Watchdog")], thread_names(plant)
        large = [(p, via) for p, via, _ in shm if len(p) > zenoh_shm.THRESHOLD]
        assert len(large) >= 20, [len(p) for p, _, _ in shm]
        # mapped, not read off the socket; as bytes only when a subscriber still held two batches (the pool's room)
        assert sum(via for _, via in large) >= 0.8 * len(large), [(len(p), via) for p, via in large]
        assert not [len(p) for p, via, _ in shm if len(p) <= zenoh_shm.THRESHOLD and via]  # small ones as bytes
        big_plain = [p for p, via, _ in plain_samples if len(p) > zenoh_shm.THRESHOLD]
        assert big_plain and not any(via for _, via, _ in plain_samples)
        for p in [p for p, _ in large] + big_plain:  # whole batches of consecutive ticks either way
            assert len(p) % STATE == 0
            t = ticks(p)
            assert (np.diff(t.astype(np.int64)) == 1).all(), t
        # one batch a FAST_BATCH_WALL when the run is faster than twice real time, unless it fills up first
        stamps = [ts for _, _, ts in shm]
        for (p, _, ts), before in zip(shm[1:], stamps, strict=False):
            rows = len(p) // STATE
            if rows > 2 * FAST_ROWS and rows < BATCH_TICKS:
                assert ts - before >= FAST_BATCH_WALL - BATCH_WALL - 0.005, (rows, ts - before)
        assert v.stop() in (0, -signal.SIGTERM)


def capsh_memlock(kb: int):
    """A command line run under RLIMIT_MEMLOCK ``kb`` without CAP_IPC_LOCK, as a container's unprivileged user."""

    def wrap(argv: list[str]) -> list[str]:
        return ["capsh", "--drop=cap_ipc_lock", "--", "-c", f"ulimit -l {kb} && exec {shlex.join(argv)}"]

    return wrap


@pytest.mark.skipif(shutil.which("capsh") is None or os.geteuid() != 0, reason="needs capsh and root to drop a cap")
@pytest.mark.timeout(150)
def test_a_vehicle_that_may_not_lock_memory_flies_without_shared_memory():
    with quadsitl_up("--speed", "0", wrap=capsh_memlock(64)) as v:
        got: queue.Queue = queue.Queue()
        with zenoh.open(telemetry.zenoh_config(connect=[v.zenoh], shared_memory=True)) as session:
            subscribe_state(session, got)
            samples = take(got, 20, v)  # Zenoh's session would have aborted the autopilot as it opened
            procs = processes(v)
            for pid, cmd in procs.items():
                assert locked_kb(pid) == 0, (cmd, locked_kb(pid))
        assert any(len(p) > zenoh_shm.THRESHOLD for p, _, _ in samples)
        assert not any(via for _, via, _ in samples)
        assert any(" -m autopilot " in cmd for cmd in procs.values()), procs
        assert v.stop() in (0, -signal.SIGTERM)


def test_allowed_follows_the_memlock_limit_and_the_capability(tmp_path, monkeypatch):
    status = tmp_path / "status"
    limit = [64 * 1024]
    monkeypatch.setattr(resource, "getrlimit", lambda _: (limit[0], limit[0]))
    status.write_text("Name:\tpython\nCapEff:\t0000000000000000\n")
    assert not zenoh_shm.allowed(status=status)
    status.write_text(f"Name:\tpython\nCapEff:\t{1 << zenoh_shm.CAP_IPC_LOCK:016x}\n")
    assert zenoh_shm.allowed(status=status)
    status.write_text("Name:\tpython\nCapEff:\t000001ffffffbfff\n")  # every capability but CAP_IPC_LOCK
    assert not zenoh_shm.allowed(status=status)
    limit[0] = 8 << 20  # a desktop's default
    assert zenoh_shm.allowed(status=status)
    assert zenoh_shm.allowed(zenoh_shm.SESSION_LOCKS + zenoh_shm.HOSTED_LOCKS + zenoh_shm.POOL_BYTES, status=status)
    assert not zenoh_shm.allowed(16 << 20, status=status)
    limit[0] = resource.RLIM_INFINITY
    assert zenoh_shm.allowed(1 << 40, status=status)
    # and a configuration asked for it has it only where allowed
    monkeypatch.setattr(zenoh_shm, "allowed", lambda need=0: False)
    assert not zenoh_shm.enabled(telemetry.zenoh_config(shared_memory=True))
    monkeypatch.setattr(zenoh_shm, "allowed", lambda need=0: True)
    conf = telemetry.zenoh_config(shared_memory=True)
    assert zenoh_shm.enabled(conf)
    assert json.loads(conf.get_json("transport/shared_memory/mode")) == "init"
    assert json.loads(conf.get_json("transport/shared_memory/transport_optimization/enabled")) is False
    assert not zenoh_shm.enabled(telemetry.zenoh_config())


class Recorder:
    def __init__(self) -> None:
        self.puts: list[object] = []

    def put(self, payload: object) -> None:
        self.puts.append(payload)


def test_put_goes_through_the_pool_when_large_and_as_bytes_otherwise():
    from zenoh.shm import ShmProvider, ZShmMut

    provider = ShmProvider.default_backend(64 * 1024)
    pub = Recorder()
    large, small = bytes(range(256)) * 100, b"x" * zenoh_shm.THRESHOLD
    zenoh_shm.put(pub, large, provider)
    zenoh_shm.put(pub, small, provider)
    zenoh_shm.put(pub, large, None)
    held = pub.puts[0]  # a subscriber still holds the first: the pool has room for two
    zenoh_shm.put(pub, large, provider)
    zenoh_shm.put(pub, large, provider)  # no room: as bytes, at once
    kinds = [type(p) for p in pub.puts]
    assert kinds == [ZShmMut, bytes, bytes, ZShmMut, bytes], kinds
    assert bytes(held) == large and bytes(pub.puts[3]) == large
    assert pub.puts[4] == large


def batcher(rows: int, last_flush: float) -> ZenohOut:
    """A vehicle's publisher without a session, ``rows`` batched since ``last_flush``."""
    out = ZenohOut(None, "v1", False, "drop", np.zeros(kernel.IO_SIZE, dtype=np.int64))
    out.io[kernel.ROWS] = rows
    out.last_flush = last_flush
    return out


@pytest.mark.parametrize(
    ("rows", "after", "early", "due"),
    [
        (0, 1.0, 0.0, False),  # nothing batched
        (20, BATCH_WALL - 0.001, 0.0, False),  # real time: every BATCH_WALL
        (20, BATCH_WALL, 0.0, True),
        (20, 0.001, BATCH_WALL, True),  # the chores' early flush
        (FAST_ROWS, BATCH_WALL, 0.0, True),  # twice real time still BATCH_WALL
        (FAST_ROWS + 1, BATCH_WALL, 0.0, False),  # faster: FAST_BATCH_WALL
        (1600, FAST_BATCH_WALL - 0.001, 0.0, False),
        (1600, FAST_BATCH_WALL, 0.0, True),
        (1600, FAST_BATCH_WALL - BATCH_WALL, BATCH_WALL, True),
    ],
)
def test_a_batch_is_due_after_its_period(rows, after, early, due):
    out = batcher(rows, 100.0)
    assert out.due(100.0 + after + (1e-9 if due else 0.0), early=early) is due  # at the period: due
    if rows:
        assert out.deadline(1e9) == pytest.approx(100.0 + (FAST_BATCH_WALL if rows > FAST_ROWS else BATCH_WALL))
    else:
        assert out.deadline(1e9) == 1e9


def test_a_paused_run_sends_its_batch_at_the_next_chores_not_a_fast_period_later():
    out = batcher(1600, 100.0)  # a fast run's batch: due FAST_BATCH_WALL after its last flush
    out.io[kernel.TICK] = 5000
    assert not out.idle()  # ticks came since the last look (none yet)
    out.io[kernel.TICK] = 5400
    assert not out.idle()
    assert out.idle()  # none since: the run paused or ended
    assert not out.due(100.0 + BATCH_WALL)  # what the period alone would say
    out.io[kernel.ROWS] = 0
    assert not out.idle()  # nothing batched: nothing to send
