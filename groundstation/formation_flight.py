"""``quadsitl fly --vehicles N --formation KIND``: a fleet flies a formation manoeuvre (:mod:`groundstation.formation`)
in lockstep, each vehicle a flight controller of its own, and the flight is measured as a fleet.

Processes, on free loopback ports: an autopilot per vehicle (system ids, names v1..vN and homes on the grid of
:func:`groundstation.fleet.plan_fleet`), one plant process for the fleet on one clock, and a ground station per
vehicle that flies the vehicle's part of the plan (``DIR/v{i}/trajectory.csv``, a position trajectory in its own
local frame) and logs its telemetry (``DIR/v{i}/telemetry.csv``, ``flight.tlog``). The plant holds its clock at
SENSOR_GROUND_S until every autopilot has armed, and each ground station switches to offboard and arms there
(``--hold-until-armed``, ``--arm-at``), so every vehicle's flight time counts from the same tick: the plan's t.
After the plan's last phase each ground station lands its vehicle where it is. Each autopilot runs as ``fly``'s
does: its ground station sends the trajectory ahead (``--setpoints-ahead``) and the autopilot flies each setpoint
from the tick it is for (``--offboard-lockstep``; a ground station that falls behind holds the fleet's clock), and
telemetry waits rather than drops (``LOGGED``).

Written: each vehicle's ``metrics.json`` (its position tracking) next to its telemetry, and for the fleet
``DIR/metrics.json`` (formation error and tracking error per phase, the minimum separation, when and between
which vehicles; :func:`groundstation.formation.fleet_metrics`), ``DIR/formation.csv`` (those over time) and
``DIR/fig_formation.png`` (every path seen from above over the plan, and the errors and separation over time).
"""

from __future__ import annotations

import argparse
import contextlib
import functools
import json
import socket
import sys
import time
from pathlib import Path

import numpy as np

from groundstation import formation
from groundstation.fleet import VehiclePlan, plan_fleet
from groundstation.launcher import (
    FLY_DIVERGED,
    LOGGED,
    OFFBOARD_LOCKSTEP,
    SETPOINTS_AHEAD,
    compile_once,
    dashboard_port,
    flight_interrupted,
    keep_dashboard,
    publish_info,
    signing_env,
    start_dashboard,
    write_report,
)
from quadsitl.children import Children, run_supervised, supervise
from quadsitl.cli_util import UsageError, parse_floats, state_argv, wind_argv
from quadsitl.config import SENSOR_GROUND_S, load_preset
from quadsitl.frames import PX4_HOME
from quadsitl.process_util import free_port

DEFAULT_ALTITUDE, DEFAULT_DISTANCE = 5.0, 10.0  # [m]


def parse_formation(text: str) -> tuple[str, float, float]:
    """``--formation KIND[:altitude=M][,distance=M]`` → (kind, altitude [m], distance [m]), or a UsageError naming
    the option, the value and what is allowed."""
    kind, _, rest = text.partition(":")
    usage = f"{'|'.join(formation.KINDS)}[:altitude=M][,distance=M]"
    if kind not in formation.KINDS:
        raise UsageError(f"--formation {text!r}: expected {usage}")
    values = {"altitude": DEFAULT_ALTITUDE, "distance": DEFAULT_DISTANCE}
    bounds = {"altitude": (1.0, 100.0), "distance": (0.0, 1000.0)}
    for item in (i.strip() for i in rest.split(",") if i.strip()):
        key, eq, value = (p.strip() for p in item.partition("="))
        if not eq or key not in values:
            raise UsageError(f"--formation {text!r}: unknown parameter {item!r}; expected {usage}")
        (number,) = parse_floats(f"--formation {text!r}: {key}", value, 1)
        lo, hi = bounds[key]
        if not lo <= number <= hi:
            raise UsageError(f"--formation {text!r}: {key}={value}: expected metres in [{lo:g}, {hi:g}]")
        values[key] = number
    return kind, values["altitude"], values["distance"]


def check_fleet_flight(args: argparse.Namespace) -> tuple[list[VehiclePlan], formation.Plan]:
    """The fleet and its plan, or a UsageError naming the option, before anything starts."""
    if args.mission:
        raise UsageError(f"--mission {args.mission} with --vehicles {args.vehicles}: a fleet flies --formation")
    if args.trajectory != "step":
        raise UsageError(f"--trajectory {args.trajectory!r} with --vehicles {args.vehicles}: each vehicle flies its "
                         "part of --formation")  # fmt: skip
    if args.duration is not None:
        raise UsageError(f"--duration {args.duration:g} with --formation: the plan's phases set the flight's length")
    kind, altitude, distance = parse_formation(args.formation or "line")
    fleet = plan_fleet(args.vehicles, preset=args.preset, home=PX4_HOME, spacing=args.spacing,
                       gcs_listen="127.0.0.1:0", gcs_remote="none", api_listen="127.0.0.1:0",
                       api_remote="none")  # fmt: skip
    return fleet, formation.plan(kind, [v.offset for v in fleet], args.spacing, altitude, distance)


def fly_fleet(args: argparse.Namespace) -> int:
    """Fly the formation; the exit status for ``quadsitl fly``."""
    fleet, plan = check_fleet_flight(args)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    zenoh_ep = f"tcp/127.0.0.1:{free_port(socket.SOCK_STREAM)}"
    children = Children(env=signing_env(args.signing_key))
    quiet = ["--quiet"] if args.quiet else []
    web_port = dashboard_port(args.dashboard_port) if args.dashboard else None
    gcs_names = [f"gcs {v.name}" for v in fleet]

    def flight(stack: contextlib.ExitStack) -> int:
        compile_once(children.env)
        plant = ["sitl", "--preset", args.preset, "--speed", str(args.speed), "--hold-until-armed",
                 repr(SENSOR_GROUND_S)]  # fmt: skip
        gcs_ports, taken = [], set()  # ports picked for processes that have not bound them yet
        for v in fleet:
            folder = out / v.name
            folder.mkdir(parents=True, exist_ok=True)
            formation.write_vehicle_csv(folder / "trajectory.csv", plan, v.index)
            plant_port = free_port(avoid=taken)
            api_port = free_port(avoid=taken | {plant_port})
            taken |= {plant_port, api_port}
            gcs_ports.append(api_port)
            home = ",".join(repr(x) for x in v.home)
            ap = ["autopilot", "--preset", v.preset, "--plant-listen", f"127.0.0.1:{plant_port}",
                  "--system-id", str(v.system_id), "--api-listen", f"127.0.0.1:{api_port}", "--api-remote", "none",
                  "--gcs-listen", "127.0.0.1:0", "--gcs-remote", "none", "--home", home, "--vehicle", v.name,
                  "--zenoh-listen" if v.index == 0 else "--zenoh-connect", zenoh_ep, *LOGGED,
                  "--offboard-lockstep", repr(OFFBOARD_LOCKSTEP), *quiet]  # fmt: skip
            if args.controller:
                ap += ["--controller", args.controller]
            for item in args.controller_param:
                ap += ["--controller-param", item]
            children.start(f"autopilot {v.name}", ap + state_argv(args))
            plant += ["--autopilot", f"127.0.0.1:{plant_port}", "--vehicle", v.name, "--home", home]
            if v.preset != args.preset:
                plant += ["--vehicle-preset", f"{v.number}={v.preset}"]
        if args.integrator:
            plant += ["--integrator", args.integrator]
        children.start("plant", plant + wind_argv(args) + state_argv(args) + quiet)
        info = publish_info(fleet, zenoh_ep)  # system ids and homes, for the dashboard's fleet view
        if info is not None:
            stack.callback(info.close)
        if web_port is not None:
            print(f"quadsitl fly: dashboard at {start_dashboard(children, web_port, zenoh_ep)}", flush=True)
        for v, api_port in zip(fleet, gcs_ports, strict=True):
            folder = out / v.name
            children.start(f"gcs {v.name}", ["groundstation", "--preset", v.preset, "--connect",
                                             f"127.0.0.1:{api_port}", "--target-system", str(v.system_id),
                                             "--vehicle", v.name, "--zenoh-connect", zenoh_ep, "--trajectory",
                                             str(folder / "trajectory.csv"), "--duration", repr(plan.duration),
                                             "--arm-at", repr(SENSOR_GROUND_S), "--out", str(folder),
                                             "--setpoints-ahead", repr(SETPOINTS_AHEAD),
                                             "--quiet"])  # fmt: skip
        if not args.quiet:
            print(
                f"quadsitl fly: {len(fleet)} vehicles, formation {plan.kind}: take off, form up, translate "
                f"{plan.distance:g} m north, rotate 90°, hold, land ({plan.duration:.1f} s of plan)",
                flush=True,
            )
        status = supervise(children, "quadsitl fly", done=gcs_names,
                           finished=lambda: all(children.procs[name].poll() == 0 for name in gcs_names),
                           diverged=lambda _plant: fleet_diverged(children, gcs_names, out),
                           tick=None if info is None else lambda: info.tick(time.monotonic()))  # fmt: skip
        if status is not None:
            return status
        # the plant first, as a lone vehicle's `fly` does: autopilots stopped before it left it waiting, and after
        # 0.5 s it called the first of them lost; then the others together
        children.stop(names=["plant"])
        children.stop(names=[name for name in children.procs if name not in ("plant", "dashboard")])
        write_fleet_report(out, fleet, plan, args)
        if web_port is not None:
            keep_dashboard(children)
        return 0

    return run_supervised(children, "quadsitl fly", flight, functools.partial(flight_interrupted, children, gcs_names))


def fleet_diverged(children: Children, gcs_names: list[str], out: Path) -> int:
    """A vehicle's state diverged (the plant ended with PLANT_DIVERGED, having said why): each ground station
    ``gcs_names`` stopped, so that it writes what it logged in ``out``/v*/; ``fly``'s exit status, said."""
    time.sleep(0.3)
    for name in gcs_names:  # each writes what it logged
        children.stop(names=[name])
    print(f"quadsitl fly: a vehicle's state diverged (above); the flown telemetry is in {out}/v*/ (exit status "
          f"{FLY_DIVERGED})", file=sys.stderr)  # fmt: skip
    return FLY_DIVERGED


def write_fleet_report(out: Path, fleet: list[VehiclePlan], plan: formation.Plan, args: argparse.Namespace) -> dict:
    """Each vehicle's metrics.json, and the fleet's metrics.json, formation.csv and figure (the module's
    docstring); prints the fleet's table unless --quiet. Returns the fleet's metrics."""
    from groundstation.telemetry_csv import read_csv
    from quadsitl.cli_util import with_state, with_wind

    runs = []
    for v in fleet:
        folder = out / v.name
        one = argparse.Namespace(
            **{
                **vars(args),
                "trajectory": str(folder / "trajectory.csv"),
                "out": str(folder),
                "quiet": True,
                "no_figures": True,
                "mission": None,
            }
        )  # its own report, quietly
        write_report(folder, with_state(with_wind(load_preset(v.preset), args), args), one)
        runs.append(read_csv(folder / "telemetry.csv"))
    t, track = formation.common_track(plan, runs)
    metrics = formation.fleet_metrics(plan, t, track)
    series = metrics.pop("series")
    metrics["per_vehicle"] = {v.name: json.loads((out / v.name / "metrics.json").read_text()).get("position")
                              for v in fleet}  # fmt: skip
    metrics["state"] = args.state or "truth"
    (out / "metrics.json").write_text(json.dumps(metrics, indent=2) + "\n")
    table = np.column_stack([series["t"], series["formation_max_m"], series["separation_min_m"]])
    np.savetxt(out / "formation.csv", table, delimiter=",", header="t,formation_error_max_m,separation_min_m",
               comments="", fmt="%.6f")  # fmt: skip
    if not args.no_figures:
        from groundstation.figures import write_formation_figure

        write_formation_figure(out, plan, t, track, series, f"{len(fleet)} vehicles, formation {plan.kind}")
    if not args.quiet:
        print(formation.format_table(metrics))
        print(f"wrote {out}/metrics.json, formation.csv, {'fig_formation.png, ' if not args.no_figures else ''}"
              f"and v1..v{len(fleet)}/ (telemetry.csv, flight.tlog, metrics.json, trajectory.csv)")  # fmt: skip
    return metrics
