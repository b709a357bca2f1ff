"""The autopilot process's command line (``quadsitl autopilot``): its options, and their checks beyond argparse's."""

from __future__ import annotations

import argparse

from autopilot.telemetry_out import CONGESTION
from quadsitl import telemetry, wire
from quadsitl.cli_util import (
    UsageError,
    add_preset_arguments,
    add_state_arguments,
    check_range,
    check_system_id,
    parse_home,
)
from quadsitl.config import Preset


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="quadsitl autopilot",
        description="The autopilot: discrete backstepping (or PD) control loop, MAVLink to the plant and to "
        "ground stations (PX4 SITL's ports and conventions), telemetry to Zenoh.",
        epilog="examples:\n  quadsitl autopilot --preset paper\n"
        "  quadsitl autopilot --preset x500 --controller pd --zenoh-listen tcp/127.0.0.1:7447\n"
        "  quadsitl autopilot --gcs-remote none --api-listen 127.0.0.1:24580 --api-remote none",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_preset_arguments(p)
    add_state_arguments(p)
    p.add_argument(
        "--plant-listen",
        default="127.0.0.1:14560",
        metavar="HOST:PORT",
        help="UDP address for the plant link (default: 127.0.0.1:14560)",
    )
    for name, listen, remote, who in (
        ("gcs", 18570, 14550, "ground stations: QGroundControl, MAVProxy"),
        ("api", 14580, 14540, "offboard APIs: MAVSDK, scripts"),
    ):
        p.add_argument(
            f"--{name}-listen",
            default=f"127.0.0.1:{listen}",
            metavar="HOST:PORT",
            help=f"local UDP address of the {name} link, for {who} (default: 127.0.0.1:{listen})",
        )
        p.add_argument(
            f"--{name}-remote",
            default=f"127.0.0.1:{remote}",
            metavar="HOST:PORT|none",
            help=f"where the {name} link streams even before anyone talks to it (default: 127.0.0.1:{remote})",
        )
    p.add_argument("--system-id", type=int, default=1, help="MAVLink system id (default: 1)")
    p.add_argument(
        "--home",
        metavar="LAT,LON,ALT",
        help="home position: degrees, degrees, metres AMSL (default: PX4 SITL's, 47.397742,8.545594,488)",
    )
    p.add_argument(
        "--telemetry-rate",
        type=float,
        default=50.0,
        metavar="HZ",
        help="ATTITUDE, ATTITUDE_QUATERNION, LOCAL_POSITION_NED, ATTITUDE_TARGET rate in simulated time "
        "(default: 50; MAV_CMD_SET_MESSAGE_INTERVAL changes any stream)",
    )
    p.add_argument(
        "--setpoint-timeout",
        type=float,
        default=1.0,
        metavar="S",
        help="offboard setpoint loss failsafe, simulated seconds (default: 1; parameter COM_OF_LOSS_T)",
    )
    p.add_argument(
        "--offboard-lockstep",
        type=float,
        metavar="S",
        help="lockstep, for a ground station that stamps its offboard setpoints' time_boot_ms with this vehicle's "
        "clock (quadsitl fly's): answer no plant tick more than S simulated seconds after the moment the newest "
        "setpoint was made for, waiting at most 0.25 s of wall time per setpoint, so a ground station that falls "
        "behind a sped-up run holds its clock (default: off, as PX4)",
    )
    p.add_argument(
        "--signing-key",
        metavar="HEX|FILE",
        help="MAVLink 2 signing on the ground-station links: 64 hex digits or a file holding them; unsigned, "
        f"wrongly signed and replayed messages are refused (default: ${wire.SIGNING_ENV}, else no signing). "
        "A file or the environment keeps the key out of the process list",
    )
    p.add_argument(
        "--logs",
        metavar="DIR",
        help="keep a ULog of each flight, from arming to disarming, in DIR/YYYY-MM-DD/HH_MM_SS.ulg (UTC), as PX4's "
        "logger does, and serve them over MAVLink's log protocol (default: none; quadsitl up keeps them)",
    )
    telemetry.add_zenoh_arguments(p)
    p.add_argument("--no-zenoh", action="store_true", help="do not publish telemetry to Zenoh")
    p.add_argument(
        "--quiet",
        "-q",
        action="store_true",
        help="no note on exit of how often the --offboard-lockstep clock waited, unless a wait ran out",
    )
    p.add_argument(
        "--telemetry-congestion",
        choices=tuple(CONGESTION),
        default="drop",
        help="when a telemetry subscriber's link is full: drop the record (default: the vehicle never waits for a "
        "subscriber), or block until there is room, so that every subscriber gets every tick (a lockstep run whose "
        "logger must have them all, as quadsitl fly's; a subscriber that falls behind then holds the clock)",
    )
    return p


def check(args: argparse.Namespace, preset: Preset) -> None:
    """The options argparse cannot check, checked (UsageError naming the option, the value and what is allowed);
    ``--home`` and ``--signing-key`` resolved in place."""
    check_range("--telemetry-rate", args.telemetry_rate, 0.0, 1.0 / preset.sim.period)
    check_range("--setpoint-timeout", args.setpoint_timeout, 0.0, 3600.0)
    # 0: a ground station that sends its setpoints ahead (quadsitl gcs --setpoints-ahead); NaN is refused too
    if args.offboard_lockstep is not None and not 0.0 <= args.offboard_lockstep <= 60.0:
        raise UsageError(f"--offboard-lockstep {args.offboard_lockstep!r}: expected a number in [0, 60]")
    check_system_id(args.system_id)
    args.home = parse_home(args.home)
    args.signing_key = wire.resolve_signing_key(args.signing_key)
