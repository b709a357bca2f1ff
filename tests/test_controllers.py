"""The backstepping controller (eqs 18–33 with errata 3, 4, 7, 8), the designed error dynamics to
round-off, the PD baseline, and the closed loop of the paper's experiment."""

import dataclasses
import math

import numpy as np
import pytest

from autopilot.backstepping import BacksteppingController
from autopilot.factory import make_controller
from autopilot.gains import GainError, poles_from_rates, rates_from_poles, stability_interval
from autopilot.pd import PDController
from groundstation.offline import run_offline
from quadsitl.config import load_preset
from quadsitl.mixer import inputs_to_forces
from quadsitl.state import Reference, VehicleState
from sitl.plant import Plant

PAPER = load_preset("paper")
V = PAPER.vehicle
T = PAPER.sim.period
POLES = poles_from_rates([10.0] * 8, T)


def test_erratum4_hover_thrust_equals_weight():
    # At the reference, at rest, level: u1 must be m·g. The paper's printed (28), −(1 − K3/m)·x2 + g,
    # would command m·g/T = 19.6 kN.
    c = BacksteppingController(V, T, POLES)
    u = c.step(VehicleState(z=-5.0), Reference(5.0, 0, 0, 0))
    assert u.u1 == pytest.approx(V.mass * V.gravity, rel=1e-12)
    assert (u.u2, u.u3, u.u4) == pytest.approx((0, 0, 0), abs=1e-12)


def test_erratum4_u1_compensates_drag_with_T_K3_over_m():
    # Climbing at the reference altitude with ḣ = 1 and poles 0 (dead-beat): e1 = 0, e2 = 1,
    # x2d⁺ = (λ1 − 1)/T·(e1 + T·ḣ) = −1, so (28) gives u1 = m/T·(−(1 − T·K3/m)·1 + T·g − 1).
    c = BacksteppingController(V, T, (0.0,) * 8)
    u = c.step(VehicleState(z=-5.0, vz=-1.0), Reference(5.0, 0, 0, 0))
    k3 = V.drag[2]
    assert u.u1 == pytest.approx(V.mass / T * (-(1 - T * k3 / V.mass) + T * V.gravity - 1.0), rel=1e-12)


def test_erratum3_u4_uses_K6_over_Iz():
    # Dead-beat poles, at the yaw reference with ψ̇ = 1: x8d⁺ = −1, u4 = Iz/T·(−(1 − T·K6/Iz)·1 − 1).
    # The printed (31) has (1 − T·K6/m), which differs because m = 2 ≠ Iz = 2.2.
    c = BacksteppingController(V, T, (0.0,) * 8)
    u = c.step(VehicleState(z=-5.0, yaw_dot=1.0), Reference(5.0, 0, 0, 0))
    k6 = V.drag[5]
    assert u.u4 == pytest.approx(V.izz / T * (-(1 - T * k6 / V.izz) - 1.0), rel=1e-12)
    assert u.u4 != pytest.approx(V.izz / T * (-(1 - T * k6 / V.mass) - 1.0), rel=1e-9)


def test_erratum7_rates_give_the_documented_epsilon_interval():
    lo, hi = stability_interval(POLES, T)
    assert pytest.approx((0.99,) * 8) == POLES
    assert lo == pytest.approx(4 * T**2 * 0.99**2 / (1 - 0.99**2))
    assert 1.9e-4 < lo < 2.1e-4
    assert hi == pytest.approx(1 - T**2 - 0.99**2) and 0.0198 < hi < 0.0200
    assert rates_from_poles(POLES, T) == pytest.approx((10.0,) * 8)


def test_erratum7_the_papers_gains_read_literally_are_refused():
    with pytest.raises(GainError, match=r"condition \(41\).*λ1 = -10"):
        stability_interval((-10.0,) * 8, T)
    with pytest.raises(GainError):
        BacksteppingController(V, T, (-10.0,) * 8)


@pytest.mark.parametrize(
    ("index", "pole", "eq"),
    [(0, 1.5, 41), (2, -1.0, 42), (4, 1.0, 43), (6, 1.2, 44), (1, 0.9999999, 41), (7, -1.0, 44)],
)
def test_erratum7_every_channel_is_checked(index, pole, eq):
    # The paper's Lyapunov sum runs to 6 (erratum 6); the yaw channel (λ7, λ8) is checked as well.
    poles = list(POLES)
    poles[index] = pole
    with pytest.raises(GainError, match=rf"\({eq}\).*λ{index + 1} = "):
        stability_interval(poles, T)


def test_erratum7_conflicting_conditions_name_both():
    poles = list(POLES)
    poles[0] = 0.9999  # needs ε > 4T²λ²/(1 − λ²) ≈ 0.02
    with pytest.raises(GainError, match=r"conditions \(41\) and \(4[1-4]\) conflict.*λ1"):
        stability_interval(poles, T)


def test_erratum8_tilt_reference_is_limited_and_thrust_stays_finite():
    c = BacksteppingController(V, T, POLES, max_tilt=math.radians(30), thrust_min=0.0, thrust_max=100.0)
    c.step(VehicleState(z=-5.0), Reference(5.0, 1.4, -1.4, 0.0))
    # e3 = φ − φ_d with φ_d clamped to 30°.
    assert c.errors[2] == pytest.approx(-math.radians(30))
    assert c.errors[4] == pytest.approx(math.radians(30))
    # Measured at 89.9° roll: 1/(cφcθ) is bounded by cos(max_tilt), u1 within limits.
    u = c.step(VehicleState(z=-5.0, roll=math.radians(89.9)), Reference(5.0, 0, 0, 0))
    assert math.isfinite(u.u1) and 0.0 <= u.u1 <= 100.0


def _designed_dynamics_run(vehicle, poles, state, ref, ticks=1500):
    preset = dataclasses.replace(PAPER, vehicle=vehicle)
    plant = Plant(preset, integrator="euler", substeps=1)
    plant.state = state
    c = BacksteppingController(vehicle, T, poles, thrust_min=-1e9, thrust_max=1e9)
    errors = []
    for _ in range(ticks):
        u = c.step(plant.state, ref)
        errors.append(c.errors)
        # Give the plant the Ωr the controller assumed (it could not know the current command's).
        plant.step(inputs_to_forces(u, vehicle.d_over_b), omega_r=c.omega_r)
    return np.array(errors)


@pytest.mark.parametrize(
    "vehicle",
    [V, dataclasses.replace(V, ixx=1.0, iyy=1.6, izz=2.2)],  # the paper's, and one with Ix ≠ Iy
    ids=["paper", "asymmetric"],
)
def test_designed_error_dynamics_hold_to_round_off(vehicle):
    poles = (0.99, 0.985, 0.98, 0.975, 0.97, 0.995, 0.992, 0.96)
    start = VehicleState(z=-1.0, vz=0.5, roll=0.1, pitch=-0.2, yaw=3.0, roll_dot=0.3, pitch_dot=-0.4, yaw_dot=0.5)
    ref = Reference(5.0, math.pi / 3, math.pi / 3, math.pi / 3)
    e = _designed_dynamics_run(vehicle, poles, start, ref)
    assert np.abs(e[0]).max() > 1.0  # the errors are far from zero at the start
    for j in range(4):
        i, n = 2 * j, 2 * j + 1
        lam_i, lam_n = poles[i], poles[n]
        # (27) e_i⁺ = λ_i·e_i + T·e_(i+1)  and  (33) e_(i+1)⁺ = λ_(i+1)·e_(i+1)
        pos = e[1:, i] - (lam_i * e[:-1, i] + T * e[:-1, n])
        rate = e[1:, n] - lam_n * e[:-1, n]
        assert np.abs(pos).max() <= 1e-9, f"channel {j}: position error dynamics off by {np.abs(pos).max()}"
        assert np.abs(rate).max() <= 1e-9, f"channel {j}: rate error dynamics off by {np.abs(rate).max()}"


def test_designed_dynamics_fail_without_the_errata():
    # A controller with the printed (28) (no T on g) does not give e2⁺ = λ2·e2: the test above can fail.
    class Printed28(BacksteppingController):
        def step(self, state, reference):
            u = super().step(state, reference)
            c = math.cos(state.roll) * math.cos(state.pitch)
            return u._replace(u1=u.u1 + self.vehicle.mass / (T * c) * (self.vehicle.gravity - T * self.vehicle.gravity))

    plant = Plant(PAPER, integrator="euler")
    c = Printed28(V, T, POLES)
    u = c.step(plant.state, PAPER.reference)
    e2 = c.errors[1]
    plant.step(inputs_to_forces(u, V.d_over_b), omega_r=c.omega_r)
    c.step(plant.state, PAPER.reference)
    assert abs(c.errors[1] - 0.99 * e2) > 1.0


@pytest.mark.parametrize("integrator", ["euler", "rk4"])
def test_paper_experiment_settles_within_2pct_in_under_1s(integrator):
    _, metrics = run_offline(PAPER, ["backstepping"], integrator=integrator, duration=2.0)
    for channel, m in metrics["backstepping"].items():
        assert m["settling_time"] is not None and m["settling_time"] < 1.0, (channel, m)
        assert abs(m["steady_state_error"]) < 1e-6


def test_paper_experiment_does_not_depend_on_the_integrator():
    e, _ = run_offline(PAPER, ["backstepping"], integrator="euler", duration=2.0)
    r, _ = run_offline(PAPER, ["backstepping"], integrator="rk4", substeps=4, duration=2.0)
    a, b = e["backstepping"].state, r["backstepping"].state
    assert np.abs(a[:, 2] - b[:, 2]).max() < 0.01  # altitude: 8 mm at most, in the transient
    assert np.abs(a[:, 6:9] - b[:, 6:9]).max() < 0.003  # angles [rad]
    assert np.abs(a[-1, [2, 6, 7, 8]] - b[-1, [2, 6, 7, 8]]).max() < 1e-6


def test_erratum10_paper_forces_go_negative_and_peak_near_600N():
    res, _ = run_offline(PAPER, ["backstepping"], duration=2.0)
    f = res["backstepping"].forces
    assert -200 < f.min() < -100 and 550 < f.max() < 650


def test_pd_baseline_hand_value_and_convergence():
    kp, kd = (100.0,) * 4, (20.0,) * 4
    pd = PDController(V, kp, kd)
    u = pd.step(VehicleState(z=-4.0, vz=-1.0, roll_dot=0.5), Reference(5.0, 0.1, 0.0, 0.0))
    assert u.u1 == pytest.approx(V.mass * (V.gravity + 100 * 1.0 - 20 * 1.0))
    assert u.u2 == pytest.approx(V.ixx / V.arm_length * (100 * 0.1 - 20 * 0.5))
    _, metrics = run_offline(PAPER, ["pd"], duration=3.0)
    for m in metrics["pd"].values():
        assert abs(m["steady_state_error"]) < 1e-3


@pytest.mark.parametrize("name", ["paper", "x500"])
def test_erratum9_pd_gains_are_fair(name):
    # Shipped PD gains put the linearised PD poles where the backstepping rates are:
    # kp = k_i·k_(i+1), kd = k_i + k_(i+1).
    p = load_preset(name)
    k = rates_from_poles(p.poles(), p.sim.period)
    for j in range(4):
        assert p.controller.pd_kp[j] == pytest.approx(k[2 * j] * k[2 * j + 1])
        assert p.controller.pd_kd[j] == pytest.approx(k[2 * j] + k[2 * j + 1])


def test_realistic_preset_flies_within_motor_limits():
    p = load_preset("x500")
    res, metrics = run_offline(p, ["backstepping", "pd"])
    for kind in ("backstepping", "pd"):
        f = res[kind].forces
        assert f.min() >= 0.0 and f.max() <= p.actuators.max_thrust
        for channel, m in metrics[kind].items():
            assert abs(m["steady_state_error"]) < 0.01, (kind, channel, m)


def test_factory_applies_overrides():
    c = make_controller(PAPER, rates=[5.0] * 8, position_loop=False)  # `sim`: the paper's experiment alone
    assert c.poles == pytest.approx((0.995,) * 8)
    with pytest.raises(GainError, match=r"condition \(56\).*k10 \(x velocity\) = 2 1/s.*0 < k10 ≤ 1.66667 1/s"):
        make_controller(PAPER, rates=[5.0] * 8)  # the flight controller's horizontal loop would outrun the attitude
    c = make_controller(PAPER, poles=[0.9] * 8)
    assert c.poles == (0.9,) * 8
    assert isinstance(make_controller(PAPER, "pd"), PDController)
