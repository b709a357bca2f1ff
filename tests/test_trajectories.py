"""Reference trajectories, pure: the position shapes (geometry, the velocity feed-forward against the numerical
derivative, yaw), the position CSV and its refusals, and ``--trajectory`` parsing."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from groundstation import trajectories as tr
from quadsitl.cli_util import UsageError
from quadsitl.state import Reference

PAPER = Reference(5.0, math.pi / 3, math.pi / 3, math.pi / 3)
H = 1e-5  # [s] step of the central differences


def numerical_velocity(f, t: float) -> tuple[float, float, float]:
    """(vx, vy, climb) by central differences of a position trajectory at t."""
    a, b = f(t - H), f(t + H)
    return (b.x - a.x) / (2 * H), (b.y - a.y) / (2 * H), (b.altitude - a.altitude) / (2 * H)


def times(hold: float, period: float, laps: float = 1.5, n: int = 997) -> np.ndarray:
    """Sample times across the hold, the spin-up and laps, none on the kinks (t = hold, hold + period/4)."""
    t = np.linspace(0.0, hold + laps * period, n) + 1e-3 * math.pi
    kinks = (hold, hold + period / 4)
    return np.array([x for x in t if min(abs(x - k) for k in kinks) > 10 * H])


@pytest.mark.parametrize("shape", ["circle", "figure8"])
def test_velocity_feed_forward_is_the_numerical_derivative_of_the_position(shape):
    f = tr.make(f"{shape}:period=12,hold=2", PAPER)
    assert isinstance(f, tr.PositionTrajectory)
    for t in times(2.0, 12.0):
        sp = f(t)
        assert (sp.vx, sp.vy, sp.climb) == pytest.approx(numerical_velocity(f, t), abs=1e-6), t


def test_the_circle_passes_home_heads_north_and_keeps_its_radius():
    R, P, hold = 4.0, 16.0, 3.0
    f = tr.make(f"circle:radius={R},period={P},hold={hold}", PAPER)
    # The hold: at home, at the preset's altitude, at rest, the nose along the path's first direction (north).
    for t in (0.0, 1.0, hold):
        assert f(t) == (0.0, 0.0, 5.0, 0.0, 0.0, 0.0, 0.0)
    for t in times(hold, P):
        sp = f(t)
        assert math.hypot(sp.x, sp.y - R) == pytest.approx(R, abs=1e-12)  # centre (0, R): R east of home
        assert sp.altitude == 5.0 and sp.climb == 0.0
    # Full speed 2πR/P after the spin-up (a quarter period), along the path: yaw = the velocity's heading.
    sp = f(hold + P / 2)
    assert math.hypot(sp.vx, sp.vy) == pytest.approx(2 * math.pi * R / P, rel=1e-12)
    assert sp.yaw == pytest.approx(math.atan2(sp.vy, sp.vx), abs=1e-12)
    # First north, then east: clockwise seen from above (x north, y east).
    early = f(hold + 1.0)
    assert early.vx > 0 and early.y > 0 and abs(early.vy) < early.vx
    # One lap ends back at home, at the trajectory's natural duration; yaw stays in [−π, π].
    end = f(f.duration)
    assert (end.x, end.y) == pytest.approx((0.0, 0.0), abs=1e-9)
    assert f.duration == pytest.approx(hold + P + P / 8)
    assert all(-math.pi <= f(t).yaw <= math.pi for t in times(hold, P, laps=3))


def test_the_figure_eight_spans_its_size_crosses_home_and_yaws_along_the_path():
    a, P = 6.0, 20.0
    f = tr.make(f"figure8:size={a},period={P},altitude=3,hold=0", PAPER)
    pts = np.array([f(t)[:2] for t in np.linspace(P / 4, P / 4 + P, 4001)])
    assert pts[:, 0].max() == pytest.approx(a, rel=1e-4) and pts[:, 0].min() == pytest.approx(-a, rel=1e-4)
    assert pts[:, 1].max() == pytest.approx(a / 2, rel=1e-4) and pts[:, 1].min() == pytest.approx(-a / 2, rel=1e-4)
    # Through home at θ = 0 (t = 0) and θ = π, first to the north-east.
    theta_pi = P / 8 + P / 2  # θ = ω(τ − S/2) = π
    assert f(theta_pi)[:2] == pytest.approx((0.0, 0.0), abs=1e-12)
    assert f(0.0).yaw == pytest.approx(math.pi / 4)
    for t in times(0.0, P):
        sp = f(t)
        assert sp.altitude == 3.0
        if math.hypot(sp.vx, sp.vy) > 1e-3:
            assert sp.yaw == pytest.approx(math.atan2(sp.vy, sp.vx), abs=1e-9), t
    peak = max(math.hypot(f(t).vx, f(t).vy) for t in np.linspace(P / 4, 1.25 * P, 2001))
    assert peak == pytest.approx(math.sqrt(2) * 2 * math.pi * a / P, rel=1e-4)  # at home


def test_a_fixed_yaw_is_kept_and_the_altitude_defaults_to_the_presets():
    f = tr.make("circle:yaw=1.2", Reference(2.0))
    assert {f(t).yaw for t in (0.0, 7.0, 13.0)} == {1.2}
    assert f(9.0).altitude == 2.0
    assert tr.make("figure8:yaw=travel", PAPER)(0.0).yaw == pytest.approx(math.pi / 4)


def test_the_attitude_trajectories_are_unchanged():
    assert tr.make("step", PAPER)(0.0) == PAPER and tr.make("step", PAPER)(7.0) == PAPER
    assert tr.make("ramp", PAPER)(1.0) == pytest.approx(tuple(v / 2 for v in PAPER))
    assert tr.make("sine", PAPER)(0.5) == pytest.approx(tuple(v * 1.2 for v in PAPER))


@pytest.mark.parametrize(
    ("spec", "message"),
    [
        ("circle:radius=-1", "--trajectory 'circle:radius=-1': radius = -1: expected a number in (0, 1000] m"),
        ("circle:period=0.5", "period = 0.5: expected a number in (1, 3600] s"),
        ("circle:hold=-2", "hold = -2: expected a number in [0, 3600] s"),
        ("circle:radius=abc", "radius='abc' is not a number; expected circle[:radius=M][,period=S]"),
        ("circle:yaw=north", "yaw='north' is not a number [rad] or travel"),
        ("circle:speed=3", "unknown parameter 'speed=3'; expected circle[:radius=M]"),
        ("figure8:radius=3", "unknown parameter 'radius=3'; expected figure8[:size=M]"),
        ("circle:altitude=nan", "altitude='nan' is not a number"),
        ("circle:radius=50,period=10", "a peak speed of 31.4 m/s exceeds 12 m/s (PX4's MPC_XY_VEL_MAX default)"),
        ("figure8:size=20,period=14", "a peak speed of 12.7 m/s exceeds 12 m/s"),
        (
            "spiral",
            "--trajectory 'spiral': expected step, ramp, sine, circle[:...], figure8[:...], hold[:...] or an existing",
        ),
        ("hold:altitude=-1", "--trajectory 'hold:altitude=-1': altitude = -1: expected a number in (0, 10000] m"),
        ("hold:duration=0", "duration = 0: expected a number in (0, 3600] s"),
        ("hold:yaw=4", "yaw = 4: expected a number in [-3.14159, 3.14159] rad"),
        ("hold:yaw=west", "yaw = nan: expected a number"),
        ("hold:speed=1", "unknown parameter 'speed=1'; expected hold[:altitude=M][,duration=S][,yaw=RAD]"),
    ],
)
def test_bad_shapes_are_refused_naming_the_option_the_value_and_what_is_allowed(spec, message):
    with pytest.raises(UsageError) as err:
        tr.make(spec, PAPER)
    assert message in str(err.value)


def test_hold_is_a_fixed_position_setpoint_above_home_for_its_duration():
    hold = tr.make("hold:altitude=3,duration=7,yaw=0.5", PAPER)
    assert isinstance(hold, tr.PositionTrajectory) and hold.duration == 7.0
    for t in (0.0, 3.3, 100.0):
        assert hold(t) == tr.PositionSetpoint(0.0, 0.0, 3.0, 0.5, 0.0, 0.0, 0.0)
    plain = tr.make("hold", PAPER)
    assert plain(1.0).altitude == PAPER.altitude and plain(1.0).yaw == 0.0 and plain.duration == 20.0


def test_a_shape_at_altitude_zero_asks_for_an_altitude():
    with pytest.raises(UsageError, match=r"altitude 0 \(the preset's reference; give altitude=M\)"):
        tr.make("circle", Reference(0.0))
    assert tr.make("circle:altitude=4", Reference(0.0))(0.0).altitude == 4.0


# ---- the position CSV -----------------------------------------------------------------------------------


def write(tmp_path: Path, text: str, name: str = "path.csv") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def test_a_position_csv_is_interpolated_held_and_its_slope_is_the_feed_forward(tmp_path):
    path = write(tmp_path, "t, x, y, altitude, yaw\n1, 0, 0, 2, 0\n3, 4, -2, 2, 0.5\n5, 4, -2, 5, 6.0\n\n")
    f = tr.make(str(path), PAPER)
    assert isinstance(f, tr.PositionTrajectory) and f.duration == 5.0
    assert f(0.0) == (0.0, 0.0, 2.0, 0.0, 0.0, 0.0, 0.0)  # the first row, held before its t
    sp = f(2.0)
    assert sp[:4] == pytest.approx((2.0, -1.0, 2.0, 0.25)) and sp[4:] == pytest.approx((2.0, -1.0, 0.0))
    sp = f(4.5)
    assert sp[:3] == pytest.approx((4.0, -2.0, 4.25)) and sp[4:] == pytest.approx((0.0, 0.0, 1.5))
    assert sp.yaw == pytest.approx(math.remainder(0.5 + 0.75 * 5.5, 2 * math.pi))  # sent wrapped
    assert f(9.0) == pytest.approx((4.0, -2.0, 5.0, math.remainder(6.0, 2 * math.pi), 0.0, 0.0, 0.0))
    for t in (1.5, 2.7, 3.3, 4.9):  # inside segments: the feed-forward is the numerical derivative
        assert (f(t).vx, f(t).vy, f(t).climb) == pytest.approx(numerical_velocity(f, t), abs=1e-6)


def test_an_attitude_csv_is_still_an_attitude_trajectory(tmp_path):
    path = write(tmp_path, "t,altitude,roll,pitch,yaw\n0,1,0,0,0\n2,3,0.2,0,0\n")
    f = tr.make(str(path), PAPER)
    assert not isinstance(f, tr.PositionTrajectory)
    assert f(1.0) == pytest.approx(Reference(2.0, 0.1, 0.0, 0.0))


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("t,x,y,altitude,yaw\n0,0,0,1,0\n1,abc,0,1,0\n", "path.csv, line 3, column x: 'abc' is not a number"),
        ("t,x,y,altitude,yaw\n0,0,0,1,0\n1,0,0,1\n", "path.csv, line 3, column yaw: no value; expected a number"),
        ("t,x,y,altitude,yaw\n0,0,0,1,0\n1,0,,1,0\n", "path.csv, line 3, column y: no value"),
        ("t,x,y,altitude,yaw\n0,0,0,-1,0\n", "path.csv, line 2, column altitude: -1; expected a number ≥ 0 [m]"),
        ("t,x,y,altitude,yaw\n-1,0,0,1,0\n", "path.csv, line 2, column t: -1; expected a number ≥ 0 [s]"),
        ("t,x,y,altitude,yaw\n0,0,0,1,0\n1,inf,0,1,0\n", "line 3, column x: 'inf'; expected a finite number"),
        ("t,x,y,altitude,yaw\n0,0,0,1,0\n\n0,1,0,1,0\n",
         "path.csv, line 4, column t: 0 is not after the previous row's 0; t must increase"),
        ("t,x,y,altitude,yaw\n0,0,0,1,0\n1,13,0,1,0\n",
         "path.csv, line 3, columns x, y: 13 m/s from the previous row exceeds 12 m/s"),
        ("t,x,y,altitude,yaw\n0,0,0,1,0\n1,0,0,5,0\n", "path.csv, line 3, column altitude: 4 m/s from the previous"),
        ("t,x,y,altitude,yaw\n0,0,0,5,0\n1,0,0,3,0\n", "line 3, column altitude: -2 m/s from the previous row;"),
        ("t,x,y,altitude,yaw\n", "path.csv: no rows after the header t, x, y, altitude, yaw"),
        ("t,x,y,yaw\n0,0,0,0\n", "path.csv: missing column(s) altitude; a position trajectory has the columns t, x,"),
        ("t,x,y,altitude,roll,pitch,yaw\n0,0,0,1,0,0,0\n", "path.csv: its header has both an attitude trajectory's"),
        ("t,altitude,roll\n0,1,0\n", "path.csv: missing column(s) pitch, yaw; expected t, altitude, roll, pitch, yaw"),
        ("t,altitude,roll,pitch,yaw\n0,1,0,0,0\n1,1,1.6,0,0\n", "line 3, column roll: 1.6; expected |roll| < π/2"),
        ("t,altitude,roll,pitch,yaw\n0,-1,0,0,0\n", "path.csv, line 2, column altitude: -1; expected a number ≥ 0 [m]"),
        ("t,altitude,roll,pitch,yaw\n0,1,0,0,0\n1,1,0,x,0\n", "path.csv, line 3, column pitch: 'x' is not a number"),
        ("t,altitude,roll,pitch,yaw\n1,1,0,0,0\n0.5,1,0,0,0\n", "line 3, column t: 0.5 is not after the previous"),
    ],
)  # fmt: skip
def test_bad_csvs_are_refused_naming_the_file_line_and_column(tmp_path, text, message):
    path = write(tmp_path, text)
    with pytest.raises(UsageError) as err:
        tr.make(str(path), PAPER)
    assert message in str(err.value)
    assert str(path) in str(err.value)
