"""``quadsitl gains``: check backstepping gains against conditions (41)–(44)."""

from __future__ import annotations

import argparse

from autopilot.gains import GainError, poles_from_rates, rates_from_poles, stability_interval
from quadsitl.cli_util import UsageError, check_range, parse_floats
from quadsitl.config import ConfigError, load_preset

GAINS_EPILOG = """examples:
  quadsitl gains
  quadsitl gains --gains 5,5,10,10,10,10,10,10
  quadsitl gains --poles -10,-10,-10,-10,-10,-10,-10,-10   # the paper's k = 10 read literally: refused
"""


def add_gains_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--preset", default="paper", help="preset for T and default gains (default: paper)")
    p.add_argument("--period", type=float, metavar="T", help="control period [s] (default: the preset's)")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--gains", metavar="k1,..,k8", help="rates in 1/s (λ = 1 − T·k)")
    g.add_argument("--poles", metavar="l1,..,l8", help="discrete poles λ")


def run_gains(args: argparse.Namespace) -> int:
    try:
        preset = load_preset(args.preset)
    except ConfigError as exc:
        raise UsageError(str(exc)) from None
    check_range("--period", args.period, 0.0, 0.1)
    T = args.period or preset.sim.period
    if args.gains:
        poles = poles_from_rates(parse_floats("--gains", args.gains, 8), T)
    elif args.poles:
        poles = parse_floats("--poles", args.poles, 8)
    elif preset.controller.gains is not None:
        poles = poles_from_rates(preset.controller.gains, T)
    else:
        poles = preset.poles()
    try:
        lo, hi = stability_interval(poles, T)
    except GainError as exc:
        raise UsageError(f"inadmissible gains: {exc}") from None
    print(f"T = {T:g} s")
    for i, (lam, k) in enumerate(zip(poles, rates_from_poles(poles, T)), start=1):
        print(f"  λ{i} = {lam:<10.6g} k{i} = {k:.6g} 1/s")
    print(f"conditions (41)–(44) hold for {lo:.6g} < ε < {hi:.6g}")
    return 0
