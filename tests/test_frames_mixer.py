"""Frames (DESIGN.md §2, paper eq (1)) and the mixer (eq (8)) against hand-derived values."""

import math

import pytest

from quadsitl.frames import (
    body_rates_to_euler_rates,
    euler_rates_to_body_rates,
    euler_to_quaternion,
    quaternion_to_euler,
    wrap_pi,
)
from quadsitl.mixer import allocate, forces_to_inputs, inputs_to_forces, residual_rotor_speed, rotor_speeds


def test_eq1_body_rates_hand_values():
    # φ = 0, θ = 0: body rates equal Euler rates.
    assert euler_rates_to_body_rates(0, 0, 0.1, 0.2, 0.3) == pytest.approx((0.1, 0.2, 0.3))
    # θ = 30°, φ = 0, pure yaw rate 1: p = −sin θ, q = 0, r = cos θ.
    p, q, r = euler_rates_to_body_rates(0.0, math.radians(30), 0.0, 0.0, 1.0)
    assert (p, q, r) == pytest.approx((-0.5, 0.0, math.sqrt(3) / 2))
    # φ = 90°, pure pitch rate 1: q = cos φ = 0, r = −sin φ = −1.
    assert euler_rates_to_body_rates(math.pi / 2, 0.0, 0.0, 1.0, 0.0) == pytest.approx((0, 0, -1), abs=1e-15)


@pytest.mark.parametrize("angles", [(0.3, -0.4, 2.0), (-1.2, 1.1, -3.0), (1.0471975511965976,) * 3])
def test_eq1_inverse_round_trip(angles):
    roll, pitch, _ = angles
    rates = (0.7, -1.3, 2.1)
    p, q, r = euler_rates_to_body_rates(roll, pitch, *rates)
    assert body_rates_to_euler_rates(roll, pitch, p, q, r) == pytest.approx(rates, abs=1e-12)


@pytest.mark.parametrize("angles", [(0.3, -0.4, 2.0), (-1.2, 1.1, -3.0), (0.0, 0.0, math.pi / 2)])
def test_quaternion_round_trip_and_convention(angles):
    q = euler_to_quaternion(*angles)
    assert sum(c * c for c in q) == pytest.approx(1.0)
    assert quaternion_to_euler(*q) == pytest.approx(angles, abs=1e-12)
    # Yaw 90° about NED z (down): q = [cos 45°, 0, 0, sin 45°].
    assert euler_to_quaternion(0, 0, math.pi / 2) == pytest.approx((math.sqrt(0.5), 0, 0, math.sqrt(0.5)))


def test_wrap_pi():
    assert wrap_pi(math.pi + 0.1) == pytest.approx(-math.pi + 0.1)
    assert wrap_pi(-math.pi - 0.1) == pytest.approx(math.pi - 0.1)
    assert wrap_pi(0.5) == 0.5


def test_eq8_mixer_hand_values():
    # Motor 1 rear, 2 right, 3 front, 4 left; d/b = 2.5 (paper: d = 5, b = 2).
    u = forces_to_inputs((1.0, 2.0, 3.0, 4.0), 2.5)
    assert u == pytest.approx((10.0, 4.0 - 2.0, 3.0 - 1.0, 2.5 * (-1 + 2 - 3 + 4)))
    # Left motor alone rolls right-wing-down (+u2); front motor alone pitches nose-up (+u3).
    assert forces_to_inputs((0, 0, 0, 1.0), 2.5).u2 == 1.0
    assert forces_to_inputs((0, 0, 1.0, 0), 2.5).u3 == 1.0


def test_eq8_inverse():
    u = (20.0, 1.5, -0.7, 0.9)
    f = inputs_to_forces(u, 0.016)
    assert forces_to_inputs(f, 0.016) == pytest.approx(u)


def test_erratum5_residual_rotor_speed_alternates_signs():
    # Ωr = Ω1 − Ω2 + Ω3 − Ω4 (the paper prints + Ω4). b = 2: Ω = sqrt(F/2).
    forces = (2.0, 8.0, 18.0, 32.0)  # Ω = 1, 2, 3, 4
    assert rotor_speeds(forces, 2.0) == pytest.approx((1, 2, 3, 4))
    assert residual_rotor_speed(forces, 2.0) == pytest.approx(1 - 2 + 3 - 4)
    # Equal motors (hover) give no gyroscopic term; the paper's printed sign would give 2Ω.
    assert residual_rotor_speed((5.0,) * 4, 2.0) == pytest.approx(0.0)
    # Reversible rotors keep the sign of the thrust.
    assert rotor_speeds((-8.0, 0, 0, 0), 2.0)[0] == pytest.approx(-2.0)


def test_allocate_exact_when_it_fits_and_bounded_when_not():
    u = (20.0, 1.0, -1.0, 0.01)
    assert allocate(u, 0.016, 0.0, 8.5) == pytest.approx(inputs_to_forces(u, 0.016))
    # Too much collective: torques kept, thrust lowered to fit.
    f = allocate((40.0, 1.0, 0.0, 0.0), 0.016, 0.0, 8.5)
    assert max(f) <= 8.5 and min(f) >= 0.0
    assert f[3] - f[1] == pytest.approx(1.0)  # u2 preserved
    # Torque alone larger than the range: everything inside, sign of the torque kept.
    f = allocate((10.0, 30.0, 0.0, 0.0), 0.016, 0.0, 8.5)
    assert all(0.0 <= x <= 8.5 for x in f) and f[3] > f[1]


def test_allocate_gives_up_yaw_before_the_collective_and_roll_and_pitch_before_neither():
    d, f_max = 0.016, 8.5
    # Hover (19.6 N) with a roll torque and a yaw torque the motors cannot make beside it: the yaw is cut, the
    # collective and the roll kept (the old allocation kept the yaw and lowered the collective: the vehicle sank).
    u = (19.6, 2.0, 0.0, 0.5)
    f = allocate(u, d, 0.0, f_max)
    got = forces_to_inputs(f, d)
    assert got[0] == pytest.approx(19.6) and got[1] == pytest.approx(2.0) and got[2] == pytest.approx(0.0)
    assert 0.0 < got[3] < 0.5 and all(0.0 <= x <= f_max for x in f)
    # A roll torque beyond the range: scaled to the whole range (the collective where that fits: mid-range), and
    # the yaw gets nothing.
    f = allocate((19.6, 12.0, 0.0, 0.2), d, 0.0, f_max)
    got = forces_to_inputs(f, d)
    assert got[1] == pytest.approx(f_max) and got[0] == pytest.approx(2 * f_max) and got[3] == pytest.approx(0.0)
