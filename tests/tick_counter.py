"""A telemetry subscriber that keeps every tick it gets, run as its own process so that a test can stop it
(SIGSTOP) while the vehicle publishes: what a logger that falls behind looks like to the vehicle. It subscribes to
everything of vehicle v1, says ``ready`` on stdout once the first sample came (the subscription then reaches the
autopilot: its mission document comes every second), and when its stdin closes, takes what comes for GRACE more
seconds (a finished run's last batch is on its way: this counts ticks, it does not time them) and prints one JSON
object: for each full-rate stream, the ticks it got, sorted and unique.

    python -m tests.tick_counter tcp/127.0.0.1:7447
"""

from __future__ import annotations

import json
import sys
import time

import numpy as np
import zenoh

from groundstation.logger import CHANNEL, DTYPES
from quadsitl import telemetry

GRACE = 0.5  # [s]


def main() -> int:
    ticks: dict[str, list[np.ndarray]] = {s: [] for s in telemetry.STREAMS}
    with zenoh.open(telemetry.zenoh_config(connect=[sys.argv[1]])) as session:
        sub = session.declare_subscriber(telemetry.key("v1", "**"), zenoh.handlers.FifoChannel(CHANNEL))
        sub.recv()  # the first sample, whatever it is
        print("ready", flush=True)
        sys.stdin.read()  # until the test closes it
        streams = {telemetry.key("v1", s): s for s in ticks}  # not the overview's slow copies
        end = time.monotonic() + GRACE
        while (sample := sub.try_recv()) is not None or time.monotonic() < end:
            if sample is None:
                time.sleep(0.005)
                continue
            stream = streams.get(str(sample.key_expr))
            if stream is not None:
                ticks[stream].append(np.frombuffer(sample.payload.to_bytes(), dtype=DTYPES[stream])["tick"])
        sub.undeclare()
    got = {s: np.unique(np.concatenate(t)).tolist() if t else [] for s, t in ticks.items()}
    print(json.dumps(got), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
