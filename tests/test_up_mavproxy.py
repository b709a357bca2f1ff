"""MAVProxy (from PyPI) against ``quadsitl up`` the way its users run it: ``mavproxy.py
--master=udpin:<the port the vehicle streams to>``, then commands typed at its prompt (here: written to
its stdin). It sees the vehicle and its PX4 mode, downloads the parameters, shows and sets one, sees a
refused set, arms, flies an offboard attitude setpoint and lands. The plant runs in real time."""

import os
import queue
import re
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from tests.mavclient import quadsitl_up

MAVPROXY = Path(sys.executable).parent / "mavproxy.py"


class MAVProxy:
    def __init__(self, port: int, home: Path) -> None:
        env = {**os.environ, "HOME": str(home), "PYTHONUNBUFFERED": "1"}
        self.proc = subprocess.Popen(
            [sys.executable, str(MAVPROXY), f"--master=udpin:127.0.0.1:{port}", "--no-state"],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, bufsize=1,
            env=env, cwd=home,
        )  # fmt: skip
        self.lines: queue.Queue[str | None] = queue.Queue()
        self.log: list[str] = []
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        for line in self.proc.stdout:
            self.lines.put(line.rstrip("\n"))
        self.lines.put(None)

    def expect(self, pattern: str, timeout: float = 15.0, seen_before: bool = False) -> re.Match:
        """The first new output line matching ``pattern`` (or, with ``seen_before``, any line so far)."""
        rx = re.compile(pattern)
        for line in self.log if seen_before else ():
            if found := rx.search(line):
                return found
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            try:
                line = self.lines.get(timeout=0.1)
            except queue.Empty:
                continue
            if line is None:
                break
            self.log.append(line)
            found = rx.search(line)
            if found:
                return found
        raise AssertionError(f"MAVProxy printed no line matching {pattern!r}; its output:\n" + "\n".join(self.log))

    def send(self, command: str) -> None:
        self.proc.stdin.write(command + "\n")
        self.proc.stdin.flush()

    def close(self) -> None:
        """Killed: it ends neither on SIGTERM nor promptly on its own ``exit`` (each cost 5–10 s a test), and with
        ``--no-state`` it has nothing to save."""
        if self.proc.poll() is None:
            self.proc.kill()
        self.proc.wait()


@pytest.fixture
def mavproxy(tmp_path):
    with quadsitl_up("--mode", "realtime") as v:
        mp = MAVProxy(v.gcs_port, tmp_path)
        try:
            yield mp
        finally:
            mp.close()
        assert v.proc.poll() is None, "quadsitl up died while MAVProxy used it"


def test_mavproxy_sees_the_vehicle_sets_parameters_arms_and_flies_offboard(mavproxy):
    mp = mavproxy
    mp.expect(r"Detected vehicle 1:1")
    mp.expect(r"Mode LOITER")  # PX4 auto/loiter, decoded from HEARTBEAT.custom_mode
    count = int(mp.expect(r"Received (\d+) parameters").group(1))
    assert count >= 30

    mp.send("param show BS_K1")
    assert float(mp.expect(r"BS_K1\s+([-\d.]+)").group(1)) == 10.0
    mp.send("param set BS_K1 9")
    end = time.monotonic() + 10  # MAVProxy shows the new value once the vehicle's PARAM_VALUE has come back
    while True:
        time.sleep(0.25)
        mp.send("param show BS_K1")
        shown = float(mp.expect(r"BS_K1\s+([-\d.]+)").group(1))
        if shown != 10.0 or time.monotonic() > end:
            break
    assert shown == 9.0
    mp.send("param set VM_MASS -1")
    mp.expect(r"Param set refused: VM_MASS = -1: expected a number in \(0, 10000\] kg")
    mp.send("param show VM_MASS")
    assert float(mp.expect(r"VM_MASS\s+([-\d.]+)").group(1)) == 2.0

    mp.send("arm throttle")
    mp.expect(r"COMPONENT_ARM_DISARM: ACCEPTED")
    mp.expect(r"^(.*> )?ARMED")

    # Offboard: a setpoint stream first (10° roll: q = [cos 5°, sin 5°, 0, 0]), then PX4's offboard mode.
    # (MAVProxy's "mode OFFBOARD" does not work for PX4 vehicles: it sends a tuple; "long DO_SET_MODE" does.)
    # The thrust is flown, normalised to the motors' 4 × 10 000 N: 0.0004 (16 N) keeps the paper's 2 kg vehicle on
    # the ground, where it rolls to 10°.
    attitude = "attitude 0.9961947 0.0871557 0 0 0.0004"
    streaming = threading.Event()
    streaming.set()

    def stream() -> None:  # 5 Hz, as a user's script at the prompt would keep sending
        while streaming.is_set():
            mp.send(attitude)
            time.sleep(0.2)

    sender = threading.Thread(target=stream, daemon=True)
    sender.start()
    try:
        time.sleep(0.5)
        mp.send("long DO_SET_MODE 1 6 0")
        mp.expect(r"DO_SET_MODE: ACCEPTED")
        mp.expect(r"Mode OFFBOARD")
        time.sleep(3.0)
    finally:
        streaming.clear()
        sender.join()
    mp.send("status ATTITUDE")
    att = mp.expect(r"ATTITUDE \{.*roll : ([-\d.e]+), pitch : ([-\d.e]+)")
    assert float(att.group(1)) == pytest.approx(0.17453, abs=2e-3) and abs(float(att.group(2))) < 2e-3

    mp.send("long NAV_LAND 0 0 0 0 0 0 0")
    mp.expect(r"NAV_LAND: ACCEPTED")
    mp.expect(r"^(.*> )?DISARMED", timeout=20)
    mp.expect(r"Mode LAND", seen_before=True)


@pytest.mark.timeout(120)
def test_mavproxy_on_the_shared_port_sees_every_vehicle_of_a_fleet_and_arms_the_one_it_targets(tmp_path):
    """``up --vehicles 3``: one MAVProxy on the ground stations' port detects three vehicles with distinct system
    ids; ``vehicle 3`` at its prompt points it at system id 3, and ``arm throttle`` arms vehicle 3 only (each
    vehicle's armed flag read from its Zenoh status stream)."""
    import zenoh

    from quadsitl import telemetry
    from tests.mavclient import fleet_up

    with fleet_up(3) as v:
        armed: dict[str, bool] = {}
        session = zenoh.open(telemetry.zenoh_config(connect=[v.zenoh]))

        def on_status(sample) -> None:
            rows = telemetry.records("status", sample.payload.to_bytes())
            armed[str(sample.key_expr).split("/")[1]] = bool(rows[-1][telemetry.FIELDS["status"].index("armed")])

        sub = session.declare_subscriber("quadsitl/*/status", on_status)
        mp = MAVProxy(v.gcs_port, tmp_path)
        try:
            seen: set[int] = set()
            while len(seen) < 3:
                seen.add(int(mp.expect(r"Detected vehicle (\d+):1 on link", timeout=60).group(1)))
            assert seen == {1, 2, 3}, mp.log
            # A vehicle's first heartbeat may come before its first state (the fleet's plant re-sends its tick to a
            # vehicle that starts late every 50 ms): arming is denied until then, as PX4's pre-arm checks deny it.
            # Its telemetry flowing says it has one.
            end = time.monotonic() + 30
            while time.monotonic() < end and set(armed) != {"v1", "v2", "v3"}:
                time.sleep(0.05)
            assert set(armed) == {"v1", "v2", "v3"}, armed
            mp.send("vehicle 3")
            mp.send("arm throttle")
            mp.expect(r"ARMED", timeout=30)
            end = time.monotonic() + 10
            while time.monotonic() < end and armed != {"v1": False, "v2": False, "v3": True}:
                time.sleep(0.1)
            assert armed == {"v1": False, "v2": False, "v3": True}, (armed, mp.log[-20:])
        finally:
            mp.close()
            sub.undeclare()
            session.close()
        assert v.proc.poll() is None, "quadsitl up died while MAVProxy used it"
