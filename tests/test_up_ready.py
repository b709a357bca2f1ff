"""``quadsitl up`` says it is ready only once the vehicle is: its "Ctrl-C stops." line comes after the autopilot's
first heartbeat, so a client started on that line finds the vehicle; before it, a cold cache is said to compile."""

import os
import socket
import subprocess
import sys

import pytest
from pymavlink import mavutil

from tests.mavclient import free_port, free_ports


@pytest.mark.timeout(120)
def test_the_ready_line_comes_after_the_first_heartbeat():
    taken: set[int] = set()
    gcs, api, gcs_listen, api_listen = (free_ports(1, taken=taken) for _ in range(4))
    ground = mavutil.mavlink_connection(f"udpin:127.0.0.1:{gcs}", dialect="common")
    argv = [sys.executable, "-m", "groundstation.cli", "up", "--gcs-listen", f"127.0.0.1:{gcs_listen}",
            "--gcs-remote", f"127.0.0.1:{gcs}", "--api-listen", f"127.0.0.1:{api_listen}", "--api-remote",
            f"127.0.0.1:{api}", "--zenoh-listen", f"tcp/127.0.0.1:{free_port(socket.SOCK_STREAM)}"]  # fmt: skip
    proc = subprocess.Popen(argv, stdout=subprocess.PIPE, text=True, start_new_session=True,
                            env={**os.environ, "PYTHONUNBUFFERED": "1"})  # fmt: skip
    try:
        lines = []
        for line in proc.stdout:
            lines.append(line)
            if "Ctrl-C stops." in line:
                break
        else:
            pytest.fail(f"no ready line: {lines}")
        # The heartbeat went out before the ready line, so it waits in this socket now: on loopback a datagram is in
        # the receiver's buffer when its sendto returns. (A thread that timestamped each heartbeat as it took it raced
        # this thread's reading of the line: CI once saw the heartbeat 2.5 ms "after" it.)
        waiting = []
        while (m := ground.recv_match(blocking=False)) is not None:
            waiting.append(m.get_type())
        assert "HEARTBEAT" in waiting, f"the ready line came before the vehicle's first heartbeat: {waiting}"
        assert not any("compiling" in line for line in lines)  # the suite compiled everything first
    finally:
        proc.terminate()
        try:
            proc.wait(15)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
        ground.close()


def test_a_cold_cache_is_told_from_a_warm_one(tmp_path):
    code = "from quadsitl.compile_cache import cached; print(cached('plant_loop.serve'))"
    cold = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60,
                          env={**os.environ, "NUMBA_CACHE_DIR": str(tmp_path)})  # fmt: skip
    warm = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert (cold.stdout.strip(), warm.stdout.strip()) == ("False", "True")  # the suite compiled it first
