"""Hosted vehicles flown in a group by one thread (autopilot.group, plant_loop.serve_group): every vehicle's every
datagram answered once and in order, the answers the very bytes a vehicle flying its own loop sends, and a vehicle
whose ticks are Python's (no plant yet) read by Python and then served in compiled code."""

import socket
import threading
import time

import numpy as np
import pytest

from autopilot import tick as kernel
from autopilot.group import Group, groups_of
from autopilot.process import Autopilot, build_parser
from quadsitl import codec, fastio, wire
from quadsitl.config import load_preset
from quadsitl.process_util import free_ports_apart, set_receive_timeout

pytestmark = [pytest.mark.skipif(not fastio.AVAILABLE, reason="compiled loops: Linux, numba on"),
              pytest.mark.timeout(240)]  # fmt: skip
PERIOD = 0.001
TICKS = 300


def state(tick: int, vehicle: int) -> tuple:
    """Vehicle ``vehicle``'s state at ``tick``: each vehicle's its own, every tick another."""
    x = 0.001 * tick + 10.0 * vehicle
    return (x, -x, -2.0 - vehicle, 0.1, -0.1, 0.05, 0.01 * np.sin(x), 0.02, 0.3 * x, 0.0, 0.01, -0.02 * vehicle)


def state_frame(tick: int, vehicle: int) -> bytes:
    frame = np.zeros(codec.FRAME_MAX, dtype=np.uint8)
    n = codec.encode_state(frame, tick & 0xFF, wire.PLANT_SYSTEM_ID, wire.PLANT_COMPONENT_ID,
                           codec.usec_of(tick, PERIOD), state(tick, vehicle))  # fmt: skip
    return frame[:n].tobytes()


@pytest.fixture
def fleet():
    """Three autopilots (paper preset, system id 1, the same options: the same answers to the same datagrams) and a
    plant socket for each."""
    ports = free_ports_apart(3)
    aps, plants = [], []
    for port in ports:
        args = build_parser().parse_args(["--preset", "paper", "--plant-listen", f"127.0.0.1:{port}", "--gcs-listen",
                                          "127.0.0.1:0", "--gcs-remote", "none", "--api-listen", "127.0.0.1:0",
                                          "--api-remote", "none", "--no-zenoh"])  # fmt: skip
        args.home, args.signing_key = None, None
        aps.append(Autopilot(load_preset("paper"), args))
        aps[-1].plant.unlocked = True
        plant = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        plant.bind(("127.0.0.1", 0))
        set_receive_timeout(plant, 5.0)
        plants.append(plant)
    yield aps, plants, [("127.0.0.1", p) for p in ports]
    for p in plants:
        p.close()
    for ap in aps:
        ap.close()


def test_a_group_answers_every_tick_of_its_own_vehicle_as_a_vehicle_on_its_own_loop_does(fleet):
    aps, plants, addresses = fleet
    grouped, alone = aps[:2], aps[2]
    groups, single = groups_of(aps, threads=2)
    assert [len(g) for g in groups] == [2, 1] and not single  # same kind: groups as even as they come
    # vehicle 0 locks to its plant through Python's loop before the group starts, and so does the vehicle on its own
    # loop; vehicle 1's first datagram is Python's in the group (no plant yet: READABLE), its later ones the loop's
    answers: list[list[bytes]] = [[], [], []]
    for v in (0, 2):
        plants[v].sendto(state_frame(1, v), addresses[v])
        aps[v].on_plant_datagram(*aps[v].plant.sock.recvfrom_into(aps[v].plant.rx))
        answers[v].append(plants[v].recv(1000))
    stop, ready = threading.Event(), []
    threads = [threading.Thread(target=Group(grouped).run, args=(stop, lambda: ready.append(1))),
               threading.Thread(target=alone.run, args=(stop, lambda: ready.append(1)))]  # fmt: skip
    for t in threads:
        t.start()
    try:
        for tick in range(2, TICKS):
            for v in range(3):
                plants[v].sendto(state_frame(tick, 0 if v == 2 else v), addresses[v])
            for v in range(3):
                answers[v].append(plants[v].recv(1000))
    finally:
        stop.set()
        for t in threads:
            t.join(10)
    assert len(ready) == 3 and not any(t.is_alive() for t in threads)
    assert answers[0] == answers[2]  # the same bytes as the vehicle on its own loop, tick by tick
    for v in (0, 1):  # each vehicle flew its own datagrams, each once, in order: no other vehicle's
        stamps = [codec.decode_actuators(np.frombuffer(a.ljust(codec.FRAME_MAX, b"\0"), dtype=np.uint8).copy(),
                                         len(a), np.zeros(4), 1.0) for a in answers[v]]  # fmt: skip
        assert stamps == [1000 * k for k in range(1 + v, TICKS)]
        assert np.allclose(aps[v].st[:12], state(TICKS - 1, v), rtol=1e-6, atol=1e-6)  # its own last state (float32)
        assert aps[v].io[kernel.TICK] == TICKS - 1
    assert aps[1].plant.address is not None and aps[1].serving()  # its first datagram through Python locked it


def test_a_group_polls_before_it_blocks_only_while_its_plants_run_unpaced(fleet):
    """As a vehicle alone (SpinThenBlock, PaceGauge): ticks as fast as they are answered make the group poll before
    it blocks (spin_ns, the budget); ticks a millisecond apart (real time) make it block at once."""
    aps, plants, addresses = fleet
    group = Group(aps[:2])
    stop = threading.Event()
    thread = threading.Thread(target=group.run, args=(stop, lambda: None))
    thread.start()
    tick = 1

    def fly(seconds: float, period: float) -> float:
        """Ticks for ``seconds``, ``period`` apart (0: each as soon as both answers came) → ticks per second."""
        nonlocal tick
        began = time.monotonic()
        first = tick
        while time.monotonic() - began < seconds:
            for v in (0, 1):
                plants[v].sendto(state_frame(tick, v), addresses[v])
            for v in (0, 1):
                plants[v].recv(1000)
            tick += 1
            if period:
                time.sleep(period)
        return (tick - first) / (time.monotonic() - began)

    try:
        assert group.budget_ns > 0
        for _ in range(2):
            rate = fly(0.6, 0.0)
            assert group.spin_ns == group.budget_ns, rate  # unpaced: PACED_BELOW x real time or faster
            rate = fly(0.6, PERIOD)
            assert group.spin_ns == 0 and rate < 1.5 / PERIOD, rate
    finally:
        stop.set()
        thread.join(10)
    assert not thread.is_alive()
