"""``quadsitl dashboard``: live telemetry in the browser, fed by Zenoh.

Zenoh subscribers hand their samples to ring channels in Zenoh's own threads; a task polls them every ``POLL``
seconds and files them into the pure :class:`~groundstation.dashboard.model.Fleet`, so no Python runs per sample
on Zenoh's side and a slow page can never push back on the vehicle (a full ring drops its oldest samples). Every
vehicle is followed through its overview (``quadsitl/*/slow/*``: the newest record of each stream, in one sample 20
times a second, :data:`quadsitl.telemetry.SLOW`), its mission and its info; only a vehicle a page shows is followed
at the full rate (``quadsitl/<vehicle>/*``, while a page shows it). A publisher sends only where a subscriber
matches, so the other vehicles' full-rate streams stay in their autopilots: with the page open, a fleet's autopilots
spend what they would without it.

Routes (Starlette on uvicorn):

    GET /               the page (uPlot, vendored under static/vendor/uplot)
    GET /api/vehicles   JSON: every vehicle with its latest state, references, actuators, status, rates,
                        system id and home
    GET /api/fleet      JSON: the fleet view: the origin, every vehicle's status, pose, home offset and trail
    GET /api/stream     server-sent events: every PUSH seconds (PUSH_FAST while a vehicle runs faster than
                        FAST_RTF × real time), the fleet view with each vehicle's new trail points, and with
                        ``?vehicle=NAME`` that vehicle's full status and its new plot rows (the other vehicles'
                        plot rows never go out: the fleet costs a page a few points per vehicle per update)
    GET /static/...     the page's scripts and styles

Any number of tabs: each stream keeps its own cursors into the shared, decimated series and trails.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import math
import os
import signal
import sys
import time
from collections.abc import AsyncIterator, Sequence
from pathlib import Path

import zenoh

from groundstation.dashboard.model import MAX_VEHICLES, ROW_FIELDS, STALE_AFTER, Fleet
from groundstation.vehicle_info import INFO
from quadsitl import telemetry
from quadsitl.cli_util import UsageError, check_range, serve_until_stopped
from quadsitl.process_util import bind_tcp, run_stoppable, start_process

STATIC = Path(__file__).parent / "static"
POLL = 0.02  # [s] wall between drains of the Zenoh ring channel
PUSH = 0.25  # [s] wall between server-sent events to each page (the page redraws on each)...
PUSH_FAST = 1.0  # ...and while a run goes faster than FAST_RTF × real time: such a run wants every core, and
FAST_RTF = 2.0  # the page's work (and this server's) would take ticks from it
MAX_ROWS = 250  # plot rows per vehicle in one update, at most (every n-th when more are new)
MAX_TRAIL = 500  # trail points per vehicle in one update, at most (a long --window: every n-th)
RING = 16384  # samples the ring channel holds between drains (≈ 4 s of a 1 kHz run's four streams)
DEFAULT_CONNECT = "tcp/127.0.0.1:7447"  # where `quadsitl up` listens


def ts_seconds(ts: zenoh.Timestamp) -> float:
    """A Zenoh timestamp [s since the epoch, the publisher's clock]."""
    return ts.get_time().timestamp()


class Dashboard:
    """The shell around the fleet model: the Zenoh subscriber and the per-page update builder."""

    def __init__(self, session: zenoh.Session, fleet: Fleet) -> None:
        self.session = session
        self.fleet = fleet
        p = telemetry.PREFIX
        self.subs = [session.declare_subscriber(k, zenoh.handlers.RingChannel(RING))
                     for k in (f"{p}/*/{telemetry.SLOW}/*", f"{p}/*/{telemetry.MISSION}", f"{p}/*/{INFO}")]  # fmt: skip
        self.watched: dict[str, list] = {}  # name: [its full-rate subscriber, pages showing it]
        self.stopping = False
        self.said: dict[str, str | None] = {}  # the info refusal last reported on stderr, per vehicle

    def drain(self) -> int:
        """File every sample waiting in the rings; returns how many."""
        n, now, ingest = 0, time.monotonic(), self.fleet.ingest
        for sub in (*self.subs, *(w[0] for w in self.watched.values())):
            recv = sub.try_recv
            while (sample := recv()) is not None:
                ts = sample.timestamp  # when it was published (telemetry.zenoh_config stamps it), if it says
                ingest(str(sample.key_expr), sample.payload.to_bytes(), now, None if ts is None else ts_seconds(ts))
                n += 1
        return n

    def watch(self, name: str) -> bool:
        """A page shows vehicle ``name``: follow it at the full rate (one subscriber, however many pages). False
        when ``name`` cannot be a key chunk, or MAX_VEHICLES are followed already."""
        w = self.watched.get(name)
        if w is None:
            if not name or any(c in name for c in "/*$#?") or len(self.watched) >= MAX_VEHICLES:
                return False
            try:
                sub = self.session.declare_subscriber(telemetry.key(name, "*"), zenoh.handlers.RingChannel(RING))
            except zenoh.ZError:
                return False
            w = self.watched[name] = [sub, 0]
        w[1] += 1
        return True

    def unwatch(self, name: str) -> None:
        """A page stopped showing ``name``; the last one lets its full rate go (its overview takes over at once)."""
        w = self.watched.get(name)
        if w is None:
            return
        w[1] -= 1
        if w[1] <= 0:
            del self.watched[name]
            with contextlib.suppress(zenoh.ZError):
                w[0].undeclare()
            if name in self.fleet.vehicles:
                self.fleet.vehicles[name].full_wall = -math.inf

    def ask_info(self) -> None:
        """Ask for every vehicle's info document now (``quadsitl up`` answers; others put it once a second)."""
        with contextlib.suppress(zenoh.ZError):
            for reply in self.session.get(f"{telemetry.PREFIX}/*/{INFO}", timeout=2.0):
                if reply.ok is not None:
                    self.fleet.ingest(str(reply.ok.key_expr), reply.ok.payload.to_bytes(), time.monotonic())

    def report_refusals(self) -> None:
        """A refused info document said once on stderr (per vehicle and reason), and on the page."""
        for name, v in self.fleet.vehicles.items():
            if v.info_error != self.said.get(name):
                self.said[name] = v.info_error
                if v.info_error:
                    print(f"quadsitl dashboard: {telemetry.PREFIX}/{name}/{INFO} refused: {v.info_error}",
                          file=sys.stderr, flush=True)  # fmt: skip

    async def poll(self) -> None:
        with contextlib.suppress(Exception):  # the answers to a get arrive on Zenoh's threads: not on the loop
            await asyncio.to_thread(self.ask_info)
        while not self.stopping:
            self.drain()
            self.report_refusals()
            await asyncio.sleep(POLL)

    def push_interval(self) -> float:
        """Wall seconds until a page's next update: PUSH, or PUSH_FAST while any live vehicle runs fast."""
        now = time.monotonic()
        fast = any(
            now - v.last_wall <= STALE_AFTER and (v.rates()[1] or 0.0) > FAST_RTF for v in self.fleet.vehicles.values()
        )
        return PUSH_FAST if fast else PUSH

    def update(self, cursors: dict, selected: str | None = None) -> dict:
        """What a page has not seen yet: the fleet view (:meth:`Fleet.fleet_view`) with each vehicle's trail
        points after its cursor, and for the ``selected`` vehicle (None: none) its summary and the plot rows
        after its cursor (generation, seq), as columns. ``reset`` tells the page to drop what it drew for that
        vehicle (its trail, its rows)."""
        now = time.monotonic()
        view = self.fleet.fleet_view(now)
        for entry in view["vehicles"]:
            v = self.fleet.vehicles[entry["name"]]
            gen, seq = cursors.get(("trail", v.name), (-1, 0))
            reset = gen != v.generation
            pts = v.trail_since(0 if reset else seq)
            if len(pts) > MAX_TRAIL:
                pts = pts[:: -(-len(pts) // MAX_TRAIL)]
            cursors["trail", v.name] = (v.generation, v.trail_seq)
            entry["trail"] = {"reset": reset, "t": [round(p[0], 3) for p in pts],
                              "x": [round(p[1], 3) for p in pts], "y": [round(p[2], 3) for p in pts]}  # fmt: skip
        vehicle = None
        v = self.fleet.vehicles.get(selected) if selected else None
        if v is not None:
            gen, seq = cursors.get(v.name, (-1, 0))
            reset = gen != v.generation
            rows = v.rows_since(0 if reset else seq)
            if len(rows) > MAX_ROWS:  # a run faster than the eye: thin what this update carries
                rows = rows[:: -(-len(rows) // MAX_ROWS)]
            cursors[v.name] = (v.generation, v.seq)
            cols = {f: [round(r[i], 5) for r in rows] for i, f in enumerate(ROW_FIELDS)}
            vehicle = {**v.summary(now), "reset": reset, "rows": cols}
        return {"fleet": view, "vehicle": vehicle, "fields": ROW_FIELDS}

    def fleet_json(self) -> dict:
        """``/api/fleet``: the fleet view with every vehicle's whole trail."""
        view = self.fleet.fleet_view(time.monotonic())
        for entry in view["vehicles"]:
            pts = self.fleet.vehicles[entry["name"]].trail_since(0)
            entry["trail"] = {"t": [p[0] for p in pts], "x": [p[1] for p in pts], "y": [p[2] for p in pts]}
        return view


def _json_safe(obj):
    """NaN and infinities are not JSON: they go out as null."""
    if isinstance(obj, float):
        return obj if obj == obj and abs(obj) != float("inf") else None
    if isinstance(obj, dict):
        return {k: _json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_json_safe(v) for v in obj]
    return obj


def make_app(dash: Dashboard):
    """The Starlette app serving the page, the JSON endpoint and the event stream."""
    from starlette.applications import Starlette
    from starlette.requests import Request
    from starlette.responses import FileResponse, JSONResponse, StreamingResponse
    from starlette.routing import Mount, Route
    from starlette.staticfiles import StaticFiles

    async def index(_request: Request) -> FileResponse:
        return FileResponse(STATIC / "index.html", headers={"Cache-Control": "no-cache"})

    async def vehicles(_request: Request) -> JSONResponse:
        return JSONResponse(_json_safe({"vehicles": dash.fleet.summaries(time.monotonic())}))

    async def fleet(_request: Request) -> JSONResponse:
        return JSONResponse(_json_safe(dash.fleet_json()))

    hello = {"window": dash.fleet.window, "plot_rate": dash.fleet.plot_rate, "fields": ROW_FIELDS}

    async def stream(request: Request) -> StreamingResponse:
        selected = request.query_params.get("vehicle") or None  # a name the fleet lacks: no plot rows

        async def events() -> AsyncIterator[str]:
            cursors: dict = {}
            watching = selected is not None and dash.watch(selected)  # its full rate while this page shows it
            try:
                yield f"event: hello\ndata: {json.dumps(hello)}\n\n"
                while not dash.stopping and not await request.is_disconnected():
                    update = dash.update(cursors, selected)
                    yield f"data: {json.dumps(_json_safe(update), separators=(',', ':'))}\n\n"
                    await asyncio.sleep(dash.push_interval())
            finally:
                if watching:
                    dash.unwatch(selected)

        return StreamingResponse(
            events(), media_type="text/event-stream", headers={"Cache-Control": "no-cache", "X-Accel-Buffering": "no"}
        )

    @contextlib.asynccontextmanager
    async def lifespan(_app):
        task = asyncio.create_task(dash.poll())
        try:
            yield
        finally:
            dash.stopping = True
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await task

    return Starlette(
        routes=[
            Route("/", index),
            Route("/api/vehicles", vehicles),
            Route("/api/fleet", fleet),
            Route("/api/stream", stream),
            Mount("/static", StaticFiles(directory=STATIC), name="static"),
        ],
        lifespan=lifespan,
    )


EXAMPLES = """examples:
  quadsitl dashboard                                   # the vehicle of `quadsitl up`, at http://127.0.0.1:8050
  quadsitl dashboard --port 0                          # any free port (the URL is printed)
  quadsitl dashboard --zenoh-connect tcp/10.0.0.5:7447 --host 0.0.0.0
  quadsitl fly --dashboard --speed 1                   # starts one alongside a flight
  quadsitl replay runs/fly/telemetry.csv --zenoh-listen tcp/127.0.0.1:7447   # an old run, then open the page
"""


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="quadsitl dashboard",
        description="Serve a live telemetry dashboard: every vehicle seen on Zenoh, its altitude and attitude "
        "against their references, tracking errors, u1..u4, motor forces, x/y and a status panel. "
        f"Without Zenoh options it connects to {DEFAULT_CONNECT}, where `quadsitl up` listens.",
        epilog=EXAMPLES,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--host", default="127.0.0.1", help="address to serve on (default: 127.0.0.1, this machine only)")
    p.add_argument("--port", type=int, default=8050, help="TCP port to serve on (default: 8050; 0 = any free port)")
    p.add_argument("--window", type=float, default=20.0, metavar="S", help="simulated seconds shown (default 20)")
    p.add_argument(
        "--plot-rate", type=float, default=50.0, metavar="HZ", help="plotted rows per simulated second (default 50)"
    )
    p.add_argument("--quiet", "-q", action="store_true", help="print only errors")
    telemetry.add_zenoh_arguments(p, vehicle=False)
    return p


def serve(args: argparse.Namespace) -> int:
    import uvicorn

    check_range("--window", args.window, 1.0, 3600.0)
    check_range("--plot-rate", args.plot_rate, 1.0, 1000.0)
    if not 0 <= args.port <= 65535:
        raise UsageError(f"--port {args.port}: expected 0..65535")
    if not (args.zenoh_connect or args.zenoh_listen or args.zenoh_config):
        args.zenoh_connect = [DEFAULT_CONNECT]
    sock = bind_tcp("--port", str(args.port), args.host, args.port, "(0 picks a free one)", host_option="--host")
    try:
        session = zenoh.open(telemetry.config_from_args(args))  # no shared memory: its rings would hold the pool
    except zenoh.ZError as exc:
        sock.close()
        raise UsageError(f"cannot open the Zenoh session: {exc}") from None
    dash = Dashboard(session, Fleet(args.plot_rate, args.window))
    host, port = sock.getsockname()[:2]
    config = uvicorn.Config(make_app(dash), log_level="warning", access_log=False,
                            timeout_graceful_shutdown=1, lifespan="on")  # fmt: skip
    server = uvicorn.Server(config)
    if not args.quiet:
        where = ", ".join(args.zenoh_connect or args.zenoh_listen or [args.zenoh_config])
        print(f"quadsitl dashboard: http://{host}:{port}/  (Zenoh {where}; Ctrl-C stops)", flush=True)
    try:
        run_server(server, sock)
    finally:
        dash.stopping = True
        for sub in (*dash.subs, *(w[0] for w in dash.watched.values())):
            with contextlib.suppress(Exception):
                sub.undeclare()
        session.close()
        sock.close()
    return 0


def run_server(server, sock) -> None:
    """``server.run(sockets=[sock])``, with its event loop made while SIGINT and SIGTERM wait: a stop request in
    the middle of the loop's construction left a half-made loop whose clean-up printed a traceback at exit (seen
    once in CI). A stop that came meanwhile is raised as soon as the loop is whole, and the Runner closes it."""
    stops = {signal.SIGINT, signal.SIGTERM}
    with asyncio.Runner(loop_factory=server.config.get_loop_factory()) as runner:
        old = signal.pthread_sigmask(signal.SIG_BLOCK, stops)
        try:
            runner.get_loop()
        finally:
            signal.pthread_sigmask(signal.SIG_SETMASK, old)
        runner.run(server.serve(sockets=[sock]))


def yield_to_the_vehicle() -> None:
    """Run at idle priority (Linux SCHED_IDLE; elsewhere nice 19): the dashboard gets only the CPU time that
    the plant and the autopilot leave, and their wake-ups always preempt it. On a 2-core machine a lockstep
    run keeps both cores busy, so a dashboard at normal priority would cost the vehicle ticks."""
    try:
        os.sched_setscheduler(0, os.SCHED_IDLE, os.sched_param(0))
    except (AttributeError, OSError):
        with contextlib.suppress(OSError):
            os.nice(19)


def main(argv: Sequence[str] | None = None) -> int:
    start_process(quiet_gc=False)
    yield_to_the_vehicle()
    return serve_until_stopped(build_parser(), serve, argv)


if __name__ == "__main__":
    sys.exit(run_stoppable(main, name="quadsitl dashboard"))
