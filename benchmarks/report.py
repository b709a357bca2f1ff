"""``quadsitl bench``'s report: every figure with its unit and the baseline measured beside it in the same run, printed
on stderr as it comes and, with ``--json``, written as one JSON document on stdout at the end."""

from __future__ import annotations

import sys
from collections.abc import Mapping
from dataclasses import asdict, dataclass

from benchmarks import machine


@dataclass
class Figure:
    """One measured figure: ``value`` in ``unit``, against ``baseline`` (the same unit, measured in the same run, named
    ``baseline_name``), and their ``ratio`` (value / baseline unless given otherwise)."""

    name: str
    value: float
    unit: str
    baseline: float | None = None
    baseline_name: str = ""
    ratio: float | None = None


class Report:
    """The figures of a run in the order measured; each printed on stderr as it is added unless ``quiet``."""

    def __init__(self, quiet: bool) -> None:
        self.figures: list[Figure] = []
        self.quiet = quiet

    def add(self, name: str, value: float, unit: str, baseline: float | None = None, baseline_name: str = "",
            ratio: float | None = None) -> Figure:  # fmt: skip
        """A figure, its ratio to ``baseline`` computed when not given (and the baseline is not 0 or None)."""
        if ratio is None and baseline:
            ratio = value / baseline
        f = Figure(name, value, unit, baseline, baseline_name, ratio)
        self.figures.append(f)
        if not self.quiet:
            base = f"   baseline {baseline:,.6g} ({baseline_name})" if baseline is not None else ""
            rat = f"   ratio {ratio:.3g}" if ratio is not None else ""
            print(f"  {name:46s} {value:>12,.6g} {unit:10s}{base}{rat}", file=sys.stderr, flush=True)
        return f

    def section(self, title: str) -> None:
        """A section's title, before its figures."""
        if not self.quiet:
            print(f"\n{title}", file=sys.stderr, flush=True)

    def document(self, ratio: float | None, extra: Mapping[str, object], elapsed: float, host: dict,
                 skipped: Mapping[str, tuple[str, tuple[str, ...]]]) -> dict[str, object]:  # fmt: skip
        """The JSON report: ``lockstep_ratio``, the sections' own keys (``extra``), ``elapsed_s``, ``machine``, every
        figure, and ``skipped`` {section: its reason and the keys absent} when a section did not run (``skipped``:
        {section: (why, the keys it would have written)})."""
        report = {"lockstep_ratio": ratio, **extra, "elapsed_s": elapsed, "machine": host,
                  "figures": [asdict(f) for f in self.figures]}  # fmt: skip
        if skipped:  # their figures are absent, not zero: say why
            report["skipped"] = {part: {"reason": why, "absent": list(absent)}
                                 for part, (why, absent) in skipped.items()}  # fmt: skip
        return report


def summary(ratio: float | None, elapsed: float, host: dict, took: Mapping[str, float]) -> None:
    """The last lines on stderr: each section's wall time (``took`` [s]), then ``lockstep_ratio`` (when the lockstep
    section ran), the run's length [s] and the machine (:func:`benchmarks.machine.describe`)."""
    sections = ", ".join(f"{name} {s:.0f}" for name, s in took.items())
    ratio_text = f"lockstep_ratio = {ratio:.3f} against the fastest ping-pong; " if ratio is not None else ""
    print(f"\nsections [s]: {sections}\n{ratio_text}{elapsed:.0f} s on {machine.one_line(host)}", file=sys.stderr)


def steal_since(r: Report, before: tuple[int, int]) -> float:
    """The hypervisor's share of CPU time since ``before`` (:func:`benchmarks.machine.cpu_times`), added as the
    section's last figure: on a virtual machine the same section can differ widely in two runs back to back, and a
    host busy elsewhere is one reason to tell."""
    steal = machine.steal_ratio(before, machine.cpu_times())
    r.add("  the hypervisor's steal time during the section", steal, "ratio")
    return steal
