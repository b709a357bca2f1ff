"""MAVLink 2 signing on the ground-station links, with raw pymavlink clients: signed commands work;
unsigned, wrongly signed and replayed ones are refused and counted; the key never reaches the logs or
the process list."""

import os
import subprocess
import sys
import time

import pytest
from pymavlink import mavutil
from pymavlink.dialects.v20 import common as M  # noqa: N812 (the MAVLink constants, short)

from groundstation.launcher import free_port

KEY = bytes(range(32))
KEY_HEX = KEY.hex()


NO_ANSWER = 1.5  # [s] wall: how long a refused command is listened to for an answer that must not come


class Raw:
    """A pymavlink connection that also keeps the bytes of what it sent (to replay them)."""

    def __init__(self, port: int, key: bytes | None, system: int = 255) -> None:
        self.conn = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=system,
                                               source_component=190, dialect="common")  # fmt: skip
        if key is not None:
            self.conn.setup_signing(key, sign_outgoing=True)
        self.sent: list[bytes] = []
        self.seen_texts: list[str] = []
        original = self.conn.write

        def write(buf):
            self.sent.append(bytes(buf))
            return original(buf)

        self.conn.write = write

    def ack(self, cmd: int, timeout: float = 10.0):
        """The COMMAND_ACK for ``cmd`` (at once when it comes; a loaded machine may take seconds), or None."""
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            m = self.conn.recv_match(blocking=True, timeout=0.1)
            if m is None:
                continue
            if m.get_type() == "STATUSTEXT":
                self.seen_texts.append(m.text)
            if m.get_type() == "COMMAND_ACK" and m.command == cmd:
                return m
        return None


@pytest.fixture
def signed_autopilot(tmp_path):
    keyfile = tmp_path / "key"
    keyfile.write_text(KEY_HEX + "\n")
    api = free_port()
    ap = subprocess.Popen([sys.executable, "-m", "autopilot", "--no-zenoh", "--plant-listen", "127.0.0.1:0",
                           "--gcs-listen", "127.0.0.1:0", "--gcs-remote", "none", "--api-listen", f"127.0.0.1:{api}",
                           "--api-remote", "none", "--signing-key", str(keyfile)],
                          stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)  # fmt: skip
    try:
        yield ap, api
    finally:
        ap.terminate()
        ap.wait(10)


def test_signed_commands_work_and_strangers_are_refused_and_counted(signed_autopilot):
    ap, port = signed_autopilot
    good = Raw(port, KEY)
    hb, end = None, time.monotonic() + 60  # the autopilot starts in 2-4 s; far longer on a loaded machine
    while hb is None and time.monotonic() < end and ap.poll() is None:
        good.conn.mav.heartbeat_send(6, 8, 0, 0, 0)  # as a ground station does, once a second
        hb = good.conn.recv_match(type="HEARTBEAT", blocking=True, timeout=1.0)
    assert hb is not None and hb.get_signed(), "the vehicle's own messages are signed"
    good.conn.mav.command_long_send(1, 1, M.MAV_CMD_REQUEST_MESSAGE, 0, M.MAVLINK_MSG_ID_AUTOPILOT_VERSION,
                                    0, 0, 0, 0, 0, 0)  # fmt: skip
    assert good.ack(M.MAV_CMD_REQUEST_MESSAGE).result == M.MAV_RESULT_ACCEPTED

    unsigned = Raw(port, None, system=200)
    unsigned.conn.mav.command_long_send(1, 1, M.MAV_CMD_REQUEST_MESSAGE, 0, 148, 0, 0, 0, 0, 0, 0)
    assert unsigned.ack(M.MAV_CMD_REQUEST_MESSAGE, NO_ANSWER) is None

    wrong = Raw(port, bytes(32), system=201)
    wrong.conn.mav.command_long_send(1, 1, M.MAV_CMD_REQUEST_MESSAGE, 0, 148, 0, 0, 0, 0, 0, 0)
    assert wrong.ack(M.MAV_CMD_REQUEST_MESSAGE, NO_ANSWER) is None

    # A replay: the signed command to land, sent again byte for byte, is refused (its timestamp is not newer).
    # (A mode change, not arming: without a plant there is no vehicle state, and arming is refused anyway.)
    good.conn.mav.command_long_send(1, 1, M.MAV_CMD_DO_SET_MODE, 0, 1, 4, 6, 0, 0, 0, 0)  # PX4 auto/land
    assert good.ack(M.MAV_CMD_DO_SET_MODE).result == M.MAV_RESULT_ACCEPTED
    land_frame = good.sent[-1]
    good.conn.mav.command_long_send(1, 1, M.MAV_CMD_DO_SET_MODE, 0, 1, 4, 3, 0, 0, 0, 0)  # back to hold
    assert good.ack(M.MAV_CMD_DO_SET_MODE).result == M.MAV_RESULT_ACCEPTED
    good.conn.port.sendto(land_frame, ("127.0.0.1", port))  # the replay
    assert good.ack(M.MAV_CMD_DO_SET_MODE, NO_ANSWER) is None
    good.conn.mav.command_long_send(1, 1, M.MAV_CMD_REQUEST_MESSAGE, 0, M.MAVLINK_MSG_ID_HEARTBEAT, 0, 0, 0, 0, 0, 0)
    hb = good.conn.recv_match(type="HEARTBEAT", blocking=True, timeout=3)
    assert hb.custom_mode == (4 << 16) | (3 << 24), "the replayed command switched to land"

    # counted, and said: the first refusal is announced with the running count
    assert any("Unsigned or badly signed message refused" in t for t in good.seen_texts), good.seen_texts
    assert any("so far)" in t for t in good.seen_texts)

    ap.terminate()
    out, err = ap.communicate(timeout=10)
    assert KEY_HEX not in out + err
    for p in (unsigned, wrong, good):
        p.conn.close()


def test_the_key_stays_out_of_the_process_list_and_bad_keys_are_named_without_the_value(tmp_path, cli):
    env = {**os.environ, "QUADSITL_SIGNING_KEY": KEY_HEX}
    ap = subprocess.Popen([sys.executable, "-m", "autopilot", "--no-zenoh", "--plant-listen", "127.0.0.1:0",
                           "--gcs-listen", "127.0.0.1:0", "--gcs-remote", "none", "--api-listen", "127.0.0.1:0",
                           "--api-remote", "none"], env=env, stderr=subprocess.PIPE, text=True)  # fmt: skip
    try:
        time.sleep(0.8)
        assert ap.poll() is None
        with open(f"/proc/{ap.pid}/cmdline") as f:
            assert KEY_HEX not in f.read()
    finally:
        ap.terminate()
        ap.wait(10)
    secret = "ab" * 31 + "zz"  # 64 characters, not hex
    r = cli("autopilot", "--no-zenoh", "--signing-key", secret)
    assert r.returncode == 2 and "--signing-key: expected 64 hex digits" in r.stderr and secret not in r.stderr


def test_fly_with_signing_signs_every_frame_and_keeps_the_key_out_of_the_outputs(tmp_path, cli):
    r = cli("fly", "--duration", "1", "--out", str(tmp_path), "--no-figures", "--signing-key", KEY_HEX)
    assert r.returncode == 0, r.stderr
    frames = []
    log = mavutil.mavlink_connection(str(tmp_path / "flight.tlog"))
    while (m := log.recv_match()) is not None:
        frames.append(bytes(m.get_msgbuf()))
    assert len(frames) > 50
    assert all(f[0] == 0xFD and f[2] & 0x01 for f in frames), "an unsigned frame crossed the signed link"
    for path in tmp_path.iterdir():
        assert KEY not in path.read_bytes() and KEY_HEX.encode() not in path.read_bytes()
    assert KEY_HEX not in r.stdout + r.stderr
