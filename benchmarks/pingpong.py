"""The floor under any two-process lockstep: a bare UDP ping-pong between two Python processes, with
datagrams the size of the plant link's (ODOMETRY out, HIL_ACTUATOR_CONTROLS back)."""

from __future__ import annotations

import socket
import subprocess
import sys
import time

STATE_BYTES = 245  # a MAVLink 2 ODOMETRY frame
ANSWER_BYTES = 93  # a MAVLink 2 HIL_ACTUATOR_CONTROLS frame


def echo(port: int, count: int) -> None:
    """The autopilot's side: answer each datagram with one of ANSWER_BYTES."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", port))
    print("ready", flush=True)
    answer = bytes(ANSWER_BYTES)
    for _ in range(count):
        _data, sender = sock.recvfrom(65535)
        sock.sendto(answer, sender)


def measure(round_trips: int = 20000, warmup: int = 500) -> float:
    """Round trips per second between this process and an echo process (the plant's side here)."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    total = round_trips + warmup
    proc = subprocess.Popen([sys.executable, "-m", "benchmarks.pingpong", str(port), str(total)],
                            stdout=subprocess.PIPE, text=True)  # fmt: skip
    try:
        assert proc.stdout.readline().strip() == "ready"
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        sock.settimeout(5.0)
        state, target = bytes(STATE_BYTES), ("127.0.0.1", port)
        for _ in range(warmup):
            sock.sendto(state, target)
            sock.recv(65535)
        start = time.perf_counter()
        for _ in range(round_trips):
            sock.sendto(state, target)
            sock.recv(65535)
        elapsed = time.perf_counter() - start
        sock.close()
        proc.wait(10)
        return round_trips / elapsed
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


if __name__ == "__main__":
    echo(int(sys.argv[1]), int(sys.argv[2]))
