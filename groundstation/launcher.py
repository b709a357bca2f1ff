"""``quadsitl fly`` and ``quadsitl up``: the processes as separate OS processes on loopback ports.

``fly`` starts plant, autopilot and ground station on free ports, waits for the ground station to finish
the flight, then writes metrics.json and the figures from the Zenoh-logged telemetry.csv, exactly as
``quadsitl sim`` does. ``up`` starts plant and autopilot only, on PX4 SITL's MAVLink ports, and runs
until stopped, for QGroundControl, MAVProxy, MAVSDK or a script to fly.

If any child fails, both exit non-zero naming the process. Every child is torn down on exit, SIGINT (Ctrl-C)
and SIGTERM (SIGTERM, then SIGKILL after 3 s for a child that hangs), and each child asks the kernel to
end it if the launcher itself dies. Both signals are handled also when the launcher was started with SIGINT
ignored, as a script's background job is (``quadsitl.process_util.handle_stop_signals``, installed by
``groundstation.cli.main``). A stop ends ``up``, and ``fly`` once its flight is done, with status 0; a flight
stopped before its end exits 130 (SIGINT) or 143 (SIGTERM), its logs saved up to the interruption.

A plant whose state diverged (it exits with ``PLANT_DIVERGED``, having said why on stderr and told the autopilot,
which relays it to the ground stations in a STATUSTEXT) ends ``fly`` with what was flown and ``up`` at once, both
with status 3 (:data:`FLY_DIVERGED`, :data:`UP_DIVERGED`; docs/failures.md).
"""

from __future__ import annotations

import contextlib
import functools
import json
import os
import socket
import subprocess
import sys
import time
from collections.abc import Collection
from dataclasses import asdict
from pathlib import Path

from groundstation.fleet import VehiclePlan, zenoh_argv
from quadsitl.children import Children, describe, run_supervised, supervise
from quadsitl.cli_util import CLOCKS, UsageError, state_argv, wind_argv, wind_settings, with_state
from quadsitl.compile_cache import cached, compiling
from quadsitl.config import SENSOR_GROUND_S, Preset, WindParams, load_preset
from quadsitl.process_util import (
    PLANT_DIVERGED,
    bind_tcp,
    bind_udp,
    free_port,
    hold_cores_awake,
    parse_remote,
    stop_status,
)

# [s] simulated: `fly`'s ground station sends the trajectory this far ahead of the vehicle's clock, each setpoint
# stamped with the tick it is for (gcs --setpoints-ahead), and the autopilot flies each from that tick and answers no
# tick the ground station has not sent for (--offboard-lockstep 0: autopilot.offboard_lockstep). The horizon moves on a
# grid of pacing.AHEAD_KEEPALIVE, so at each read it is a second ahead of the clock, which waits only for a read more
# than half a second of flight late (docs/performance.md#the-ground-station-in-lockstep). The lead stays within the
# autopilot's HOLD_AHEAD (2 s). The reference flown at every tick is the ground station's for that tick on any machine,
# so every run flies to the byte.
SETPOINTS_AHEAD = 1.5
OFFBOARD_LOCKSTEP = 0.0
# `fly`'s autopilots: a full telemetry link holds the vehicle instead of losing ticks. The ground station's logger must
# get every tick, and a lockstep clock can wait; dropping lost ticks whenever the logger was descheduled while the
# vehicle ran ahead (the links' buffers hold a few hundred ticks, docs/telemetry.md).
LOGGED = ("--telemetry-congestion", "block")
# `up` says it is ready once every autopilot has sent its first heartbeat; before that, when the compiled loop the
# autopilot serves the plant with is not in numba's cache, that the first run compiles.
READY_FUNCTION = "plant_loop.serve"
READY_TIMEOUT = 600.0  # [s] wall: the longest `up` waits to say it is ready (a cold compile on a slow machine)


def signing_env(key_text: str | None) -> dict[str, str] | None:
    """The environment that hands a signing key to the children: the environment, not the command line,
    so that the key stays out of the process list."""
    if not key_text:
        return None
    import os

    from quadsitl import wire

    wire.resolve_signing_key(key_text)  # refuse a bad key here, with the option's name
    return {**os.environ, wire.SIGNING_ENV: key_text}


def add_dashboard_arguments(p) -> None:
    """``--dashboard`` and ``--dashboard-port`` for ``fly`` and ``up``."""
    p.add_argument("--dashboard", action="store_true", help="also serve the live dashboard and print its URL")
    p.add_argument(
        "--dashboard-port", type=int, default=8050, metavar="P", help="its port (default: 8050; 0 = any free port)"
    )


def dashboard_port(port: int) -> int:
    """The port the dashboard will serve on: checked free now, so that a busy one is refused before anything
    starts, with the option to change it; 0 picks a free one."""
    if not 0 <= port <= 65535:
        raise UsageError(f"--dashboard-port {port}: expected 0..65535 (0 = any free port)")
    if port == 0:
        return free_port(socket.SOCK_STREAM)
    bind_tcp("--dashboard-port", str(port), "127.0.0.1", port, "(0 picks a free one)").close()
    return port


def start_dashboard(children: Children, port: int, zenoh_endpoint: str, timeout: float = 60.0,
                    zenoh_config: str | None = None) -> str:  # fmt: skip
    """Start ``quadsitl dashboard`` on ``port`` subscribed to ``zenoh_endpoint`` (with the Zenoh configuration
    file ``zenoh_config``, if any); returns its URL once it accepts connections. A dashboard that exits fails at
    once; one that is alive gets ``timeout`` seconds: it runs at idle priority, so while a fleet's 2N processes load
    on a busy machine it may wait long for a core."""
    config = ["--zenoh-config", zenoh_config] if zenoh_config else []
    children.start("dashboard", ["groundstation.dashboard.server", "--port", str(port), "--zenoh-connect",
                                 zenoh_endpoint, *config, "--quiet"])  # fmt: skip
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if children.procs["dashboard"].poll() is not None:
            break
        with contextlib.suppress(OSError), socket.create_connection(("127.0.0.1", port), timeout=0.2):
            return f"http://127.0.0.1:{port}/"
        time.sleep(0.05)
    raise RuntimeError("the dashboard did not start" if children.procs["dashboard"].poll() is not None
                       else f"the dashboard did not accept connections within {timeout:g} s")  # fmt: skip


def up(preset: Preset, args, fleet: list[VehiclePlan]) -> int:
    """Plant and autopilot of each vehicle of ``fleet`` (:func:`groundstation.fleet.plan_fleet`) until Ctrl-C or
    SIGTERM (exit 0), until a plant's state diverges (exit UP_DIVERGED), or until one of them fails (exit 1)."""
    children = Children(env=signing_env(args.signing_key))
    if args.dashboard and args.no_zenoh:
        raise UsageError("--dashboard needs the Zenoh telemetry: drop --no-zenoh")
    web_port = dashboard_port(args.dashboard_port) if args.dashboard else None
    check_ports_free(args, fleet)
    if args.cores_awake:  # refused (no root) before anything starts; the plant holds the request for the run
        os.close(hold_cores_awake())

    def interrupted(exc: KeyboardInterrupt) -> int:  # Ctrl-C or SIGTERM: how `up` is meant to end
        if not args.quiet:
            print("quadsitl up: stopping " + ", ".join(children.procs), file=sys.stderr)
        return 0

    return run_supervised(children, "quadsitl up", lambda stack: run_up(children, stack, preset, args, fleet, web_port),
                          interrupted)  # fmt: skip


def run_up(children: Children, stack: contextlib.ExitStack, preset: Preset, args, fleet: list[VehiclePlan],
           web_port: int | None) -> int:  # fmt: skip
    """``up``'s processes started (the dashboard's on ``web_port``, if any) and its banner printed, then watched until
    one fails: the exit status. The vehicles' info publisher, when Zenoh is on, closes with ``stack``."""
    if len(fleet) > 1:  # for the modes the fleet flies (its presets' [sensors], --state) and its clock
        modes = {with_state(load_preset(v.preset), args).sensors is not None for v in fleet}
        compile_once(children.env, modes, (args.mode,))
    # One plant process simulates every vehicle on one clock (sitl.lockstep.run_lockstep); an autopilot each.
    plant = ["sitl", "--preset", args.preset, "--mode", args.mode] + (["--cores-awake"] if args.cores_awake else [])
    taken = planned_ports(fleet)  # an internal port never lands on a later vehicle's, not yet bound
    hosted: list[str] = ["autopilot.host"]  # --hosted: every vehicle's autopilot options, in one process
    for v in fleet:
        plant_port = free_port(avoid=taken)
        taken.add(plant_port)
        named = "" if len(fleet) == 1 else f" {v.name}"
        ap = ["autopilot", "--preset", v.preset, "--plant-listen", f"127.0.0.1:{plant_port}",
              "--system-id", str(v.system_id), "--gcs-listen", v.gcs_listen, "--gcs-remote", v.gcs_remote,
              "--api-listen", v.api_listen, "--api-remote", v.api_remote]  # fmt: skip
        if args.controller is not None:
            ap += ["--controller", args.controller]
        for item in args.controller_param:
            ap += ["--controller-param", item]
        home = ["--home", ",".join(repr(x) for x in v.home)] if args.home is not None or len(fleet) > 1 else []
        ap += home + state_argv(args)
        if args.logs != "none":  # each vehicle's flight logs, as each PX4 SITL instance keeps its own
            ap += ["--logs", str(Path(args.logs) / v.name) if len(fleet) > 1 else args.logs]
        if args.no_zenoh:
            ap.append("--no-zenoh")
        else:  # the first vehicle's session listens, the others connect to it (and find each other), or a router
            ap += ["--vehicle", v.name, *zenoh_argv(v.index, args.zenoh_listen, args.zenoh_connect, True,
                                                    args.zenoh_config)]  # fmt: skip
        if args.hosted:
            hosted += ["--", *ap[1:]]
        else:
            children.start("autopilot" + named, ap, ready=True)
        plant += ["--autopilot", f"127.0.0.1:{plant_port}", "--vehicle", v.name, *home]
        if v.preset != args.preset:
            plant += ["--vehicle-preset", f"{v.number}={v.preset}"]
    if args.mode == "lockstep":
        plant += ["--speed", str(args.speed)]
    if args.impair:
        plant += ["--impair", args.impair]
    plant += wind_argv(args) + state_argv(args)
    if not args.no_zenoh:  # wind changes on quadsitl/<vehicle>/wind (sitl/wind_link.py)
        plant += zenoh_argv(0, args.zenoh_listen, args.zenoh_connect, False, args.zenoh_config)
    if args.hosted:
        children.start("autopilots", hosted, ready=True)
    children.start("plant", plant + (["--quiet"] if args.quiet else []))
    info = None if args.no_zenoh else publish_info(fleet, zenoh_endpoint(args), bool(args.zenoh_connect),
                                                   args.zenoh_config)  # fmt: skip
    if info is not None:  # the vehicles' quadsitl/<vehicle>/info documents
        stack.callback(info.close)
    url = None
    if web_port is not None:
        url = start_dashboard(children, web_port, zenoh_endpoint(args), zenoh_config=args.zenoh_config)
    if not args.quiet:
        if not cached(READY_FUNCTION):
            print(compiling("up"), flush=True)
        children.wait_ready(READY_TIMEOUT)  # the banner after the first heartbeat
        if all(p.poll() is None for p in children.procs.values()):  # not when a child ended first: said below
            print(banner(preset, args, url) if len(fleet) == 1 else fleet_banner(fleet, args, url), flush=True)
    tick = None if info is None else lambda: info.tick(time.monotonic())
    return supervise(children, "quadsitl up", diverged=up_diverged, tick=tick, period=0.1)


def up_diverged(name: str) -> int:
    """The plant ``name`` of ``up`` ended because its state diverged (it said why): ``up``'s exit status, said."""
    time.sleep(0.2)  # the autopilot relays the plant's STATUSTEXT to the ground stations as it comes
    print(f"quadsitl up: the {name}'s state diverged (above; the ground stations were told in a STATUSTEXT); stopping "
          f"the others (exit status {UP_DIVERGED})", file=sys.stderr)  # fmt: skip
    return UP_DIVERGED


def publish_info(fleet: list[VehiclePlan], endpoint: str, client: bool = False, config_file: str | None = None):
    """Every vehicle's ``quadsitl/<vehicle>/info`` (system id, home, preset; groundstation.vehicle_info), put
    once a second from a Zenoh session of the launcher's own connected to ``endpoint`` (the first autopilot's,
    or with ``client`` a router's, whose client it then is, as the vehicles' sessions are), so that a dashboard
    anywhere on that Zenoh network places the fleet on one map (``config_file``: the vehicles' Zenoh configuration,
    TLS for one). None, with a warning, when the session does not open: the vehicles fly on without it."""
    import zenoh

    from groundstation.vehicle_info import InfoPublisher, encode_info
    from quadsitl.telemetry import zenoh_config

    docs = {v.name: encode_info(v.system_id, v.home, Path(v.preset).stem, len(fleet)) for v in fleet}
    session = None
    try:
        session = zenoh.open(zenoh_config("client" if client else "peer", connect=[endpoint], config_file=config_file))
        return InfoPublisher(session, docs)
    except zenoh.ZError as exc:
        if session is not None:
            session.close()
        print(f"quadsitl up: warning: no vehicle info on Zenoh (homes, system ids for maps): {exc}",
              file=sys.stderr, flush=True)  # fmt: skip
        return None


def compile_once(env: dict[str, str] | None, modes: Collection[bool] = (False, True),
                 clocks: Collection[str] = CLOCKS) -> None:  # fmt: skip
    """Before a fleet starts: compile the equations once, into numba's cache, in two processes of their own (one on
    each core), so that the fleet's 2N processes load them instead of each compiling the same code at once (a cold
    start): for the ``modes`` its vehicles fly (True: on sensors) and the plant's ``clocks``. One compiles the
    autopilot's tick, its bulk first, and loops; the other the parts of that tick it can meanwhile
    (:func:`autopilot.tick.warm_up_share`), then the plant's (docs/performance.md#compiling-on-first-run)."""
    modes, clocks = sorted(set(modes)), sorted(set(clocks))
    level = "from quadsitl.jit import favour_compile_time; favour_compile_time(); "  # as the processes compile
    autopilot = (level + "from autopilot.tick import warm_up; from autopilot.process import warm_up_loops; "
                 f"[warm_up(s) for s in {modes!r}]; warm_up_loops({modes!r})")  # fmt: skip
    plant = (level + f"from autopilot.tick import warm_up_share; [warm_up_share(s) for s in {modes!r}]; "
             "from quadsitl.config import load_preset; from sitl.plant import Plant; from sitl.process "
             f"import warm_up; warm_up(Plant(load_preset('paper')), {modes!r}, {clocks!r})")  # fmt: skip
    compilers = [subprocess.Popen([sys.executable, "-c", code], env=env) for code in (autopilot, plant)]
    try:
        failed = [p.wait() != 0 for p in compilers]
    finally:
        for p in compilers:
            if p.poll() is None:
                p.kill()
                p.wait()
    if any(failed):
        raise RuntimeError("compiling the equations failed (above)")


def planned_ports(fleet: list[VehiclePlan]) -> set[int]:
    """Every port named in ``fleet``'s links (listen and remote, any host): ports the fleet's own processes and
    clients bind soon, which ``up`` must not hand out for its internal links."""
    ports = set()
    for v in fleet:
        for option, address in (("--gcs-listen", v.gcs_listen), ("--gcs-remote", v.gcs_remote),
                                ("--api-listen", v.api_listen), ("--api-remote", v.api_remote)):  # fmt: skip
            parsed = parse_remote(option, address)  # None for "none"
            if parsed is not None and parsed[1]:  # port 0: any, chosen by the OS
                ports.add(parsed[1])
    return ports


def check_ports_free(args, fleet: list[VehiclePlan]) -> None:
    """Refuse, before starting anything, the ports ``up`` would find busy: each named with its option (and the
    vehicle, in a fleet)."""
    for v in fleet:
        for option, address in (("--gcs-listen", v.gcs_listen), ("--api-listen", v.api_listen)):
            try:
                bind_udp(option, address).close()
            except UsageError as exc:
                raise UsageError(f"{exc} (vehicle {v.number})" if len(fleet) > 1 else str(exc)) from None
    if not args.no_zenoh and args.zenoh_listen and args.zenoh_listen.startswith("tcp/"):
        host, _, port = args.zenoh_listen[4:].rpartition(":")
        if not port.isdigit():
            raise UsageError(f"--zenoh-listen {args.zenoh_listen}: expected tcp/HOST:PORT")
        bind_tcp("--zenoh-listen", args.zenoh_listen, host, int(port), "tcp/HOST:PORT, or --no-zenoh").close()


def pace_of(args) -> str:
    """How an ``up`` run keeps time, as its banner says it."""
    if args.mode == "lockstep":
        pace = "lockstep, as fast as possible" if args.speed == 0 else f"lockstep at {args.speed:g}× real time"
    else:
        pace = "real time (free-running plant)"
    return pace + (", cores kept awake (PM QoS)" if getattr(args, "cores_awake", False) else "")


def fleet_banner(fleet: list[VehiclePlan], args, dashboard_url: str | None = None) -> str:
    """What ``up --vehicles N`` prints: every vehicle's ids, ports and the one-line client connection for each."""
    pace = pace_of(args)
    gcs = fleet[0].gcs_remote
    lines = [
        f"quadsitl up: {len(fleet)} vehicles, {args.controller or 'each preset'}'s controller, {pace}",
        f"  ground stations: every vehicle streams MAVLink to udp {gcs}"
        + (f"    {on_host(gcs)}mavproxy.py --master=udpin:{client_address(gcs)}" if gcs != "none" else ""),
        "  vehicle  sysid  preset      north,east [m]  gcs link        api link → offboard API (MAVSDK)",
    ]
    for v in fleet:
        api = "none" if v.api_remote == "none" else f"udpin://0.0.0.0:{v.api_remote.rpartition(':')[2]}"
        api += "" if v.api_remote == "none" else f" {on_host(v.api_remote)}".rstrip(": ")
        where = f"{v.offset[0]:6.1f},{v.offset[1]:<7.1f}"
        lines.append(f"  {v.name:7}  {v.system_id:5}  {Path(v.preset).stem[:10]:10}  {where}  {v.gcs_listen:15} "
                     f"{v.api_listen} → {api}")  # fmt: skip
    if not args.no_zenoh:
        lines.append(f"  telemetry:       Zenoh {zenoh_where(args)}, keys quadsitl/<vehicle>/{{state,setpoint,"
                     "actuators,status,mission}")  # fmt: skip
    if not args.no_zenoh:
        lines.append("  wind:            each vehicle's preset and the wind options; change one with JSON on "
                     "quadsitl/<vehicle>/wind")  # fmt: skip
    if dashboard_url:
        lines.append(f"  dashboard:       {dashboard_url}")
    lines.append("  Ctrl-C stops.")
    return "\n".join(lines)


def on_host(remote: str) -> str:
    """``on HOST: `` for a client that runs on another host than the vehicles' (HOST:PORT), else nothing."""
    host = remote.rpartition(":")[0]
    return "" if host.startswith("127.") or host == "localhost" else f"on {host}: "


def client_address(remote: str) -> str:
    """The address a client listens on to hear a link that streams to ``remote``: itself on this host, every
    interface (0.0.0.0) on another."""
    return f"0.0.0.0:{remote.rpartition(':')[2]}" if on_host(remote) else remote


def zenoh_endpoint(args) -> str:
    """Where a subscriber of ``up``'s telemetry connects: the first autopilot's listener, else the router."""
    return args.zenoh_listen or args.zenoh_connect[0]


def zenoh_where(args) -> str:
    """The banner's Zenoh endpoints: the first autopilot's listener and the routers the sessions connect to."""
    routers = getattr(args, "zenoh_connect", None) or []
    via = f"through the router at {', '.join(routers)}" if routers else ""
    config = getattr(args, "zenoh_config", None)
    return " and ".join(w for w in (args.zenoh_listen, via) if w) + (f" (configuration {config})" if config else "")


def describe_wind(w: WindParams) -> str:
    """The wind in a few words, for a banner: ``5 m/s from 270°, light turbulence, a 3 m/s gust from 0° 2 s after
    lift-off``, or ``calm``."""
    parts = [f"{w.speed_m_s:g} m/s from {w.from_deg:g}°"] if w.speed_m_s else []
    if w.turbulence != "none":
        parts.append(f"{w.turbulence} turbulence")
    if w.gust_m_s:
        parts.append(f"a {w.gust_m_s:g} m/s gust from {w.gust_from_deg:g}° {w.gust_start_s:g} s after lift-off")
    if any(w.force_n):
        parts.append(f"a force of ({', '.join(f'{f:g}' for f in w.force_n)}) N, NED")
    return ", ".join(parts) or "calm"


def banner(preset: Preset, args, dashboard_url: str | None = None) -> str:
    kind = args.controller or preset.controller.type
    pace = pace_of(args)
    lines = [f"quadsitl up: preset {preset.name}, {kind} controller, {pace}; system id {args.system_id}"]
    for name, remote, tool in (
        ("ground stations", args.gcs_remote or "127.0.0.1:14550", "mavproxy.py --master=udpin:{}"),
        ("offboard APIs", args.api_remote or "127.0.0.1:14540", "MAVSDK: add_any_connection('udpin://{}')"),
    ):
        if remote.lower() == "none":
            lines.append(f"  {name + ':':17}MAVLink only to whoever talks to the autopilot")
        else:
            lines.append(f"  {name + ':':17}MAVLink to udp {remote}    {tool.format(remote)}")
    if not args.no_zenoh:
        lines.append(
            f"  telemetry:       Zenoh {zenoh_where(args)}, keys quadsitl/v1/{{state,setpoint,actuators,status}}"
        )
    lines.append(f"  wind:            {describe_wind(preset.wind)}"
                 + ("" if args.no_zenoh else "; change it with JSON on the Zenoh key quadsitl/v1/wind"))  # fmt: skip
    if dashboard_url:
        lines.append(f"  dashboard:       {dashboard_url}")
    lines.append("  Ctrl-C stops.")
    return "\n".join(lines)


def fly(preset_name: str, preset: Preset, args) -> int:
    """Run one flight; returns the exit status for the ``quadsitl fly`` command."""
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    plant_port = free_port()
    gcs_port = free_port(avoid={plant_port})
    gcs_listen = free_port(avoid={plant_port, gcs_port})  # three UDP ports none of which is bound yet: distinct
    zenoh_port = free_port(socket.SOCK_STREAM)
    zenoh_ep = f"tcp/127.0.0.1:{zenoh_port}"
    quiet = ["--quiet"] if args.quiet else []
    children = Children(env=signing_env(args.signing_key))
    web_port = dashboard_port(args.dashboard_port) if args.dashboard else None
    if not args.quiet and not cached(READY_FUNCTION):  # the processes compile before their first tick
        print(compiling("fly"), flush=True)

    def flight(_stack: contextlib.ExitStack) -> int:
        ap = ["autopilot", "--preset", preset_name, "--plant-listen", f"127.0.0.1:{plant_port}",
              "--api-listen", f"127.0.0.1:{gcs_port}", "--api-remote", "none", "--gcs-listen",
              f"127.0.0.1:{gcs_listen}", "--gcs-remote", "none", "--zenoh-listen", zenoh_ep,
              "--offboard-lockstep", repr(OFFBOARD_LOCKSTEP), *LOGGED, *quiet]  # fmt: skip
        if args.controller:
            ap += ["--controller", args.controller]
        for item in args.controller_param:
            ap += ["--controller-param", item]
        mission = getattr(args, "mission", None)
        home = ["--home", args.home] if mission and args.home else []
        children.start("autopilot", ap + home + state_argv(args))
        if web_port is not None:
            url = start_dashboard(children, web_port, zenoh_ep)
            print(f"quadsitl fly: dashboard at {url}", flush=True)
        plant = [
            "sitl",
            "--preset",
            preset_name,
            "--autopilot",
            f"127.0.0.1:{plant_port}",
            "--speed",
            str(args.speed),
        ]
        if args.integrator:
            plant += ["--integrator", args.integrator]
        # The vehicle waits on the ground for SENSOR_GROUND_S (on sensors, the estimator aligns in its first second)
        # and the plant's clock holds there until it is armed: every run, and `sim`, start flying at the same tick,
        # and plant and autopilot wait (a datagram every 50 ms) instead of racing through ground ticks on the cores
        # the ground station needs to start (which made the lockstep loops give up polling into the flight). A mission
        # is selected there and then armed, which starts it (groundstation.mission_flight).
        hold = ["--hold-until-armed", repr(SENSOR_GROUND_S)]
        # Once landed and disarmed the flight is over: the clock holds, so the results are written on idle cores
        # (it ran on, both loops polling, until the ground station had written its files and the plant was stopped).
        children.start("plant", plant + wind_argv(args) + state_argv(args) + home + hold + ["--hold-when-landed"]
                       + quiet)  # fmt: skip
        gcs = ["groundstation", "--preset", preset_name, "--connect", f"127.0.0.1:{gcs_port}",
               "--zenoh-connect", zenoh_ep, "--trajectory", args.trajectory, "--out", str(out),
               "--setpoints-ahead", repr(SETPOINTS_AHEAD), *quiet]  # fmt: skip
        gcs += ["--arm-at", repr(SENSOR_GROUND_S)]
        if args.duration:
            gcs += ["--duration", str(args.duration)]
        if mission:
            gcs += ["--mission", str(mission)] + (["--home", args.home] if args.home else [])
        children.start("gcs", gcs)
        status = supervise(children, "quadsitl fly", done="gcs", finished=lambda: children.procs["gcs"].poll() == 0,
                           diverged=lambda _plant: end_diverged(children, out, preset, args))  # fmt: skip
        if status is not None:
            return status
        for name in ("plant", "autopilot", "gcs"):  # the flight is over; a dashboard stays, below
            children.stop(names=[name])
        write_report(out, preset, args)
        if web_port is not None:
            keep_dashboard(children)
        return 0

    return run_supervised(children, "quadsitl fly", flight, functools.partial(flight_interrupted, children, ["gcs"]))


def flight_interrupted(children: Children, gcs: Collection[str], exc: KeyboardInterrupt) -> int:
    """``fly``'s exit status on a stop request (SIGINT or SIGTERM: ``exc``): 0 after the flight, its ground stations
    ``gcs`` done and the dashboard kept showing it (that is how it is closed); else the signal's status, said."""
    if "dashboard" in children.procs and all(children.procs[name].poll() == 0 for name in gcs):
        return 0
    print("quadsitl fly: interrupted; stopping " + ", ".join(children.procs), file=sys.stderr)
    return stop_status(exc)


FLY_DIVERGED = PLANT_DIVERGED  # `quadsitl fly`'s exit status when the plant's state diverged (docs/failures.md)
UP_DIVERGED = PLANT_DIVERGED  # `quadsitl up`'s, when a plant's did


def end_diverged(children: Children, out: Path, preset: Preset, args) -> int:
    """The plant's state left its bounds (the plant ended with PLANT_DIVERGED): let the last telemetry batch
    reach the ground station, stop it (it writes telemetry.csv and flight.tlog with every tick flown), stop the
    autopilot, and write metrics.json with ``diverged`` and ``diverged_at`` [s]: the time of the first tick not
    flown, as the sweeps' batch engine counts it."""
    time.sleep(0.3)  # the autopilot flushes a partial telemetry batch within BATCH_WALL of its last tick
    for name in ("gcs", "autopilot"):
        children.stop(names=[name])
    if not (out / "telemetry.csv").is_file() or len((out / "telemetry.csv").read_text().splitlines()) < 2:
        print("quadsitl fly: the plant's state diverged before the flight began; nothing was flown (exit status "
              f"{FLY_DIVERGED})", file=sys.stderr)  # fmt: skip
        return FLY_DIVERGED
    write_report(out, preset, args, diverged=True)
    return FLY_DIVERGED


def keep_dashboard(children: Children) -> None:
    """After a flight with ``--dashboard``: keep the page up, showing the finished run, until Ctrl-C."""
    print("quadsitl fly: flight done; the dashboard keeps showing it until Ctrl-C", file=sys.stderr, flush=True)
    while children.procs["dashboard"].poll() is None:
        time.sleep(0.2)
    print(f"quadsitl fly: error: {describe('dashboard', children.procs['dashboard'].returncode)}", file=sys.stderr)


def write_report(out: Path, preset: Preset, args, diverged: bool = False) -> None:
    """metrics.json and the figures from telemetry.csv. A position trajectory adds the position tracking
    metrics (printed instead of the step-response table, which its computed attitude references make
    meaningless) and the x–y path figure."""
    import numpy as np  # here, not at the top: `quadsitl --help` should not wait for matplotlib

    from autopilot.flight_log import log_of
    from groundstation import trajectories
    from groundstation.metrics import (
        battery_use,
        estimate_rms,
        format_position_table,
        format_table,
        outputs_from_columns,
        position_metrics,
        run_metrics,
    )
    from groundstation.telemetry_csv import read_csv
    from quadsitl import ulog
    from quadsitl.frames import PX4_HOME

    data = read_csv(out / "telemetry.csv")
    logged = data  # as written: in sensor mode the estimate in x..r, the truth after (the ULog has both)
    t = data["t"]
    sensing = "x_true" in data  # sensor mode: what the vehicle did is the truth; x..r is what the autopilot believed
    if sensing:
        estimate = {c: data[c] for c in ("x", "y", "altitude", "roll", "pitch", "yaw")}
        data = {**data, **{c: data[c + "_true"] for c in ("x", "y", "z", "roll", "pitch", "yaw")},
                "altitude": -data["z_true"]}  # fmt: skip
    y = outputs_from_columns(data["altitude"], data["roll"], data["pitch"], data["yaw"])
    ref = np.column_stack([data[c] for c in ("altitude_ref", "roll_ref", "pitch_ref", "yaw_ref")])
    u = np.column_stack([data[c] for c in ("u1", "u2", "u3", "u4")])
    kind = args.controller or preset.controller.type
    metrics = {kind: run_metrics(t, y, ref, u)}
    settings = {"mode": "lockstep", "speed": args.speed, "duration": float(len(t) * preset.sim.period),
                "period": preset.sim.period, "trajectory": args.trajectory, **wind_settings(preset)}  # fmt: skip
    # diverged_at [s]: the first tick not flown (the plant's state at its start was outside the bounds), the one
    # after the last flown: a tick lost on the way to the logger in between does not move it.
    period = preset.sim.period
    flown = round(float(t[-1]) / period) + 1 if diverged else 0
    report = {"preset": preset.name, **settings, "diverged": diverged,
              "diverged_at": round(flown * period, 9) if diverged else None, "runs": metrics}  # fmt: skip
    if sensing:  # the estimate's error over the flight (RMS), and the sensors flown
        report["state"] = "sensors"
        report["sensors"] = asdict(preset.sensors) if preset.sensors is not None else None
        report["estimate_rms"] = estimate_rms(estimate, data)
    mission = getattr(args, "mission", None)
    trajectory = None if mission else trajectories.make(args.trajectory, preset.reference)
    position = None
    if mission:
        report.update(trajectory=None, mission=str(mission))
    if mission or isinstance(trajectory, trajectories.PositionTrajectory):
        columns = ("x", "y", "x_ref", "y_ref", "altitude", "altitude_ref")
        position = {kind: position_metrics(*(data[c] for c in columns))}
        report["position"] = position
    if (used := battery_use(data)) is not None:
        report["battery"] = used
    (out / "metrics.json").write_text(json.dumps(report, indent=2) + "\n")
    origin = tuple(json.loads((out / "mission.json").read_text())["origin"]) if mission else PX4_HOME
    ulog.write(out / "flight.ulg", log_of(logged, preset, kind, origin, mission=bool(mission)))
    figures: list[Path] = []
    if not args.no_figures:
        from groundstation.figures import write_figures, write_mission_figure, write_path_figure  # matplotlib: slow

        title = f"preset {preset.name}, fly"
        figures = write_figures({kind: {"t": t, "outputs": y, "reference": ref, "inputs": u}}, out, title)
        if mission:
            figures.append(write_mission_figure(out, data, json.loads((out / "mission.json").read_text()),
                                                f"{title}, {mission}"))  # fmt: skip
        elif position is not None:
            planned = np.array([trajectory(float(tk))[:2] for tk in t]).reshape(-1, 2).T
            path = write_path_figure(out, data["x"], data["y"], data["x_ref"], data["y_ref"],
                                     f"{title}, {args.trajectory}", planned=(planned[0], planned[1]))  # fmt: skip
            figures.append(path)
    if diverged:  # said even with --quiet: the flight did not fly its duration
        missing = f" ({flown - len(t)} of them missing from the telemetry)" if len(t) < flown else ""
        print(f"quadsitl fly: the plant's state diverged at t = {report['diverged_at']:.3f} s of the flight "
              f"(telemetry.csv's clock; the plant's counts from its start): {flown} ticks flown{missing}, in {out}/"
              f"telemetry.csv, flight.tlog, flight.ulg and metrics.json (exit status {FLY_DIVERGED})",
              file=sys.stderr)  # fmt: skip
    if not args.quiet:
        print(format_table(metrics) if position is None else format_position_table(position))
        if mission:
            print(mission_summary(json.loads((out / "mission.json").read_text())))
        names = ["telemetry.csv", "flight.tlog", "flight.ulg", "metrics.json", *(["mission.json"] if mission else []),
                 *(f.name for f in figures)]  # fmt: skip
        print(f"wrote {out}/" + ", ".join(names))


def mission_summary(doc: dict) -> str:
    """One line per item: its command and the simulated time it was reached."""
    lines = ["item  command                reached at t [s]"]
    for it in doc["items"]:
        t = it["reached_t"]
        lines.append(f"{it['seq']:>4}  {it['name'] or it['command']!s:<22} {'-' if t is None else f'{t:.2f}':>16}")
    return "\n".join(lines)
