"""The ``quadsitl`` command.

    quadsitl sim      the closed loop in one process (no network): telemetry, metrics, figures
    quadsitl fly      plant, autopilot and a scripted ground station as processes, one flight
    quadsitl up       plant and autopilot on PX4 SITL's ports, for QGroundControl, MAVProxy, MAVSDK
    quadsitl dashboard  live telemetry of every vehicle on Zenoh, in the browser
    quadsitl replay   play a recorded telemetry.csv or .tlog back onto Zenoh
    quadsitl router   a Zenoh router, for telemetry across machines
    quadsitl presets  list the shipped presets, or show one
    quadsitl gains    check backstepping gains against the paper's conditions (41)–(44)
    quadsitl sweep    Monte-Carlo sweeps: many trials batched on the compiled equations, a table and its summary

Errors are one line on stderr and a non-zero exit (2 for bad input), never a traceback.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

from autopilot.cli import GAINS_EPILOG, add_gains_arguments, run_gains
from autopilot.gains import GainError, poles_from_rates
from groundstation.launcher import add_dashboard_arguments
from groundstation.sweep.command import add_sweep_parser
from groundstation.up_network import zenoh_and_addresses
from quadsitl.cli_util import (
    CLOCKS,
    UsageError,
    add_preset_arguments,
    add_state_arguments,
    add_wind_arguments,
    attach_negative_values,
    check_duration,
    check_speed,
    check_system_id,
    parse_controller_params,
    parse_floats,
    wind_settings,
    with_state,
    with_wind,
)
from quadsitl.config import ConfigError, Preset, load_preset, preset_toml
from quadsitl.process_util import (
    CORES_AWAKE_HELP,
    PLANT_DIVERGED,
    handle_stop_signals,
    run_stoppable,
    stop_requested,
    stop_status,
    whole_lines,
)
from sitl.cli import add_presets_arguments, run_presets
from sitl.impair import add_impair_argument, impairment_from

EXAMPLES_SIM = """examples:
  quadsitl sim --preset paper --compare --out runs/paper
  quadsitl sim --preset paper --integrator rk4 --duration 3 --out runs/rk4
  quadsitl sim --preset paper --gains 5,5,10,10,10,10,10,10 --out runs/slow-altitude
  quadsitl sim --preset x500 --controller pd --out runs/x500-pd
  quadsitl sim --from-sweep runs/mass --trial 17 --out runs/mass-17   # one trial of a sweep, again
"""


def _load(name: str) -> Preset:
    try:
        return load_preset(name)
    except ConfigError as exc:
        raise UsageError(str(exc)) from None


def _from_sweep(args: argparse.Namespace) -> Preset:
    """``sim --from-sweep DIR --trial K``: trial K of the sweep in DIR as a preset (the options that would fly
    something else are refused); the sweep's trajectory or mission goes into ``args``."""
    from groundstation.sweep.spec import load_sweep
    from groundstation.sweep.trials import trial_preset

    if args.trial is None:
        raise UsageError("--from-sweep needs --trial K (the trial's number, as in trials.csv)")
    flown = ("preset", "controller", "duration", "integrator", "substeps", "gains", "poles", "compare", "wind",
             "turbulence", "gust", "wind_seed", "state", "sensor_seed", "trajectory", "mission", "home",
             "controller_param")  # fmt: skip
    given = [f"--{k.replace('_', '-')}" for k in flown if getattr(args, k) not in (None, False, [])]
    if given:
        raise UsageError(f"{given[0]} does not go with --from-sweep: the trial flies as the sweep flew it (its "
                         "preset, controller, duration, gains, air, state, trajectory or mission)")  # fmt: skip
    try:
        spec = load_sweep(Path(args.from_sweep))
        args.trajectory, args.mission = spec.trajectory, None if spec.mission is None else str(spec.mission.path)
        return trial_preset(spec, args.trial)
    except ConfigError as exc:
        raise UsageError(f"--from-sweep {args.from_sweep} --trial {args.trial}: {exc}") from None


SIM_DIVERGED = PLANT_DIVERGED  # `quadsitl sim`'s exit status when a run's state diverged, as fly's (docs/failures.md)


def cmd_sim(args: argparse.Namespace) -> int:
    if args.trial is not None and args.from_sweep is None:
        raise UsageError("--trial goes with --from-sweep DIR (the sweep's folder)")
    if args.from_sweep is not None:
        preset = _from_sweep(args)
    else:
        preset = with_state(with_wind(_load(args.preset or "paper"), args), args)
    check_duration(args.duration)
    if args.substeps is not None and not 1 <= args.substeps <= 1000:
        raise UsageError(f"--substeps {args.substeps}: expected an integer in [1, 1000]")
    rates = parse_floats("--gains", args.gains, 8) if args.gains else None
    poles = parse_floats("--poles", args.poles, 8) if args.poles else None
    primary = args.controller or preset.controller.type
    kinds = [primary] + ([k for k in ("backstepping", "pd", "px4") if k != primary] if args.compare else [])
    values = parse_controller_params(args.controller_param, primary)
    if (rates or poles) and "backstepping" not in kinds:
        raise UsageError("--gains/--poles set the backstepping gains; add --compare or --controller backstepping")
    integrator = args.integrator or preset.sim.integrator
    duration = args.duration or preset.sim.duration
    label = "sim:" if len(kinds) == 1 else f"sim ({' + '.join(kinds)}):"
    # after the checks: a refusal is answered without loading the compiler (docs/performance.md#cold-start)
    from autopilot.plugin import ControllerError
    from autopilot.setpoints import SetpointError
    from groundstation.metrics import format_position_table, format_table
    from groundstation.mission_files import MISSION_DURATION, load
    from groundstation.offline import run_offline, tracking, write_outputs
    from groundstation.progress import FlightProgress
    from groundstation.trajectories import PositionTrajectory, make
    from quadsitl.cli_util import parse_home
    from quadsitl.frames import PX4_HOME

    trajectory = args.trajectory or "step"
    path = make(trajectory, preset.reference)  # a bad name or file: one line, before anything is compiled
    mission = None
    if args.mission is not None:
        if args.trajectory is not None and args.from_sweep is None:
            raise UsageError(f"--trajectory {args.trajectory!r} with --mission: a flight flies one or the other")
        mission = load(args.mission)  # refused as fly refuses it, in one line
        duration = args.duration or MISSION_DURATION
    elif args.home is not None:
        raise UsageError(f"--home {args.home!r}: only with --mission (it places the mission's waypoints)")
    planned = mission.planned_home if mission is not None else None  # where the plan expects the vehicle
    home = parse_home(args.home) or planned or PX4_HOME
    if args.duration is None and isinstance(path, PositionTrajectory) and mission is None:
        duration = path.duration
    try:
        with FlightProgress(duration * len(kinds), enabled=not args.quiet, label=label) as bar:
            results, metrics = run_offline(preset, kinds, duration, integrator, args.substeps, rates=rates,
                                           poles=poles, progress=bar.update, trajectory=trajectory, mission=mission,
                                           home=home, controller_values=values, announce=not args.quiet)  # fmt: skip
    except GainError as exc:
        what = f"trial {args.trial} was not flown by the sweep: " if args.from_sweep is not None else ""
        raise UsageError(f"{what}inadmissible gains: {exc}") from None
    except ControllerError as exc:
        raise UsageError(str(exc)) from None
    except SetpointError as exc:
        raise UsageError(f"--trajectory {trajectory}: {exc}") from None
    settings = {
        "trajectory": None if mission else trajectory,
        **({"mission": str(mission.path)} if mission else {}),
        "integrator": integrator,
        "duration": duration,
        "period": preset.sim.period,
        "poles": list(poles_from_rates(rates, preset.sim.period) if rates else poles or preset.poles()),
        **({"controller_params": values} if values else {}),
        **wind_settings(preset),
    }
    out = Path(args.out)
    files = write_outputs(out, preset, results, metrics, settings, figures=not args.no_figures, mission=mission,
                          home=home)  # fmt: skip
    if args.from_sweep is not None:  # the trial as a preset of its own: `quadsitl fly --preset` takes it
        (out / "preset.toml").write_text(preset_toml(preset), encoding="utf-8")
        files.append(out / "preset.toml")
    if not args.quiet:
        print(
            f"preset {preset.name}, integrator {integrator}, T = {preset.sim.period:g} s, "
            f"{len(next(iter(results.values())).t)} ticks"
        )
        flown = {k: r for k, r in results.items() if len(r.t)}
        print(format_position_table(tracking(flown)) if isinstance(path, PositionTrajectory) or mission else
              format_table({k: m for k, m in metrics.items() if m is not None}))  # fmt: skip
        print("wrote " + ", ".join(str(f) for f in files))
    diverged = {k: r for k, r in results.items() if r.diverged_at is not None}
    for kind, r in diverged.items():  # said even with --quiet: the run did not fly its duration
        print(f"quadsitl sim: the state diverged at t = {r.diverged_at:.3f} s ({kind}): {r.diverged_what}; "
              f"{len(r.t)} ticks flown before it are in the telemetry and metrics.json", file=sys.stderr)  # fmt: skip
    for kind, r in results.items():  # the failsafe flew the rest: said even with --quiet
        if r.controller_failed_at is not None:
            print(f"quadsitl sim: {kind} commanded a non-finite value at t = {r.controller_failed_at:.3f} s: the "
                  "failsafe flew the backstepping from then on and landed", file=sys.stderr)  # fmt: skip
    unfinished = {k: r.mission.where for k, r in results.items() if r.mission is not None and r.mission.where}
    for kind, where in unfinished.items():  # as fly's: the flight so far is kept
        print(f"quadsitl sim: error: {where} ({kind}); the flight so far is in {out}", file=sys.stderr)
    failed = any(r.controller_failed_at is not None for r in results.values())
    return SIM_DIVERGED if diverged else 1 if unfinished or failed else 0


EXAMPLES_FLY = """examples:
  quadsitl fly --preset paper --out runs/fly
  quadsitl fly --preset paper --speed 1 --duration 10 --out runs/realtime-pace
  quadsitl fly --preset x500 --trajectory sine --duration 10 --out runs/x500-sine
  quadsitl fly --preset x500 --trajectory circle --out runs/circle          # offboard position setpoints
  quadsitl fly --preset x500 --trajectory figure8:size=4,period=25,yaw=0 --out runs/figure8
  quadsitl fly --preset x500 --trajectory path.csv   # a CSV with the header t,x,y,altitude,yaw
  quadsitl fly --preset x500 --mission tests/data/square.plan --out runs/square   # a QGroundControl plan
  quadsitl fly --dashboard --speed 1 --trajectory sine --duration 30   # watch it at http://127.0.0.1:8050
"""

PROCESSES = {
    "plant": ("sitl.process", "the simulated quadrotor process (MAVLink/UDP to the autopilot)"),
    "autopilot": ("autopilot.process", "the autopilot process (control loop, MAVLink, Zenoh telemetry)"),
    "gcs": ("groundstation.gcs", "the ground-station process (flies a trajectory, logs telemetry)"),
    "bench": ("benchmarks.bench", "measure the SITL's speed against this machine's own baselines"),
    "dashboard": ("groundstation.dashboard.server", "live telemetry dashboard in the browser, fed by Zenoh"),
    "replay": ("groundstation.replay", "play a recorded telemetry.csv or .tlog back onto Zenoh"),
    "router": ("groundstation.router", "a Zenoh router, for telemetry across machines"),
    "soak": ("groundstation.soak", "fly a fleet through missions for a long time; report memory and tick rate"),
}


def check_controller(args: argparse.Namespace, preset: Preset) -> None:
    """A controller to load (``--controller file.py:Name``, its ``--controller-param``s) loaded, checked and probed on
    ``preset``'s model here, before any process starts (one line when it cannot fly), and named by its absolute path
    for the processes."""
    from quadsitl.controller_names import absolute, is_plugin

    values = parse_controller_params(args.controller_param, args.controller or preset.controller.type)
    if args.controller is None or not is_plugin(args.controller):
        return
    from autopilot.factory import make_controller
    from autopilot.plugin import ControllerError

    try:
        make_controller(preset, args.controller, values=values)
    except ControllerError as exc:
        raise UsageError(str(exc)) from None
    args.controller = absolute(args.controller)


def cmd_fly(args: argparse.Namespace) -> int:
    from groundstation.launcher import fly

    preset = with_state(with_wind(_load(args.preset), args), args)
    check_controller(args, preset)
    if args.vehicles != 1 or args.formation:
        from groundstation.formation_flight import check_fleet_flight, fly_fleet

        check_speed(args.speed)
        check_fleet_flight(args)  # refuse a bad fleet or formation (one line) before anything starts
        return fly_fleet(args)
    check_duration(args.duration)
    check_speed(args.speed)
    from groundstation.trajectories import make

    if args.mission:
        from groundstation.mission_files import load
        from quadsitl.cli_util import parse_home

        if args.trajectory != "step":
            raise UsageError(f"--trajectory {args.trajectory!r} with --mission: a flight flies one or the other")
        parse_home(args.home)
        mission = load(args.mission)  # refuse what the vehicle would refuse (one line) before anything starts
        if args.home is None and mission.planned_home is not None:  # the vehicle starts where the plan expects it
            args.home = ",".join(repr(float(v)) for v in mission.planned_home)
    else:
        if args.home:
            raise UsageError(f"--home {args.home!r}: only with --mission (it places the mission's waypoints)")
        make(args.trajectory, preset.reference)  # refuse a bad trajectory (one line) before anything starts
    return fly(args.preset, preset, args)


EXAMPLES_UP = """examples:
  quadsitl up                                   # then: mavproxy.py --master=udpin:127.0.0.1:14550
  quadsitl up --preset x500 --controller pd
  quadsitl up --speed 5                         # lockstep at 5× real time
  quadsitl up --mode realtime                   # free-running plant on the wall clock
  quadsitl up --gcs-remote 192.168.1.20:14550   # stream to a ground station on another machine
  quadsitl up --vehicles 2 --zenoh-connect tcp/192.168.1.20:7447   # telemetry through a router there
  quadsitl up --vehicles 2 --zenoh-connect tls/router.lan:7447 --zenoh-config subscriber-tls.json5   # over TLS
  quadsitl up --dashboard                       # and the live dashboard at http://127.0.0.1:8050
"""


def cmd_up(args: argparse.Namespace) -> int:
    from groundstation.fleet import check_vehicle_count, plan_fleet
    from groundstation.launcher import up
    from quadsitl.cli_util import parse_home, parse_vehicle_presets
    from quadsitl.frames import PX4_HOME
    from quadsitl.process_util import parse_address, parse_remote

    preset = with_state(with_wind(_load(args.preset), args), args)
    check_controller(args, preset)
    check_speed(args.speed)
    check_system_id(args.system_id)
    for option in ("gcs_listen", "api_listen"):
        if getattr(args, option) is not None:
            parse_address("--" + option.replace("_", "-"), getattr(args, option))
    for option in ("gcs_remote", "api_remote"):
        if getattr(args, option) is not None:
            parse_remote("--" + option.replace("_", "-"), getattr(args, option))
    home = parse_home(args.home) or PX4_HOME
    zenoh_and_addresses(args)
    impairment_from(args.impair, args.mode)  # refuse a bad --impair here, before starting anything
    check_vehicle_count(args.vehicles)
    presets = parse_vehicle_presets(args.vehicle_preset, args.vehicles)
    for number, name in presets.items():
        try:
            other = load_preset(name)
        except ConfigError as exc:
            raise UsageError(f"--vehicle-preset {number}={name}: {exc}") from None
        if other.sim.period != preset.sim.period:  # the fleet's one plant process has one clock
            raise UsageError(f"--vehicle-preset {number}={name}: its control period is {other.sim.period:g} s, "
                             f"--preset {args.preset}'s {preset.sim.period:g} s; a fleet has one clock")  # fmt: skip
    fleet = plan_fleet(args.vehicles, preset=args.preset, first_system_id=args.system_id, home=home,
                       spacing=args.spacing, gcs_listen=args.gcs_listen, gcs_remote=args.gcs_remote,
                       api_listen=args.api_listen, api_remote=args.api_remote, vehicle_presets=presets)  # fmt: skip
    return up(preset, args, fleet)


TRAJECTORY_HELP = (
    "attitude setpoints: step (default), ramp, sine, or a CSV file t,altitude,roll,pitch,yaw; offboard position "
    "setpoints: circle[:radius=M,period=S,altitude=M,hold=S,yaw=RAD|travel], figure8[:size=M,period=S,...], "
    "hold[:altitude=M,duration=S,yaw=RAD], or a "
    "CSV file t,x,y,altitude,yaw (see docs/commands.md)"
)

MISSION_HELP = (
    "fly a mission, uploaded through the MAVLink mission protocol: a QGroundControl .plan, a waypoint CSV "
    "lat,lon,altitude[,hold,radius,yaw] or a QGC WPL 110 file (see docs/missions.md); --duration then bounds it in "
    "simulated seconds (default 900)"
)
HOME_HELP = (
    "with --mission: the vehicle's home (default: the mission file's planned home, QGroundControl's "
    "plannedHomePosition or a WPL file's line 0; else PX4 SITL's, in Zürich)"
)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="quadsitl",
        description="MAVLink software-in-the-loop quadrotor with a discrete-time backstepping autopilot.",
        epilog="""examples:
  quadsitl sim --preset paper --compare --out runs/paper     # the paper's experiment, one process
  quadsitl fly --preset paper --out runs/fly                 # three processes over MAVLink/UDP, lockstep
  quadsitl up --dashboard                                    # PX4 SITL's ports, live dashboard in the browser
  quadsitl replay runs/fly/telemetry.csv                     # an old run back onto Zenoh

Run 'quadsitl COMMAND --help' for the options and examples of each command. The reference (commands,
the MAVLink interface, the Zenoh schema, failure behaviour, performance) is in the documentation: docs/ in
the source, or 'mkdocs serve' there.""",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)

    sim = sub.add_parser(
        "sim",
        help="run the closed loop in one process (no network)",
        epilog=EXAMPLES_SIM,
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description="Simulate plant and controller in one process and write telemetry.csv, metrics.json "
        "and figures reproducing the paper's Figures 2–4.",
    )
    add_preset_arguments(sim)
    sim.add_argument("--duration", type=float, metavar="S", help="simulated seconds of flight (default: a position "
                     "trajectory's own length, else the preset's)")  # fmt: skip
    sim.add_argument("--trajectory", metavar="NAME|FILE", help=TRAJECTORY_HELP + "; as fly flies it")
    sim.add_argument("--mission", metavar="FILE", help=MISSION_HELP)
    sim.add_argument("--home", metavar="LAT,LON,ALT", help=HOME_HELP)
    sim.add_argument("--integrator", choices=("euler", "rk4"), help="plant integrator (default: the preset's)")
    sim.add_argument("--substeps", type=int, metavar="N", help="integration sub-steps per control period")
    g = sim.add_mutually_exclusive_group()
    g.add_argument("--gains", metavar="k1,..,k8", help="backstepping gains as rates in 1/s (λ = 1 − T·k)")
    g.add_argument("--poles", metavar="l1,..,l8", help="backstepping gains as discrete poles λ")
    sim.add_argument("--compare", action="store_true", help="also run the other controller and overlay it")
    sim.add_argument("--out", default="runs/sim", metavar="DIR", help="output folder (default: runs/sim)")
    sim.add_argument("--no-figures", action="store_true", help="skip the PNG figures")
    sim.add_argument("--quiet", "-q", action="store_true", help="print nothing on success")
    sim.add_argument("--from-sweep", metavar="DIR", help="fly trial --trial of the sweep written into DIR again, "
                     "alone: the same flight to the bit (writes the trial's preset.toml too)")  # fmt: skip
    sim.add_argument("--trial", type=int, metavar="K", help="with --from-sweep: the trial's number")
    add_state_arguments(sim)
    add_wind_arguments(sim)
    sim.set_defaults(func=cmd_sim, preset=None)

    fl = sub.add_parser(
        "fly",
        help="plant, autopilot and ground station as separate processes (MAVLink/UDP, Zenoh)",
        epilog=EXAMPLES_FLY,
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description="Start plant, autopilot and ground station on free loopback ports, fly the trajectory in "
        "lockstep, and write telemetry.csv (from Zenoh), flight.tlog, metrics.json and figures.",
    )
    add_preset_arguments(fl)
    fl.add_argument(
        "--duration",
        type=float,
        metavar="S",
        help="simulated seconds of flight (default: a position trajectory's own length, else the preset's)",
    )
    fl.add_argument(
        "--speed",
        type=float,
        default=0.0,
        metavar="F",
        help="cap the lockstep pace at F × real time (default 0: as fast as possible)",
    )
    fl.add_argument("--integrator", choices=("euler", "rk4"), help="plant integrator (default: the preset's)")
    fl.add_argument("--trajectory", default="step", metavar="NAME|FILE", help=TRAJECTORY_HELP)
    fl.add_argument("--mission", metavar="FILE", help=MISSION_HELP)
    fl.add_argument("--home", metavar="LAT,LON,ALT", help=HOME_HELP)
    fl.add_argument("--vehicles", type=int, default=1, metavar="N", help="fly a fleet of N vehicles in formation "
                    "(see --formation; each vehicle's logs in DIR/v1..vN/)")  # fmt: skip
    fl.add_argument("--formation", metavar="KIND[:altitude=M][,distance=M]", help="line (default with --vehicles), "
                    "grid or circle: take off, form up, translate DISTANCE north (default 10 m), rotate 90°, land, "
                    "at ALTITUDE (default 5 m; docs/fleets.md)")  # fmt: skip
    fl.add_argument("--spacing", type=float, default=3.0, metavar="M", help="with --vehicles: metres between vehicles "
                    "on the starting grid and in the formation (default 3)")  # fmt: skip
    fl.add_argument("--out", default="runs/fly", metavar="DIR", help="output folder (default: runs/fly)")
    fl.add_argument("--no-figures", action="store_true", help="skip the PNG figures")
    fl.add_argument("--quiet", "-q", action="store_true", help="print only errors")
    fl.add_argument("--signing-key", metavar="HEX|FILE", help="MAVLink 2 signing between ground station and autopilot")
    add_dashboard_arguments(fl)
    add_state_arguments(fl)
    add_wind_arguments(fl)
    fl.set_defaults(func=cmd_fly)

    upp = sub.add_parser(
        "up",
        help="plant and autopilot on PX4 SITL's MAVLink ports, for QGroundControl, MAVProxy, MAVSDK",
        epilog=EXAMPLES_UP,
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description="Start the plant and the autopilot and keep them running until Ctrl-C or SIGTERM (exit 0; "
        "also from a script that starts it in the background). Like PX4 SITL, the "
        "autopilot streams MAVLink to 127.0.0.1:14550 (ground stations) and 127.0.0.1:14540 (offboard APIs) "
        "and answers whoever talks to it; telemetry also goes to Zenoh.",
    )
    add_preset_arguments(upp)
    upp.add_argument(
        "--mode",
        choices=CLOCKS,
        default="lockstep",
        help="lockstep (default): deterministic, paced by --speed; realtime: the plant runs on the wall clock",
    )
    upp.add_argument(
        "--speed", type=float, default=1.0, metavar="F", help="lockstep pace, × real time (default 1; 0 = no cap)"
    )
    upp.add_argument("--cores-awake", action="store_true", help=CORES_AWAKE_HELP)
    upp.add_argument(
        "--hosted",
        action="store_true",
        help="every vehicle's autopilot in one process (a thread each; its own ports, MAVLink identity, parameters "
        "and failsafes as before): a fleet's memory is its vehicles', not one interpreter each",
    )
    for name, listen, remote in (("gcs", 18570, 14550), ("api", 14580, 14540)):
        upp.add_argument(
            f"--{name}-listen",
            metavar="HOST:PORT",
            help=f"the autopilot's local address for the {name} link (default: 127.0.0.1:{listen})",
        )
        upp.add_argument(
            f"--{name}-remote",
            metavar="HOST:PORT|none",
            help=f"where the {name} link streams (default: 127.0.0.1:{remote})",
        )
    add_impair_argument(upp)
    add_state_arguments(upp)
    add_wind_arguments(upp)
    upp.add_argument(
        "--system-id",
        type=int,
        default=1,
        help="MAVLink system id (default: 1; with --vehicles, the first vehicle's, the others count up from it)",
    )
    upp.add_argument(
        "--vehicles",
        type=int,
        default=1,
        metavar="N",
        help="how many vehicles, each its own plant and autopilot on PX4's multi-vehicle ports (vehicle "
        "i = 1..N: system id i, Zenoh name vi, gcs link 18570+i-1 → 14550, api link 14580+i-1 → "
        "14540+i-1; default 1)",
    )
    upp.add_argument(
        "--spacing",
        type=float,
        default=3.0,
        metavar="M",
        help="with --vehicles: metres between vehicles on the starting grid (default 3)",
    )
    upp.add_argument("--vehicle-preset", action="append", default=[], metavar="K=PRESET",
                     help="with --vehicles: vehicle K flies PRESET (a name or a TOML file) instead of --preset "
                     "(repeatable)")  # fmt: skip
    upp.add_argument("--home", metavar="LAT,LON,ALT", help="home position (default: PX4 SITL's, in Zürich)")
    upp.add_argument(
        "--zenoh-listen",
        metavar="ENDPOINT",
        help="where the (first) autopilot's Zenoh session listens (default: tcp/127.0.0.1:7447; none with "
        "--zenoh-connect)",
    )
    upp.add_argument("--zenoh-connect", action="append", default=[], metavar="ENDPOINT",
                     help="instead: every vehicle's Zenoh sessions are clients of this router, on this host or "
                     "another (`quadsitl router`, started first; repeatable), e.g. tcp/10.0.0.2:7447")  # fmt: skip
    upp.add_argument("--zenoh-config", metavar="FILE",
                     help="a Zenoh JSON5 configuration for every session up opens (the vehicles', the plant's, the "
                     "dashboard's): TLS and access control, e.g. for a router that requires them (docs/security.md); "
                     "--zenoh-listen and --zenoh-connect replace its endpoints")  # fmt: skip
    upp.add_argument("--no-zenoh", action="store_true", help="no Zenoh telemetry")
    upp.add_argument("--logs", default="runs/up/logs", metavar="DIR|none",
                     help="where each vehicle keeps a ULog of each flight, from arming to disarming, as PX4's logger "
                     "does (DIR/YYYY-MM-DD/HH_MM_SS.ulg; with --vehicles, DIR/v1/..., DIR/v2/...), served to ground "
                     "stations over MAVLink's log protocol; none: no logs (default: runs/up/logs)")  # fmt: skip
    add_dashboard_arguments(upp)
    upp.add_argument("--quiet", "-q", action="store_true", help="print only errors")
    upp.add_argument(
        "--signing-key",
        metavar="HEX|FILE",
        help="MAVLink 2 signing on both ground-station links: 64 hex digits or a file holding them (or set "
        "$QUADSITL_SIGNING_KEY); unsigned, wrongly signed and replayed messages are refused",
    )
    upp.set_defaults(func=cmd_up)

    add_sweep_parser(sub)

    for name, (_module, help_text) in PROCESSES.items():
        sub.add_parser(name, help=help_text, add_help=False)

    pre = sub.add_parser(
        "presets",
        help="list the shipped presets, or show one",
        epilog="examples:\n  quadsitl presets\n  quadsitl presets x500",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_presets_arguments(pre)
    pre.set_defaults(func=run_presets)

    gains = sub.add_parser(
        "gains",
        help="check backstepping gains against conditions (41)–(44)",
        epilog=GAINS_EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_gains_arguments(gains)
    gains.set_defaults(func=run_gains)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """The ``quadsitl`` command: every command stops cleanly on SIGINT and SIGTERM, also when started with SIGINT
    ignored (a script's background job); the process commands install the same handlers themselves."""
    handle_stop_signals()
    whole_lines()
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv and argv[0] in PROCESSES:  # the process commands parse their own options
        import importlib

        module = PROCESSES[argv[0]][0]  # imported inside run_stoppable: a stop may come while it loads
        return run_stoppable(lambda: importlib.import_module(module).main(argv[1:]), name=f"quadsitl {argv[0]}",
                             stopped=None if argv[0] in ("gcs", "bench") else 0)  # fmt: skip
    parser = build_parser()
    args = parser.parse_args(attach_negative_values(argv, ("--gains", "--poles")))
    try:
        return args.func(args)
    except UsageError as exc:
        print(f"quadsitl {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as exc:  # SIGINT or SIGTERM (StopRequested), when a command did not handle it
        print(f"quadsitl {args.command}: interrupted", file=sys.stderr)
        return stop_status(exc)
    except Exception as exc:
        signum = stop_requested()
        if signum is None:
            raise
        # as run_stoppable: the stop came where the interrupted code reported it as an error of its own
        print(f"quadsitl {args.command}: interrupted; while stopping: {type(exc).__name__}: {exc}", file=sys.stderr)
        return 128 + signum


if __name__ == "__main__":
    sys.exit(main())
