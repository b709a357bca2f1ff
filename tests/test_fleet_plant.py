"""One plant process for a fleet (``quadsitl plant --autopilot A --autopilot B ...``): one simulated clock for every
vehicle. The test plays the autopilots itself, on real UDP sockets, so it can hold one back and watch what the
plant sends the others; the datagrams are read with pymavlink.

- Lockstep: no vehicle gets tick k + 1 before every vehicle has answered tick k; a silent autopilot holds the
  whole fleet (its tick re-sent), and the fleet goes on when it answers.
- Each vehicle is integrated under its own autopilot's forces only; vehicle 1 of a fleet is, to the byte, the
  vehicle a plant of one simulates; the others draw their own sensor noise.
- Real time: every vehicle gets a state each period and flies its own commands.
- A vehicle that diverges ends the run, named, and only its autopilot is told.
- Bad fleets are refused in one line naming the option, before any socket is bound.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from importlib import resources
from pathlib import Path

import pytest

from benchmarks.machine import process_cpu_seconds
from quadsitl import codec, failures, wire
from quadsitl.config import load_preset
from quadsitl.process_util import PLANT_DIVERGED

PAPER = load_preset("paper")
MAX_THRUST = PAPER.actuators.max_thrust
HOVER = PAPER.vehicle.mass * 9.81 / 4  # [N] per motor, about


class FakeAutopilot:
    """An autopilot's end of the plant link, played by the test: a bound UDP socket, pymavlink to read the plant's
    datagrams, the project's encoder for the answers."""

    def __init__(self) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(5.0)
        self.address = f"127.0.0.1:{self.sock.getsockname()[1]}"
        self.mav = wire.link(1, 1)
        self.plant: tuple[str, int] | None = None

    def receive(self, timeout: float = 5.0) -> list:
        """The messages of the next datagram from the plant ([] when none comes within ``timeout``)."""
        self.sock.settimeout(timeout)
        try:
            data, self.plant = self.sock.recvfrom(65535)
        except TimeoutError:
            return []
        return self.mav.parse_buffer(data) or []

    def next_tick(self, timeout: float = 5.0, since: int = 0) -> tuple[int, object]:
        """(time_usec, ODOMETRY or HIL_STATE_QUATERNION) of the next state datagram stamped ``since`` or later (older
        ones, re-sent while the plant free-wheeled, are passed over)."""
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            for m in self.receive(max(0.01, end - time.monotonic())):
                if m.get_type() in ("ODOMETRY", "HIL_STATE_QUATERNION") and m.time_usec >= since:
                    return m.time_usec, m
        raise AssertionError(f"no state from the plant at {self.address} within {timeout} s")

    def answer(self, time_usec: int, forces: tuple[float, float, float, float], armed: bool = True) -> None:
        msg = wire.actuator_message(time_usec, forces, MAX_THRUST, armed)
        self.sock.sendto(codec.pack(msg, self.mav), self.plant)

    def close(self) -> None:
        self.sock.close()


@contextlib.contextmanager
def fleet_plant(n: int, *extra: str, tmp: Path | None = None) -> Iterator[tuple[subprocess.Popen, list[FakeAutopilot]]]:
    aps = [FakeAutopilot() for _ in range(n)]
    argv = [sys.executable, "-m", "sitl", "--preset", "paper"]
    for ap in aps:
        argv += ["--autopilot", ap.address]
    plant = subprocess.Popen([*argv, *extra], stderr=subprocess.PIPE, text=True)
    try:
        yield plant, aps
    finally:
        if plant.poll() is None:
            plant.terminate()
            try:
                plant.wait(5)
            except subprocess.TimeoutExpired:
                plant.kill()
                plant.wait()
        for ap in aps:
            ap.close()


@pytest.mark.timeout(60)
def test_lockstep_no_vehicle_runs_ahead_and_a_silent_one_holds_the_fleet():
    with fleet_plant(3, "--quiet") as (plant, aps):
        t0 = [ap.next_tick(30)[0] for ap in aps]  # 30 s: the plant's first start may load the compiled code
        assert t0 == [0, 0, 0]
        # vehicles 1 and 3 answer tick 0 at once; vehicle 2 holds back: nobody may see tick 1
        aps[0].answer(0, (HOVER,) * 4)
        aps[2].answer(0, (HOVER,) * 4)
        seen = {i: [] for i in range(3)}
        end = time.monotonic() + 10  # 4 re-sends each come within 0.2 s; a loaded machine may hold this test back
        while time.monotonic() < end and min(len(seen[0]), len(seen[2])) < 4:
            for i in (0, 2):
                with contextlib.suppress(AssertionError):
                    seen[i].append(aps[i].next_tick(0.05)[0])
        # no tick 1 anywhere; the answered ones are re-sent tick 0 while vehicle 2 keeps the fleet waiting (every
        # 50 ms: an autopilot that heard nothing for long would declare its plant lost and land)
        assert all(t == 0 for i in (0, 2) for t in seen[i]), seen
        assert len(seen[0]) >= 4 and len(seen[2]) >= 4, seen
        resent = [aps[1].next_tick(1.0)[0] for _ in range(3)]
        assert resent == [0, 0, 0]
        aps[1].answer(0, (HOVER,) * 4)
        # now the fleet goes on together, tick by tick, for 200 ticks
        for k in range(1, 200):
            want = codec.usec_of(k, PAPER.sim.period)
            stamps = [ap.next_tick(5, since=want if k == 1 else 0)[0] for ap in aps]
            assert stamps == [want] * 3, (k, stamps)
            for ap, t in zip(aps, stamps, strict=True):
                ap.answer(t, (HOVER,) * 4)
        assert plant.poll() is None


@pytest.mark.timeout(60)
def test_in_flight_a_silent_last_vehicle_holds_the_fleet_and_the_others_get_their_tick_again():
    """Once every autopilot has answered, the fleet's clock runs in compiled code (sitl.lockstep_loop), and the
    vehicles before a silent one have already stepped, their next datagram in their own buffers: the re-sends while
    the fleet waits must be the tick they answered, never the next (the loop keeps each tick's datagrams)."""
    with fleet_plant(3, "--quiet") as (plant, aps):
        for k in range(100):  # the clock runs: the first answers were heard
            want = codec.usec_of(k, PAPER.sim.period)
            stamps = [ap.next_tick(30 if k == 0 else 5, since=want)[0] for ap in aps]
            assert stamps == [want] * 3, (k, stamps)
            for ap in aps:
                ap.answer(want, (HOVER,) * 4)
        held = codec.usec_of(100, PAPER.sim.period)
        assert [ap.next_tick(5, since=held)[0] for ap in aps] == [held] * 3
        aps[0].answer(held, (HOVER,) * 4)
        aps[1].answer(held, (HOVER,) * 4)  # vehicle 3 says nothing: vehicles 1 and 2 step, the fleet waits
        resent = {0: [], 1: []}
        end = time.monotonic() + 10
        while time.monotonic() < end and min(len(r) for r in resent.values()) < 3:
            for i in (0, 1):
                with contextlib.suppress(AssertionError):
                    resent[i].append(aps[i].next_tick(0.05)[0])
        assert resent[0][:3] == [held] * 3 and resent[1][:3] == [held] * 3, resent
        assert all(t == held for r in resent.values() for t in r), resent  # never tick 101 before vehicle 3 answers
        aps[2].answer(held, (HOVER,) * 4)
        for k in range(101, 120):  # and on together
            want = codec.usec_of(k, PAPER.sim.period)
            stamps = [ap.next_tick(5, since=want)[0] for ap in aps]
            assert stamps == [want] * 3, (k, stamps)
            for ap in aps:
                ap.answer(want, (HOVER,) * 4)
        assert plant.poll() is None


@pytest.mark.timeout(60)
def test_an_autopilot_gone_is_waited_for_at_the_free_wheel_pace_not_flooded():
    """An autopilot whose port is closed answers each of the plant's sends with an ICMP error, which ends the plant's
    next receive at once. The plant must still wait FREEWHEEL_PERIOD (50 ms) between its sends of the held tick: it
    once sent it again about 28,000 times a second, to every vehicle of the fleet, on a core of its own."""
    with fleet_plant(2, "--quiet") as (plant, aps):
        assert [ap.next_tick(30)[0] for ap in aps] == [0, 0]
        for ap in aps:
            ap.answer(0, (HOVER,) * 4)
        t1 = [ap.next_tick(5, since=1)[0] for ap in aps]
        aps[1].close()  # vehicle 2's autopilot goes: its port refuses
        aps[0].answer(t1[0], (HOVER,) * 4)
        cpu, end, resent = process_cpu_seconds(plant.pid), time.monotonic() + 1.0, []
        while time.monotonic() < end:
            got = aps[0].receive(max(0.01, end - time.monotonic()))
            resent += [m.time_usec for m in got if hasattr(m, "time_usec")]
        used = process_cpu_seconds(plant.pid) - cpu
        # the fleet holds at tick 1 (vehicle 1 hears it again, to know its plant is there) about every 50 ms
        assert set(resent) == {t1[0]} and 5 <= len(resent) <= 25, (len(resent), set(resent))
        assert used < 0.3, used  # was a whole core
        assert plant.poll() is None


def _fly(aps: list[FakeAutopilot], forces: list[tuple[float, ...]], ticks: int) -> list[list]:
    """Answer ``ticks`` ticks, vehicle i with forces[i]; every vehicle's states, in order."""
    states: list[list] = [[] for _ in aps]
    for k in range(ticks):
        for i, ap in enumerate(aps):
            t, m = ap.next_tick(30 if k == 0 else 3)  # the first: the plant may be loading its compiled code
            states[i].append(m)
            ap.answer(t, forces[i])
    return states


@pytest.mark.timeout(60)
def test_each_vehicle_flies_its_own_autopilots_forces():
    climb, rest = (1.2 * HOVER,) * 4, (0.0,) * 4
    with fleet_plant(3, "--quiet") as (_plant, aps):
        states = _fly(aps, [rest, climb, rest], 500)
    z = [s[-1].z for s in states]
    assert z[1] < -0.05, z  # vehicle 2 climbed (NED: up is negative z)
    assert z[0] == 0.0 and z[2] == 0.0, z  # the others rest on the ground


@pytest.mark.timeout(90)
def test_vehicle_1_of_a_fleet_is_the_lone_vehicle_and_the_others_draw_their_own_noise():
    """Sensor mode: the messages vehicle 1 of a fleet of 2 gets are, byte for byte, those of a plant of one; vehicle
    2's sensors measure the same rest with other noise (its seeds + 1). Compared tick by tick, by their payloads: a
    plant whose answer came late (a loaded machine) sends the tick again after 50 ms, which takes the next MAVLink
    sequence numbers, so the frames of every later tick differ in those bytes."""

    def record(n: int) -> list[list[list]]:
        """Each vehicle's messages of its first 300 ticks, one list per tick (a re-sent tick is answered again, as an
        autopilot answers any repeat, and not kept)."""
        out: list[list[list]] = [[] for _ in range(n)]
        seen: list[set[int]] = [set() for _ in range(n)]
        with fleet_plant(n, "--state", "sensors", "--quiet") as (_plant, aps):
            while min(len(o) for o in out) < 300:
                for i, ap in enumerate(aps):
                    ap.sock.settimeout(30)
                    data, ap.plant = ap.sock.recvfrom(65535)
                    messages = ap.mav.parse_buffer(data)
                    t = next(m.time_usec for m in messages if m.get_type() == "HIL_SENSOR")
                    if t not in seen[i]:
                        seen[i].add(t)
                        out[i].append(messages)
                    ap.answer(t, (0.0,) * 4)
        return [o[:300] for o in out]

    def payloads(ticks: list[list]) -> list[list[bytes]]:
        return [[(m.get_msgId(), bytes(m.get_payload())) for m in tick] for tick in ticks]

    alone, fleet = record(1), record(2)
    assert payloads(fleet[0]) == payloads(alone[0])
    accel = [[(m.xacc, m.yacc, m.zacc) for tick in f for m in tick if m.get_type() == "HIL_SENSOR"] for f in fleet]
    assert len(accel[0]) == len(accel[1]) == 300
    assert accel[0] != accel[1]
    mean_z = [sum(a[2] for a in acc) / len(acc) for acc in accel]
    assert all(abs(m + 9.8) < 0.2 for m in mean_z), mean_z  # both at rest: −g along z, FRD


@pytest.mark.timeout(90)
def test_a_mixed_fleet_flies_each_on_its_own_state_and_a_gps_failure_reaches_the_compiled_clock(tmp_path):
    """A preset with [sensors] beside one without (``--vehicle-preset``), on the compiled lockstep clock: vehicle 1
    gets its true state (ODOMETRY), vehicle 2 its sensors' (HIL_SENSOR, HIL_GPS and the truth). Vehicle 2's autopilot
    passes on MAV_CMD_INJECT_FAILURE (the GPS off): from then on no HIL_GPS comes, though the clock reads the fleet's
    arrays (sitl.fleet_arrays), which replace each vehicle's own."""
    preset = tmp_path / "x500_sensors.toml"
    preset.write_text((resources.files("quadsitl") / "presets" / "x500.toml").read_text() + "\n[sensors]\n")
    kinds: list[set[str]] = [set(), set()]
    fixes: list[int] = []  # vehicle 2's HIL_GPS stamps [us]
    off_at = -1
    with fleet_plant(2, "--vehicle-preset", f"2={preset}", "--quiet") as (_plant, aps):
        for k in range(1500):
            for i, ap in enumerate(aps):
                ap.sock.settimeout(30 if k == 0 else 5)  # the first: the plant may be loading its compiled code
                data, ap.plant = ap.sock.recvfrom(65535)
                messages = ap.mav.parse_buffer(data)
                kinds[i] |= {m.get_type() for m in messages}
                t = next(m.time_usec for m in messages if m.get_type() in ("ODOMETRY", "HIL_SENSOR"))
                fixes += [m.time_usec for m in messages if m.get_type() == "HIL_GPS" and i == 1]
                command = b""
                if i == 1 and k == 700:
                    off_at = t
                    command = codec.pack(
                        ap.mav.command_long_encode(
                            1, 1, wire.mavlink.MAV_CMD_INJECT_FAILURE, 0, failures.GPS, failures.OFF, 0, 0, 0, 0, 0
                        ),
                        ap.mav,
                    )
                answer = codec.pack(wire.actuator_message(t, (0.0,) * 4, MAX_THRUST, True), ap.mav)
                ap.sock.sendto(command + answer, ap.plant)
    assert "ODOMETRY" in kinds[0] and not kinds[0] & {"HIL_SENSOR", "HIL_GPS"}, kinds[0]
    assert {"HIL_SENSOR", "HIL_GPS", "HIL_STATE_QUATERNION"} <= kinds[1] and "ODOMETRY" not in kinds[1], kinds[1]
    assert len([t for t in fixes if t <= off_at]) >= 3, fixes
    assert [t for t in fixes if t > off_at] == []


@pytest.mark.timeout(60)
def test_realtime_every_vehicle_gets_every_period_and_flies_its_own_command():
    climb, rest = (1.2 * HOVER,) * 4, (0.0,) * 4
    with fleet_plant(2, "--mode", "realtime", "--ticks", "1500", "--quiet") as (plant, aps):
        aps[0].next_tick(30)  # started
        last: list = [None, None]
        counts = [0, 0]
        end = time.monotonic() + 20
        while plant.poll() is None and time.monotonic() < end:
            for i, ap in enumerate(aps):
                for m in ap.receive(0.002):
                    if m.get_type() == "ODOMETRY":
                        counts[i] += 1
                        last[i] = m
                        ap.answer(m.time_usec, climb if i == 0 else rest)
        assert plant.wait(10) == 0
        for i, ap in enumerate(aps):  # what came while this test was held back and is still queued
            while messages := ap.receive(0.001):
                counts[i] += sum(m.get_type() == "ODOMETRY" for m in messages)
    assert min(counts) > 1000, counts  # 1500 states each in 1.5 s of real time (a few may be lost under load)
    assert last[0].z < -0.05 and last[1].z == 0.0, (last[0].z, last[1].z)


@pytest.mark.timeout(60)
def test_a_diverging_vehicle_ends_the_run_named_and_only_its_autopilot_is_told():
    lopsided = (MAX_THRUST, 0.0, MAX_THRUST, 0.0)  # a torque no attitude survives
    with fleet_plant(2) as (plant, aps):
        with pytest.raises(AssertionError):  # the plant stops sending when vehicle 2 leaves its bounds
            _fly(aps, [(HOVER,) * 4, lopsided], 5000)
        assert plant.wait(10) == PLANT_DIVERGED
        err = plant.stderr.read()
        told = [[m.text for m in ap.receive(0.5) if m.get_type() == "STATUSTEXT"] for ap in aps]
    assert "plant: vehicle v2 diverged at t = " in err, err
    assert told[0] == [] and any("Simulation diverged" in t for t in told[1]), told


def _refusal(*argv: str) -> str:
    r = subprocess.run([sys.executable, "-m", "sitl", "--preset", "paper", *argv], capture_output=True, text=True,
                       timeout=60)  # fmt: skip
    assert r.returncode == 2, r
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1, r.stderr
    return lines[0]


def test_bad_fleets_are_refused_naming_the_option(tmp_path):
    three = ["--autopilot", "127.0.0.1:15001", "--autopilot", "127.0.0.1:15002", "--autopilot", "127.0.0.1:15003"]
    slow = tmp_path / "slow.toml"
    text = (Path(__file__).parent.parent / "quadsitl" / "presets" / "paper.toml").read_text()
    slow.write_text(text.replace("period = 0.001", "period = 0.002"))
    cases = {
        ("--vehicle", "a", "--vehicle", "b"): "--vehicle given 2 times: expected once (for every vehicle) or 3 times",
        ("--vehicle", "a", "--vehicle", "b", "--vehicle", "a"): "two vehicles named alike",
        ("--home", "47,8,400", "--home", "47,8,400"): "--home given 2 times",
        ("--vehicle-preset", "4=x500"): "vehicle 4 is not in the fleet (1..3, --autopilot given 3 times)",
        ("--vehicle-preset", f"2={slow}"): "its control period is 0.002 s, --preset paper's 0.001 s",
        ("--bind", "127.0.0.1:65534"): "vehicle 3 would need port 65536, beyond 65535",
        ("--autopilot", "nowhere"): "--autopilot 'nowhere'",
    }
    for extra, expected in cases.items():
        line = _refusal(*three, *extra)
        assert expected in line, (extra, line)
        assert line.startswith("quadsitl plant: error: "), line


def test_under_chrt_the_plant_clock_runs_one_priority_above_the_autopilots():
    """``chrt -f 10 quadsitl up --mode realtime ...``: every process inherits SCHED_FIFO 10; the real-time plant
    takes 11, so the fleet's clock never waits behind an autopilot. Under the default policy nothing changes."""
    code = ("import os; from quadsitl.process_util import clock_above_its_peers as up; "
            "print(up(), os.sched_getscheduler(0) == os.SCHED_FIFO, os.sched_getparam(0).sched_priority)")  # fmt: skip
    plain = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert plain.stdout.split() == ["False", "False", "0"], plain
    fifo = subprocess.run(["chrt", "-f", "10", sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    if fifo.returncode != 0 and "ermission" in fifo.stderr and not os.environ.get("CI"):
        pytest.skip(f"SCHED_FIFO not permitted here (root or CAP_SYS_NICE; CI runs as root): {fifo.stderr.strip()}")
    assert fifo.stdout.split() == ["True", "True", "11"], fifo


def _default_timer_slack() -> None:
    """A child's timer slack as a fresh login's (50 µs), whatever this test process's is (the floor's loops set
    theirs when they run in it)."""
    import ctypes

    ctypes.CDLL("libc.so.6").prctl(29, ctypes.c_ulong(50_000), 0, 0, 0)  # PR_SET_TIMERSLACK


@pytest.mark.timeout(60)
@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="timer slack is Linux's")
@pytest.mark.parametrize("mode", ["realtime", "lockstep"])
def test_the_real_time_plant_asks_for_its_timers_on_time(mode):
    """The real-time plant's clock sleeps to each tick's due time; the kernel's default slack (50 µs) would let every
    one of those sleeps end up to that much late. The real-time plant takes 1 µs (TIMER_SLACK_NS); a lockstep plant,
    which sleeps on no timer, keeps what it was started with."""
    from quadsitl.process_util import TIMER_SLACK_NS

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as ap:
        ap.bind(("127.0.0.1", 0))
        ap.settimeout(30)
        plant = subprocess.Popen([sys.executable, "-m", "sitl", "--preset", "paper", "--mode", mode, "--quiet",
                                  "--autopilot", f"127.0.0.1:{ap.getsockname()[1]}"],
                                 preexec_fn=_default_timer_slack, stderr=subprocess.PIPE)  # fmt: skip
        try:
            ap.recvfrom(65535)  # the first tick: the plant's clock has started
            slack = int(Path(f"/proc/{plant.pid}/timerslack_ns").read_text())
        finally:
            plant.kill()
            plant.wait()
    assert slack == (TIMER_SLACK_NS if mode == "realtime" else 50_000), (mode, slack)


def cpu_latency_request() -> int:
    """The kernel's current PM QoS target for every core's wake-up latency [µs] (2,000,000,000: none)."""
    import struct

    with open("/dev/cpu_dma_latency", "rb") as f:
        return struct.unpack("=i", f.read(4))[0]


@pytest.mark.timeout(60)
@pytest.mark.skipif(not Path("/dev/cpu_dma_latency").exists(), reason="no PM QoS interface (Linux's)")
@pytest.mark.skipif(os.geteuid() != 0, reason="writing /dev/cpu_dma_latency needs root (CI runs as root)")
def test_cores_awake_holds_every_core_out_of_idle_states_while_the_plant_runs():
    """``--cores-awake``: the plant writes 0 µs to /dev/cpu_dma_latency and keeps it open for as long as it runs, so
    the kernel keeps every core polling when idle; the kernel drops the request when the plant ends."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as ap:
        ap.bind(("127.0.0.1", 0))
        ap.settimeout(30)
        plant = subprocess.Popen([sys.executable, "-m", "sitl", "--preset", "paper", "--mode", "realtime", "--quiet",
                                  "--cores-awake", "--autopilot", f"127.0.0.1:{ap.getsockname()[1]}"])  # fmt: skip
        try:
            ap.recvfrom(65535)  # the clock has started
            held = [os.readlink(f"/proc/{plant.pid}/fd/{fd}") for fd in os.listdir(f"/proc/{plant.pid}/fd")]
            during = cpu_latency_request()
        finally:
            plant.kill()  # however it ends, the kernel drops its request
            plant.wait()
    assert "/dev/cpu_dma_latency" in held and during == 0


@pytest.mark.timeout(60)
@pytest.mark.skipif(shutil.which("setpriv") is None or os.geteuid() != 0, reason="needs root to drop it (setpriv)")
@pytest.mark.parametrize("command", ["plant", "up"])
def test_without_the_right_to_it_cores_awake_is_refused_in_one_line(command):
    """Run as nobody, ``--cores-awake`` is refused before anything starts: one line naming the option, the file and
    what it needs, exit 2."""
    import tempfile

    with tempfile.TemporaryDirectory() as home:  # nobody's: pytest's own temporary folders are root's alone
        os.chmod(home, 0o777)
        env = {**os.environ, "HOME": home, "NUMBA_CACHE_DIR": home}
        plant = [sys.executable, "-m", "sitl", "--mode", "realtime", "--autopilot", "127.0.0.1:9"]
        up = [sys.executable, "-m", "groundstation.cli", "up", "--mode", "realtime", "--no-zenoh"]
        argv = plant if command == "plant" else up
        r = subprocess.run(["setpriv", "--reuid=65534", "--regid=65534", "--clear-groups", *argv, "--cores-awake"],
                           capture_output=True, text=True, timeout=50, env=env)  # fmt: skip
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 2 and len(lines) == 1, r
    assert lines[0] == (f"quadsitl {command}: error: --cores-awake: cannot write /dev/cpu_dma_latency (Permission "
                        "denied): it needs root, or write access to it")  # fmt: skip
