"""The compiled lockstep loops (autopilot.plant_loop, sitl.lockstep_loop, on quadsitl.fastio's libc calls): each
datagram handled as the Python loops handle it, Python given the loop back whenever it has something to do, and
flights the same to the bit with the compiled loops and without them."""

import socket
import subprocess
import sys
import time

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink

from autopilot import plant_loop
from autopilot import tick as kernel
from autopilot.process import Autopilot, build_parser
from quadsitl import codec, fastio, wire
from quadsitl.config import load_preset
from quadsitl.process_util import PACE_WINDOW, PATIENCE, free_ports_apart, set_receive_timeout, wait_readable

pytestmark = pytest.mark.skipif(not fastio.AVAILABLE, reason="compiled loops: Linux, numba on")
PERIOD = 0.001


def test_libc_calls_move_datagrams_and_read_the_monotonic_clock():
    a, b = socket.socket(socket.AF_INET, socket.SOCK_DGRAM), socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        a.bind(("127.0.0.1", 0))
        b.bind(("127.0.0.1", 0))
        to_a = fastio.sockaddr(a.getsockname())
        assert fastio.address_of(to_a) == a.getsockname()
        data = np.arange(7, dtype=np.uint8)
        sent = _sendto(b.fileno(), data, to_a)
        assert sent == 7
        rx, sender, length = np.zeros(64, dtype=np.uint8), np.zeros(fastio.SOCKADDR_IN, np.uint8), np.zeros(1, np.int32)
        time.sleep(0.01)
        assert _recvfrom(a.fileno(), rx, sender, length) == 7
        assert rx[:7].tolist() == list(range(7)) and fastio.address_of(sender) == b.getsockname()
        assert _recvfrom(a.fileno(), rx, sender, length) == -1  # nothing waits: MSG_DONTWAIT returns at once
        before = time.monotonic_ns()
        now = _clock()
        assert before <= now <= time.monotonic_ns()  # time.monotonic's clock
    finally:
        a.close()
        b.close()


if fastio.AVAILABLE:
    from quadsitl.jit import jit

    @jit
    def _sendto(fd, data, to):
        return fastio.sendto(fd, data.ctypes.data, data.size, 0, to.ctypes.data, fastio.SOCKADDR_IN)

    @jit
    def _recvfrom(fd, rx, sender, length):
        length[0] = fastio.SOCKADDR_IN
        return fastio.recvfrom(fd, rx.ctypes.data, rx.size, fastio.MSG_DONTWAIT, sender.ctypes.data,
                               length.ctypes.data)  # fmt: skip

    @jit
    def _clock():
        return fastio.monotonic_ns()


def test_the_compiled_receive_polls_for_its_patience_and_counts_the_wait():
    a, b = socket.socket(socket.AF_INET, socket.SOCK_DGRAM), socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        a.bind(("127.0.0.1", 0))
        b.connect(a.getsockname())
        rx, sender, length = np.zeros(64, dtype=np.uint8), np.zeros(fastio.SOCKADDR_IN, np.uint8), np.zeros(1, np.int32)
        stats = np.zeros(plant_loop.STATS_SIZE, dtype=np.int64)
        budget, patience = 5_000_000, 20_000_000_000  # [ns]
        # The late peer is another process: the compiled receive holds the GIL while it polls, as the autopilot's
        # and the plant's loops do (their peers are processes too).
        port = a.getsockname()[1]
        peer = subprocess.Popen([sys.executable, "-c", "import socket, sys, time; sys.stdin.readline(); "
                                 f"time.sleep(0.1); socket.socket(2, 2).sendto(b'late', ('127.0.0.1', {port}))"],
                                stdin=subprocess.PIPE, text=True)  # fmt: skip
        peer.stdin.write("go\n")
        peer.stdin.flush()
        began = time.monotonic()
        n = fastio.receive(a.fileno(), rx, sender, length, True, budget, patience, stats)
        assert peer.wait(10) == 0
        assert n == 4 and bytes(rx[:4]) == b"late" and time.monotonic() - began >= 0.09
        # Polled for (not blocked on), and late: it came after half the budget.
        assert stats[plant_loop.POLLED] == 1 and stats[plant_loop.LATE] == 1 and stats[plant_loop.BLOCKED] == 0
        began = time.monotonic()
        assert fastio.receive(a.fileno(), rx, sender, length, True, budget, budget, stats) == fastio.RAN_OUT
        assert 0.004 <= time.monotonic() - began < 1.0 and stats[plant_loop.POLLED] == 1  # gave up after the budget
    finally:
        a.close()
        b.close()


@pytest.fixture
def vehicle():
    """An autopilot (the process's object, no Zenoh; its api link streams telemetry to a port) and a socket that
    plays its plant."""
    port, remote = free_ports_apart(2)
    args = build_parser().parse_args(["--preset", "paper", "--plant-listen", f"127.0.0.1:{port}", "--gcs-listen",
                                      "127.0.0.1:0", "--gcs-remote", "none", "--api-listen", "127.0.0.1:0",
                                      "--api-remote", f"127.0.0.1:{remote}", "--no-zenoh"])  # fmt: skip
    args.home, args.signing_key = None, None
    ap = Autopilot(load_preset("paper"), args)
    plant = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    plant.bind(("127.0.0.1", 0))
    set_receive_timeout(plant, 2.0)
    yield ap, plant, ("127.0.0.1", port)
    plant.close()
    ap.close()


def state_frame(tick: int) -> bytes:
    frame = np.zeros(codec.FRAME_MAX, dtype=np.uint8)
    n = codec.encode_state(frame, tick & 0xFF, wire.PLANT_SYSTEM_ID, wire.PLANT_COMPONENT_ID,
                           codec.usec_of(tick, PERIOD), (0.0,) * 12)  # fmt: skip
    return frame[:n].tobytes()


def answer_of(data: bytes) -> tuple[int, bool]:
    """(stamp, armed) of a HIL_ACTUATOR_CONTROLS datagram."""
    buf = np.zeros(codec.FRAME_MAX, dtype=np.uint8)
    buf[: len(data)] = np.frombuffer(data, dtype=np.uint8)
    stamp = codec.decode_actuators(buf, len(data), np.zeros(4), 1.0)
    assert stamp >= 0
    return stamp, bool(buf[codec.HEADER_SIZE + codec.HIL_SIZE - 1] & codec.SAFETY_ARMED)


def serve(ap: Autopilot, deadline_s: float = 5.0, limit: int = plant_loop.NO_LIMIT, polling: bool = True,
          ground_every_s: float = 0.0):  # fmt: skip
    stats = np.zeros(plant_loop.STATS_SIZE, dtype=np.int64)
    p = ap.plant
    deadline = time.monotonic_ns() + int(deadline_s * 1e9)
    out = plant_loop.serve(p.sock.fileno(), p.rx_array, p.sender, p.sender_len, p.address, p.tx, ap.io,
                           ap.tick_arguments(), deadline, polling, 50_000_000, 50_000_000, 8, limit, stats,
                           ap.destinations.out, ap.ground_fds, int(ground_every_s * 1e9))  # fmt: skip
    return out, stats


def test_the_compiled_loop_answers_each_tick_and_gives_python_what_it_must_do(vehicle):
    ap, plant, autopilot = vehicle
    plant.sendto(state_frame(1), autopilot)
    nbytes, sender = ap.plant.sock.recvfrom_into(ap.plant.rx)  # the first datagram: Python's loop locks to the plant
    ap.on_plant_datagram(nbytes, sender)
    assert answer_of(plant.recv(1000)) == (1000, False) and ap.plant.address is not None
    for k in range(2, 12):
        plant.sendto(state_frame(k), autopilot)
    time.sleep(0.05)
    stamps, returns = [], []
    while True:
        (status, nbytes, flags), stats = serve(ap, deadline_s=0.5)
        # Every tick is answered in the loop; one with a telemetry message due is Python's to finish, its answer
        # already sent; then nothing comes within the budget.
        stamps += [answer_of(plant.recv(1000))[0] for _ in range(int(stats[plant_loop.ANSWERED]))]
        returns.append(status)
        if status != plant_loop.SENT:
            break
        assert flags & kernel.STREAM and flags & kernel.ANSWER
        ap._finish_tick(flags & ~kernel.ANSWER, nbytes, ap.plant.peer, time.monotonic())  # the telemetry goes
    # Each tick answered once, in order, the SENT ones too, and nothing more.
    assert stamps == [1000 * k for k in range(2, 12)] and ap.io[kernel.TICK] == 11
    assert plant_loop.SENT in returns
    plant.setblocking(False)
    with pytest.raises(BlockingIOError):
        plant.recv(1000)
    assert returns[-1] == plant_loop.QUIET and 1 < len(returns) < 10  # Python's turn only now and then


def test_the_loop_sends_the_ticks_telemetry_frames_itself(vehicle):
    """A tick with only compiled telemetry due (ATTITUDE and the other 50 Hz messages, the positions, the targets, the
    motor outputs) does not come back to Python: the loop sends the frames to the link's destinations after the
    answer, in one datagram."""
    ap, plant, autopilot = vehicle
    ground = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    ground.bind(("127.0.0.1", 0))
    set_receive_timeout(ground, 2.0)
    ap.links[1].remote = ground.getsockname()  # the api link streams to it
    ap.refresh_streams()
    plant.sendto(state_frame(199), autopilot)
    ap.on_plant_datagram(*ap.plant.sock.recvfrom_into(ap.plant.rx))
    plant.recv(1000)
    assert ap.destinations.count[0] == 1
    for k in (200, 201, 202):  # 200: all nine due (phase 0; GPS_RAW_INT at 5 Hz), the others nothing
        plant.sendto(state_frame(k), autopilot)
    time.sleep(0.05)
    (status, _, _), stats = serve(ap, deadline_s=0.3)
    assert status == plant_loop.QUIET and stats[plant_loop.ANSWERED] == 3  # never back to Python in between
    assert [answer_of(plant.recv(1000))[0] for _ in range(3)] == [200_000, 201_000, 202_000]
    msgs = wire.link(0, 0).parse_buffer(ground.recv(65535))
    assert [m.get_type() for m in msgs] == ["GPS_RAW_INT", "ATTITUDE", "ATTITUDE_QUATERNION", "LOCAL_POSITION_NED",
                                            "GLOBAL_POSITION_INT", "SERVO_OUTPUT_RAW", "ATTITUDE_TARGET",
                                            "POSITION_TARGET_LOCAL_NED", "ACTUATOR_OUTPUT_STATUS"]  # fmt: skip
    assert {getattr(m, "time_boot_ms", None) or m.time_usec // 1000 for m in msgs} == {200}
    assert len({m.get_seq() for m in msgs}) == 9
    ground.close()


def locked_without_streams(ap: Autopilot, plant: socket.socket, autopilot: tuple[str, int]) -> None:
    """The autopilot locked to ``plant`` by its first datagram (tick 1, answered), with no telemetry message due."""
    plant.sendto(state_frame(1), autopilot)
    ap.on_plant_datagram(*ap.plant.sock.recvfrom_into(ap.plant.rx))
    plant.recv(1000)
    ap.io[kernel.NEXT_STREAM_TICK] = 10**9


def test_a_stranger_a_deadline_and_a_limit_hand_the_loop_back(vehicle):
    ap, plant, autopilot = vehicle
    locked_without_streams(ap, plant, autopilot)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as other:
        other.bind(("127.0.0.1", 0))
        other.sendto(state_frame(2), autopilot)
        time.sleep(0.02)
        (status, nbytes, _), _ = serve(ap)
        assert status == plant_loop.STRANGER and fastio.address_of(ap.plant.sender) == other.getsockname()
        assert nbytes == len(state_frame(2)) and ap.io[kernel.TICK] == 1  # not flown: the plant's own tick only
    plant.sendto(state_frame(2), autopilot)
    plant.sendto(state_frame(3), autopilot)
    time.sleep(0.02)
    (status, _, _), stats = serve(ap, deadline_s=0.0)  # the deadline has passed: back after one tick
    assert status == plant_loop.DUE and stats[plant_loop.ANSWERED] == 1 and answer_of(plant.recv(1000))[0] == 2000
    (status, _, flags), stats = serve(ap, limit=2)  # tick 3 is past the limit: its answer is Python's to send
    assert status == plant_loop.TICKED and flags == kernel.ANSWER and stats[plant_loop.ANSWERED] == 0
    assert ap.io[kernel.TICK] == 3


def test_a_datagram_on_a_ground_link_hands_the_loop_back_and_nothing_else_does(vehicle):
    """The ground-station sockets are asked between ticks (every ``ground_every_ns``, here every tick): the loop
    serves tick after tick while they are empty, and goes back to Python (GROUND) once a datagram waits on one,
    which Python then reads."""
    ap, plant, autopilot = vehicle
    locked_without_streams(ap, plant, autopilot)
    for k in range(2, 7):
        plant.sendto(state_frame(k), autopilot)
    time.sleep(0.02)
    (status, _, _), stats = serve(ap, deadline_s=0.3)
    assert status == plant_loop.QUIET and stats[plant_loop.ANSWERED] == 5  # asked five times, nothing waited
    assert [answer_of(plant.recv(1000))[0] for _ in range(5)] == [1000 * k for k in range(2, 7)]
    assert stats[plant_loop.NEXT_GROUND] > 0  # and the next time to ask moved on
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as gcs:
        heartbeat = wire.link(255, 190).heartbeat_encode(6, 8, 0, 0, 0).pack(wire.link(255, 190))
        gcs.sendto(heartbeat, ap.links[1].sock.getsockname())  # the api link
        for k in range(7, 10):
            plant.sendto(state_frame(k), autopilot)
        time.sleep(0.02)
        (status, _, _), stats = serve(ap, deadline_s=0.3)
        assert status == plant_loop.GROUND and stats[plant_loop.ANSWERED] == 1  # back after the next tick
        assert answer_of(plant.recv(1000))[0] == 7000
        for link in ap.links:
            link.sock.setblocking(False)  # as Autopilot.run has them
        ap.poll_gcs()  # what Python does then: the datagram read, its sender now a peer of the link
        assert ap.links[1].peers and ap.gcs_heard is not None
        ap.io[kernel.NEXT_STREAM_TICK] = 10**9  # (a new peer started the streams again: none due here)
        (status, _, _), stats = serve(ap, deadline_s=0.3)
        assert status == plant_loop.QUIET and stats[plant_loop.ANSWERED] == 2  # nothing waits any more


def test_a_blocking_loop_comes_back_to_poll_once_the_plant_answers_fast(vehicle):
    ap, plant, autopilot = vehicle
    locked_without_streams(ap, plant, autopilot)
    set_receive_timeout(ap.plant.sock, 0.5)
    for k in range(2, 14):
        plant.sendto(state_frame(k), autopilot)
    time.sleep(0.02)
    (status, _, _), stats = serve(ap, polling=False)  # each wait short (the datagrams wait): hot after 8
    assert status == plant_loop.DUE and stats[plant_loop.BLOCKED] == 8 and stats[plant_loop.SHORT] == 8
    ap.plant.wait.tally(0, 0, False, int(stats[plant_loop.BLOCKED]), int(stats[plant_loop.SHORT]))
    assert ap.plant.wait.polling()


def test_the_autopilot_is_patient_only_with_a_plant_nothing_paces(vehicle, monkeypatch):
    # A paced plant (real time, --speed 1) must not find its autopilot polling through each period with patience
    # (after a real-time plant's catch-up burst made it hot); an unpaced one keeps the patience (lockstep's speed).
    import autopilot.plant_link as process

    # serve_plant() with the chores due at once hands back after every tick, and yields the core each time: on a
    # machine whose cores are taken (the suite's other workers; three busy loops do it) each yield gave away a slice,
    # and the "fast" ticks
    # below never reached PACED_BELOW × real time. The yield is another test's subject; here only the pace counts.
    monkeypatch.setattr(process.os, "sched_yield", lambda: None)
    ap, plant, autopilot = vehicle
    locked_without_streams(ap, plant, autopilot)
    set_receive_timeout(ap.plant.sock, 0.5)
    wait = ap.plant.wait
    assert wait.patience == PATIENCE
    k = 2
    began = time.monotonic()
    while time.monotonic() - began < 3 * PACE_WINDOW:  # a tick every 5 ms of wall: 0.2 x real time
        plant.sendto(state_frame(k), autopilot)
        k += 1
        ap.next_chores = 0.0
        ap.serve_plant()  # back to Python after the tick
        assert answer_of(plant.recv(1000))[0] == codec.usec_of(k - 1, PERIOD)
        time.sleep(0.005)
    assert wait.patience == wait.budget
    began = time.monotonic()
    while time.monotonic() - began < 10 * PACE_WINDOW and wait.patience != PATIENCE:  # as fast as it answers
        for _ in range(20):
            plant.sendto(state_frame(k), autopilot)
            k += 1
        for _ in range(20):
            ap.next_chores = 0.0
            ap.serve_plant()
        for _ in range(20):
            plant.recv(1000)
    assert wait.patience == PATIENCE


def test_the_autopilot_yields_its_core_once_its_answer_is_out_and_before_pythons_work(vehicle, monkeypatch):
    """A tick that leaves work to Python (a telemetry message Python builds) or a deadline (the telemetry batch, the
    wall-clock work) hands the loop back; before that work the autopilot yields its core (``sched_yield``), so that
    fleet-mates waiting for it answer their ticks first, and only once its own answer is out. Ticks that leave
    Python nothing to do yield nothing."""
    import autopilot.plant_link as process

    ap, plant, autopilot = vehicle
    yields: list[bool] = []  # each yield: was this tick's answer already at the plant?
    monkeypatch.setattr(process.os, "sched_yield", lambda: yields.append(wait_readable(plant, 0.0)))
    plant.sendto(state_frame(1), autopilot)
    nbytes, sender = ap.plant.sock.recvfrom_into(ap.plant.rx)
    ap.on_plant_datagram(nbytes, sender)
    plant.recv(1000)
    set_receive_timeout(ap.plant.sock, 0.2)
    for k in range(2, 42):
        plant.sendto(state_frame(k), autopilot)
    returns = []
    ap.next_chores = time.monotonic() + 10.0
    while (status := ap.serve_plant()) != plant_loop.QUIET:
        returns.append(status)
        while wait_readable(plant, 0.0):
            plant.recv(1000)
    handed_back = [r for r in returns if r in (plant_loop.SENT, plant_loop.DUE)]
    assert handed_back and len(yields) == len(handed_back) and all(yields)
    ap.next_chores = time.monotonic() + 10.0
    assert ap.serve_plant() == plant_loop.QUIET and len(yields) == len(handed_back)


def test_arming_answers_a_holding_plant_at_once(vehicle):
    ap, plant, autopilot = vehicle
    plant.sendto(state_frame(1), autopilot)
    ap.on_plant_datagram(*ap.plant.sock.recvfrom_into(ap.plant.rx))
    assert answer_of(plant.recv(1000)) == (1000, False)
    time.sleep(0.01)  # the plant holds tick 1 (quadsitl plant --hold-until-armed): it says nothing
    arm = mavlink.MAVLink_command_long_message(1, 1, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0)
    ap.receiver.on_message(arm, ap.links[1])
    assert ap.commander.armed
    assert answer_of(plant.recv(1000)) == (1000, True)  # the same tick's answer, armed, without a re-send


@pytest.mark.parametrize("preset", ["paper", "sensors", "fleet"])
def test_flights_are_the_same_to_the_bit_with_and_without_the_compiled_loops(tmp_path, cli, preset, monkeypatch):
    """``fleet``: two vehicles through a formation on one clock, which the plant's compiled loop runs for every
    vehicle in one call (sitl.lockstep_loop), each tick's answers awaited in the vehicles' order as in Python."""
    argv = ["fly", "--preset", "x500" if preset == "sensors" else "paper", "--duration", "2", "--no-figures", "--quiet"]
    if preset == "sensors":
        argv += ["--state", "sensors"]
    if preset == "fleet":
        argv = ["fly", "--vehicles", "2", "--formation", "line", "--no-figures", "--quiet"]
    tables = {}
    for loops in ("0", "1"):
        monkeypatch.setenv(fastio.LOOPS_ENV, loops)
        out = tmp_path / loops
        r = cli(*argv, "--out", str(out))
        assert r.returncode == 0, r.stderr
        files = ["v1/telemetry.csv", "v2/telemetry.csv"] if preset == "fleet" else ["telemetry.csv"]
        tables[loops] = [(out / f).read_text() for f in files]
    assert tables["0"] == tables["1"]
    if preset == "fleet":  # the whole manoeuvre, each vehicle's own
        assert len(tables["1"][0].splitlines()) > 20_000 and tables["1"][0] != tables["1"][1]
    else:
        assert len(tables["1"][0].splitlines()) == 2001


def test_a_bad_loops_setting_is_one_line_from_both_processes(cli, monkeypatch):
    monkeypatch.setenv(fastio.LOOPS_ENV, "yes")
    for argv in (["autopilot", "--no-zenoh", "--plant-listen", "127.0.0.1:0"], ["plant", "--ticks", "1"]):
        r = cli(*argv)
        assert r.returncode == 2
        assert r.stderr.strip().splitlines() == [
            f"quadsitl {argv[0]}: error: ${fastio.LOOPS_ENV} = 'yes': expected 0 (Python loops) or 1 (compiled loops, "
            "the default)"
        ]
