"""``quadsitl up`` across machines, its options checked before anything starts: the Zenoh endpoints and configuration
(:func:`zenoh_and_addresses`, :func:`check_zenoh_config`), and the address a MAVLink link that streams to another host
binds.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from quadsitl.cli_util import UsageError


def check_zenoh_config(option: str, path: str) -> str:
    """A Zenoh JSON5 configuration file that Zenoh reads → its absolute path (the processes that open it may run
    elsewhere); a UsageError naming the option, the file and Zenoh's complaint otherwise."""
    import zenoh

    file = Path(path)
    if not file.is_file():
        raise UsageError(f"{option} {path}: no such file (a Zenoh JSON5 configuration: see docs/security.md)")
    try:
        zenoh.Config.from_file(str(file))
    except zenoh.ZError as exc:
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else "not a Zenoh configuration"
        raise UsageError(f"{option} {path}: Zenoh cannot read it: {first}") from None
    return str(file.resolve())


def zenoh_and_addresses(args: argparse.Namespace) -> None:
    """``up`` across machines: the Zenoh endpoints checked and resolved (the first autopilot listens on
    tcp/127.0.0.1:7447 unless the vehicles connect to a router instead), and a MAVLink link that streams to
    another host binds, unless told where, the address this host reaches that host from (a loopback-bound
    socket cannot send there), on its PX4 port."""
    from groundstation.fleet import API_LISTEN, GCS_LISTEN, address_toward
    from groundstation.router import router_reachable

    if args.zenoh_config is not None:
        if args.no_zenoh:
            raise UsageError(f"--zenoh-config {args.zenoh_config} with --no-zenoh: expected one or the other")
        args.zenoh_config = check_zenoh_config("--zenoh-config", args.zenoh_config)
    for text in args.zenoh_connect:
        if args.no_zenoh or args.zenoh_listen:
            other = "--no-zenoh" if args.no_zenoh else f"--zenoh-listen {args.zenoh_listen}"
            raise UsageError(f"--zenoh-connect {text} with {other}: expected one or the other (with a router, "
                             "subscribers connect to the router; run one here too for a local one)")  # fmt: skip
        router_reachable("--zenoh-connect", text)
    if args.zenoh_listen is None and not args.zenoh_connect:
        args.zenoh_listen = "tcp/127.0.0.1:7447"
    for link, port in (("gcs", GCS_LISTEN), ("api", API_LISTEN)):
        remote = getattr(args, f"{link}_remote")
        if getattr(args, f"{link}_listen") is None and remote is not None and remote.lower() != "none":
            host = address_toward(f"--{link}-remote", remote)
            if not host.startswith("127."):
                setattr(args, f"{link}_listen", f"{host}:{port}")
