"""The floor under any two-process lockstep: a bare UDP ping-pong between two Python processes, with
datagrams the size of the plant link's (ODOMETRY out, HIL_ACTUATOR_CONTROLS back).

Both sides block in ``recv`` (the client's safety timeout is the kernel's SO_RCVTIMEO, which costs nothing
per call, not Python's socket timeout, which adds a ``poll`` to every receive). With ``spin`` both sides
wait as the plant and the autopilot do (:class:`quadsitl.process_util.SpinThenBlock`): the same floor for
a loop that polls instead of sleeping."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import time

from quadsitl.children import stop
from quadsitl.process_util import SpinThenBlock, set_receive_timeout

STATE_BYTES = 245  # a MAVLink 2 ODOMETRY frame
ANSWER_BYTES = 93  # a MAVLink 2 HIL_ACTUATOR_CONTROLS frame


def echo(port: int, count: int, spin: bool, cpu: int) -> None:
    """The autopilot's side: answer each datagram with one of ANSWER_BYTES."""
    if cpu >= 0:
        os.sched_setaffinity(0, {cpu})
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", port))
    print("ready", flush=True)
    answer = bytes(ANSWER_BYTES)
    receive = SpinThenBlock(sock.recvfrom) if spin else lambda: sock.recvfrom(65535)
    for _ in range(count):
        _data, sender = receive()
        sock.sendto(answer, sender)


def measure(round_trips: int = 20000, warmup: int = 500, spin: bool = False, cpu: int | None = None) -> float:
    """Round trips per second between this process and an echo process (the plant's side here); with
    ``cpu``, both processes run on that one core (this one only while it measures)."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    total = round_trips + warmup
    proc = subprocess.Popen([sys.executable, "-m", "benchmarks.pingpong", str(port), str(total), str(int(spin)),
                             str(-1 if cpu is None else cpu)],
                            stdout=subprocess.PIPE, text=True)  # fmt: skip
    try:
        assert proc.stdout.readline().strip() == "ready"
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        set_receive_timeout(sock, 5.0)
        state, target = bytes(STATE_BYTES), ("127.0.0.1", port)
        receive = SpinThenBlock(sock.recv) if spin else lambda: sock.recv(65535)
        affinity = os.sched_getaffinity(0)
        if cpu is not None:
            os.sched_setaffinity(0, {cpu})
        for _ in range(warmup):
            sock.sendto(state, target)
            receive()
        start = time.perf_counter()
        for _ in range(round_trips):
            sock.sendto(state, target)
            receive()
        elapsed = time.perf_counter() - start
        os.sched_setaffinity(0, affinity)
        sock.close()
        proc.wait(10)
        return round_trips / elapsed
    finally:
        stop(proc, grace=0)


if __name__ == "__main__":
    echo(int(sys.argv[1]), int(sys.argv[2]), sys.argv[3] == "1", int(sys.argv[4]))
