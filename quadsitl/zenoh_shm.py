"""Zenoh's shared memory for the telemetry batches: whether this process may have it (:func:`allowed`), the session
settings that turn it on (:func:`configure`), a process's one pool (:func:`pool`) and a put through it (:func:`put`).

A subscriber on the same host whose session has shared memory on maps a batch put from the pool instead of reading it
through its socket: the autopilot writes it once, not once per subscriber, and nobody copies it through the kernel
(docs/performance.md#fan-out). A subscriber elsewhere, or one with shared memory off, gets the same bytes as before.
A subscriber that keeps samples in a channel (Zenoh's FIFO or ring) holds their pool memory until it takes them, and
with it every batch that then finds no room goes as bytes: quadsitl's logger and dashboard keep shared memory off.

Everything is set up when the session opens and the pool is made (``mode: "init"``; Zenoh's own optimisation, which
would make a pool lazily on the first large put, stays off): nothing is locked into memory in the middle of a flight,
which under SCHED_FIFO cost a fleet its deadlines (docs/fleets.md#real-time-on-a-virtual-machine).
"""

from __future__ import annotations

import functools
import resource
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import zenoh
    from zenoh.shm import ShmProvider

# An autopilot's pool: several of its largest batches (BATCH_TICKS of every stream); a batch that finds no room goes
# as bytes. With the sessions' segments it fits a desktop's 8 MB RLIMIT_MEMLOCK (docs/performance.md#fan-out).
POOL_BYTES = 6 << 20
# What sessions with shared memory lock into RAM: Zenoh's own segments when the first opens and a little for each
# one after it, with room (docs/performance.md#fan-out).
SESSION_LOCKS = 1536 << 10
HOSTED_LOCKS = 512 << 10  # the sessions of a process's hosted vehicles after its first
THRESHOLD = 3072  # [bytes] smaller payloads go as bytes: a real-time batch of 20 ticks, as Zenoh's own threshold
CAP_IPC_LOCK = 14  # the capability that lifts RLIMIT_MEMLOCK (linux/capability.h)


def allowed(need: int = SESSION_LOCKS, status: Path = Path("/proc/self/status")) -> bool:
    """Whether this process may lock ``need`` bytes into RAM: it holds CAP_IPC_LOCK, or its RLIMIT_MEMLOCK has room
    for them. Zenoh's session aborts when it opens if it cannot lock its segments (a container's 64 kB limit)."""
    soft, _ = resource.getrlimit(resource.RLIMIT_MEMLOCK)
    if soft == resource.RLIM_INFINITY or soft >= need:
        return True
    try:
        caps = next(line.split()[1] for line in status.read_text().splitlines() if line.startswith("CapEff:"))
    except (OSError, StopIteration, IndexError):
        return False
    return bool(int(caps, 16) >> CAP_IPC_LOCK & 1)


def configure(conf: zenoh.Config, on: bool) -> None:
    """Shared memory on (when ``on`` and :func:`allowed`), set up as the session opens; else off."""
    if on and allowed():
        conf.insert_json5("transport/shared_memory/enabled", "true")
        conf.insert_json5("transport/shared_memory/mode", '"init"')
        conf.insert_json5("transport/shared_memory/transport_optimization/enabled", "false")
    else:
        conf.insert_json5("transport/shared_memory/enabled", "false")


def enabled(conf: zenoh.Config) -> bool:
    """Whether a configuration (quadsitl's, or a user's ``--zenoh-config``) has shared memory on."""
    import json

    return json.loads(conf.get_json("transport/shared_memory/enabled")) is True


@functools.cache
def pool() -> ShmProvider | None:
    """This process's pool of POOL_BYTES, made once and shared by the vehicles it hosts; None when it cannot be made
    (no room under RLIMIT_MEMLOCK beside the sessions', no /dev/shm): batches then go as bytes."""
    import zenoh
    from zenoh.shm import ShmProvider

    if not allowed(SESSION_LOCKS + HOSTED_LOCKS + POOL_BYTES):
        return None
    try:
        return ShmProvider.default_backend(POOL_BYTES)
    except zenoh.ZError:
        return None


@functools.cache
def _alloc_policy() -> tuple[object, type[Exception]]:
    """(the pool's allocation policy: collect what subscribers let go of and defragment, never wait; Zenoh's error),
    made once: a put's own imports and policy cost as much as its copy
    (docs/performance.md#a-hosted-fleet-in-lockstep)."""
    import zenoh
    from zenoh.shm import Defragment, GarbageCollect

    return Defragment(GarbageCollect()), zenoh.ZError


def put(pub: zenoh.Publisher, payload: bytes, provider: ShmProvider | None) -> None:
    """``payload`` put through ``provider``'s shared memory when it is over THRESHOLD; as bytes when it is not, when
    there is no provider, or when the pool is full (a subscriber still holds earlier batches): never a wait."""
    if provider is not None and len(payload) > THRESHOLD:
        policy, error = _alloc_policy()
        try:
            buf = provider.alloc(len(payload), policy)
        except error:
            pub.put(payload)
            return
        buf[:] = payload
        pub.put(buf)
        return
    pub.put(payload)
