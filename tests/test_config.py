"""Presets: the shipped ones load; bad files are refused with the key, the value and what is allowed."""

import math

import numpy as np
import pytest

from quadsitl.config import ConfigError, WindParams, available_presets, load_preset, parse_preset

PAPER_TEXT = (__import__("importlib").resources.files("quadsitl") / "presets" / "paper.toml").read_text()


def test_shipped_presets_load():
    assert {"paper", "x500"} <= set(available_presets())
    p = load_preset("paper")
    assert p.vehicle.mass == 2.0 and (p.vehicle.ixx, p.vehicle.iyy, p.vehicle.izz) == (1.25, 1.25, 2.2)
    assert p.vehicle.drag == (0.1, 0.1, 0.1, 0.012, 0.012, 0.012)
    assert p.vehicle.rotor_inertia == 1.0 and p.vehicle.d_over_b == 2.5 and p.vehicle.gravity == 9.8
    assert p.sim.period == 0.001 and p.controller.gains == (10.0,) * 8
    assert p.reference.altitude == 5.0 and p.reference.roll == pytest.approx(math.pi / 3)
    assert p.actuators.reversible and p.actuators.min_thrust == -p.actuators.max_thrust
    x = load_preset("x500")
    assert not x.actuators.reversible and x.actuators.min_thrust == 0.0


def _edit(old: str, new: str) -> str:
    assert old in PAPER_TEXT
    return PAPER_TEXT.replace(old, new, 1)


@pytest.mark.parametrize(
    ("old", "new", "message"),
    [
        ("mass = 2.0", "mass = -2.0", r"vehicle\.mass = -2\.0: expected a finite number > 0"),
        ("mass = 2.0", 'mass = "heavy"', r"vehicle\.mass = 'heavy': expected a finite number > 0"),
        ("mass = 2.0", "mass = 2.0\nmas = 3.0", r"unknown key vehicle\.mas; allowed in \[vehicle\]: mass"),
        (
            "inertia = [1.25, 1.25, 2.2]",
            "inertia = [1.25, 2.2]",
            r"vehicle\.inertia = \[1\.25, 2\.2\]: expected 3",
        ),
        (
            'integrator = "euler"',
            'integrator = "rk5"',
            r"sim\.integrator = 'rk5': expected one of: euler, rk4",
        ),
        ("period = 0.001", "period = 1.0", r"sim\.period = 1\.0: expected a number in \[1e-5, 0\.1\] s"),
        ("substeps = 1", "substeps = 1.5", r"sim\.substeps = 1\.5: expected an integer"),
        (
            'model = "ideal"',
            'model = "magic"',
            r"actuators\.model = 'magic': expected one of: ideal, realistic",
        ),
        ("altitude = 5.0", "altitude = 5.0\n[extra]", r"unknown key 'extra'"),
        (
            "roll = 1.0471975511965976",
            "roll = 1.6",
            r"reference\.roll = 1\.6: expected a number in \(−π/2, π/2\)",
        ),
        (
            "max_tilt = 1.3962634015954636",
            "max_tilt = 0.5",
            r"reference\.roll = 1\.04.*exceeds controller\.max_tilt",
        ),
        ("gains = [", "poles = [0.9, 0.9, 0.9, 0.9, 0.9, 0.9, 0.9, 0.9]\ngains = [", r"exactly one of"),
        ("thrust_min = -40000.0", "thrust_min = 50000.0", r"thrust_min = 50000\.0: must be below"),
        ("[pd]", "[pd]\nkp = [1, 2]\n[pdx]", r"unknown key 'pdx'|pd\.kp"),
        ("mass = 2.0", "mass = inf", r"vehicle\.mass = inf"),
        (
            "drag = [0.1, 0.1, 0.1, 0.012, 0.012, 0.012]",
            "drag = [0.1, 0.1, 0.1, 0.012, 0.012, true]",
            r"vehicle\.drag = .*expected 6 finite numbers >= 0",
        ),
    ],
)
def test_bad_values_are_refused_with_key_value_and_allowed(old, new, message):
    with pytest.raises(ConfigError, match=message):
        parse_preset(_edit(old, new), "t")


def test_missing_key_and_section():
    with pytest.raises(ConfigError, match=r"missing key vehicle\.mass"):
        parse_preset(_edit("mass = 2.0 ", "# "), "t")
    start = PAPER_TEXT.index("[reference]")
    with pytest.raises(ConfigError, match=r"missing section \[reference\]"):
        parse_preset(PAPER_TEXT[:start], "t")


def test_not_toml_and_unknown_preset(tmp_path):
    with pytest.raises(ConfigError, match="not valid TOML"):
        parse_preset("mass = = 2", "t")
    with pytest.raises(ConfigError, match=r"unknown preset 'nope'; available presets: .*paper"):
        load_preset("nope")
    with pytest.raises(ConfigError, match="does not exist"):
        load_preset(str(tmp_path / "missing.toml"))
    f = tmp_path / "mine.toml"
    f.write_text(_edit("mass = 2.0", "mass = 3.0"))
    assert load_preset(str(f)).vehicle.mass == 3.0


def test_a_model_section_gives_the_autopilot_its_own_model_of_the_vehicle_key_by_key():
    from dataclasses import replace

    from autopilot.commander import CommanderSettings
    from autopilot.factory import make_controller
    from autopilot.params import values_from
    from quadsitl.param_arrays import vehicle_array

    p = parse_preset(_edit("[actuators]", "[model]\nmass = 2.4\ninertia = [1.0, 1.1, 2.0]\n\n[actuators]"))
    assert p.vehicle.mass == 2.0 and p.vehicle.ixx == 1.25  # the plant's vehicle is untouched
    model = p.autopilot_model
    assert (model.mass, model.ixx, model.iyy, model.izz) == (2.4, 1.0, 1.1, 2.0)
    assert model == replace(p.vehicle, mass=2.4, ixx=1.0, iyy=1.1, izz=2.0)  # the others are the vehicle's
    assert load_preset("paper").autopilot_model == load_preset("paper").vehicle  # no [model]: the vehicle itself
    # what the autopilot builds on: its controllers and its parameters (VM_*)
    assert np.array_equal(make_controller(p).v, vehicle_array(model))
    assert values_from(p, "backstepping", CommanderSettings())["VM_MASS"] == 2.4
    with pytest.raises(ConfigError, match=r"model\.mass = -1\.0: expected a finite number > 0"):
        parse_preset(_edit("[actuators]", "[model]\nmass = -1.0\n\n[actuators]"))
    with pytest.raises(ConfigError, match=r"unknown key model\.mas; allowed in \[model\]: mass"):
        parse_preset(_edit("[actuators]", "[model]\nmas = 1.0\n\n[actuators]"))


def test_a_wind_section_sets_the_wind_and_is_checked_key_by_key():
    section = '[wind]\nspeed_m_s = 5\nfrom_deg = 270\nturbulence = "light"\nforce_n = [1, 0, 0]\n'
    p = parse_preset(PAPER_TEXT + "\n" + section)
    assert p.wind == WindParams(speed_m_s=5.0, from_deg=270.0, turbulence="light", force_n=(1.0, 0.0, 0.0))
    assert load_preset("paper").wind == WindParams()  # no section: calm
    for text, message in [
        ("speed_m_s = 51", r"wind\.speed_m_s = 51: expected a number in \[0, 50\] m/s"),
        ("from_deg = -10", r"wind\.from_deg = -10: expected a number in \[0, 360\] deg"),
        ('turbulence = "gale"', r"wind\.turbulence = 'gale': expected one of: none, light, moderate, severe"),
        ("gust_rise_s = 0", r"wind\.gust_rise_s = 0: expected a number in \(0, 100\] s"),
        ("force_n = [1, 2]", r"wind\.force_n = \[1, 2\]: expected 3 numbers in \[-1000, 1000\] N"),
        ("seed = -1", r"wind\.seed = -1: expected an integer"),
        ("speed = 5", r"unknown key wind\.speed; allowed in \[wind\]: speed_m_s, from_deg"),
    ]:
        with pytest.raises(ConfigError, match=message):
            parse_preset(PAPER_TEXT + f"\n[wind]\n{text}\n")


def test_a_wind_change_is_checked_key_by_key_as_the_preset_section_is():
    from quadsitl.config import wind_change

    assert wind_change(b'{"speed_m_s": 5, "force_n": [1, 2, 3]}') == {"speed_m_s": 5.0, "force_n": (1.0, 2.0, 3.0)}
    for payload, message in [
        (b'{"speed_m_s": 80}', r"^wind\.speed_m_s = 80: expected a number in \[0, 50\] m/s$"),
        (b'{"speed_m_s": NaN}', r"^wind\.speed_m_s = nan: expected"),
        (b'{"turbulence": 3}', r"^wind\.turbulence = 3: expected one of: none, light, moderate, severe$"),
        (b'{"gale": 1}', r"^wind: unknown key 'gale'; allowed: speed_m_s, from_deg, turbulence"),
        (b"[5, 270]", r"^wind: \[5, 270\]: expected a JSON object with any of: speed_m_s"),
        (b"{}", r"^wind: \{\}: expected a JSON object"),
        (b"\xff", r"^wind: not JSON"),
    ]:
        with pytest.raises(ConfigError, match=message):
            wind_change(payload)


def test_the_initial_state_takes_rates():
    from quadsitl.config import initial_state

    p = parse_preset(PAPER_TEXT + "\n[initial]\naltitude = 1.0\nclimb_rate = 0.5\nroll_rate = 0.1\nyaw_rate = -0.2\n")
    s = initial_state(p)
    assert (s.z, s.vz, s.roll_dot, s.pitch_dot, s.yaw_dot) == (-1.0, -0.5, 0.1, 0.0, -0.2)  # NED: z, vz down
    with pytest.raises(ConfigError, match=r"initial\.roll_rate = inf: expected a finite number \[rad/s\]"):
        parse_preset(PAPER_TEXT + "\n[initial]\nroll_rate = inf\n")


@pytest.mark.parametrize("name", ["paper", "x500", "edited"])
def test_a_preset_written_as_toml_reads_back_the_same_to_the_bit(name):
    from dataclasses import replace

    from quadsitl.config import preset_toml

    if name == "edited":  # every optional part: a model, poles, rates at the start, sensors, wind, an awkward text
        p = parse_preset(_edit("[actuators]", "[model]\nmass = 2.1\ndrag = [0.1, 0.2, 0.3, 0, 0, 0.1]\n\n[actuators]"))
        sensors = parse_preset(PAPER_TEXT + "\n[sensors]\nseed = 7\n").sensors
        wind = WindParams(5.0, 1 / 3, "severe", 2.5, 0.7, 1.1, 90.0, 2**62, (0.1, -0.2, 1 / 7))
        p = replace(p, description='a "quoted" one\\ with ünïcode\nand a line', sensors=sensors, wind=wind,
                    controller=replace(p.controller, gains=None, poles=tuple(1 - 0.001 * k for k in range(8))),
                    initial=replace(p.initial, altitude=0.1 + 0.2, roll_rate=1 / 3),
                    model=(*p.model, ("ixx", 1.0000000000000002)))  # fmt: skip
    else:
        p = load_preset(name)
    q = parse_preset(preset_toml(p), p.name)
    assert q.autopilot_model == p.autopilot_model
    assert replace(q, model=()) == replace(p, model=())
