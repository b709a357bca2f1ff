"""A telemetry subscriber process for the fan-out benchmark: subscribes to a vehicle's four Zenoh streams,
counts what arrives and how late (now − the publisher's timestamp), and on SIGTERM prints a JSON summary."""

from __future__ import annotations

import json
import os
import signal
import sys
import threading
import time

import zenoh

from quadsitl import telemetry


def main(endpoint: str, vehicle: str, nice: int) -> None:
    if nice:
        os.nice(nice)
    # SIGTERM blocked before Zenoh starts its threads (they inherit the mask) and taken by sigwait below, which needs
    # no Python handler and takes it whichever thread the kernel would have picked: a subscriber waiting on an Event
    # for its handler now and then gave no result within 20 s (docs/performance.md#when-a-process-goes; never caught in
    # the act)
    signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGTERM})
    conf = telemetry.zenoh_config("peer", connect=[endpoint])
    session = zenoh.open(conf)
    lock = threading.Lock()
    counts = dict.fromkeys(telemetry.STREAMS, 0)
    latencies: list[float] = []

    def callback(stream: str):
        def cb(sample: zenoh.Sample) -> None:
            now = time.time()
            ts = sample.timestamp
            records = len(sample.payload) // telemetry.STREAMS[stream].size
            with lock:
                counts[stream] += records
                if stream == "state" and ts is not None:
                    latencies.append(now - ts.get_time().timestamp())

        return cb

    subs = [session.declare_subscriber(telemetry.key(vehicle, s), callback(s)) for s in telemetry.STREAMS]
    print("ready", flush=True)
    signal.sigwait({signal.SIGTERM})
    with lock:
        print(json.dumps({"counts": counts, "latencies": latencies, "streams": len(subs)}), flush=True)
    os._exit(0)  # the result is all the bench waits for: closing a session on a loaded machine can take a while


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2], int(sys.argv[3]) if len(sys.argv) > 3 else 0)
