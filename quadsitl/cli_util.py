"""Small helpers every command line uses: one-line errors and option parsing."""

from __future__ import annotations

import argparse
import math
import re


class UsageError(Exception):
    """Bad command-line input: printed as one line, exit status 2."""


def parse_floats(option: str, text: str, count: int) -> tuple[float, ...]:
    """'a,b,...' → ``count`` finite floats, or a UsageError naming the option and the value."""
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        values = ()
    if len(values) != count or not all(math.isfinite(v) for v in values):
        raise UsageError(f"{option} {text!r}: expected {count} comma-separated finite numbers")
    return values


def check_range(option: str, value: float | None, lo: float, hi: float) -> None:
    """Refuse a value outside (lo, hi] with a message naming the option."""
    if value is not None and not (lo < value <= hi):
        raise UsageError(f"{option} {value!r}: expected a number in ({lo:g}, {hi:g}]")


def attach_negative_values(argv: list[str], options: tuple[str, ...]) -> list[str]:
    """argparse reads '--poles -10,-10,...' as two options; rewrite it as '--poles=-10,...'."""
    out: list[str] = []
    i = 0
    while i < len(argv):
        a = argv[i]
        if a in options and i + 1 < len(argv) and re.match(r"^-[\d.]", argv[i + 1]):
            out.append(f"{a}={argv[i + 1]}")
            i += 2
            continue
        out.append(a)
        i += 1
    return out


def add_preset_arguments(p: argparse.ArgumentParser, controller: bool = True) -> None:
    """``--preset`` (a shipped name or a TOML path) and, optionally, ``--controller``."""
    p.add_argument("--preset", default="paper", help="preset name or path to a TOML file (default: paper)")
    if controller:
        p.add_argument("--controller", choices=("backstepping", "pd"), help="default: the preset's")
