"""Small helpers every command line uses: one-line errors and option parsing."""

from __future__ import annotations

import argparse
import math
import re
import sys
from collections.abc import Callable, Sequence
from dataclasses import asdict, replace
from typing import Any

from quadsitl.config import (
    SCHEMA,
    TURBULENCE_W20_KNOTS,
    ConfigError,
    Preset,
    WindParams,
    check_value,
    default_sensors,
)
from quadsitl.controller_names import ALLOWED, is_controller_name, is_plugin


class UsageError(Exception):
    """Bad command-line input: printed as one line, exit status 2."""


def serve_until_stopped(parser: argparse.ArgumentParser, serve: Callable[[argparse.Namespace], int],
                        argv: Sequence[str] | None) -> int:  # fmt: skip
    """The main of a command that serves until stopped (the router, the dashboard): ``serve(args)``'s status; a
    UsageError as one line and status 2; SIGINT or SIGTERM (StopRequested) as its end, status 0."""
    args = parser.parse_args(argv)
    try:
        return serve(args)
    except UsageError as exc:
        print(f"{parser.prog}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 0


def parse_floats(option: str, text: str, count: int) -> tuple[float, ...]:
    """'a,b,...' → ``count`` finite floats, or a UsageError naming the option and the value."""
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        values = ()
    if len(values) != count or not all(math.isfinite(v) for v in values):
        raise UsageError(f"{option} {text!r}: expected {count} comma-separated finite numbers")
    return values


def parse_home(text: str | None) -> tuple[float, float, float] | None:
    """``--home LAT,LON,ALT`` → (lat [deg], lon [deg], alt [m AMSL]); None when not given."""
    if text is None:
        return None
    lat, lon, alt = parse_floats("--home", text, 3)
    if not (-90.0 <= lat <= 90.0 and -180.0 <= lon <= 180.0 and -1000.0 <= alt <= 100000.0):
        raise UsageError(f"--home {text!r}: expected latitude in [-90, 90], longitude in [-180, 180], altitude "
                         "in [-1000, 100000] m")  # fmt: skip
    return lat, lon, alt


def parse_vehicle_presets(values: Sequence[str], n: int, fleet: str | None = None) -> dict[int, str]:
    """``--vehicle-preset K=PRESET`` options → {vehicle number K (1-based): preset}; refuses an unknown vehicle,
    a repeated one and a malformed value, naming the option. ``fleet`` says what made the fleet n vehicles
    (default ``--vehicles n``)."""
    fleet = fleet or f"--vehicles {n}"
    out: dict[int, str] = {}
    for text in values:
        number, sep, preset = text.partition("=")
        if not sep or not number.strip().isdigit() or not preset.strip():
            raise UsageError(f"--vehicle-preset {text!r}: expected K=PRESET, e.g. 2=x500 (vehicle K of 1..{n})")
        k = int(number)
        if not 1 <= k <= n:
            raise UsageError(f"--vehicle-preset {text!r}: vehicle {k} is not in the fleet (1..{n}, {fleet})")
        if k in out:
            raise UsageError(f"--vehicle-preset {text!r}: vehicle {k} already has preset {out[k]!r}")
        out[k] = preset.strip()
    return out


def per_vehicle(option: str, values: Sequence[str] | None, n: int, fleet: str) -> list[str] | None:
    """A repeatable option that describes one vehicle of ``n``: given once (every vehicle's) or once per vehicle,
    in order; None when not given; a UsageError naming the option otherwise."""
    if not values:
        return None
    if len(values) == 1:
        return list(values) * n
    if len(values) != n:
        raise UsageError(f"{option} given {len(values)} times: expected once (for every vehicle) or {n} times (one "
                         f"per vehicle, in order; {fleet})")  # fmt: skip
    return list(values)


def check_range(option: str, value: float | None, lo: float, hi: float) -> None:
    """Refuse a value outside (lo, hi] with a message naming the option."""
    if value is not None and not (lo < value <= hi):
        raise UsageError(f"{option} {value!r}: expected a number in ({lo:g}, {hi:g}]")


# The options several commands take, each checked by one function wherever it is given.
SPEED_MAX = 1000.0  # --speed: the fastest pace asked for, × real time
SYSTEM_IDS = (1, 255)  # MAVLink's system ids a vehicle may take


def check_speed(speed: float) -> None:
    """``--speed F``: a lockstep pace of F × real time, in [0, SPEED_MAX] (0: as fast as possible); anything else
    (NaN too) refused naming the option."""
    if not 0.0 <= speed <= SPEED_MAX:
        raise UsageError(f"--speed {speed!r}: expected a number in [0, {SPEED_MAX:g}] (0 = as fast as possible)")


def check_system_id(system_id: int) -> None:
    """``--system-id N``: a MAVLink system id in SYSTEM_IDS (1..255), else refused naming the option."""
    lo, hi = SYSTEM_IDS
    if not lo <= system_id <= hi:
        raise UsageError(f"--system-id {system_id}: expected an integer in {lo}..{hi}")


def check_duration(duration: float | None) -> None:
    """``--duration S`` [s, simulated]: a flight's length, in the range of a preset's ``sim.duration``; None: not
    given."""
    limit = SCHEMA["sim"]["duration"]
    check_range("--duration", duration, limit.low, limit.high)


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


CONTROLLER_HELP = f"{ALLOWED} (docs/controllers.md)"


def controller_name(value: str) -> str:
    """``--controller``'s value: a built-in's name, or a controller to load (``file.py:Name``, ``module:Name``), which
    is loaded, checked and compiled when the command flies it."""
    if is_controller_name(value):
        return value
    raise argparse.ArgumentTypeError(f"{value!r}: expected {CONTROLLER_HELP}")


def parse_controller_params(values: Sequence[str], controller: str | None) -> dict[str, float]:
    """``--controller-param NAME=VALUE`` (repeated) → {NAME: value}; only with a controller that plugs in (its names
    are checked when it is loaded)."""
    out: dict[str, float] = {}
    for item in values:
        name, sep, text = item.partition("=")
        try:
            value = float(text)
        except ValueError:
            value = math.nan
        if not sep or not name.strip() or not math.isfinite(value):
            raise UsageError(f"--controller-param {item!r}: expected NAME=VALUE, VALUE a finite number")
        out[name.strip()] = value
    if out and (controller is None or not is_plugin(controller)):
        raise UsageError(
            f"--controller-param {values[0]!r}: only a controller that plugs in (px4, file.py:Name) "
            "has parameters of its own; the built-ins' gains are --gains, --poles, the preset's"
        )
    return out


def add_preset_arguments(p: argparse.ArgumentParser, controller: bool = True) -> None:
    """``--preset`` (a shipped name or a TOML path) and, optionally, ``--controller``."""
    p.add_argument("--preset", default="paper", help="preset name or path to a TOML file (default: paper)")
    if controller:
        p.add_argument("--controller", type=controller_name, metavar="NAME",
                       help=f"{CONTROLLER_HELP} (default: the preset's)")  # fmt: skip
        p.add_argument("--controller-param", action="append", default=[], metavar="NAME=VALUE",
                       help="a parameter of a controller that plugs in (px4 or yours), by its name or MAVLink name "
                            "(repeat for more); checked against its range and the controller's check")  # fmt: skip


WIND_OPTIONS = ("--wind", "--turbulence", "--gust", "--wind-seed")


def add_wind_arguments(p: argparse.ArgumentParser) -> None:
    """The wind options (``--wind``, ``--turbulence``, ``--gust``, ``--wind-seed``): the air the plant flies in,
    over the preset's [wind] section (calm without one). :func:`with_wind` applies them."""
    g = p.add_argument_group("wind", "the air the plant flies in, over the preset's [wind] (calm without one)")
    g.add_argument("--wind", metavar="SPEED,FROM", help="a mean wind: its speed [m/s] and the direction it blows "
                   "from [deg clockwise from north], e.g. 5,270: 5 m/s from the west")  # fmt: skip
    g.add_argument("--turbulence", choices=tuple(TURBULENCE_W20_KNOTS), help="Dryden turbulence (MIL-F-8785C level)")
    g.add_argument("--gust", metavar="SPEED,FROM[,START[,RISE]]", help="a 1 - cos gust: its speed [m/s], the "
                   "direction it blows from [deg], when it starts [s after lift-off, default 0] and how long it "
                   "takes to rise [s, default 1]; then it holds")  # fmt: skip
    g.add_argument("--wind-seed", type=int, metavar="N", help="the turbulence's seed (default: the preset's, or 0)")


def with_wind(preset: Preset, args: argparse.Namespace) -> Preset:
    """``preset`` with the wind options given over its [wind]; each value is checked as the [wind] key it sets,
    and refused with the option, the key, the value and what is allowed."""
    values: dict[str, Any] = {}
    given: dict[str, str] = {}  # key -> the option that set it, as typed
    if args.wind is not None:
        values["speed_m_s"], values["from_deg"] = parse_floats("--wind", args.wind, 2)
        given.update(speed_m_s=f"--wind {args.wind}", from_deg=f"--wind {args.wind}")
    if args.turbulence is not None:
        values["turbulence"], given["turbulence"] = args.turbulence, f"--turbulence {args.turbulence}"
    if args.gust is not None:
        n = len(args.gust.split(","))
        if not 2 <= n <= 4:
            raise UsageError(
                f"--gust {args.gust!r}: expected 2 to 4 comma-separated numbers: SPEED,FROM[,START[,RISE]]"
            )
        for key, value in zip(("gust_m_s", "gust_from_deg", "gust_start_s", "gust_rise_s"),
                              parse_floats("--gust", args.gust, n)):  # fmt: skip
            values[key], given[key] = value, f"--gust {args.gust}"
    if args.wind_seed is not None:
        values["seed"], given["seed"] = args.wind_seed, f"--wind-seed {args.wind_seed}"
    for key, value in values.items():
        try:
            check_value(f"wind.{key}", value, SCHEMA["wind"][key])
        except ConfigError as exc:
            raise UsageError(f"{given[key]}: {exc}") from None
    return replace(preset, wind=replace(preset.wind, **values)) if values else preset


def wind_argv(args: argparse.Namespace) -> list[str]:
    """The wind options given on this command line, as arguments for the plant process it starts."""
    out: list[str] = []
    for option in WIND_OPTIONS:
        value = getattr(args, option[2:].replace("-", "_"), None)
        if value is not None:
            out += [option, str(value)]
    return out


def wind_settings(preset: Preset) -> dict[str, Any]:
    """What a run's metrics.json says of its air: ``{"wind": {...}}`` with the [wind] keys, or nothing when calm."""
    return {} if preset.wind == WindParams() else {"wind": asdict(preset.wind)}


STATE_SOURCES = ("truth", "sensors")
CLOCKS = ("lockstep", "realtime")  # the plant's --mode (and up's): its clock


def add_state_arguments(p: argparse.ArgumentParser) -> None:
    """``--state truth|sensors`` and ``--sensor-seed``: what the autopilot flies on (docs/sensors.md).
    :func:`with_state` applies them."""
    g = p.add_argument_group("state", "what the autopilot flies on")
    g.add_argument("--state", choices=STATE_SOURCES, help="truth: the plant's true state (the paper's experiment); "
                   "sensors: its IMU, magnetometer, barometer and GPS, through the autopilot's estimator (default: "
                   "sensors when the preset has a [sensors] section, else truth)")  # fmt: skip
    g.add_argument("--sensor-seed", type=int, metavar="N", help="the sensors' noise seed (default: the preset's, or 0)")


def with_state(preset: Preset, args: argparse.Namespace) -> Preset:
    """``preset`` flown on what ``--state`` says: with sensors (its [sensors], or the defaults) or without (the
    truth); ``--sensor-seed`` over the sensors' seed. In sensor mode the vehicle must start at rest on the ground
    (the estimator aligns there first); anything else is refused naming the key."""
    state = args.state or ("sensors" if preset.sensors is not None else "truth")
    if args.sensor_seed is not None:
        if state != "sensors":
            raise UsageError(f"--sensor-seed {args.sensor_seed}: the autopilot flies on the truth; add --state sensors")
        try:
            check_value("sensors.seed", args.sensor_seed, SCHEMA["sensors"]["seed"])
        except ConfigError as exc:
            raise UsageError(f"--sensor-seed {args.sensor_seed}: {exc}") from None
    if state == "truth":
        return replace(preset, sensors=None)
    try:
        sensors = preset.sensors or default_sensors(preset.sim)
    except ConfigError as exc:
        raise UsageError(str(exc)) from None
    if args.sensor_seed is not None:
        sensors = replace(sensors, seed=args.sensor_seed)
    i = preset.initial
    for key in ("altitude", "climb_rate", "roll_rate", "pitch_rate", "yaw_rate"):
        if getattr(i, key) != 0.0:
            raise UsageError(f"--state sensors: initial.{key} = {getattr(i, key)!r}: must be 0 in sensor mode (the "
                             "vehicle starts at rest on the ground, where the estimator aligns)")  # fmt: skip
    return replace(preset, sensors=sensors)


def state_argv(args: argparse.Namespace) -> list[str]:
    """The state options given on this command line, for the processes it starts."""
    out = ["--state", args.state] if args.state else []
    return out + (["--sensor-seed", str(args.sensor_seed)] if args.sensor_seed is not None else [])
