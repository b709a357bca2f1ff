"""The plant process (``quadsitl plant``, ``python -m sitl``): owns the truth state and integrates it.

One MAVLink 2 UDP link to the autopilot (see :mod:`quadsitl.wire`). Each tick's datagram is the state as
ODOMETRY (``--state truth``), or in sensor mode (``--state sensors``, the default when the preset has a [sensors]
section) what the vehicle's sensors measure of it: HIL_SENSOR, HIL_GPS when a fix is delivered, and the ground
truth as HIL_STATE_QUATERNION (:mod:`quadsitl.hil`), the GPS's latitude and longitude from ``--home``.

- ``lockstep`` (default): the plant is the clock. For tick k it sends the state stamped with the
  simulated time, waits for the HIL_ACTUATOR_CONTROLS answering tick k, then integrates one period.
  Until an answer comes (at start, or if the autopilot goes away) it free-wheels: it re-sends the
  state every 50 ms without advancing time. ``--speed F`` caps the pace at F × real time (0 = as fast
  as possible): a late tick is made up, but time lost to a stall longer than PACE_SLACK (or to holding) is not
  caught up in a burst (:mod:`sitl.lockstep`).
- ``realtime``: integrates on the wall clock at period T and applies the latest actuator command it has
  (:mod:`sitl.realtime`).

In both, actuator messages older than the last one used (by ``time_usec``) are discarded.

Divergence: the state x(k) is checked at the start of every tick k, before it goes out (the autopilot's
controller never sees it), with the check of the sweeps' batch engine and ``quadsitl sim``
(:func:`sitl.plant.inside`, its default bounds). A state that is not finite or out of its bounds ends the run:
it is not sent; the plant says one line on stderr naming the quantity, its value and the bound, tells the
autopilot in a STATUSTEXT (severity CRITICAL, which the autopilot relays to its ground stations), and exits with
status :data:`~quadsitl.process_util.PLANT_DIVERGED` (3).

Wind: the preset's [wind] and the wind options; given a Zenoh endpoint or configuration (``quadsitl up`` gives
its own), the plant also takes wind changes on ``quadsitl/<vehicle>/wind`` (:mod:`sitl.wind_link`).

This module is the process's shell: its options, the vehicles they ask for (:func:`fleet_from_args`), the warm-up of
the compiled code before the clock starts (:func:`warm_up`), and :func:`main`. Each vehicle is a
:class:`sitl.vehicle.Vehicle`, its link to its autopilot a :class:`sitl.plant_link.PlantLink`.
"""

from __future__ import annotations

import argparse
import contextlib
import copy
import json
import socket
import sys
import time
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from quadsitl import codec, fastio, hil, wire
from quadsitl.cli_util import (
    CLOCKS,
    UsageError,
    add_preset_arguments,
    add_state_arguments,
    add_wind_arguments,
    check_speed,
    parse_home,
    parse_vehicle_presets,
    per_vehicle,
    with_state,
    with_wind,
)
from quadsitl.config import ConfigError, load_preset
from quadsitl.frames import PX4_HOME
from quadsitl.jit import favour_compile_time
from quadsitl.process_util import (
    CORES_AWAKE_HELP,
    HOT_AFTER,
    PLANT_DIVERGED,
    bind_udp,
    clock_above_its_peers,
    hold_cores_awake,
    parse_address,
    rss_mb,
    set_receive_timeout,
    start_process,
    timers_on_time,
)
from quadsitl.telemetry import add_zenoh_arguments, config_from_args
from quadsitl.timing import late_periods, period_stats
from sitl import lockstep_loop, realtime_loop, tick
from sitl.impair import add_impair_argument, impairment_from
from sitl.lockstep import run_lockstep
from sitl.plant import Plant, state_inside
from sitl.plant_link import LOST_AFTER_NS, PlantLink
from sitl.realtime import run_realtime
from sitl.vehicle import DivergedError, Vehicle
from sitl.wind_link import WindLink


def warm_up(plant: Plant, modes: Iterable[bool] | None = None, clocks: Iterable[str] = CLOCKS) -> None:
    """Compile (or load from numba's cache) everything a tick calls, before the first tick, on a copy: for the
    plant's own mode (on sensors or the truth, :attr:`sitl.plant.Plant.sens`) or for each of ``modes`` (True: on
    sensors), and for each of ``clocks`` (lockstep's tick inlines the dynamics; real time steps them out of line).
    A process compiles only what it flies (docs/performance.md#compiling-on-first-run)."""
    for sensing in sorted(set((plant.sensing,) if modes is None else modes)):
        for clock in clocks:
            _WARM[clock](copy.deepcopy(plant), sensing)


def _warm_arrays(twin: Plant, sensing: bool) -> tuple[np.ndarray, np.ndarray, tuple | None]:
    """A link's buffer and bookkeeping in the mode (no answer used yet), and the sensors' arrays it is given."""
    link = np.zeros(max(codec.FRAME_MAX, hil.DATAGRAM_MAX), dtype=np.uint8)
    io = np.zeros(tick.IO_SIZE, dtype=np.int64)
    io[tick.SENSING], io[tick.LAST_USEC] = sensing, -1
    return link, io, twin.sensors.arrays if sensing else None


def _warm_lockstep(twin: Plant, sensing: bool) -> None:
    link, io, sens = _warm_arrays(twin, sensing)
    args = (twin.x, twin.motors, twin.out, twin.v, twin.a, twin.air, twin.air_rng, twin.period, twin.substeps,
            twin.method, link, io, sens)  # fmt: skip
    n = codec.encode_actuators(link, 0, 1, 1, 0, (0.0, 0.0, 0.0, 0.0), 1.0, False)
    tick.lockstep_tick(link, n, 0, 1.0, twin.commanded.copy(), twin.commanded, *args, 0)
    tick.take_and_step(0, 0, twin.commanded, twin.commanded.copy(), *args, 0)
    tick.encode_tick(link, io, twin.x, twin.out, twin.air, sens, 0, twin.period)  # (sitl.plant_link: from Python)
    codec.decode_actuators(link, n, twin.commanded, 1.0)
    state_inside(twin.x)
    rt = np.zeros(realtime_loop.RT_SIZE, dtype=np.int64)
    realtime_loop.heard(rt, 1)  # (a held lockstep clock's: PlantLink.heard and check_lost)
    realtime_loop.lost_clock(rt, 2, LOST_AFTER_NS)
    if fastio.AVAILABLE:  # the compiled clock (sitl.lockstep_loop), a fleet of one: its answer to tick 0 waiting
        with _loopback_pair() as (a, b):
            tx, rt_io, work, params, air_rng, received = _rows(twin, link, io)
            rt_io[0, tick.LAST_USEC] = -1  # (the tick calls above took tick 0's answer)
            b.send(link[:n].tobytes())
            lockstep_loop.run(np.array([a.fileno()], dtype=np.int64), np.zeros(65535, dtype=np.uint8), 0, 1,
                              np.ones(1), received, work, params, air_rng, _sensor_rows(twin, sensing),
                              np.array([twin.substeps]), np.array([twin.method]), twin.period, tx, rt_io,
                              np.zeros_like(tx), np.zeros(1, dtype=np.int64), 0, np.ones(1, dtype=np.bool_),
                              np.full(1, 1000), np.full(1, 1000), HOT_AFTER,
                              np.zeros((1, lockstep_loop.STATS_SIZE), dtype=np.int64))  # fmt: skip


def _warm_realtime(twin: Plant, sensing: bool) -> None:
    link, io, sens = _warm_arrays(twin, sensing)
    tick.encode_tick(link, io, twin.x, twin.out, twin.air, sens, 0, twin.period)  # (sitl.plant_link: from Python)
    n = codec.encode_actuators(link, 0, 1, 1, 0, (0.0, 0.0, 0.0, 0.0), 1.0, False)
    codec.decode_actuators(link, n, twin.commanded, 1.0)
    twin.step()  # (the Python period's, impaired links: sitl.plant.step_work, which the compiled period calls too)
    state_inside(twin.x)
    realtime_loop.send_order(0, 0, 1)  # (the Python period's order of sending, impaired links)
    if fastio.AVAILABLE:  # the compiled period (sitl.realtime_loop), a fleet of one: its state sent, its answer taken
        with _loopback_pair() as (a, b):
            tx, rt_io, work, params, air_rng, received = _rows(twin, link, io)
            fds, rt = np.array([a.fileno()], dtype=np.int64), np.zeros((1, realtime_loop.RT_SIZE), dtype=np.int64)
            realtime_loop.send_ticks(fds, tx, rt_io, work, _sensor_rows(twin, sensing), 0, twin.period)
            b.recv(65535)
            b.send(link[:n].tobytes())
            realtime_loop.take_and_step_all(fds, np.zeros(65535, dtype=np.uint8), received, np.ones(1), rt_io, rt,
                                            work, params, air_rng, np.array([twin.substeps]), np.array([twin.method]),
                                            0, 0, True, twin.period, 0, np.zeros(1, dtype=np.int64))  # fmt: skip


_WARM = {"lockstep": _warm_lockstep, "realtime": _warm_realtime}


@contextlib.contextmanager
def _loopback_pair() -> Iterator[tuple[socket.socket, socket.socket]]:
    """Two connected UDP sockets on loopback (the first's receive times out after 0.1 s)."""
    udp = (socket.AF_INET, socket.SOCK_DGRAM)
    with socket.socket(*udp) as a, socket.socket(*udp) as b:
        a.bind(("127.0.0.1", 0))
        b.bind(("127.0.0.1", 0))
        a.connect(b.getsockname())
        b.connect(a.getsockname())
        set_receive_timeout(a, 0.1)
        yield a, b


def _rows(twin: Plant, link: np.ndarray, io: np.ndarray) -> list[np.ndarray]:
    """A fleet of one's arrays (sitl.fleet_arrays): tx, io, work, params, air_rng, received."""
    return [x[None].copy() for x in (link, io, twin.work, twin.params, twin.air_rng, twin.commanded)]


def _sensor_rows(twin: Plant, sensing: bool) -> tuple | None:
    return tuple(x[None].copy() for x in twin.sensors.arrays) if sensing else None


def open_wind_links(args: argparse.Namespace, vehicles: Sequence[Vehicle]) -> Any:
    """One Zenoh session, when the command line gives an endpoint or a configuration, taking each vehicle's wind
    changes on ``quadsitl/<vehicle>/wind``; None otherwise."""
    if not (args.zenoh_listen or args.zenoh_connect or args.zenoh_config):
        return None
    import zenoh

    keys = ", ".join(f"quadsitl/{v.name}/wind" for v in vehicles)
    try:
        session = zenoh.open(config_from_args(args))
    except Exception as exc:  # zenoh.ZError and the like: a bad endpoint or configuration
        raise UsageError(f"Zenoh session (for wind changes on {keys}): {exc}") from None
    for v in vehicles:
        v.wind = WindLink(session, v.name, v.preset.wind)
    return session


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="quadsitl plant",
        description="The simulated quadrotor: integrates the truth state and talks MAVLink over UDP to the autopilot.",
        epilog="examples:\n  quadsitl plant --preset paper --autopilot 127.0.0.1:14560\n"
        "  quadsitl plant --preset x500 --mode realtime --autopilot 127.0.0.1:14560",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_preset_arguments(p, controller=False)
    p.add_argument(
        "--autopilot",
        action="append",
        metavar="HOST:PORT",
        help="where the autopilot listens for the plant (default: 127.0.0.1:14560); repeat it to simulate a fleet, "
        "one vehicle per autopilot, on one clock",
    )
    p.add_argument(
        "--bind",
        default="127.0.0.1:0",
        metavar="HOST:PORT",
        help="local address of the plant's socket (default: 127.0.0.1, any port; in a fleet vehicle i's is PORT + i)",
    )
    p.add_argument("--vehicle-preset", action="append", default=[], metavar="K=PRESET",
                   help="in a fleet, vehicle K (1-based) flies PRESET (a name or a TOML file) instead of --preset; "
                   "every preset must have the same control period (repeatable)")  # fmt: skip
    p.add_argument("--mode", choices=CLOCKS, default="lockstep", help="default: lockstep")
    p.add_argument("--cores-awake", action="store_true", help=CORES_AWAKE_HELP)
    p.add_argument(
        "--speed",
        type=float,
        default=0.0,
        metavar="F",
        help="lockstep pace cap, × real time (0 = as fast as possible; default 0)",
    )
    p.add_argument(
        "--hold-until-armed",
        type=float,
        metavar="S",
        help="lockstep: at S simulated seconds, hold the clock until the autopilot's answer says armed (quadsitl fly "
        "uses it with sensors: its flight then starts after the same ticks on the ground in every run)",
    )
    p.add_argument("--hold-when-landed", action="store_true",
                   help="lockstep, one vehicle: once the vehicle has flown, hold the clock while the autopilot's "
                   "answer says disarmed and the vehicle rests on the ground; arming again resumes it (quadsitl fly: "
                   "the flight is over, and nothing ticks while the results are written)")  # fmt: skip
    p.add_argument("--integrator", choices=("euler", "rk4"), help="default: the preset's")
    p.add_argument("--substeps", type=int, metavar="N", help="default: the preset's")
    p.add_argument("--ticks", type=int, metavar="N", help="stop after N ticks (default: run until stopped)")
    add_impair_argument(p)
    p.add_argument(
        "--on-autopilot-loss",
        choices=("zero", "last"),
        default="zero",
        help="realtime mode, when the autopilot stops answering: zero thrust (default) or hold its last command",
    )
    p.add_argument("--stats", metavar="FILE", help="write the run's pace (and, in realtime, its timing) as JSON")
    p.add_argument("--quiet", "-q", action="store_true", help="no summary at the end (errors still print)")
    add_state_arguments(p)
    p.add_argument("--home", action="append", metavar="LAT,LON,ALT", help="where the local origin is on the globe, "
                   "for the GPS: degrees, degrees, metres AMSL (default: PX4 SITL's, 47.397742,8.545594,488); in a "
                   "fleet once for every vehicle or once per --autopilot, in order")  # fmt: skip
    add_wind_arguments(p)
    p.add_argument("--vehicle", action="append", metavar="NAME", help="the vehicle's name in the Zenoh keys "
                   "quadsitl/<vehicle>/wind (default: v1; in a fleet v1..vN, or one per --autopilot, in "
                   "order)")  # fmt: skip
    add_zenoh_arguments(p, vehicle=False)  # a session only when an endpoint or a configuration is given: for wind
    return p


def fleet_from_args(args: argparse.Namespace) -> list[Vehicle]:
    """The vehicles the command line asks for: one per ``--autopilot``, each with its preset (``--preset``, or
    ``--vehicle-preset``), state and wind options, home and name; a UsageError naming the option otherwise.
    Vehicle i (0-based) draws its sensor noise and turbulence from the seeds + i: every vehicle its own."""
    autopilots = [parse_address("--autopilot", a) for a in args.autopilot or ["127.0.0.1:14560"]]
    n = len(autopilots)
    fleet = f"--autopilot given {n} times"
    names = per_vehicle("--vehicle", args.vehicle, n, fleet) or [f"v{i + 1}" for i in range(n)]
    if len(set(names)) != n:
        raise UsageError(f"--vehicle {' '.join(names)}: two vehicles named alike; each needs a name of its own")
    homes = [parse_home(h) for h in per_vehicle("--home", args.home, n, fleet) or [None] * n]
    presets = parse_vehicle_presets(args.vehicle_preset, n, fleet)
    check_speed(args.speed)
    host, port = parse_address("--bind", args.bind)
    if port and port + n - 1 > 65535:
        raise UsageError(f"--bind {args.bind}: vehicle {n} would need port {port + n - 1}, beyond 65535")
    if args.hold_until_armed is not None and (args.mode != "lockstep" or not 0.0 <= args.hold_until_armed <= 3600.0):
        raise UsageError(f"--hold-until-armed {args.hold_until_armed!r}: expected a number of seconds in [0, 3600], "
                         "in lockstep")  # fmt: skip
    if args.hold_when_landed and (args.mode != "lockstep" or n > 1):
        vehicles = f"{n} vehicle{'s' if n > 1 else ''}"
        raise UsageError(f"--hold-when-landed: only in lockstep with one vehicle (here: {args.mode}, {vehicles}); "
                         "a fleet's one clock would stop for all when the first one lands")  # fmt: skip
    impairment_from(args.impair, args.mode)  # refused here, before any socket is bound
    base = with_state(with_wind(load_preset(args.preset), args), args)
    vehicles: list[Vehicle] = []
    for i, (autopilot, name, home) in enumerate(zip(autopilots, names, homes, strict=True)):
        preset = base
        if i + 1 in presets:
            try:
                preset = with_state(with_wind(load_preset(presets[i + 1]), args), args)
            except ConfigError as exc:
                raise UsageError(f"--vehicle-preset {i + 1}={presets[i + 1]}: {exc}") from None
            if preset.sim.period != base.sim.period:
                raise UsageError(f"--vehicle-preset {i + 1}={presets[i + 1]}: its control period is "
                                 f"{preset.sim.period:g} s, --preset {args.preset}'s {base.sim.period:g} s; one clock "
                                 "needs one period")  # fmt: skip
        if i > 0:  # every vehicle its own noise and turbulence
            preset = replace(preset, wind=replace(preset.wind, seed=(preset.wind.seed + i) % 2**63))
            if preset.sensors is not None:
                preset = replace(preset, sensors=replace(preset.sensors, seed=(preset.sensors.seed + i) % 2**63))
        plant = Plant(preset, integrator=args.integrator, substeps=args.substeps, home=home or PX4_HOME)
        bind = f"{host}:{port + i if port else 0}"
        link = PlantLink(bind_udp("--bind", bind), autopilot, preset.actuators.max_thrust, preset.sim.period,
                         impairment_from(args.impair, args.mode),
                         sensing=preset.sensors is not None, name=name if n > 1 else "")  # fmt: skip
        if args.hold_until_armed is not None:
            link.io[tick.HOLD_TICK] = round(args.hold_until_armed / preset.sim.period)
        link.io[tick.HOLD_LANDED] = int(args.hold_when_landed)
        link.sensors = plant.sensors  # failure injection (the autopilot passes MAV_CMD_INJECT_FAILURE on)
        vehicles.append(Vehicle(name, preset, plant, link))
    return vehicles


def main(argv: Sequence[str] | None = None) -> int:
    start_process()
    favour_compile_time()  # compiles at -O2: a first run's wait (docs/performance.md#compiling-on-first-run)
    parser = build_parser()
    args = parser.parse_args(argv)
    vehicles: list[Vehicle] = []
    session = None
    try:
        fastio.compiled_loops()  # $QUADSITL_COMPILED_LOOPS checked before anything starts
        # held (open) until this process ends: the kernel drops the request then, however it ends
        awake = hold_cores_awake() if args.cores_awake else None  # noqa: F841
        vehicles = fleet_from_args(args)
        warm_up(vehicles[0].plant, {v.plant.sensing for v in vehicles}, (args.mode,))
        session = open_wind_links(args, vehicles)
    except (UsageError, ConfigError) as exc:
        for v in vehicles:
            v.link.close()
        print(f"{parser.prog}: error: {exc}", file=sys.stderr)
        return 2
    period = vehicles[0].plant.period
    if args.mode == "realtime":
        clock_above_its_peers()  # under chrt -f: the clock one priority above the autopilots
        timers_on_time()  # each tick's timer fires within 1 µs of its due time, not 50
    start, cpu_start = time.monotonic(), time.process_time()
    starts: list[float] = []
    late: list[list[int]] = [[] for _ in vehicles]
    try:
        if args.mode == "lockstep":
            run_lockstep(vehicles, args.speed, args.ticks)
        else:
            run_realtime(vehicles, args.ticks, starts if args.stats else None, args.on_autopilot_loss,
                         late if args.stats else None)  # fmt: skip
    except KeyboardInterrupt:  # SIGINT or SIGTERM (process_util.StopRequested): a requested stop; say what the run did
        pass
    except DivergedError as exc:  # one line, always: the run ends with a status of its own
        print(f"plant: {exc}; the run ends (exit status {PLANT_DIVERGED})", file=sys.stderr, flush=True)
        exc.vehicle.link.announce(wire.mavlink.MAV_SEVERITY_CRITICAL, f"Simulation diverged at t = {exc.t:.3f} s: "
                                  f"{exc.what}; the plant stopped")  # fmt: skip
        return PLANT_DIVERGED
    finally:
        for v in vehicles:
            v.link.close()
            if v.wind is not None:
                v.wind.close()
        if session is not None:
            session.close()
    elapsed = time.monotonic() - start
    plant = vehicles[0].plant
    if args.stats:
        ticks = round(plant.time / period)
        # The pace from the autopilots' first answers on (tick 0 waits for the autopilots to start or to take this
        # plant over, which is not the loop's speed); the whole run's wall time next to it.
        first = min((v.link.first_heard for v in vehicles if v.link.first_heard is not None), default=start)
        flying = time.monotonic() - first
        stats = {"mode": args.mode, "vehicles": len(vehicles), "ticks": ticks, "wall_s": elapsed,
                 "answered_wall_s": flying, "ticks_per_s": max(ticks - 1, 0) / max(flying, 1e-9),
                 "cpu_s": time.process_time() - cpu_start,  # this process's CPU over wall_s (not its start-up)
                 "receives_polled": sum(v.link.wait.polled for v in vehicles),
                 "receives_blocked": sum(v.link.wait.blocked for v in vehicles),
                 "polling_budget_s": vehicles[0].link.wait.budget,  # SpinThenBlock: what makes a wait hot
                 "polling_patience_s": vehicles[0].link.wait.patience,
                 "peak_memory_mb": rss_mb("self", "VmHWM")}  # fmt: skip
        if args.mode == "realtime":  # the clock's timing, and the autopilots' answers that missed their period
            stats.update(period_stats(starts, period))
            stats["answer_miss_ratios"] = [v.late / max(v.answered + v.late, 1) for v in vehicles]
            # which periods: tick k due at clock_t0_s + k·period [s, CLOCK_MONOTONIC], to set beside other clocks
            stats["period_s"] = period
            stats["clock_t0_s"] = starts[0] if starts else None
            stats["clock_late_ticks"] = late_periods(starts, period, starts[0]) if starts else []
            stats["answer_late_ticks"] = late
            stats["answered_ticks"] = [v.answered + v.late for v in vehicles]  # the answer ratios' denominators
        Path(args.stats).write_text(json.dumps(stats, indent=2) + "\n")
    if args.quiet:
        return 0
    fleet = f"{len(vehicles)} vehicles, " if len(vehicles) > 1 else ""
    print(f"plant: {fleet}{plant.time:.3f} s simulated in {elapsed:.3f} s; "
          f"{sum(v.link.discarded for v in vehicles)} stale actuator messages discarded", file=sys.stderr)  # fmt: skip
    for v in vehicles:
        im = v.link.impairment
        if im is not None:
            who = f" ({v.name})" if len(vehicles) > 1 else ""
            print(f"plant: link impairment{who} dropped {im.dropped}, duplicated {im.duplicated}, reordered "
                  f"{im.reordered} datagrams", file=sys.stderr)  # fmt: skip
    return 0
