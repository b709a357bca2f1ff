"""The plant: eqs (2)–(7) against hand-derived values, errata 1, 2 and 6, integrators, actuators and
the ground plane, the wind and an external force."""

import dataclasses
import math

import numpy as np
import pytest

from quadsitl.config import ActuatorParams, WindParams, load_preset
from quadsitl.mixer import inputs_to_forces
from quadsitl.param_arrays import actuator_array, vehicle_array
from quadsitl.state import VehicleState
from sitl import dynamics
from sitl.actuators import advance
from sitl.integrators import euler, rk4
from sitl.plant import Plant

PAPER = load_preset("paper")
V = PAPER.vehicle
T = PAPER.sim.period


def derivatives(s, u, wr, v, d=dynamics.CALM):
    """The compiled eqs (2)–(7) for a VehicleState and a VehicleParams, in calm air unless ``d`` (the wind [m/s,
    NED] and an external force [N, NED]) says otherwise."""
    return dynamics.derivatives(tuple(map(float, s)), tuple(map(float, u)), float(wr), vehicle_array(v),
                                tuple(map(float, d)))  # fmt: skip


def test_hover_is_an_equilibrium():
    d = derivatives(VehicleState(z=-3.0), (V.mass * V.gravity, 0, 0, 0), 0.0, V)
    assert d == pytest.approx((0.0,) * 12, abs=1e-12)


def test_eq4_vertical_in_ned_hand_value():
    # Level, climbing at 1 m/s (vz = −1), u1 = 30 N: ḧ = 30/2 − 9.8 − 0.1·1/2 = 5.15 → z̈ = −5.15.
    d = derivatives(VehicleState(vz=-1.0), (30.0, 0, 0, 0), 0.0, V)
    assert d[5] == pytest.approx(-5.15)
    assert d[2] == -1.0


def test_erratum6_eq2_eq3_horizontal_in_ned():
    # φ = 0, θ = 30°, ψ = 0: thrust tilts forward (nose-up pitch points thrust backwards in NED):
    # ẍ = −(cφ sθ cψ + sφ sψ)·u1/m = −0.5·20/2 = −5; ÿ = −(cφ sθ sψ − sφ cψ)·u1/m = 0.
    d = derivatives(VehicleState(pitch=math.radians(30)), (20.0, 0, 0, 0), 0.0, V)
    assert d[3] == pytest.approx(-5.0) and d[4] == pytest.approx(0.0, abs=1e-12)
    # φ = 30°, ψ = 0: right-wing-down roll accelerates to the right (+y):
    # ÿ = −(0 − sφ)·u1/m = 0.5·20/2 = 5 (eq (3) with its parenthesis closed after sφcψ).
    d = derivatives(VehicleState(roll=math.radians(30), vy=2.0), (20.0, 0, 0, 0), 0.0, V)
    assert d[4] == pytest.approx(5.0 - 0.1 * 2.0 / 2.0)


def test_eq5_to_eq7_hand_values():
    s = VehicleState(roll_dot=0.2, pitch_dot=-0.3, yaw_dot=0.5)
    u, wr = (0.0, 1.0, 2.0, 3.0), 4.0
    ix, iy, iz, arm, jr = V.ixx, V.iyy, V.izz, V.arm_length, V.rotor_inertia
    k4, k5, k6 = V.drag[3:]
    d = derivatives(s, u, wr, V)
    assert d[9] == pytest.approx(
        -0.3 * 0.5 * (iy - iz) / ix + jr / ix * -0.3 * wr + arm / ix * 1.0 - k4 * arm / ix * 0.2
    )
    assert d[10] == pytest.approx(
        0.2 * 0.5 * (iz - ix) / iy + jr / iy * 0.2 * wr + arm / iy * 2.0 - k5 * arm / iy * -0.3
    )
    assert d[11] == pytest.approx(0.2 * -0.3 * (ix - iy) / iz + 3.0 / iz - k6 / iz * 0.5)


def test_drag_acts_on_the_velocity_through_the_air_and_a_force_adds_its_acceleration():
    # Hovering (u1 = m·g, level) and moving north at 1 m/s in a wind of (3, −2, 0.5) m/s NED with a push of
    # (0.4, 0, −0.2) N: ẍ = −K1·(1 − 3)/m + 0.4/m, ÿ = −K2·(0 + 2)/m, z̈ = −K3·(0 − 0.5)/m − 0.2/m.
    m, (k1, k2, k3) = V.mass, V.drag[:3]
    d = derivatives(VehicleState(z=-3.0, vx=1.0), (m * V.gravity, 0, 0, 0), 0.0, V, (3.0, -2.0, 0.5, 0.4, 0.0, -0.2))
    assert d[3:6] == pytest.approx((-k1 * (1.0 - 3.0) / m + 0.4 / m, -k2 * 2.0 / m, k3 * 0.5 / m - 0.2 / m), abs=1e-15)
    # moving with the air, no drag: the hover equilibrium again
    d = derivatives(VehicleState(z=-3.0, vx=3.0, vy=-2.0), (m * V.gravity, 0, 0, 0), 0.0, V, (3.0, -2.0, 0, 0, 0, 0))
    assert d[3:6] == pytest.approx((0.0, 0.0, 0.0), abs=1e-15)


def test_a_steady_wind_carries_a_hovering_vehicle_at_the_rate_of_its_drag():
    """Level, thrust = weight, in a 4 m/s wind from the south (the air moving north): forward Euler makes
    vx(k) = 4·(1 − (1 − T·K1/m)^k) exactly, toward the wind's speed with time constant m/K1 = 20 s."""
    preset = dataclasses.replace(PAPER, initial=dataclasses.replace(PAPER.initial, altitude=10.0),
                                 wind=WindParams(speed_m_s=4.0, from_deg=180.0))  # fmt: skip
    plant = Plant(preset)
    hover = inputs_to_forces((V.mass * V.gravity, 0, 0, 0), V.d_over_b)
    for _ in range(5000):
        plant.step(hover)
    decay = (1.0 - T * V.drag[0] / V.mass) ** 5000
    assert plant.wind == pytest.approx((4.0, 0.0, 0.0), abs=1e-12)
    assert plant.state.vx == pytest.approx(4.0 * (1.0 - decay), rel=1e-9) and abs(plant.state.vy) < 1e-12


def test_a_calm_wind_section_flies_as_no_section_to_the_bit_and_wind_or_turbulence_change_the_flight():
    def fly(wind):
        plant = Plant(dataclasses.replace(PAPER, initial=dataclasses.replace(PAPER.initial, altitude=5.0), wind=wind))
        thrust = inputs_to_forces((V.mass * V.gravity + 0.3, 0.01, -0.02, 0.001), V.d_over_b)
        rows = []
        for _ in range(800):
            plant.step(thrust)
            rows.append(plant.x.copy())
        return np.array(rows)

    calm = fly(WindParams())
    assert np.array_equal(calm, fly(WindParams(from_deg=90.0, gust_rise_s=3.0, seed=9)))  # calm whatever else
    assert not np.array_equal(calm, fly(WindParams(speed_m_s=1.0)))
    light = fly(WindParams(turbulence="light", seed=1))
    assert not np.array_equal(calm, light) and np.array_equal(light, fly(WindParams(turbulence="light", seed=1)))
    assert not np.array_equal(light, fly(WindParams(turbulence="light", seed=2)))


def _euler_plant_step(s, u, wr=0.0, v=V):
    return euler(tuple(map(float, s)), tuple(map(float, u)), wr, vehicle_array(v), dynamics.CALM, T)


def test_erratum1_pitch_integrates_pitch_rate():
    # Eq (14) corrected: x5⁺ = x5 + T·x6 (the paper prints x5 + T·x5).
    s = VehicleState(z=-1.0, pitch=0.4, pitch_dot=2.0)
    out = _euler_plant_step(s, (V.mass * V.gravity, 0, 0, 0))
    assert out[7] == pytest.approx(0.4 + T * 2.0, abs=1e-15)
    assert out[7] != pytest.approx(0.4 + T * 0.4)


def test_erratum2_yaw_rate_update():
    # Eq (17) corrected: x8⁺ = (1 − T·K6/Iz)·x8 + T·x4·x6·(Ix − Iy)/Iz + T/Iz·u4 (the paper prints K8 and x4).
    v = dataclasses.replace(V, ixx=1.0, iyy=1.5)  # make the coupling term non-zero
    s = VehicleState(z=-1.0, roll_dot=0.3, pitch_dot=-0.2, yaw_dot=0.7)
    u4 = 2.0
    out = _euler_plant_step(s, (v.mass * v.gravity, 0, 0, u4), 0.0, v)
    k6 = v.drag[5]
    expected = (1 - T * k6 / v.izz) * 0.7 + T * 0.3 * -0.2 * (v.ixx - v.iyy) / v.izz + T / v.izz * u4
    assert out[11] == pytest.approx(expected, abs=1e-15)


def test_rk4_is_fourth_order():
    # Level free fall with drag from rest over 1 s, u1 = 0: vz(t) = (m·g/K3)·(1 − e^(−K3·t/m)) exactly;
    # the error shrinks ~16× when the step halves.
    v, s0, u = vehicle_array(V), (0.0,) * 12, (0.0,) * 4
    m, g, k3 = V.mass, V.gravity, V.drag[2]

    def run(n):
        s = s0
        for _ in range(n):
            s = rk4(s, u, 0.0, v, dynamics.CALM, 1.0 / n)
        return abs(s[5] - m * g / k3 * (1.0 - math.exp(-k3 / m)))

    ratio = run(10) / run(20)
    assert 14 < ratio < 18
    assert abs(euler(s0, u, 0.0, v, dynamics.CALM, 0.1)[5] - 0.1 * g) < 1e-15


def test_realistic_actuators_clamp_and_lag():
    a = actuator_array(ActuatorParams("realistic", 8.0, time_constant_up=0.02, time_constant_down=0.04))
    a_no_lag = actuator_array(ActuatorParams("realistic", 8.0))
    assert advance((0.0,) * 4, (-1.0, 4.0, 9.0, 8.0), 0.001, a_no_lag)[0] == (0.0, 4.0, 8.0, 8.0)
    # Spin-up: after one time constant the force reaches 1 − 1/e of the step.
    motors = (0.0,) * 4
    for _ in range(20):
        motors, _mean = advance(motors, (8.0,) * 4, 0.001, a)
    assert motors[0] == pytest.approx(8.0 * (1 - math.exp(-1)), rel=1e-12)
    # Spin-down uses the slower constant.
    motors = (8.0,) * 4
    for _ in range(40):
        motors, _mean = advance(motors, (0.0,) * 4, 0.001, a)
    assert motors[0] == pytest.approx(8.0 * math.exp(-1), rel=1e-12)


def test_ideal_actuators_are_reversible_without_lag():
    new, mean = advance((0.0,) * 4, (-130.0, 600.0, 0.0, 2e4), 0.001, actuator_array(PAPER.actuators))
    assert new == mean == (-130.0, 600.0, 0.0, 1e4)


def test_ground_plane_holds_a_disarmed_vehicle():
    plant = Plant(PAPER)
    for _ in range(2000):
        plant.step((0.0,) * 4)
        assert plant.state.z == 0.0 and plant.state.vz == 0.0
    assert plant.on_ground


def test_ground_plane_catches_a_falling_vehicle():
    x500 = dataclasses.replace(load_preset("x500"), initial=dataclasses.replace(PAPER.initial, altitude=1.0))
    plant = Plant(x500)
    lowest = 0.0
    for _ in range(1500):  # free fall from 1 m takes 0.45 s
        plant.step((0.0,) * 4)
        lowest = max(lowest, plant.state.z)
    assert lowest == 0.0 and plant.on_ground and plant.state.vz == 0.0


def test_ground_plane_does_not_touch_a_takeoff():
    plant = Plant(PAPER)
    thrust = inputs_to_forces((2 * V.mass * V.gravity, 0, 0, 0), V.d_over_b)
    plant.step(thrust)
    # Forward Euler: z⁺ = z + T·vz = 0 on the first tick, but the vehicle is climbing.
    assert plant.state.vz < 0 and not plant.on_ground
    plant.step(thrust)
    assert plant.state.z < 0
