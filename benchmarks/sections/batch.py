"""6. the sweeps' batch engine: vehicle-steps per second of ``quadsitl sweep``'s engine (the paper's controller and
plant, 5 s trials), in one process and over one worker process per core, against ``quadsitl sim``'s compiled loop of
the whole vehicle on the same step; and that loop on the x500's circle (``sim_circle_steps_per_s``); with ``--full``
also on sensors, beside a sweep on sensors."""

from __future__ import annotations

import dataclasses
import os
import time

from benchmarks.report import Report
from benchmarks.sections.base import Context, Section

FULL_VEHICLE = """
preset = "{preset}"
trajectory = "hold:altitude=5,duration=5"
trials = {trials}
[vary]
mismatch.mass = {{ dist = "uniform", low = 0.8, high = 1.2 }}
mismatch.inertia = {{ dist = "uniform", low = 0.8, high = 1.2 }}
"""


def bench_batch(r: Report, trials: int, full_run: bool) -> dict:
    """Vehicle-steps per second of the sweeps' batch engine on the paper's controller and plant (the
    paper-mass-mismatch spec: the paper's step, ±20 % mass and inertia mismatch, 5 s per trial), in this process
    and over one worker process per core, against ``quadsitl sim``'s loop of the whole vehicle
    (:mod:`groundstation.vehicle`: the autopilot's tick and the plant's, compiled) on the same step, measured in
    the same run; that loop on the x500's circle (position loop and limits, truth, calm air), and with ``full_run``
    on its sensors (the x500-wind-hold spec's hold, through the estimator), beside that spec's sweep."""
    from groundstation.offline import run_offline
    from groundstation.sweep.run import fly, run_sweep, warm_up
    from groundstation.sweep.spec import load_spec, parse_spec
    from quadsitl.config import load_preset

    r.section("6. sweeps: the batch engine (paper's controller and plant) against quadsitl sim's vehicle loop")
    spec = load_spec("paper-mass-mismatch")
    warm_up()
    x500 = load_preset("x500")
    run_offline(spec.preset, ["backstepping"], 0.01)  # compiled, or loaded from the cache, before timing
    run_offline(x500, ["backstepping"], 0.01, trajectory="circle")

    def sim_rate(preset, seconds: float, trajectory: str) -> tuple[float, float]:
        """(the flight's steps/s in the compiled loop alone, end to end: the vehicle built, the setpoints made)"""
        flight = []
        start = time.perf_counter()
        run_offline(preset, ["backstepping"], seconds, progress=lambda s: flight.append(time.perf_counter()),
                    trajectory=trajectory)  # fmt: skip
        ticks = round(seconds / preset.sim.period)
        return ticks / (flight[-1] - flight[0]), ticks / (time.perf_counter() - start)

    scalar = max(sim_rate(spec.preset, 5.0, "step") for _ in range(3))
    circle = max(sim_rate(x500, 27.5, "circle") for _ in range(3))
    one = []
    n = max(trials // 8, 50)
    for _ in range(3):
        start = time.perf_counter()
        fly(spec, range(n))
        one.append(n * spec.ticks / (time.perf_counter() - start))
    workers = os.cpu_count() or 1
    big = spec.with_trials(trials)
    start = time.perf_counter()
    result = run_sweep(big, workers=workers)
    wall = time.perf_counter() - start
    many = result.ticks_flown / result.wall_s  # the flights, workers started and warm: what `quadsitl sweep` reports
    # The whole vehicle on the fused loop: a position hold (the position loop, its limits and integrals), truth,
    # calm, the model's mass and inertias off by up to ±20 %, on the paper's plant (Euler) and on the x500 (RK4).
    full = {}
    for name in ("paper", "x500"):
        held = parse_spec(FULL_VEHICLE.format(preset=name, trials=max(trials // 10, 200)), f"{name}-hold")
        warm_up(held)
        done = run_sweep(held, workers=workers)
        full[name] = done.ticks_flown / done.wall_s
    r.add("quadsitl sim's vehicle loop, paper step", scalar[0], "steps/s", scalar[1], "end to end")
    r.add("quadsitl sim's vehicle loop, x500 circle (truth, calm)", circle[0], "steps/s", circle[1], "end to end")
    r.add("batch engine, this process", max(one), "steps/s", scalar[0], "sim's vehicle loop")
    r.add(f"batch engine, {workers} worker processes ({trials} trials)", many, "steps/s", max(one), "one process")
    r.add(f"  {trials} trials of 5 s: the flights / end to end with the workers' start", result.wall_s, "s", wall,
          "end to end")  # fmt: skip
    r.add(f"batch engine, the whole vehicle (a hold: position loop, limits; truth, calm), paper's plant, {workers} "
          "workers", full["paper"], "steps/s", many, "the paper's law alone")  # fmt: skip
    r.add(f"  the same on the x500 (RK4), {workers} workers", full["x500"], "steps/s", many, "the paper's law alone")
    out = {"batch_steps_per_s": many, "batch_steps_per_s_one_process": max(one), "scalar_steps_per_s": scalar[0],
           "sim_circle_steps_per_s": circle[0], "sim_circle_steps_per_s_end_to_end": circle[1],
           "batch_full_vehicle_steps_per_s": full["paper"],
           "batch_full_vehicle_x500_steps_per_s": full["x500"]}  # fmt: skip
    return out | (bench_sensors(r, sim_rate, workers) if full_run else {})


def bench_sensors(r: Report, sim_rate, workers: int) -> dict:
    """``quadsitl sim``'s loop on the x500-wind-hold spec's first trial (sensors, the estimator, wind), against that
    spec's sweep over ``workers`` processes, in wind and in calm air."""
    from groundstation.sweep.run import run_sweep
    from groundstation.sweep.spec import load_spec
    from groundstation.sweep.trials import trial_preset

    wind = load_spec("x500-wind-hold")  # on sensors, through the estimator, in wind: each trial a sim flight
    hold = max(sim_rate(trial_preset(wind, 0), wind.duration, wind.trajectory) for _ in range(2))
    sensed = run_sweep(wind, workers=workers)
    # the same hold in calm air: the figure for sensors and the estimator (docs/sweeps.md#speed)
    calm = dataclasses.replace(wind, vary={k: v for k, v in wind.vary.items() if not k.startswith("wind.")})
    calm_sensed = run_sweep(calm.with_trials(120), workers=workers)
    r.add("quadsitl sim's vehicle loop, x500-wind-hold's trial 0 (sensors, wind)", hold[0], "steps/s", hold[1],
          "end to end")  # fmt: skip
    r.add(f"sweep on sensors, {workers} workers (x500-wind-hold, {wind.trials} trials)",
          sensed.ticks_flown / sensed.wall_s, "steps/s", hold[0], "sim's loop")  # fmt: skip
    r.add(f"  the same in calm air, {workers} workers (120 trials)", calm_sensed.ticks_flown / calm_sensed.wall_s,
          "steps/s", hold[0], "sim's loop, in wind")  # fmt: skip
    return {
        "sim_sensors_steps_per_s": hold[0],
        "sensor_sweep_steps_per_s": sensed.ticks_flown / sensed.wall_s,
        "sensor_sweep_calm_steps_per_s": calm_sensed.ticks_flown / calm_sensed.wall_s,
    }


def run(ctx: Context) -> dict[str, object]:
    """A sweep of ``--batch-trials`` trials: the section's steps per second (:func:`bench_batch`; on sensors with
    ``--full``)."""
    return bench_batch(ctx.report, ctx.args.batch_trials, ctx.full)


# It compiles in this process (the sweep's warm-up), not in the processes the bench starts.
SECTION = Section("batch", run, compiled=False)
