"""The real-time plant's compiled period (:mod:`sitl.realtime_loop`, through :class:`sitl.realtime_fleet.RealtimeFleet`)
does what the Python loop of :func:`sitl.realtime.run_realtime` does, vehicle by vehicle: the state sent (none once it
left its bounds), every waiting answer taken (the newest wins, stale and corrupt ones counted), the period counted
answered or late, the lost-autopilot clock, one step; and a datagram only pymavlink reads is left to Python. A fleet's
vehicles keep their own accounts, airframes and integrators in the fleet's rows."""

from __future__ import annotations

import copy
import socket
import time

import numpy as np
import pytest

from quadsitl import codec, fastio, wire
from sitl import process, realtime_loop, tick
from sitl.plant_link import AUTOPILOT_LOST_AFTER, LOST_AFTER_NS
from sitl.realtime_fleet import RealtimeFleet

pytestmark = pytest.mark.skipif(not fastio.AVAILABLE, reason="compiled code only (NUMBA_DISABLE_JIT is set)")


@pytest.fixture
def vehicle():
    """One vehicle of a real-time plant, its autopilot a bare socket; the compiled period bound to it."""
    ap = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    ap.bind(("127.0.0.1", 0))
    ap.settimeout(2.0)
    args = process.build_parser().parse_args(["--preset", "paper", "--autopilot", f"127.0.0.1:{ap.getsockname()[1]}"])
    (v,) = process.fleet_from_args(args)
    process.warm_up(v.plant)
    yield v, ap, RealtimeFleet([v])
    v.link.close()
    ap.close()


def answer(ap: socket.socket, plant_address: tuple[str, int], stamp: int, forces: tuple, max_thrust: float,
           corrupt: bool = False) -> None:  # fmt: skip
    tx = np.zeros(codec.FRAME_MAX, dtype=np.uint8)
    n = codec.encode_actuators(tx, 0, 1, 1, stamp, forces, max_thrust, True)
    if corrupt:
        tx[codec.HEADER_SIZE + 3] ^= 0xFF  # a payload byte: the checksum no longer holds
    ap.sendto(tx[:n].tobytes(), plant_address)


def test_the_state_goes_out_and_none_once_it_left_its_bounds(vehicle):
    v, ap, fleet = vehicle
    assert fleet.send(7) == -1
    data = ap.recv(65535)
    decoded = np.zeros(codec.DECODED_SIZE)
    assert codec.decode_state(np.frombuffer(data, dtype=np.uint8).copy(), len(data), decoded) == codec.usec_of(
        7, v.plant.period
    )
    assert np.array_equal(decoded[:12], v.plant.x)
    v.plant.x[2] = -1e6  # far above any bound
    assert fleet.send(8) == 0  # the first vehicle (of one) left its bounds
    ap.settimeout(0.05)
    with pytest.raises(TimeoutError):
        ap.recv(65535)


def test_the_period_takes_the_newest_answer_and_steps_as_the_python_loop_does(vehicle):
    v, ap, fleet = vehicle
    link, plant = v.link, v.plant
    to_plant = link.sock.getsockname()
    f = link.max_thrust
    twin = copy.deepcopy(plant)
    period = plant.period
    link.io[tick.LAST_USEC] = codec.usec_of(3, period)
    answer(ap, to_plant, codec.usec_of(5, period), (0.4 * f, 0.41 * f, 0.42 * f, 0.43 * f), f)
    answer(ap, to_plant, codec.usec_of(4, period), (0.1 * f,) * 4, f)  # older than the newest: stale
    answer(ap, to_plant, codec.usec_of(2, period), (0.1 * f,) * 4, f)  # older than the last used: stale
    answer(ap, to_plant, codec.usec_of(6, period), (0.1 * f,) * 4, f, corrupt=True)  # never flown
    time.sleep(0.02)
    fleet.take_and_step(codec.usec_of(5, period), LOST_AFTER_NS, True, "applying zero thrust")
    assert link.io[tick.DISCARDED] == 2 and link.io[tick.CORRUPT] == 1
    assert link.io[tick.LAST_USEC] == codec.usec_of(5, period) and (v.answered, v.late) == (1, 0)
    assert link.first_heard is not None and not link.lost
    assert np.allclose(plant.commanded, (0.4 * f, 0.41 * f, 0.42 * f, 0.43 * f))  # the newest answer's forces
    twin.step(tuple(plant.commanded))  # the Python step, on the same command
    assert np.array_equal(plant.work, twin.work) and plant.time == twin.time
    # The next period: nothing came in it, so the vehicle flies the previous command and the period is late.
    fleet.take_and_step(codec.usec_of(6, period), LOST_AFTER_NS, True, "applying zero thrust")
    twin.step()
    assert (v.answered, v.late) == (1, 1) and np.array_equal(plant.work, twin.work)


def test_a_datagram_only_pymavlink_reads_is_left_to_python_and_flown(vehicle):
    v, ap, fleet = vehicle
    link, plant = v.link, v.plant
    f = link.max_thrust
    stamp = codec.usec_of(1, plant.period)
    mav = wire.link(1, 1)
    msg = mav.hil_actuator_controls_encode(stamp, [0.5, 0.5, 0.5, 0.5] + [0.0] * 12, 0, 0)
    statustext = mav.statustext_encode(6, b"hello")
    ap.sendto(codec.pack(statustext, mav) + codec.pack(msg, mav), link.sock.getsockname())  # two messages
    time.sleep(0.02)
    fleet.take_and_step(stamp, LOST_AFTER_NS, True, "applying zero thrust")
    assert link.io[tick.LAST_USEC] == stamp and v.answered == 1
    assert np.allclose(plant.commanded, wire.forces_from_message(msg, f))


def test_a_silent_autopilot_is_lost_then_back_and_said_once_each(vehicle, capsys):
    v, ap, fleet = vehicle
    link, plant = v.link, v.plant
    f = link.max_thrust
    period = plant.period
    answer(ap, link.sock.getsockname(), codec.usec_of(0, period), (0.3 * f,) * 4, f)
    time.sleep(0.02)
    fleet.take_and_step(codec.usec_of(0, period), LOST_AFTER_NS, False, "applying the last command")
    link.rt[realtime_loop.LAST_NS] -= round((AUTOPILOT_LOST_AFTER + 0.1) * 1e9)  # silent since
    for k in (1, 2):  # lost: said once; on "last", the last command stays
        fleet.take_and_step(codec.usec_of(k, period), LOST_AFTER_NS, False, "applying the last command")
        assert link.lost and np.allclose(plant.commanded, 0.3 * f)
    fleet.take_and_step(codec.usec_of(3, period), LOST_AFTER_NS, True, "applying zero thrust")  # on "zero": none
    assert np.array_equal(plant.commanded, np.zeros(4))
    answer(ap, link.sock.getsockname(), codec.usec_of(4, period), (0.35 * f,) * 4, f)
    time.sleep(0.02)
    fleet.take_and_step(codec.usec_of(4, period), LOST_AFTER_NS, True, "applying zero thrust")
    assert not link.lost and np.allclose(plant.commanded, 0.35 * f)
    err = capsys.readouterr().err.splitlines()
    assert err == ["plant: autopilot lost (no answer for 0.5 s); applying the last command",
                   "plant: autopilot back; following its commands"]  # fmt: skip
    assert (v.answered, v.late) == (2, 3)


def test_a_held_lockstep_clock_hears_its_autopilot_through_the_same_account(vehicle, capsys):
    """Lockstep's PlantLink.heard and check_lost keep the account the real-time period keeps (rt): first and last
    heard, lost, and back said once."""
    link = vehicle[0].link
    assert link.first_heard is None and link.last_heard is None
    before = time.monotonic()
    link.heard()
    first = link.first_heard
    assert first is not None and before <= first <= time.monotonic() and link.last_heard == first
    link.rt[realtime_loop.LAST_NS] -= round((AUTOPILOT_LOST_AFTER + 0.1) * 1e9)  # silent since
    holding = "holding: simulated time stops until it answers"
    assert link.check_lost(holding) and link.check_lost(holding) and link.lost  # said once
    link.heard()
    assert not link.lost and link.first_heard == first and link.last_heard > first
    link.heard()  # heard again: nothing to say
    err = capsys.readouterr().err.splitlines()
    assert err == [f"plant: autopilot lost (no answer for 0.5 s); {holding}",
                   "plant: autopilot back; following its commands"]  # fmt: skip


@pytest.fixture
def three():
    """Three vehicles of one real-time plant, the second an x500 (the others the paper's), their autopilots bare
    sockets; Python twins of their plants; the fleet's compiled period bound to them."""
    aps = [socket.socket(socket.AF_INET, socket.SOCK_DGRAM) for _ in range(3)]
    argv = ["--preset", "paper", "--vehicle-preset", "2=x500", "--mode", "realtime"]
    for ap in aps:
        ap.bind(("127.0.0.1", 0))
        ap.settimeout(2.0)
        argv += ["--autopilot", f"127.0.0.1:{ap.getsockname()[1]}"]
    vehicles = process.fleet_from_args(process.build_parser().parse_args(argv))
    process.warm_up(vehicles[0].plant)
    fleet = RealtimeFleet(vehicles)
    yield vehicles, aps, fleet
    for v, ap in zip(vehicles, aps, strict=True):
        v.link.close()
        ap.close()


def test_a_fleet_steps_each_vehicle_in_its_own_rows_as_the_python_loop_does(three, capsys):
    vehicles, aps, fleet = three
    period = vehicles[0].plant.period
    assert not np.array_equal(vehicles[0].plant.params, vehicles[1].plant.params)  # two airframes
    for i, v in enumerate(vehicles):
        v.plant.x[0] = 10.0 * i  # the vehicle's own row of the fleet's state, written through its plant
    twins = [copy.deepcopy(v.plant) for v in vehicles]
    # tick 0: each autopilot is sent its own vehicle's state
    assert fleet.send(0) == -1
    decoded = np.zeros(codec.DECODED_SIZE)
    for i, ap in enumerate(aps):
        data = ap.recv(65535)
        first = codec.HEADER_SIZE + data[1] + 2  # the ODOMETRY; an x500's BATTERY_STATUS follows it
        assert codec.decode_state(np.frombuffer(data, dtype=np.uint8).copy(), first, decoded) >= 0
        assert decoded[0] == 10.0 * i
        assert (len(data) > first) == (vehicles[i].preset.battery is not None)
    # the first answers; the second's in a datagram only pymavlink reads (two messages); the third says nothing
    stamp = codec.usec_of(0, period)
    f0, f1 = vehicles[0].link.max_thrust, vehicles[1].link.max_thrust
    answer(aps[0], vehicles[0].link.sock.getsockname(), stamp, (0.4 * f0, 0.41 * f0, 0.42 * f0, 0.43 * f0), f0)
    mav = wire.link(1, 1)
    msg = mav.hil_actuator_controls_encode(stamp, [0.5, 0.51, 0.52, 0.53] + [0.0] * 12, 0, 0)
    two = codec.pack(mav.statustext_encode(6, b"hello"), mav) + codec.pack(msg, mav)
    aps[1].sendto(two, vehicles[1].link.sock.getsockname())
    time.sleep(0.02)
    fleet.take_and_step(stamp, LOST_AFTER_NS, True, "applying zero thrust")
    assert [(v.answered, v.late) for v in vehicles] == [(1, 0), (1, 0), (0, 0)]  # the third: never heard, not late
    commands = [(0.4 * f0, 0.41 * f0, 0.42 * f0, 0.43 * f0), tuple(wire.forces_from_message(msg, f1)), (0.0,) * 4]
    for v, twin, command in zip(vehicles, twins, commands, strict=True):
        assert np.allclose(v.plant.commanded, command)
        twin.step(tuple(v.plant.commanded))  # the Python step of that vehicle, on the same command
        assert np.array_equal(v.plant.work, twin.work) and v.plant.time == twin.time == period
    # the first autopilot falls silent: lost, said once and named; the others' accounts are untouched
    vehicles[0].link.rt[realtime_loop.LAST_NS] -= round((AUTOPILOT_LOST_AFTER + 0.1) * 1e9)
    fleet.take_and_step(codec.usec_of(1, period), LOST_AFTER_NS, True, "applying zero thrust")
    assert [v.link.lost for v in vehicles] == [True, False, False]
    assert np.array_equal(vehicles[0].plant.commanded, np.zeros(4))
    assert np.allclose(vehicles[1].plant.commanded, commands[1])  # still its last command
    assert capsys.readouterr().err.splitlines() == [
        "plant: v1's autopilot lost (no answer for 0.5 s); applying zero thrust"
    ]
    # the third vehicle's state leaves its bounds: it is named, and no vehicle is sent tick 2 (the run ends)
    vehicles[2].plant.x[2] = -1e6
    assert fleet.send(2) == 2
    for ap in aps:
        ap.settimeout(0.05)
        with pytest.raises(TimeoutError):
            ap.recv(65535)
