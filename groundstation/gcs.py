"""The ground-station process (``quadsitl gcs``, ``python -m groundstation``): its options and :func:`main`, which
flies a trajectory (:class:`groundstation.station.GroundStation`) or a mission
(:class:`groundstation.mission_flight.MissionFlight`) and exits with 0 when the flight landed, disarmed and every
telemetry tick arrived, 1 when it failed, 2 for bad options.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from groundstation.mission_flight import MissionFlight
from groundstation.station import GcsError, GroundStation
from quadsitl import telemetry, wire
from quadsitl.cli_util import UsageError, check_duration, parse_floats
from quadsitl.config import ConfigError
from quadsitl.process_util import start_process, stop_status


def build_parser() -> argparse.ArgumentParser:
    """``quadsitl gcs``'s options."""
    p = argparse.ArgumentParser(
        prog="quadsitl gcs",
        description="Ground station: fly a reference trajectory over MAVLink, log telemetry from Zenoh.",
        epilog="examples:\n  quadsitl gcs --connect 127.0.0.1:14580 --zenoh-connect tcp/127.0.0.1:7447 --out runs/gcs\n"
        "  quadsitl gcs --trajectory sine --duration 10 --zenoh-connect tcp/127.0.0.1:7447",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--preset", default="paper", help="preset for T and the step reference (default: paper)")
    p.add_argument(
        "--connect",
        default="127.0.0.1:14580",
        metavar="HOST:PORT",
        help="the autopilot's ground-station address (default: 127.0.0.1:14580)",
    )
    p.add_argument("--target-system", type=int, default=1, help="the autopilot's MAVLink system id (default 1)")
    p.add_argument(
        "--trajectory",
        default="step",
        help="attitude: step (default), ramp, sine or a CSV file t,altitude,roll,pitch,yaw; position (offboard "
        "position setpoints): circle[:radius=M,period=S,altitude=M,hold=S,yaw=RAD|travel], figure8[:size=M,...] "
        "or a CSV file t,x,y,altitude,yaw",
    )
    p.add_argument(
        "--duration",
        type=float,
        metavar="S",
        help="simulated seconds of flight (default: a position trajectory's own length, else the preset's)",
    )
    p.add_argument(
        "--mission",
        metavar="FILE",
        help="fly a mission instead: a QGroundControl .plan, a waypoint CSV lat,lon,altitude[,hold,radius,yaw] or a "
        "QGC WPL 110 file, uploaded through the mission protocol (--duration then bounds it: default 900 s)",
    )
    p.add_argument(
        "--home",
        metavar="LAT,LON,ALT",
        help="the autopilot's origin, for mission.json's north/east (default: PX4 SITL's, 47.397742,8.545594,488)",
    )
    p.add_argument(
        "--arm-at",
        type=float,
        metavar="S",
        help="switch to offboard (with --mission: to mission) and arm once the vehicle's clock reaches S simulated "
        "seconds (its lockstep plant holding there with --hold-until-armed): the flight starts at the same tick in "
        "every run",
    )
    p.add_argument(
        "--setpoints-ahead",
        type=float,
        default=0.0,
        metavar="S",
        help="send the trajectory up to S simulated seconds ahead of the vehicle's clock, each setpoint stamped with "
        "the moment it is for, to an autopilot that flies each from that moment (quadsitl autopilot "
        "--offboard-lockstep, as quadsitl fly runs both): the flight is the same to the byte on any machine "
        "(default 0: each setpoint is for the vehicle's newest moment seen, flown as it comes)",
    )
    p.add_argument("--out", default="runs/gcs", metavar="DIR", help="where telemetry.csv and flight.tlog go")
    p.add_argument("--timeout", type=float, default=600.0, metavar="S", help="give up after S wall seconds")
    p.add_argument("--quiet", "-q", action="store_true")
    p.add_argument("--signing-key", metavar="HEX|FILE", help=f"sign the MAVLink link (default: ${wire.SIGNING_ENV})")
    telemetry.add_zenoh_arguments(p)
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """``quadsitl gcs`` with the options ``argv`` (default: the command line's) → its exit status."""
    start_process(quiet_gc=False)
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        check_duration(args.duration)
        if not 0.0 <= args.setpoints_ahead <= 10.0:  # (NaN too)
            raise UsageError(f"--setpoints-ahead {args.setpoints_ahead!r}: expected a number in [0, 10]")
        args.signing_key = wire.resolve_signing_key(args.signing_key)
        args.home = parse_floats("--home", args.home, 3) if args.home else None
        gcs = (MissionFlight if args.mission else GroundStation)(args)
    except (UsageError, ConfigError) as exc:
        print(f"{parser.prog}: error: {exc}", file=sys.stderr)
        return 2
    try:
        return gcs.fly()
    except GcsError as exc:
        gcs.stop_progress()
        print(f"{parser.prog}: error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt as exc:  # SIGINT or SIGTERM (StopRequested): an unfinished flight, logs saved
        gcs.save_partial()
        return stop_status(exc)
    finally:
        gcs.close()
