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
    done = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: done.set())
    print("ready", flush=True)
    done.wait()
    with lock:  # the result first: closing a Zenoh session on a loaded machine can take a while
        print(json.dumps({"counts": counts, "latencies": latencies}), flush=True)
    for sub in subs:
        sub.undeclare()
    session.close()


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2], int(sys.argv[3]) if len(sys.argv) > 3 else 0)
