"""Crashed processes: kill -9 of the plant (the autopilot says so and fails safe, and takes the next
plant), and of the autopilot (the plant holds and says so, and a restarted autopilot carries on with the
same plant)."""

import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
from pymavlink.dialects.v20 import common as M  # noqa: N812 (the MAVLink constants, short)

from groundstation.launcher import free_port
from quadsitl.process_util import free_ports_apart
from tests.mavclient import Client


class Lines:
    """A process's stderr (written to a file), read as it comes."""

    def __init__(self, proc: subprocess.Popen) -> None:
        self.path: Path = proc.stderr_path  # type: ignore[attr-defined]

    @property
    def lines(self) -> list[str]:
        return self.path.read_text().splitlines()

    def wait_for(self, text: str, timeout: float = 10.0) -> str:
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            for line in self.lines:
                if text in line:
                    return line
            time.sleep(0.05)
        raise AssertionError(f"no line with {text!r} in {self.lines}")


@pytest.fixture
def system(tmp_path):
    ports = dict(zip(("plant", "api"), free_ports_apart(2), strict=True))
    procs: list[subprocess.Popen] = []

    def start(name: str, argv: list[str]) -> subprocess.Popen:
        # stderr to a file: nothing blocks on a full pipe, and a failing test shows what each process said
        path = tmp_path / f"{name}{len(procs)}.stderr"
        with path.open("w") as err:
            p = subprocess.Popen(argv, stderr=err, text=True)
        p.stderr_path = path  # type: ignore[attr-defined]
        procs.append(p)
        return p

    def autopilot(*extra: str) -> subprocess.Popen:
        zenoh = list(extra) or ["--no-zenoh"]
        return start("autopilot", [sys.executable, "-m", "autopilot", "--plant-listen", f"127.0.0.1:{ports['plant']}",
                                   "--gcs-listen", "127.0.0.1:0", "--gcs-remote", "none", "--api-listen",
                                   f"127.0.0.1:{ports['api']}", "--api-remote", "none", *zenoh])  # fmt: skip

    def plant(*extra: str) -> subprocess.Popen:
        return start("plant", [sys.executable, "-m", "sitl", "--autopilot", f"127.0.0.1:{ports['plant']}", *extra])

    c = Client.to(ports["api"])

    def gcs(*args: str) -> subprocess.Popen:
        return start("gcs", [sys.executable, "-m", "groundstation", "--connect", f"127.0.0.1:{ports['api']}", *args])

    autopilot.gcs = gcs  # type: ignore[attr-defined]
    try:
        yield autopilot, plant, c
    finally:
        c.conn.close()
        for p in procs:
            if p.poll() is None:
                p.kill()
            p.wait()
            said = p.stderr_path.read_text()[-2000:]  # type: ignore[attr-defined]
            print(f"--- {p.stderr_path.name} (exit {p.returncode}, ports {ports}):\n{said}")  # type: ignore[attr-defined]


def test_plant_killed_autopilot_fails_safe_and_takes_a_new_plant(system):
    autopilot, plant, c = system
    ap = autopilot()
    pl = plant("--speed", "1")
    c.connect()
    assert c.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == M.MAV_RESULT_ACCEPTED
    c.wait("ATTITUDE", lambda m: m.time_boot_ms > 500)
    pl.send_signal(signal.SIGKILL)
    pl.wait()
    c.text_containing("Plant link lost", timeout=5)
    hb = c.wait("HEARTBEAT", lambda m: m.system_status == M.MAV_STATE_CRITICAL, timeout=5)
    assert hb.custom_mode == (4 << 16) | (6 << 24)  # land
    assert ap.poll() is None
    plant("--speed", "1")  # a new plant, from a new port: the autopilot takes it once the old one is silent
    c.text_containing("Plant link restored", timeout=10)
    c.wait("ATTITUDE", lambda m: m.time_boot_ms < 400, timeout=10)  # the new plant's clock, from 0


def test_armable_only_while_a_plant_sends_vehicle_states(system):
    # SYS_STATUS's pre-arm check (what MAVSDK's health.is_armable reads) and the sensors pass only while the
    # autopilot gets vehicle states; without, arming is refused and says why.
    autopilot, plant, c = system
    autopilot()
    c.connect(armable=False)
    sensors = M.MAV_SYS_STATUS_SENSOR_3D_GYRO | M.MAV_SYS_STATUS_SENSOR_GPS | M.MAV_SYS_STATUS_PREARM_CHECK
    status = c.wait("SYS_STATUS", timeout=3)  # sent with the heartbeat while no state streams the telemetry
    assert status.onboard_control_sensors_present & sensors == sensors
    assert not status.onboard_control_sensors_health & sensors
    assert c.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == M.MAV_RESULT_DENIED
    c.text_containing("Arming denied: no vehicle state (plant link down)")
    assert "ATTITUDE" not in c.latest  # nothing else streams without a state

    pl = plant("--speed", "1")
    status = c.wait_armable(timeout=20)
    assert status.onboard_control_sensors_health & sensors == sensors
    assert c.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == M.MAV_RESULT_ACCEPTED
    pl.send_signal(signal.SIGKILL)
    pl.wait()
    c.text_containing("Plant link lost", timeout=5)
    c.wait("SYS_STATUS", lambda m: not m.onboard_control_sensors_health & sensors, timeout=3)


def test_autopilot_killed_plant_holds_and_a_restarted_autopilot_carries_on(system):
    autopilot, plant, c = system
    ap = autopilot()
    pl = plant("--speed", "1")
    lines = Lines(pl)
    c.connect()
    c.wait("ATTITUDE", lambda m: m.time_boot_ms > 500)
    os.kill(ap.pid, signal.SIGKILL)
    ap.wait()
    lines.wait_for("plant: autopilot lost (no answer for 0.5 s); holding")
    assert pl.poll() is None
    autopilot()  # same ports: the plant's free-wheeling state reaches it
    lines.wait_for("plant: autopilot back")
    c.latest.clear()
    c.connect()
    first = c.wait("ATTITUDE").time_boot_ms
    later = c.wait("ATTITUDE", lambda m: m.time_boot_ms >= first + 300, timeout=5).time_boot_ms
    assert later > first > 500  # the same plant's clock carries on


def test_realtime_plant_applies_zero_thrust_when_the_autopilot_is_gone(system):
    autopilot, plant, c = system
    ap = autopilot()
    pl = plant("--mode", "realtime")
    lines = Lines(pl)
    c.connect()
    c.wait("ATTITUDE", lambda m: m.time_boot_ms > 500)
    os.kill(ap.pid, signal.SIGKILL)
    lines.wait_for("plant: autopilot lost (no answer for 0.5 s); applying zero thrust")
    assert pl.poll() is None


def test_ground_station_heartbeat_loss_takes_the_configured_action(system):
    autopilot, plant, c = system
    autopilot()
    plant("--speed", "1")
    c.connect()  # heartbeats as a GCS
    assert c.param_set("NAV_DLL_ACT", 2).param_value == 2.0
    assert c.param_set("COM_DL_LOSS_T", 1.0).param_value == 1.0
    c.conn.mav.heartbeat_send(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, 0)
    assert c.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == M.MAV_RESULT_ACCEPTED
    c.text_containing("Ground station lost: no heartbeat for 1 s; action: land", timeout=5)
    c.wait("HEARTBEAT", lambda m: m.custom_mode == (4 << 16) | (6 << 24) and m.system_status == M.MAV_STATE_CRITICAL)
    c.conn.mav.heartbeat_send(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, 0)
    c.text_containing("Ground station back", timeout=5)


def test_ground_station_killed_mid_flight_triggers_the_setpoint_loss_failsafe(system, tmp_path):
    autopilot, plant, c = system
    endpoint = f"tcp/127.0.0.1:{free_port(socket.SOCK_STREAM)}"
    autopilot("--zenoh-listen", endpoint)
    plant("--speed", "1")
    c.connect()  # a second ground station that only watches
    gcs = autopilot.gcs("--zenoh-connect", endpoint, "--duration", "60", "--out", str(tmp_path), "--quiet")
    c.wait("HEARTBEAT", lambda m: m.custom_mode == 6 << 16 and m.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED, timeout=20)
    c.pump(1.0)
    gcs.send_signal(signal.SIGKILL)
    gcs.wait()
    c.text_containing("Failsafe: offboard setpoints lost for 1 s, landing", timeout=5)
    c.wait("HEARTBEAT", lambda m: m.custom_mode == (4 << 16) | (6 << 24))
    c.text_containing("Landed, disarmed", timeout=20)


def test_up_names_the_child_that_died_and_leaves_no_orphans():
    from tests.test_fly import alive, children_of, quadsitl

    up = subprocess.Popen(quadsitl("up", "-q", "--no-zenoh", "--gcs-listen", "127.0.0.1:0", "--gcs-remote", "none",
                                   "--api-listen", "127.0.0.1:0", "--api-remote", "none"),
                          stderr=subprocess.PIPE, text=True)  # fmt: skip
    try:
        end = time.monotonic() + 20
        while time.monotonic() < end and len(children_of(up.pid)) < 2:
            time.sleep(0.1)
        kids = children_of(up.pid)
        assert len(kids) == 2
        time.sleep(1.0)
        plant_pid = next(p for p in kids if b"sitl" in Path(f"/proc/{p}/cmdline").read_bytes())
        os.kill(plant_pid, signal.SIGKILL)
        _, err = up.communicate(timeout=15)
        assert up.returncode == 1
        assert "the plant process was killed by signal 9 (SIGKILL); stopping the others" in err
        time.sleep(0.2)
        assert not [p for p in kids if alive(p)]
    finally:
        if up.poll() is None:
            up.kill()
            up.wait()


@pytest.mark.timeout(180)
def test_fly_ends_when_its_vehicle_lands_on_a_failsafe_before_the_flight_ends(tmp_path):
    """The plant stopped for longer than PLANT_LOST_AFTER in the middle of a `fly`: the vehicle fails safe, lands and
    disarms; the ground station says so and exits 1 at once, instead of waiting for a flight whose lockstep plant
    holds its clock until the vehicle arms again (CI once waited out a test's 240 s so)."""
    from tests.test_fly import children_of, quadsitl

    argv = quadsitl("fly", "--preset", "paper", "--duration", "30", "--speed", "2", "--no-figures", "--out",
                    str(tmp_path))  # fmt: skip
    with open(tmp_path / "stderr.txt", "w+") as err:
        proc = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=err, text=True, start_new_session=True)
        try:
            end = time.monotonic() + 120
            while "gcs: flight t = " not in (tmp_path / "stderr.txt").read_text():  # the flight is under way
                assert proc.poll() is None and time.monotonic() < end, (tmp_path / "stderr.txt").read_text()
                time.sleep(0.1)
            time.sleep(1.0)
            plant = next(pid for pid in children_of(proc.pid)
                         if b"-m\0sitl" in Path(f"/proc/{pid}/cmdline").read_bytes())  # fmt: skip
            os.kill(plant, signal.SIGSTOP)
            time.sleep(1.0)  # twice PLANT_LOST_AFTER
            os.kill(plant, signal.SIGCONT)
            status = proc.wait(timeout=60)
        finally:
            if proc.poll() is None:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait()
        err.seek(0)
        text = err.read()
    assert status == 1, text
    assert "Plant link lost" in text, text
    line = next(x for x in text.splitlines() if "disarmed at t = " in x)
    assert "before its end (failsafe 2)" in line, line  # FAILSAFE_PLANT_LOST
