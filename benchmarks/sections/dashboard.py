"""5. the dashboard: the lockstep's tick rate with its page open in headless Chromium against without
(``dashboard_ratio``, ``dashboard_ratio_10x``). It needs Playwright (the test extra) and Debian's Chromium
(:mod:`benchmarks.browser`); without them it is skipped with one line saying what is missing, and the JSON has no
dashboard figures and says why under ``skipped``."""

from __future__ import annotations

import contextlib
import socket
import statistics
import time
from collections.abc import Iterator, Sequence
from pathlib import Path

from benchmarks import machine
from benchmarks.autopilots import GRACE, autopilot_process, run_plant
from benchmarks.browser import missing as browser_missing
from benchmarks.report import Report, steal_since
from benchmarks.sections.base import Context, Section
from quadsitl.children import start_module, stop
from quadsitl.process_util import free_port


@contextlib.contextmanager
def dashboard_page(browser, endpoint: str | Sequence[str]) -> Iterator[object]:
    """``quadsitl dashboard`` on the autopilots' Zenoh sessions (an endpoint, or several), its page open in
    ``browser``."""
    port = free_port(socket.SOCK_STREAM)
    connect = [a for e in ([endpoint] if isinstance(endpoint, str) else endpoint) for a in ("--zenoh-connect", e)]
    dash = start_module("groundstation.dashboard.server", "--port", str(port), *connect, "--quiet")
    page = browser.new_page(viewport={"width": 1400, "height": 1100})
    try:
        end = time.monotonic() + 20
        while True:
            try:
                page.goto(f"http://127.0.0.1:{port}/")
                break
            except Exception:  # Playwright's error while the server is still starting
                if time.monotonic() > end or dash.poll() is not None:
                    raise RuntimeError("the dashboard did not start") from None
                time.sleep(0.2)
        page.wait_for_function("() => quadsitl.updates > 0", timeout=20000)  # connected to the stream
        time.sleep(0.5)  # a page that is open, not one that is loading
        yield page
    finally:
        page.close()
        stop(dash, grace=GRACE)


def bench_dashboard(r: Report, workdir: Path, rounds: int, full: bool) -> dict:
    """Lockstep tick rate with the dashboard serving an open page against the same run without it, in
    pairs run back to back (the dashboard and its page start afresh each time; the browser, with no page
    open, stays: an idle Chromium costs a lockstep nothing measurable): paced at 10× real time (a run one watches),
    and with ``full`` as fast as possible too. The figures are medians of the pairs' ratios: a lockstep that polls on
    both cores drifts from run to run on a shared VM, and pairing and the median keep that drift out of the
    comparison. Returns ``dashboard_ratio_10x`` (and ``dashboard_ratio``)."""
    from benchmarks.browser import chromium
    from groundstation.launcher import LOGGED

    r.section("5. dashboard: lockstep ticks with the page open in headless Chromium, against without")
    out = {}
    # The autopilot as `fly` starts it: its telemetry blocks on a full link (a page that can hold it back)
    with autopilot_process(workdir, extra=LOGGED) as (plant_port, api, endpoint, _pid), chromium() as browser:
        run_plant(plant_port, workdir, 5000, arm=api)  # warm-up
        paced_pairs = rounds + 1 if full else rounds  # the quick form's: the ratio is the only figure its goal reads
        kinds = [("paced at 10x real time", "dashboard_ratio_10x", paced_pairs, 20000, ("--speed", "10"))]
        if full:  # runs of a few seconds: a page updates once a second while a run goes faster than 2x real time
            kinds.insert(0, ("as fast as possible", "dashboard_ratio", 2 * rounds + 1, 60000, ()))
        for label, key, pairs, ticks, extra in kinds:
            alone, watched, redraws = [], [], 0
            for _ in range(pairs):
                alone.append(run_plant(plant_port, workdir, ticks, *extra, arm=api)["ticks_per_s"])
                with dashboard_page(browser, endpoint) as page:
                    watched.append(run_plant(plant_port, workdir, ticks, *extra, arm=api)["ticks_per_s"])
                    seen = page.evaluate("() => ({redraws: quadsitl.redraws, lastT: quadsitl.lastT})")
                # A paced page that saw nothing would measure nothing. As fast as possible, the lockstep pair
                # polls on both cores and the dashboard (SCHED_IDLE by design) may draw only once it is over.
                if extra and (not seen["redraws"] or not seen["lastT"]):
                    raise RuntimeError(f"the dashboard page drew no telemetry during the run: {seen}")
                redraws += seen["redraws"]
            out[key] = statistics.median(w / a for w, a in zip(watched, alone))
            r.add(f"lockstep ticks, {label}, no dashboard (median)", statistics.median(alone), "1/s")
            r.add(f"  with the page open (median of {pairs} pairs' ratios)", statistics.median(watched), "1/s",
                  statistics.median(alone), "no dashboard", ratio=out[key])  # fmt: skip
            r.add("  page redraws during those runs", redraws, "")
    return out


def run(ctx: Context) -> dict[str, object]:
    """The dashboard's ratios over ``--rounds`` (the paced one in the quick form), and ``steal_dashboard``: the
    hypervisor's steal time meanwhile."""
    before = machine.cpu_times()
    out = bench_dashboard(ctx.report, ctx.work, ctx.args.rounds, ctx.full)
    out["steal_dashboard"] = steal_since(ctx.report, before)
    return out


# Optional: ``pip install -e .`` has no test extra, and Chromium is a Debian package.
SECTION = Section("dashboard", run, missing=browser_missing, absent=("dashboard_ratio", "dashboard_ratio_10x"))
