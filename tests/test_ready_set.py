"""quadsitl.fastio.ReadySet and epoll_wait, as a hosted fleet's group waits on its plant sockets
(autopilot.plant_loop.serve_group): which sockets have a datagram, told by index, without asking the others; and how
many groups a host flies (autopilot.group.group_threads)."""

import socket
import threading
import time

import numpy as np
import pytest

from autopilot import group
from quadsitl import fastio
from quadsitl.jit import jit

pytestmark = pytest.mark.skipif(not fastio.AVAILABLE, reason="compiled code on Linux only")


@jit(nogil=True)  # its waits let the thread that sends run, as serve_group's do
def _ready(epfd: int, events: np.ndarray, slot: np.ndarray, timeout_ms: int) -> np.ndarray:
    """The indices of the sockets epoll_wait finds readable, in its order (as serve_group reads them)."""
    n = fastio.epoll_wait(epfd, events.ctypes.data, events.size // fastio.EPOLL_WORDS, timeout_ms)
    out = np.empty(max(n, 0), dtype=np.int64)
    for j in range(max(n, 0)):
        out[j] = slot[events[j * fastio.EPOLL_WORDS + fastio.EPOLL_FD_WORD]]
    return out


@pytest.fixture
def socks():
    out = []
    for _ in range(5):
        s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        s.bind(("127.0.0.1", 0))
        out.append(s)
    yield out
    for s in out:
        s.close()


def test_the_sockets_with_a_datagram_are_told_by_their_index_and_only_while_one_waits(socks):
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as tx, fastio.ReadySet(socks) as ready:
        assert len(_ready(ready.fd, ready.events, ready.slot, 0)) == 0
        for i in (3, 1):
            tx.sendto(b"x" * (i + 1), socks[i].getsockname())
        time.sleep(0.05)
        assert sorted(_ready(ready.fd, ready.events, ready.slot, 0)) == [1, 3]
        assert sorted(_ready(ready.fd, ready.events, ready.slot, 0)) == [1, 3]  # still there: level-triggered
        assert socks[3].recv(100) == b"xxxx"
        assert list(_ready(ready.fd, ready.events, ready.slot, 0)) == [1]
        assert socks[1].recv(100) == b"xx"
        began = time.monotonic()
        assert len(_ready(ready.fd, ready.events, ready.slot, 100)) == 0
        assert time.monotonic() - began >= 0.09  # nothing came: it waited out its timeout


def test_a_blocked_wait_wakes_when_a_datagram_comes(socks):
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as tx, fastio.ReadySet(socks) as ready:
        _ready(ready.fd, ready.events, ready.slot, 0)  # compiled before the clock starts
        timer = threading.Timer(0.2, lambda: tx.sendto(b"y", socks[4].getsockname()))
        began = time.monotonic()
        timer.start()
        got = _ready(ready.fd, ready.events, ready.slot, 5000)
        waited = time.monotonic() - began
        timer.join()
        assert list(got) == [4] and 0.15 < waited < 4.0


def test_a_host_flies_a_group_for_each_core_but_the_plants(monkeypatch):
    for cores, threads in (({0}, 1), ({0, 1}, 1), ({0, 1, 2, 3}, 3), (set(range(8)), 7)):
        monkeypatch.setattr(group.os, "sched_getaffinity", lambda pid, c=cores: c)
        assert group.group_threads() == threads
