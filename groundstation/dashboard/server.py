"""``quadsitl dashboard``: live telemetry in the browser, fed by Zenoh.

One Zenoh subscriber on ``quadsitl/*/*`` (every vehicle, every stream) hands its samples to a ring
channel in Zenoh's own thread; a task polls it every ``POLL`` seconds and files them into the pure
:class:`~groundstation.dashboard.model.Fleet`, so no Python runs per sample on Zenoh's side and a slow
page can never push back on the vehicle (a full ring drops its oldest samples).

Routes (Starlette on uvicorn):

    GET /               the page (uPlot, vendored under static/vendor/uplot)
    GET /api/vehicles   JSON: every vehicle with its latest state, references, actuators, status, rates
    GET /api/stream     server-sent events: every PUSH seconds (PUSH_FAST while a vehicle runs faster than
                        FAST_RTF × real time), each vehicle's status and its new plot rows
    GET /static/...     the page's scripts and styles

Any number of tabs: each stream keeps its own cursor into the shared, decimated series.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import os
import sys
import time
from collections.abc import AsyncIterator, Sequence
from pathlib import Path

import zenoh

from groundstation.dashboard.model import ROW_FIELDS, Fleet
from quadsitl import telemetry
from quadsitl.cli_util import UsageError, check_range
from quadsitl.process_util import bind_tcp, run_stoppable, start_process

STATIC = Path(__file__).parent / "static"
POLL = 0.02  # [s] wall between drains of the Zenoh ring channel
PUSH = 0.25  # [s] wall between server-sent events to each page (the page redraws on each)...
PUSH_FAST = 1.0  # ...and while a run goes faster than FAST_RTF × real time: such a run wants every core, and
FAST_RTF = 2.0  # the page's work (and this server's) would take ticks from it
MAX_ROWS = 250  # plot rows per vehicle in one update, at most (every n-th when more are new)
RING = 16384  # samples the ring channel holds between drains (≈ 4 s of a 1 kHz run's four streams)
DEFAULT_CONNECT = "tcp/127.0.0.1:7447"  # where `quadsitl up` listens


class Dashboard:
    """The shell around the fleet model: the Zenoh subscriber and the per-page update builder."""

    def __init__(self, session: zenoh.Session, fleet: Fleet) -> None:
        self.session = session
        self.fleet = fleet
        self.sub = session.declare_subscriber(f"{telemetry.PREFIX}/*/*", zenoh.handlers.RingChannel(RING))
        self.stopping = False

    def drain(self) -> int:
        """File every sample waiting in the ring; returns how many."""
        n, now, ingest, recv = 0, time.monotonic(), self.fleet.ingest, self.sub.try_recv
        while (sample := recv()) is not None:
            ingest(str(sample.key_expr), sample.payload.to_bytes(), now)
            n += 1
        return n

    async def poll(self) -> None:
        while not self.stopping:
            self.drain()
            await asyncio.sleep(POLL)

    def push_interval(self) -> float:
        """Wall seconds until a page's next update: PUSH, or PUSH_FAST while any vehicle runs fast."""
        now = time.monotonic()
        fast = any((v.summary(now)["real_time_factor"] or 0.0) > FAST_RTF for v in self.fleet.vehicles.values())
        return PUSH_FAST if fast else PUSH

    def update(self, cursors: dict[str, tuple[int, int]]) -> dict:
        """What a page has not seen yet: each vehicle's summary and the plot rows after its cursor
        (generation, seq), as columns. ``reset`` tells the page to drop what it drew for that vehicle."""
        now = time.monotonic()
        out = []
        for name, v in sorted(self.fleet.vehicles.items()):
            gen, seq = cursors.get(name, (-1, 0))
            reset = gen != v.generation
            rows = v.rows_since(0 if reset else seq)
            if len(rows) > MAX_ROWS:  # a run faster than the eye: thin what this update carries
                rows = rows[:: -(-len(rows) // MAX_ROWS)]
            cursors[name] = (v.generation, v.seq)
            cols = {f: [round(r[i], 5) for r in rows] for i, f in enumerate(ROW_FIELDS)}
            out.append({**v.summary(now), "reset": reset, "rows": cols})
        return {"vehicles": out, "fields": ROW_FIELDS}


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

    hello = {"window": dash.fleet.window, "plot_rate": dash.fleet.plot_rate, "fields": ROW_FIELDS}

    async def stream(request: Request) -> StreamingResponse:
        async def events() -> AsyncIterator[str]:
            cursors: dict[str, tuple[int, int]] = {}
            yield f"event: hello\ndata: {json.dumps(hello)}\n\n"
            while not dash.stopping and not await request.is_disconnected():
                yield f"data: {json.dumps(_json_safe(dash.update(cursors)), separators=(',', ':'))}\n\n"
                await asyncio.sleep(dash.push_interval())

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
        session = zenoh.open(telemetry.config_from_args(args))
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
        server.run(sockets=[sock])
    finally:
        dash.stopping = True
        with contextlib.suppress(Exception):
            dash.sub.undeclare()
        session.close()
        sock.close()
    return 0


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
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return serve(args)
    except UsageError as exc:
        print(f"{parser.prog}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:  # SIGINT or SIGTERM (StopRequested): it serves until stopped, so that is its end
        return 0


if __name__ == "__main__":
    sys.exit(run_stoppable(main))
