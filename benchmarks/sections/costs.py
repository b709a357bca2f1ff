"""2. per-call costs [µs]: the compiled controller steps, plant steps, encode and decode of the two per-tick messages
(:mod:`benchmarks.costs`, in a process of its own) against the same source run as plain Python; and a Zenoh publish
of the four telemetry streams against the ping-pong's round trip."""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
import timeit
from collections.abc import Callable

from benchmarks import pingpong
from benchmarks.report import Report
from benchmarks.sections.base import Context, Section
from quadsitl.process_util import free_port


def per_tick(fn: Callable[[], object], number: int = 20000) -> float:
    """The cost of one call of ``fn`` [µs]: the best of three timings of ``number`` calls."""
    return min(timeit.repeat(fn, number=number, repeat=3)) / number * 1e6


def call_costs(compiled: bool) -> dict[str, float]:
    """benchmarks.costs in a process of its own: the compiled functions, or (``compiled`` False) the same
    source as ordinary Python (NUMBA_DISABLE_JIT=1)."""
    env = {**os.environ, "NUMBA_DISABLE_JIT": "0" if compiled else "1"}
    out = subprocess.run([sys.executable, "-m", "benchmarks.costs"], check=True, timeout=300, env=env,
                         capture_output=True, text=True).stdout  # fmt: skip
    return json.loads(out.strip().splitlines()[-1])


def bench_costs(r: Report, ping: float) -> None:
    """Every call's cost compiled against plain Python, and a Zenoh publish against the round trip of a ping-pong
    of ``ping`` round trips per second."""
    import zenoh

    from quadsitl import telemetry

    r.section("2. per-call costs from Python: compiled (quadsitl.jit) against the same source as plain Python")
    compiled, python = call_costs(True), call_costs(False)
    for name, us in compiled.items():
        r.add(name, us, "us", python[name], "plain Python")
    rtt = 1e6 / ping
    session = zenoh.open(telemetry.zenoh_config("peer", listen=[f"tcp/127.0.0.1:{free_port(socket.SOCK_STREAM)}"]))
    try:
        pubs = [session.declare_publisher(telemetry.key("bench", s), congestion_control=zenoh.CongestionControl.DROP)
                for s in telemetry.STREAMS]  # fmt: skip
        payloads = [bytes(f.size) for f in telemetry.STREAMS.values()]

        def publish() -> None:
            for pub, payload in zip(pubs, payloads):
                pub.put(payload)

        r.add("Zenoh publish, 4 streams, no subscriber", per_tick(publish), "us", rtt, "round trip")
        for pub in pubs:
            pub.undeclare()
    finally:
        session.close()


def run(ctx: Context) -> dict[str, object]:
    """The costs against the lockstep section's ping-pong, or one measured here when that section did not run; no
    keys of its own."""
    bench_costs(ctx.report, ctx.ping or pingpong.measure())
    return {}


SECTION = Section("costs", run)
