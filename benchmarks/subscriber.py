"""A telemetry subscriber process for the fan-out benchmark: subscribes to a vehicle's four Zenoh streams,
counts what arrives and how late (now − the publisher's timestamp), and on SIGTERM prints a JSON summary: the records
per stream (``counts``), and with a tick limit N the distinct ticks below N per stream (``distinct``: a record that
came twice, or one of another run, counts once or not at all, so the loss :func:`loss_percent` makes of it is never
negative), and the latencies.

    python -m benchmarks.subscriber ENDPOINT VEHICLE [NICE [N]]
"""

from __future__ import annotations

import json
import os
import signal
import sys
import threading
import time

import numpy as np
import zenoh

from quadsitl import telemetry


def loss_percent(results: list[dict], ticks: int) -> float:
    """The worst subscriber's loss [%] of a run of ``ticks`` ticks (0..ticks−1), from each stream's distinct ticks
    (``distinct``, counted below ``ticks``): between 0 and 100 by construction."""
    worst = min((min(r["distinct"].values()) for r in results), default=0)
    return 100.0 * (1.0 - min(worst, ticks) / ticks)


def main(endpoint: str, vehicle: str, nice: int, below: int = 0) -> None:
    if nice:
        os.nice(nice)
    # SIGTERM blocked before Zenoh starts its threads (they inherit the mask) and taken by sigwait below, which needs
    # no Python handler and takes it whichever thread the kernel would have picked: a subscriber waiting on an Event
    # for its handler now and then gave no result within 20 s (docs/performance.md#when-a-process-goes; never caught in
    # the act)
    signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGTERM})
    conf = telemetry.zenoh_config("peer", connect=[endpoint], shared_memory=True)
    session = zenoh.open(conf)
    lock = threading.Lock()
    counts = dict.fromkeys(telemetry.STREAMS, 0)
    ticks: dict[str, list[np.ndarray]] = {s: [] for s in telemetry.STREAMS}
    dtypes = {s: telemetry.record_dtype(s) for s in telemetry.STREAMS}
    latencies: list[float] = []

    def callback(stream: str):
        def cb(sample: zenoh.Sample) -> None:
            now = time.time()
            ts = sample.timestamp
            payload = sample.payload.to_bytes()
            records = len(payload) // telemetry.STREAMS[stream].size
            with lock:
                counts[stream] += records
                if below:
                    ticks[stream].append(np.frombuffer(payload[: records * dtypes[stream].itemsize],
                                                       dtype=dtypes[stream])["tick"].copy())  # fmt: skip
                if stream == "state" and ts is not None:
                    latencies.append(now - ts.get_time().timestamp())

        return cb

    subs = [session.declare_subscriber(telemetry.key(vehicle, s), callback(s)) for s in telemetry.STREAMS]
    print("ready", flush=True)
    signal.sigwait({signal.SIGTERM})
    with lock:
        distinct = {}
        for stream, chunks in ticks.items():
            seen = np.unique(np.concatenate(chunks)) if chunks else np.zeros(0, dtype=np.uint64)
            distinct[stream] = int((seen < below).sum())
        print(json.dumps({"counts": counts, "distinct": distinct, "latencies": latencies, "streams": len(subs)}),
              flush=True)  # fmt: skip
    os._exit(0)  # the result is all the bench waits for: closing a session on a loaded machine can take a while


if __name__ == "__main__":
    main(
        sys.argv[1],
        sys.argv[2],
        int(sys.argv[3]) if len(sys.argv) > 3 else 0,
        int(sys.argv[4]) if len(sys.argv) > 4 else 0,
    )
