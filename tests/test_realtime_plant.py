"""The real-time plant's clock (:func:`sitl.realtime.run_realtime`) counts an autopilot's answer by when it came, not
by when the plant got round to reading it: the plant sleeps through each period and takes every answer waiting in
its sockets when the period ends, before the step, even when its own wake-up came late (the scheduler ran something
else)."""

from __future__ import annotations

import socket

import numpy as np
import pytest

from quadsitl import codec, fastio
from sitl import process, realtime


def answer_every_state(ap: socket.socket, forces: tuple[float, ...], max_thrust: float,
                       silent: range = range(0)) -> int:  # fmt: skip
    """What an autopilot does: each state datagram waiting on ``ap`` answered with ``forces`` [N], stamped with the
    state's time, but for the ticks in ``silent`` (read, not answered); the number answered."""
    rx = np.zeros(65535, dtype=np.uint8)
    tx = np.zeros(codec.FRAME_MAX, dtype=np.uint8)
    decoded = np.zeros(codec.DECODED_SIZE)
    answered = 0
    while True:
        try:
            n, sender = ap.recvfrom_into(rx)
        except BlockingIOError:
            return answered
        stamp = codec.decode_state(rx, n, decoded)
        if stamp == codec.NOT_THIS_FRAME:  # sensor mode: HIL_SENSOR first, stamped in its first field as ODOMETRY is
            stamp = int(rx[codec.HEADER_SIZE : codec.HEADER_SIZE + 8].view(np.uint64)[0])
        assert stamp >= 0
        if round(stamp / 1000) in silent:  # [us] at 1 kHz
            continue
        m = codec.encode_actuators(tx, 0, 1, 1, stamp, forces, max_thrust, True)
        ap.sendto(tx[:m].tobytes(), sender)
        answered += 1


def fleet_of(vehicles: int, *options: str) -> tuple[list, list[socket.socket], tuple[float, ...], float]:
    """A real-time plant's fleet of ``vehicles`` (the paper preset, with the plant's ``options``), their autopilots'
    sockets, the forces they answer with [N], the maximum thrust [N]; compiled code loaded before any clock starts,
    as a real-time plant process loads it."""
    aps = []
    for _ in range(vehicles):
        ap = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        ap.bind(("127.0.0.1", 0))
        ap.setblocking(False)
        aps.append(ap)
    argv = ["--preset", "paper", "--mode", "realtime", *options]
    for ap in aps:
        argv += ["--autopilot", f"127.0.0.1:{ap.getsockname()[1]}"]
    fleet = process.fleet_from_args(process.build_parser().parse_args(argv))
    max_thrust = fleet[0].link.max_thrust
    forces = (0.3 * max_thrust, 0.31 * max_thrust, 0.32 * max_thrust, 0.33 * max_thrust)
    process.warm_up(fleet[0].plant, clocks=("realtime",))  # compiled code loaded before the clock starts: the plant's,
    scratch = np.zeros(codec.FRAME_MAX, dtype=np.uint8)
    codec.decode_state(
        scratch, codec.encode_state(scratch, 0, 1, 1, 0, np.zeros(codec.DECODED_SIZE)), np.zeros(codec.DECODED_SIZE)
    )
    codec.encode_actuators(scratch, 0, 1, 1, 0, forces, max_thrust, True)  # ... the answering autopilot's
    return fleet, aps, forces, max_thrust


@pytest.mark.parametrize("loops", ["1", "0"])  # the compiled period (sitl.realtime_loop), and the Python one
@pytest.mark.parametrize("vehicles", [1, 3])
def test_an_answer_that_came_within_its_period_counts_though_the_plant_woke_late(monkeypatch, vehicles, loops):
    monkeypatch.setenv(fastio.LOOPS_ENV, loops)
    fleet, aps, forces, max_thrust = fleet_of(vehicles)
    real_sleep_until = realtime.sleep_until
    overslept = []

    def late_wake(deadline):
        """The period's wait as a plant descheduled past its end: every autopilot answers at once (well within the
        period), and the plant wakes only after the period is over. (A tick that starts late has no wait before its
        period ends: only the plant's reading after it.)"""
        for ap in aps:
            answer_every_state(ap, forces, max_thrust)
        if deadline > realtime.time.monotonic():
            overslept.append(deadline)
        real_sleep_until(deadline + 2e-5)

    monkeypatch.setattr(realtime, "sleep_until", late_wake)
    try:
        # 0.2 s: after a stall of the machine the plant catches up tick after tick, and a catch-up tick's wait has
        # nothing to oversleep; 20 ticks were all catch-up once in CI (three busy workers)
        ticks = 200
        assert realtime.run_realtime(fleet, ticks) == ticks
        assert overslept  # periods whose wait overslept (each makes the next tick late: on a quiet machine most)
        for v in fleet:
            # tick 0's answer counts from the start (the autopilot is heard from then on); every period answered
            assert (v.answered, v.late) == (ticks, 0), v.name
            assert np.allclose(v.plant.commanded, forces)  # the answer was flown, not the previous command
            assert v.link.io[process.tick.LAST_USEC] == codec.usec_of(ticks - 1, v.plant.period)
    finally:
        for v in fleet:
            v.link.close()
        for ap in aps:
            ap.close()


@pytest.mark.parametrize("loops", ["1", "0"])
def test_each_vehicles_missed_periods_are_named_by_their_tick(monkeypatch, loops):
    """``run_realtime(..., late=...)``, what the plant's ``--stats`` give the bench to set beside the host's stalls:
    vehicle 2's autopilot silent for ticks 10-14 (read, not answered), vehicle 1's answering every tick."""
    monkeypatch.setenv(fastio.LOOPS_ENV, loops)
    fleet, aps, forces, max_thrust = fleet_of(2)
    real_sleep_until = realtime.sleep_until

    def answered_then_asleep(deadline):  # every answer in before the period ends, whatever the machine's load
        answer_every_state(aps[0], forces, max_thrust)
        answer_every_state(aps[1], forces, max_thrust, silent=range(10, 15))
        real_sleep_until(deadline)

    monkeypatch.setattr(realtime, "sleep_until", answered_then_asleep)
    late: list[list[int]] = [[], []]
    try:
        assert realtime.run_realtime(fleet, 30, late=late) == 30
        assert late == [[], [10, 11, 12, 13, 14]]
        assert [(v.answered, v.late) for v in fleet] == [(30, 0), (25, 5)]
    finally:
        for v in fleet:
            v.link.close()
        for ap in aps:
            ap.close()


# Linux's, on 64-bit machines (asm-generic/socket.h: SO_TIMESTAMPNS_OLD, a 16-byte timespec); Python names it from 3.14
SO_TIMESTAMPNS = getattr(socket, "SO_TIMESTAMPNS", 35)


def received_at(ap: socket.socket) -> int:
    """When the kernel queued the next datagram waiting on ``ap`` (SO_TIMESTAMPNS) [ns], the datagram read."""
    _, ancillary, _, _ = ap.recvmsg(65535, socket.CMSG_SPACE(16))
    ((level, kind, data),) = ancillary
    assert (level, kind) == (socket.SOL_SOCKET, SO_TIMESTAMPNS)
    seconds, nanoseconds = np.frombuffer(data[:16], dtype=np.int64)
    return int(seconds) * 10**9 + int(nanoseconds)


@pytest.mark.parametrize("loops", ["1", "0"])
def test_the_vehicles_take_turns_at_being_sent_their_tick_first(monkeypatch, loops):
    """Tick k goes to vehicle k mod N first, then on round (:func:`sitl.realtime_loop.send_order`): the vehicle sent
    to last has the least of the period left to answer in. The order is read from the kernel's receive time stamps of
    each tick's datagrams."""
    monkeypatch.setenv(fastio.LOOPS_ENV, loops)
    fleet, aps, _, _ = fleet_of(3)
    for ap in aps:
        ap.setsockopt(socket.SOL_SOCKET, SO_TIMESTAMPNS, 1)
        ap.setblocking(True)
        ap.settimeout(2.0)
    orders = []

    def read_the_order(deadline):
        stamps = [(received_at(ap), i) for i, ap in enumerate(aps)]
        orders.append([i for _, i in sorted(stamps)])
        realtime.time.sleep(max(0.0, deadline - realtime.time.monotonic()))

    monkeypatch.setattr(realtime, "sleep_until", read_the_order)
    try:
        assert realtime.run_realtime(fleet, 7) == 7
    finally:
        for v in fleet:
            v.link.close()
        for ap in aps:
            ap.close()
    assert orders == [[k % 3, (k + 1) % 3, (k + 2) % 3] for k in range(7)]


@pytest.mark.parametrize("state", ["truth", "sensors"])
@pytest.mark.parametrize("loops", ["1", "0"])
def test_nothing_compiles_in_a_real_time_period_once_warmed_up(monkeypatch, loops, state):
    """After the plant's warm-up for its mode and clock (:func:`sitl.process.warm_up`, which every plant process runs
    before its clock starts), a real-time period, compiled or Python, on the truth or on sensors, calls no compiled
    function of :mod:`sitl.realtime_loop`, :mod:`sitl.tick` or :mod:`sitl.plant` for types it has not compiled (or
    loaded): a compile on a fresh checkout would stall the clock."""
    from sitl import plant, realtime_loop, tick

    monkeypatch.setenv(fastio.LOOPS_ENV, loops)
    fleet, aps, forces, max_thrust = fleet_of(2, "--state", state)
    compiled = [f for m in (realtime_loop, tick, plant) for f in vars(m).values() if hasattr(f, "signatures")]
    before = [len(f.signatures) for f in compiled]
    real_sleep_until = realtime.sleep_until

    def answered_then_asleep(deadline):
        for ap in aps:
            answer_every_state(ap, forces, max_thrust)
        real_sleep_until(deadline)

    monkeypatch.setattr(realtime, "sleep_until", answered_then_asleep)
    try:
        assert realtime.run_realtime(fleet, 5, [], "zero", [[], []]) == 5
    finally:
        for v in fleet:
            v.link.close()
        for ap in aps:
            ap.close()
    assert [v.answered for v in fleet] == [5, 5]
    assert [len(f.signatures) for f in compiled] == before
