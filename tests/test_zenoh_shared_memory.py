"""quadsitl's Zenoh sessions do without Zenoh's shared memory (quadsitl/telemetry.py, zenoh_config): Zenoh would set
it up on the first message over 3 KB to a peer on the same host (a 16 MB pool locked into memory page by page and
two watchdog threads, about 0.2 s of CPU), in the middle of a flight and at the autopilot's priority. A real
``quadsitl up`` streams its telemetry batches (tens of KB in lockstep) to a subscriber that has shared memory on, as
Zenoh's defaults give any user's own tool, and no quadsitl process sets it up."""

import json
import os
import queue
import signal
import time
from pathlib import Path

import pytest
import zenoh

from tests.mavclient import quadsitl_up
from tests.test_fly import children_of

THRESHOLD = 3072  # [bytes] Zenoh's transport/shared_memory/transport_optimization/message_size_threshold (1.x)


def locked_kb(pid: int) -> int:
    """The process's memory locked into RAM [kB] (VmLck)."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmLck:"):
            return int(line.split()[1])
    raise AssertionError(f"no VmLck in /proc/{pid}/status")


def thread_names(pid: int) -> list[str]:
    names = []
    for tid in os.listdir(f"/proc/{pid}/task"):
        try:
            names.append(Path(f"/proc/{pid}/task/{tid}/comm").read_text().strip())
        except OSError:
            continue
    return names


@pytest.mark.timeout(120)
def test_large_telemetry_batches_reach_a_shared_memory_subscriber_and_no_process_sets_shared_memory_up():
    with quadsitl_up("--speed", "0") as v:  # lockstep as fast as it goes: batches of up to BATCH_TICKS
        conf = zenoh.Config()  # Zenoh's defaults: shared memory on
        assert json.loads(conf.get_json("transport/shared_memory/enabled")) is True
        conf.insert_json5("connect/endpoints", json.dumps([v.zenoh]))
        conf.insert_json5("scouting/multicast/enabled", "false")
        sizes: queue.Queue = queue.Queue()
        with zenoh.open(conf) as session:
            session.declare_subscriber("quadsitl/v1/state", lambda s: sizes.put(len(s.payload.to_bytes())))
            large, end = 0, time.monotonic() + 60
            while large < 20:  # twenty batches over the threshold: each one would have gone through shared memory
                assert time.monotonic() < end, f"{large} state batches over {THRESHOLD} bytes in 60 s"
                try:
                    large += sizes.get(timeout=1) > THRESHOLD
                except queue.Empty:
                    assert v.proc.poll() is None, "quadsitl up ended"
            procs = {
                pid: Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()
                for pid in (v.proc.pid, *children_of(v.proc.pid))
            }  # quadsitl up and its processes
            assert any(" -m autopilot " in cmd for cmd in procs.values()), procs
            assert any(" -m sitl " in cmd for cmd in procs.values()), procs
            for pid, cmd in procs.items():
                # Zenoh's pool would be 16 MB locked (VmLck 16,420 kB in the autopilot without this), its threads
                # "Watchdog Confirmator" and "Watchdog Validator"
                assert locked_kb(pid) < 1024, (cmd, locked_kb(pid))
                assert not [n for n in thread_names(pid) if n.startswith("Watchdog")], (cmd, thread_names(pid))
        assert v.stop() in (0, -signal.SIGTERM)
