"""``quadsitl presets``: list presets, or show one vehicle model and its hover trim."""

from __future__ import annotations

import argparse
import math

from quadsitl.cli_util import UsageError
from quadsitl.config import ConfigError, available_presets, load_preset


def add_presets_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("name", nargs="?", help="a preset name or a path to a TOML file")


def run_presets(args: argparse.Namespace) -> int:
    if args.name is None:
        for name in available_presets():
            print(f"{name:<10} {load_preset(name).description}")
        return 0
    try:
        p = load_preset(args.name)
    except ConfigError as exc:
        raise UsageError(str(exc)) from None
    v, a = p.vehicle, p.actuators
    hover = v.mass * v.gravity / 4.0
    print(f"{p.name}: {p.description}")
    print(f"  mass {v.mass:g} kg, inertia ({v.ixx:g}, {v.iyy:g}, {v.izz:g}) kg·m², arm {v.arm_length:g} m")
    print(
        f"  actuators {a.model}, F_max {a.max_thrust:g} N per motor; hover: {hover:.4g} N per motor "
        f"({100 * hover / a.max_thrust:.1f} % of F_max), Ω = {math.sqrt(hover / v.thrust_factor):.1f} rad/s"
    )
    print(f"  T = {p.sim.period:g} s, {p.sim.integrator} × {p.sim.substeps}, duration {p.sim.duration:g} s")
    print(f"  controller {p.controller.type}, poles {', '.join(f'{x:.6g}' for x in p.poles())}")
    r = p.reference
    print(f"  reference altitude {r.altitude:g} m, roll {r.roll:.6g}, pitch {r.pitch:.6g}, yaw {r.yaw:.6g} rad")
    return 0
