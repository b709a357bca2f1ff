"""quadsitl.process_util.free_port: the ports handed to child processes come from outside the OS's ephemeral range
(no other socket is given them by the OS before the child binds), are free when picked, and the pick falls back to
the OS's own choice where the ephemeral range leaves nothing outside it."""

from __future__ import annotations

import socket

import pytest

from quadsitl import process_util
from quadsitl.process_util import PICK_PORTS, ephemeral_range, free_port


@pytest.mark.parametrize("kind", [socket.SOCK_DGRAM, socket.SOCK_STREAM])
def test_free_ports_are_outside_the_ephemeral_range_and_bindable(kind):
    first, last = ephemeral_range()
    for _ in range(100):
        port = free_port(kind)
        assert PICK_PORTS[0] <= port < PICK_PORTS[1] and not first <= port <= last, port
        with socket.socket(socket.AF_INET, kind) as s:
            s.bind(("127.0.0.1", port))


def test_a_port_in_use_is_passed_over(monkeypatch):
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as busy:
        busy.bind(("127.0.0.1", PICK_PORTS[0]))
        picks = iter([PICK_PORTS[0], PICK_PORTS[0], PICK_PORTS[0] + 7])
        monkeypatch.setattr(process_util._pick, "choice", lambda seq: next(picks))
        assert free_port() == PICK_PORTS[0] + 7


def test_an_ephemeral_range_over_every_pickable_port_falls_back_to_the_os(monkeypatch):
    first, last = ephemeral_range()
    monkeypatch.setattr(process_util, "ephemeral_range", lambda: (1024, 65535))
    monkeypatch.setattr(process_util._pick, "choice", lambda seq: pytest.fail("picked from an empty range"))
    port = free_port()
    assert first <= port <= last  # the OS's choice for port 0, from its (real) ephemeral range
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", port))
