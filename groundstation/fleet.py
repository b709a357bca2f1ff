"""A fleet's plan, pure (but :func:`address_toward`, which asks the routing table): for ``quadsitl up
--vehicles N``, each vehicle's system id, Zenoh name, MAVLink ports,
home and preset, by PX4's multi-vehicle SITL conventions; checked before anything starts.

PX4 (``Tools/simulation/sitl_multiple_run.sh``, ``ROMFS/px4fmu_common/init.d-posix/px4-rc.mavlink``), for
instance i = 0 … N−1:

- system id i + 1 (here ``--system-id`` + i: the first vehicle's id, 1 by default);
- the ground-station link bound to 18570 + i and streaming to 14550 for every vehicle (one ground station
  sees the whole fleet);
- the offboard-API link bound to 14580 + i and streaming to 14540 + i, to 14549 for i > 9;
- here also: Zenoh name ``v{i+1}`` (keys ``quadsitl/v{i+1}/…``), whatever the system ids.

Explicit ``--gcs-listen`` / ``--api-listen`` / ``--api-remote`` HOST:PORT give the first vehicle's address;
vehicle i uses PORT + i (PORT 0, any free port, stays 0 for every vehicle). ``--gcs-remote`` is shared, as PX4's 14550.

Vehicles start on a grid, ``spacing`` metres apart, rows northward and columns eastward
(⌈√N⌉ columns), each with its own home: the base home (``--home``, PX4 SITL's by default) moved by its
grid offset. Each vehicle's local frame starts at its own home, as on PX4, so local positions of different
vehicles are not comparable without the offsets (:attr:`VehiclePlan.offset`).
"""

from __future__ import annotations

import math
import socket
from collections.abc import Sequence
from dataclasses import dataclass

from quadsitl.cli_util import UsageError
from quadsitl.frames import PX4_HOME, ned_to_geodetic
from quadsitl.process_util import parse_address

MAX_VEHICLES = 64
"""The largest fleet ``up`` starts: the dashboard's limit of vehicles it follows, and well beyond what a
machine runs at 1 kHz (each vehicle is two processes)."""
GCS_LISTEN, GCS_REMOTE, API_LISTEN, API_REMOTE, API_REMOTE_LAST = 18570, 14550, 14580, 14540, 14549


@dataclass(frozen=True)
class VehiclePlan:
    """One vehicle of the fleet: ``index`` i (0-based, PX4's instance), ``number`` i + 1 (its name's)."""

    index: int
    system_id: int
    name: str  # Zenoh: quadsitl/<name>/...
    gcs_listen: str  # HOST:PORT the autopilot's ground-station link binds
    gcs_remote: str  # where it streams ("none": only to whoever talks to it)
    api_listen: str
    api_remote: str
    home: tuple[float, float, float]  # latitude, longitude [deg], altitude AMSL [m]
    offset: tuple[float, float]  # north, east [m] of this home from the first vehicle's
    preset: str  # a preset name or TOML file

    @property
    def number(self) -> int:
        return self.index + 1


def _shifted(option: str, text: str | None, default: int, i: int) -> str:
    """``text`` (HOST:PORT, the first vehicle's) or 127.0.0.1:``default``, with PORT + i."""
    if text is None:
        return f"127.0.0.1:{default + i}"
    if text.lower() == "none":
        return "none"
    host, port = parse_address(option, text)
    if port == 0:  # any free port, for every vehicle
        return text
    if port + i > 65535:
        raise UsageError(f"{option} {text}: vehicle {i + 1} would need port {port + i}, beyond 65535")
    return f"{host}:{port + i}"


def address_toward(option: str, remote: str) -> str:
    """The address of this host's interface that faces ``remote`` (HOST:PORT), by the routing table (a UDP
    socket's connect sends nothing); a UsageError naming the option when there is no route or no such host."""
    host, port = parse_address(option, remote)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        try:
            sock.connect((host, port or 9))
        except OSError as exc:
            raise UsageError(f"{option} {remote}: this host cannot reach {host}: {exc.strerror or exc}") from None
        return sock.getsockname()[0]


def zenoh_argv(index: int, listen: str | None, routers: Sequence[str], autopilot: bool, config: str | None = None
               ) -> list[str]:  # fmt: skip
    """The Zenoh options of vehicle ``index``'s autopilot (or plant) in ``up``. On one host, the first autopilot
    listens on ``listen`` and every other session connects to it (peers then find each other). With ``routers``
    (``--zenoh-connect``, on this host or another) every session is instead a Zenoh client of the router: all
    its telemetry goes through the router's one port, as a firewall between hosts wants (a peer would also try
    direct connections to the other peers, on ports of their own). ``config``: a Zenoh configuration file every
    session also takes (TLS, access control; the endpoints given here replace its own)."""
    extra = ["--zenoh-config", config] if config else []
    if routers:
        return ["--zenoh-mode", "client", *(arg for r in routers for arg in ("--zenoh-connect", r)), *extra]
    return [*(["--zenoh-listen" if autopilot and index == 0 else "--zenoh-connect", listen] if listen else []), *extra]


def check_vehicle_count(n: int) -> None:
    """``--vehicles`` in 1..MAX_VEHICLES, or a UsageError naming it (checked before the per-vehicle options)."""
    if not 1 <= n <= MAX_VEHICLES:
        raise UsageError(f"--vehicles {n}: expected an integer in 1..{MAX_VEHICLES}")


def plan_fleet(
    n: int,
    *,
    preset: str,
    first_system_id: int = 1,
    home: tuple[float, float, float] = PX4_HOME,
    spacing: float = 3.0,
    gcs_listen: str | None = None,
    gcs_remote: str | None = None,
    api_listen: str | None = None,
    api_remote: str | None = None,
    vehicle_presets: dict[int, str] | None = None,
) -> list[VehiclePlan]:
    """The plan of ``n`` vehicles (see the module's docstring); a UsageError naming the option for a count beyond
    the plan, a system id beyond 255, a spacing that is not a positive number of metres, or two vehicles on one
    port."""
    check_vehicle_count(n)
    if first_system_id < 1 or first_system_id + n - 1 > 255:
        raise UsageError(f"--system-id {first_system_id} with --vehicles {n}: system ids "
                         f"{first_system_id}..{first_system_id + n - 1} must lie in 1..255")  # fmt: skip
    if not (math.isfinite(spacing) and 0.5 <= spacing <= 1000.0):
        raise UsageError(f"--spacing {spacing!r}: expected metres in [0.5, 1000]")
    presets = vehicle_presets or {}
    columns = math.ceil(math.sqrt(n))
    fleet = []
    for i in range(n):
        north, east = (i // columns) * spacing, (i % columns) * spacing
        lat, lon = ned_to_geodetic(north, east, home[0], home[1])
        if api_remote is None:
            api_to = f"127.0.0.1:{API_REMOTE + i if i <= 9 else API_REMOTE_LAST}"
        else:
            api_to = _shifted("--api-remote", api_remote, 0, i)
        fleet.append(VehiclePlan(
            index=i,
            system_id=first_system_id + i,
            name=f"v{i + 1}",
            gcs_listen=_shifted("--gcs-listen", gcs_listen, GCS_LISTEN, i),
            gcs_remote=gcs_remote or f"127.0.0.1:{GCS_REMOTE}",
            api_listen=_shifted("--api-listen", api_listen, API_LISTEN, i),
            api_remote=api_to,
            home=(lat, lon, home[2]),
            offset=(north, east),
            preset=presets.get(i + 1, preset),
        ))  # fmt: skip
    bound: dict[int, str] = {}
    for v in fleet:
        for option, address in (("--gcs-listen", v.gcs_listen), ("--api-listen", v.api_listen)):
            port = int(address.rpartition(":")[2])
            if port == 0:
                continue
            if port in bound:
                raise UsageError(f"{option} {address}: vehicle {v.number} would bind port {port}, "
                                 f"which {bound[port]} already binds")  # fmt: skip
            bound[port] = f"vehicle {v.number}'s {option}"
    return fleet
