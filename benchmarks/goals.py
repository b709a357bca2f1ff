"""The goals ``quadsitl bench`` checks, each against what this run measured (:func:`check`): a goal is met when it
holds in each of three whole runs back to back (docs/performance.md#method), so the report says, run by run, which it
checked, on which figure, against which baseline of the same run, and which it could not check (its section did not
run, or ran in the quick form).

One table, :data:`GOALS`: the project's open performance goals (docs/performance.md#goals)."""

from __future__ import annotations

import sys
from collections.abc import Callable, Mapping
from dataclasses import dataclass

QUICK_RUN_S = 120.0  # the default run's wall time [s] (docs/performance.md#goals)
FLEET = 32  # the fleet the goals are for: in real time, and in lockstep at its size or more [vehicles]


@dataclass(frozen=True)
class Goal:
    """``key`` of the JSON report at least (``at_least``) or at most ``bound``; ``against``: the baseline it is
    measured against in the same run (or what the figure is, when absolute); ``unless``: why this run cannot check it,
    or None (given the report and whether every section ran)."""

    key: str
    bound: float
    at_least: bool
    against: str
    unless: Callable[[Mapping[str, object], bool], str | None] = lambda report, whole: None

    def text(self) -> str:
        return f"{self.key} {'>=' if self.at_least else '<='} {self.bound:g}"


def _below_fleet(report: Mapping[str, object], whole: bool) -> str | None:
    size = report.get("fleet_lockstep_size")
    return None if isinstance(size, int) and size >= FLEET else f"the largest fleet measured had {size} vehicles"


def _not_quick(report: Mapping[str, object], whole: bool) -> str | None:
    return None if report.get("scope") == "quick" and whole else "only a default run of every section checks it"


# fmt: off
GOALS: tuple[Goal, ...] = (
    Goal("lockstep_ratio", 0.75, True, "fly's ticks/s over the fastest bare UDP ping-pong of this run"),
    Goal("batch_full_vehicle_steps_per_s", 2e7, True, "vehicle-steps/s on every core (the paper's law alone is "
         "batch_steps_per_s)"),
    Goal("fleet_max_realtime", FLEET, True, "vehicles at 1 kHz, each under 1 % of its periods missed (the floor of "
         "this run: fleet_floor_miss_ratio)"),
    Goal("fleet_max_realtime_fifo", FLEET, True, "the same under SCHED_FIFO (fleet_floor_miss_ratio_fifo)"),
    Goal("fleet_memory_per_vehicle_mb", 40, False, "resident memory per vehicle in the largest fleet in lockstep, "
         "hosted in one process (a process each: fleet_processes_memory_per_vehicle_mb)"),
    Goal("fleet_lockstep_ratio", 0.9, True, "the largest fleet's vehicle-ticks/s in lockstep, hosted in one process, "
         f"over one vehicle's of this run, at {FLEET} vehicles or more", _below_fleet),
    Goal("fanout_ratio_10", 0.8, True, "lockstep ticks/s with 10 Zenoh subscribers over none, this run"),
    Goal("first_run_s", 20, False, "`quadsitl fly --duration 1` with numba's cache empty, end to end [s]"),
    Goal("dashboard_ratio_10x", 0.97, True, "lockstep at 10x real time with the dashboard open over without, "
         "in pairs"),
    Goal("elapsed_s", QUICK_RUN_S, False, "the default run's wall time [s], every section in its quick form",
         _not_quick),
)
# fmt: on


def check(report: Mapping[str, object], whole: bool) -> list[dict[str, object]]:
    """Each goal of :data:`GOALS` against ``report`` (the JSON report's keys; ``whole``: every section ran): its
    figure's value and whether it is met, or ``met`` None and why it was not checked."""
    out = []
    for goal in GOALS:
        value = report.get(goal.key)
        row: dict[str, object] = {"goal": goal.text(), "key": goal.key, "bound": goal.bound, "against": goal.against,
                                  "value": value, "met": None}  # fmt: skip
        if not isinstance(value, (int, float)) or isinstance(value, bool):
            quick = report.get("scope") == "quick"
            row["why_not_checked"] = "not measured in this run" + (" (--full measures it)" if quick else "")
        elif (why := goal.unless(report, whole)) is not None:
            row["why_not_checked"] = why
        else:
            row["met"] = value >= goal.bound if goal.at_least else value <= goal.bound
        out.append(row)
    return out


def print_goals(rows: list[dict[str, object]]) -> None:
    """The goals' verdicts on stderr, one line each, after the figures."""
    print("\ngoals (each must hold in three whole runs back to back; docs/performance.md#goals):", file=sys.stderr)
    for row in rows:
        if row["met"] is None:
            verdict = f"not checked: {row['why_not_checked']}"
        else:
            verdict = f"{row['value']:,.4g}: {'met' if row['met'] else 'NOT met'}"
        print(f"  {row['goal']:40s} {verdict}   ({row['against']})", file=sys.stderr)
