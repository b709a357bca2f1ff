"""``quadsitl router``: a Zenoh router, for telemetry across machines.

On one machine the vehicles' Zenoh sessions are peers and need no router (docs/telemetry.md). Across machines,
one router that every host reaches carries the telemetry: the vehicles (``quadsitl up --zenoh-connect
tcp/ROUTER:7447``) and the subscribers (``quadsitl dashboard --zenoh-connect tcp/ROUTER:7447``) connect to it,
and it routes each sample to whoever subscribed, also between sessions that cannot reach each other directly.
It is the eclipse-zenoh package already installed, in router mode: no ``zenohd`` to install. Routers connect to
each other with ``--connect``.

It listens on ``tcp/127.0.0.1:7447`` (Zenoh's port) unless told otherwise: as everything else here, it binds
loopback by default (docs/security.md), so listening where other hosts reach it takes an explicit ``--listen
tcp/0.0.0.0:7447`` (or the address of one interface). ``--zenoh-config FILE`` (Zenoh's JSON5) adds TLS and access
control; its ``listen`` endpoints are used unless ``--listen`` is given.

Bad input (an endpoint that is not PROTOCOL/HOST:PORT, a port that is busy, an address this machine does not have)
is one line naming the option, the value and what is allowed, and exit status 2, before the router starts.
"""

from __future__ import annotations

import argparse
import errno
import socket
import sys
import time
from collections.abc import Sequence

from quadsitl.cli_util import UsageError, serve_until_stopped
from quadsitl.process_util import run_stoppable, start_process

DEFAULT_LISTEN = "tcp/127.0.0.1:7447"  # Zenoh's (and zenohd's) port, on loopback as everything here by default
PROTOCOLS = {"tcp": socket.SOCK_STREAM, "tls": socket.SOCK_STREAM, "ws": socket.SOCK_STREAM,
             "udp": socket.SOCK_DGRAM, "quic": socket.SOCK_DGRAM}  # fmt: skip
EXPECTED = "expected PROTOCOL/HOST:PORT, PROTOCOL one of tcp, tls, udp, quic, ws and PORT in 0..65535, e.g. {}"


def parse_endpoint(option: str, text: str, example: str = DEFAULT_LISTEN) -> tuple[str, str, int]:
    """A Zenoh endpoint ``PROTOCOL/HOST:PORT`` (an IPv6 host in brackets; Zenoh's ``?metadata`` and ``#config``
    suffixes allowed) → (protocol, host, port), or a UsageError naming the option, the value and what is
    allowed."""
    proto, sep, rest = text.partition("/")
    address = rest.split("?", 1)[0].split("#", 1)[0]
    host, colon, port = address.rpartition(":")
    if host.startswith("[") and host.endswith("]"):
        host = host[1:-1]
    if not (sep and colon and proto in PROTOCOLS and host and port.isdigit() and int(port) <= 65535):
        raise UsageError(f"{option} {text}: {EXPECTED.format(example)}")
    return proto, host, int(port)


def check_listen(option: str, text: str) -> None:
    """Refuse, before Zenoh starts, an endpoint this machine cannot listen on: a busy port (with how to choose
    another) or an address it does not have."""
    proto, host, port = parse_endpoint(option, text)
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    with socket.socket(family, PROTOCOLS[proto]) as sock:
        if PROTOCOLS[proto] == socket.SOCK_STREAM:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as Zenoh binds: TIME_WAIT is not busy
        try:
            sock.bind((host, port))
        except OSError as exc:
            where = f"cannot listen on {host}:{port}: {exc.strerror or exc}"
            if exc.errno == errno.EADDRINUSE:
                where += f"; choose another with {option} {proto}/HOST:PORT"
            elif exc.errno == errno.EADDRNOTAVAIL:
                where += " (not an address of this machine; 0.0.0.0 is all of them)"
            raise UsageError(f"{option} {text}: {where}") from None


def endpoints_of(conf, path: str) -> list[str]:
    """The endpoints a Zenoh configuration lists at ``path`` (a list, or Zenoh's per-mode {mode: list})."""
    import json

    value = json.loads(conf.get_json(path))
    if isinstance(value, dict):
        value = value.get("router") or []
    return list(value or [])


def router_reachable(option: str, text: str) -> None:
    """Refuse, before anything starts, a router endpoint nothing answers on: a TCP endpoint (tcp, tls, ws) must
    accept a connection within 3 s. A Zenoh client (the vehicles of ``up --zenoh-connect``) cannot open its
    session without its router."""
    proto, host, port = parse_endpoint(option, text, "tcp/10.0.0.2:7447")
    if PROTOCOLS[proto] != socket.SOCK_STREAM:
        return
    try:
        socket.create_connection((host, port), timeout=3.0).close()
    except OSError as exc:
        why = "no answer within 3 s" if isinstance(exc, TimeoutError) else exc.strerror or str(exc)
        raise UsageError(f"{option} {text}: no router answers there ({why}); start it first there: quadsitl router "
                         f"--listen {proto}/0.0.0.0:{port}") from None  # fmt: skip


EXAMPLES = """examples:
  quadsitl router                                        # tcp/127.0.0.1:7447: this machine only
  quadsitl router --listen tcp/0.0.0.0:7447              # where other hosts reach it (open TCP 7447)
  quadsitl router --listen tcp/0.0.0.0:7447 --connect tcp/10.0.0.7:7447   # and joined to another router
  quadsitl router --zenoh-config router-tls.json5        # TLS and access control (docs/security.md)
then, on the vehicles' host:   quadsitl up --vehicles 3 --zenoh-connect tcp/ROUTER:7447
and where you watch:           quadsitl dashboard --zenoh-connect tcp/ROUTER:7447
"""


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="quadsitl router",
        description="Run a Zenoh router (the eclipse-zenoh package, router mode) until Ctrl-C or SIGTERM, so that "
        "telemetry crosses machines: vehicles and subscribers on any host connect to it (see docs/fleets.md).",
        epilog=EXAMPLES,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--listen", action="append", default=[], metavar="ENDPOINT",
                   help=f"where it listens, PROTOCOL/HOST:PORT (repeatable; default: {DEFAULT_LISTEN}, this machine "
                   "only; tcp/0.0.0.0:7447 for every interface)")  # fmt: skip
    p.add_argument("--connect", action="append", default=[], metavar="ENDPOINT",
                   help="another router to connect to, PROTOCOL/HOST:PORT (repeatable)")  # fmt: skip
    p.add_argument("--zenoh-config", metavar="FILE", help="a Zenoh JSON5 configuration file (TLS, access control); "
                   "its listen endpoints are used unless --listen is given")  # fmt: skip
    p.add_argument("--quiet", "-q", action="store_true", help="print only errors")
    return p


def serve(args: argparse.Namespace) -> int:
    import zenoh

    from quadsitl.telemetry import zenoh_config

    listen = args.listen or ([] if args.zenoh_config else [DEFAULT_LISTEN])
    for text in listen:
        check_listen("--listen", text)
    for text in args.connect:
        parse_endpoint("--connect", text, "tcp/10.0.0.7:7447")
    try:
        conf = zenoh_config("router", listen, args.connect, args.zenoh_config)
        session = zenoh.open(conf)
    except zenoh.ZError as exc:
        what = f"--zenoh-config {args.zenoh_config}" if args.zenoh_config else "the Zenoh router"
        raise UsageError(f"{what}: cannot start: {exc}") from None
    try:
        if not args.quiet:
            where = ", ".join(endpoints_of(conf, "listen/endpoints")) or "nothing (connect only)"
            joined = endpoints_of(conf, "connect/endpoints")
            also = f", connecting to {', '.join(joined)}" if joined else ""
            print(f"quadsitl router: Zenoh router {session.zid()} listening on {where}{also}; Ctrl-C stops", flush=True)
        while True:
            time.sleep(1.0)
    finally:
        session.close()


def main(argv: Sequence[str] | None = None) -> int:
    start_process(quiet_gc=False)
    return serve_until_stopped(build_parser(), serve, argv)


if __name__ == "__main__":
    sys.exit(run_stoppable(main, name="quadsitl router"))
