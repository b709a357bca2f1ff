"""Test helpers: start ``quadsitl up`` on free loopback ports, and a small raw pymavlink ground station."""

from __future__ import annotations

import contextlib
import os
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from pymavlink import mavutil
from pymavlink.dialects.v20 import common as M  # noqa: N812 (the MAVLink constants, short)

from groundstation.launcher import free_port
from quadsitl import wire
from quadsitl.process_util import free_ports

PREARM_CHECK = M.MAV_SYS_STATUS_PREARM_CHECK  # SYS_STATUS: healthy = armable


@dataclass
class Vehicle:
    """A running ``quadsitl up``: the ports its two links stream to, and the process."""

    proc: subprocess.Popen
    gcs_port: int  # the ground-station link streams here (PX4: 14550)
    api_port: int  # the offboard-API link streams here (PX4: 14540)
    zenoh: str
    logs: Path | None = None  # where its flight logs go (up --logs)

    def stop(self) -> int:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                os.killpg(self.proc.pid, signal.SIGKILL)
                self.proc.wait()
        return self.proc.returncode


def quadsitl_up(*extra: str, wrap: Callable[[list[str]], list[str]] | None = None):
    """``quadsitl up`` (one vehicle) on free loopback ports: :func:`fleet_up` of one."""
    return fleet_up(1, *extra, wrap=wrap)


@contextlib.contextmanager
def fleet_up(n: int, *extra: str, wrap: Callable[[list[str]], list[str]] | None = None):
    """``quadsitl up --vehicles n`` on free loopback ports: every vehicle's ground-station link streams to
    ``gcs_port``; vehicle i's offboard-API link to ``api_port`` + i (as PX4's 14540 + i). Its flight logs go to a
    temporary folder (``logs``, removed afterwards) unless ``extra`` says where. ``wrap`` turns the command line
    into the one started (under another's limits)."""
    taken: set[int] = set()  # the five UDP ranges are picked before anything binds them: distinct
    gcs, api = free_ports(1, taken=taken), free_ports(n, taken=taken)
    gcs_listen, api_listen = free_ports(n, taken=taken), free_ports(n, taken=taken)
    zenoh = f"tcp/127.0.0.1:{free_port(socket.SOCK_STREAM)}"
    argv = [sys.executable, "-m", "groundstation.cli", "up", "--quiet", "--vehicles", str(n),
            "--gcs-listen", f"127.0.0.1:{gcs_listen}", "--gcs-remote", f"127.0.0.1:{gcs}",
            "--api-listen", f"127.0.0.1:{api_listen}", "--api-remote", f"127.0.0.1:{api}",
            "--zenoh-listen", zenoh, *extra]  # fmt: skip
    with tempfile.TemporaryDirectory(prefix="quadsitl-logs-") as logs:
        if "--logs" not in extra:
            argv += ["--logs", logs]
        proc = subprocess.Popen(wrap(argv) if wrap else argv, start_new_session=True)
        v = Vehicle(proc, gcs, api, zenoh, None if "--logs" in extra else Path(logs))
        try:
            yield v
        finally:
            v.stop()


@contextlib.contextmanager
def armable_client(*extra: str):
    """``quadsitl up`` (:func:`quadsitl_up`, with ``extra``) and a :class:`Client` on its ground-station link, once
    the vehicle is armable (the plant's first state has reached the autopilot); closed afterwards."""
    with quadsitl_up(*extra) as v:
        c = Client(v.gcs_port)
        try:
            c.wait_armable()
            yield c
        finally:
            c.close()


class Client:
    """A raw pymavlink ground station listening where the vehicle streams (like QGroundControl on 14550)."""

    def __init__(self, port: int) -> None:
        self.conn = mavutil.mavlink_connection(
            f"udpin:127.0.0.1:{port}", source_system=255, source_component=190, dialect="common"
        )
        self.latest: dict[str, object] = {}
        self.texts: list[str] = []
        self._chunks: dict[int, list[str]] = {}
        self.acks: list[object] = []

    @classmethod
    def to(cls, port: int) -> Client:
        """A client that talks first (pymavlink ``udpout``) to the autopilot's socket at ``port``."""
        c = cls.__new__(cls)
        c.conn = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=255, source_component=190,
                                            dialect="common")  # fmt: skip
        c.latest, c.texts, c._chunks, c.acks = {}, [], {}, []
        return c

    def connect(self, timeout: float = 20.0, armable: bool = True) -> None:
        """Heartbeat as a ground station until the vehicle's heartbeat arrives, then (``armable``) until
        its pre-arm check passes, as a ground station waits before arming."""
        end = time.monotonic() + timeout
        while time.monotonic() < end and "HEARTBEAT" not in self.latest:
            self.conn.mav.heartbeat_send(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, 0)
            self.pump(0.3)
        assert "HEARTBEAT" in self.latest, "no heartbeat from the vehicle"
        if armable:
            self.wait_armable(max(end - time.monotonic(), 1.0))

    def wait_armable(self, timeout: float = 20.0):
        """The first SYS_STATUS whose pre-arm check is healthy (the autopilot has a vehicle state from the
        plant), as a ground station waits before arming; it streams at 2 Hz."""
        return self.wait("SYS_STATUS", lambda m: m.onboard_control_sensors_health & PREARM_CHECK, timeout)

    def close(self) -> None:
        self.conn.close()

    def _note(self, m) -> None:
        t = m.get_type()
        self.latest[t] = m
        if t == "STATUSTEXT":
            if m.id == 0:
                self.texts.append(m.text)
            else:
                parts = self._chunks.setdefault(m.id, [])
                parts.append(m.text)
                if len(m.text) < 50:
                    self.texts.append("".join(self._chunks.pop(m.id)))
        elif t == "COMMAND_ACK":
            self.acks.append(m)
        elif t == "PARAM_VALUE":  # an integer parameter's bytes, as a ground station reads a PX4 vehicle's
            m.param_value = wire.param_from_wire(m.param_value, m.param_type)

    def pump(self, seconds: float) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            m = self.conn.recv_match(blocking=True, timeout=0.05)
            if m is not None:
                self._note(m)

    def wait(self, msg_type: str, cond=lambda m: True, timeout: float = 10.0):
        try:
            return self.wait_any(lambda m: m.get_type() == msg_type and cond(m), timeout)
        except AssertionError:
            raise AssertionError(
                f"no {msg_type} matching the condition within {timeout} s; latest: {self.latest}"
            ) from None

    def wait_any(self, cond, timeout: float = 10.0):
        """The first message of any type for which ``cond(message)`` holds (it sees every message on the way)."""
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            m = self.conn.recv_match(blocking=True, timeout=0.1)
            if m is None:
                continue
            self._note(m)
            if cond(m):
                return m
        raise AssertionError(f"no message matching the condition within {timeout} s; latest: {self.latest}")

    def heartbeat(self, timeout: float = 15.0):
        return self.wait("HEARTBEAT", lambda m: m.get_srcComponent() == 1, timeout)

    def drain(self) -> None:
        """Read (and note) every message already waiting, without blocking."""
        while (m := self.conn.recv_match(blocking=False)) is not None:
            self._note(m)

    def _request(self, send, msg_type: str, cond, timeout: float, resend: float):
        """``send(attempt)`` until a ``msg_type`` message for which ``cond`` holds answers it, as ground stations run
        a request: the messages already waiting are read first (a backlog that fills the socket's buffer drops the
        answer), and the request goes again every ``resend`` seconds without an answer, for up to ``timeout``."""
        self.drain()
        end = time.monotonic() + timeout
        attempt = 0
        while True:
            send(attempt)
            left = end - time.monotonic()
            try:
                return self.wait(msg_type, cond, min(resend, left))
            except AssertionError:
                if left <= resend:
                    raise
            attempt += 1

    def command(self, cmd: int, *params: float, timeout: float = 5.0, resend: float = 1.0, system: int = 1):
        """COMMAND_LONG to ``system`` → its COMMAND_ACK, by the MAVLink command protocol (:meth:`_request`): a
        resent command has its confirmation counted up."""
        p = [float(x) for x in params] + [0.0] * (7 - len(params))

        def send(attempt: int) -> None:
            self.conn.mav.command_long_send(system, 1, cmd, min(attempt, 255), *p)

        def answers(m) -> bool:
            return m.command == cmd and m.get_srcSystem() == system

        return self._request(send, "COMMAND_ACK", answers, timeout, resend)

    def command_int(self, system: int, frame: int, cmd: int, *params: float, timeout: float = 5.0,
                    resend: float = 1.0):  # fmt: skip
        """COMMAND_INT to ``system`` (params 1–4, x, y as integers, z) → its COMMAND_ACK, resent as :meth:`command`."""

        def send(attempt: int) -> None:
            self.conn.mav.command_int_send(system, 1, frame, cmd, 0, 0, *params)

        return self._request(send, "COMMAND_ACK", lambda m: m.command == cmd and m.get_srcSystem() == system, timeout,
                             resend)  # fmt: skip

    def text_containing(self, needle: str, timeout: float = 3.0) -> str:
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            for t in self.texts:
                if needle in t:
                    return t
            self.pump(0.05)
        raise AssertionError(f"no STATUSTEXT containing {needle!r}; got {self.texts}")

    def param_set(self, name: str, value: float, timeout: float = 10.0, resend: float = 1.0, system: int = 1):
        """PARAM_SET to ``system`` → the PARAM_VALUE that answers it (:meth:`_request`, as QGroundControl and MAVSDK
        resend it)."""

        def send(attempt: int) -> None:
            self.conn.mav.param_set_send(system, 1, name.encode(), value, M.MAV_PARAM_TYPE_REAL32)

        return self._request(send, "PARAM_VALUE", lambda m: m.param_id == name, timeout, resend)

    def setpoint(self, altitude: float, roll: float = 0.0, pitch: float = 0.0, yaw: float = 0.0) -> None:
        from quadsitl.frames import euler_to_quaternion

        q = euler_to_quaternion(roll, pitch, yaw)
        self.conn.mav.set_attitude_target_send(0, 1, 1, 71, q, 0.0, 0.0, 0.0, 0.0)  # thrust ignored (64)
        mask = 0b110111111011  # z only
        self.conn.mav.set_position_target_local_ned_send(0, 1, 1, M.MAV_FRAME_LOCAL_NED, mask, 0, 0, -altitude,
                                                        0, 0, 0, 0, 0, 0, 0, 0)  # fmt: skip

    def upload_mission(self, items: list[tuple[int, float, float, float]], timeout: float = 10.0,
                       mission_type: int = M.MAV_MISSION_TYPE_MISSION, param1: float = 0.0):  # fmt: skip
        """Upload a mission by the protocol, as a ground station does: MISSION_COUNT, then each
        MISSION_ITEM_INT the vehicle requests; returns the MISSION_ACK. ``items``: (command, latitude,
        longitude [deg], altitude above home [m]) each; ``mission_type`` 1 and ``param1`` for a geofence's items (a
        polygon's vertex count), 2 for rally points."""
        self.conn.mav.mission_count_send(1, 1, len(items), mission_type)
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            m = self.wait_any(lambda m: m.get_type() in ("MISSION_REQUEST_INT", "MISSION_ACK"), end - time.monotonic())
            if m.get_type() == "MISSION_ACK":
                return m
            command, lat, lon, alt = items[m.seq]
            self.conn.mav.mission_item_int_send(1, 1, m.seq, M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, command, 0, 1,
                                                param1, 0, 0, float("nan"), round(lat * 1e7), round(lon * 1e7), alt,
                                                mission_type)  # fmt: skip
        raise AssertionError(f"the upload of {len(items)} items did not end within {timeout} s")
