"""PX4's multicopter cascade (autopilot/px4.py, ``--controller px4``) against PX4's own unit tests, case by case:
PositionControlTest.cpp, ControlMathTest.cpp and AttitudeControlTest.cpp (src/modules/mc_pos_control/PositionControl
and src/modules/mc_att_control/AttitudeControl of PX4-Autopilot), with their inputs and expected outputs; then the
cascade flying the x500."""

from __future__ import annotations

import math

import numpy as np
import pytest

from autopilot import px4
from groundstation.offline import run_offline, tracking
from quadsitl.config import load_preset

G = 9.80665  # CONSTANTS_ONE_G
NAN = math.nan


def fixture_update(pos_sp=(NAN,) * 3, vel_sp=(NAN,) * 3, acc_sp=(NAN,) * 3):
    """PositionControlTest's fixture: Kp 1, velocity P, I and D 20, velocity limits 1 m/s, thrust limits 0.1..0.9,
    horizontal margin 0.3, tilt limit 1 rad, hover thrust 0.5, the vehicle at rest at the origin, update(0.1)."""
    vel_int = np.zeros(3)
    thrust = px4.position_control((0.0,) * 3, (0.0,) * 3, (0.0,) * 3, pos_sp, vel_sp, acc_sp, (1.0,) * 3, (20.0,) * 3,
                                  (20.0,) * 3, (20.0,) * 3, (1.0, 1.0, 1.0), 1.0, 0.1, 0.9, 0.3, 0.5, G, vel_int,
                                  0.1)  # fmt: skip
    return np.array(thrust[:3]), vel_int


def test_position_control_max_thrust_limit():
    """PositionControlMaxThrustLimit: |thrust| = 0.9 with 0.3 of it horizontal, split equally."""
    thr, vel_int = fixture_update(pos_sp=(10.0, 10.0, -10.0))
    assert thr == pytest.approx((0.3 / math.sqrt(2), 0.3 / math.sqrt(2), -math.sqrt(0.9**2 - 0.3**2)), abs=1e-6)
    assert vel_int == pytest.approx((-0.58209, -0.58209, 0.0), abs=1e-5)  # the horizontal anti-windup wound it back
    q = px4.bodyz_to_attitude(*(-thr), 0.0)
    roll = math.atan2(2 * (q[0] * q[1] + q[2] * q[3]), 1 - 2 * (q[1] ** 2 + q[2] ** 2))
    assert roll == pytest.approx(math.asin((0.3 / math.sqrt(2)) / 0.9), abs=1e-6)


def test_position_control_min_thrust_limit():
    """PositionControlMinThrustLimit: going down hard, |thrust| = 0.1, pitched by the tilt limit (1 rad)."""
    thr, _ = fixture_update(pos_sp=(10.0, 0.0, 10.0))
    assert np.linalg.norm(thr) == pytest.approx(0.1, abs=1e-6)
    assert thr == pytest.approx((0.0841471, 0.0, -0.0540302), abs=1e-6)
    assert px4.bodyz_to_attitude(*(-thr), 0.0) == pytest.approx((0.877583, 0.0, -0.479426, 0.0), abs=1e-6)


def test_idle_and_failsafe_inputs():
    """IdleThrustInput (acceleration (0, 0, 100): the minimum thrust) and FailsafeInput (descend at 0.1 m/s, no
    horizontal acceleration)."""
    thr, _ = fixture_update(acc_sp=(0.0, 0.0, 100.0))
    assert thr == pytest.approx((0.0, 0.0, -0.1), abs=1e-9)
    thr, _ = fixture_update(vel_sp=(NAN, NAN, 0.1), acc_sp=(0.0, 0.0, NAN))
    assert thr[:2] == pytest.approx((0.0, 0.0), abs=1e-9) and thr[2] == pytest.approx(-0.398028, abs=1e-6)


@pytest.mark.parametrize("which", ["position", "velocity"])
def test_position_and_velocity_direction(which):
    """PositionControlTest's Position/VelocityDirection: a setpoint ahead, right and up tilts the thrust there."""
    sp = (0.1, 0.1, -0.1)
    thr, _ = fixture_update(pos_sp=sp) if which == "position" else fixture_update(vel_sp=sp)
    assert thr == pytest.approx((0.122768, 0.122768, -0.601972), abs=1e-6)


def test_control_math():
    """ControlMathTest: limitTilt, constrainXY, thrustToAttitude."""
    assert px4.limit_tilt(1.0, 0.0, 0.0, math.radians(45)) == pytest.approx((math.sqrt(0.5), 0.0, math.sqrt(0.5)))
    bz = px4.limit_tilt(0.0, 0.0, -1.0, math.radians(45))
    assert math.degrees(math.acos(bz[2])) == pytest.approx(45.0) and np.linalg.norm(bz) == pytest.approx(1.0)
    assert px4.constrain_xy(4.0, 0.0, 0.0, -4.0, 5.0) == pytest.approx((4.0, -3.0))
    assert px4.bodyz_to_attitude(0.0, 0.0, 1.0, 0.0) == pytest.approx((1.0, 0.0, 0.0, 0.0))  # thrust (0, 0, −1)
    q = px4.bodyz_to_attitude(0.0, 0.0, 1.0, math.pi / 2)
    assert math.atan2(2 * (q[0] * q[3] + q[1] * q[2]), 1 - 2 * (q[2] ** 2 + q[3] ** 2)) == pytest.approx(math.pi / 2)
    assert px4.bodyz_to_attitude(0.0, 0.0, -1.0, math.pi / 2) == pytest.approx((0.0, math.sqrt(0.5), math.sqrt(0.5),
                                                                                0.0), abs=1e-9)  # fmt: skip


def test_attitude_control_yaw_weight_scaling():
    """AttitudeControlTest's YawWeightScaling: a pure yaw error of 0.1 rad with MC_YAW_P 2.8 and weight 0.4 gives a
    yaw rate of 0.28 rad/s (the yaw gain divided by the weight, the error by it scaled), nothing on roll and pitch;
    weight 0 gives zero, not NaN."""
    q_yaw = (math.cos(0.05), 0.0, 0.0, math.sin(0.05))
    rate = px4.attitude_control((1.0, 0.0, 0.0, 0.0), q_yaw, NAN, (6.5, 6.5, 2.8 / 0.4), 0.4, (1000.0,) * 3)
    assert rate == pytest.approx((0.0, 0.0, 0.1 * 2.8), abs=1e-4)
    assert px4.attitude_control((1.0, 0.0, 0.0, 0.0), q_yaw, NAN, (6.5, 6.5, 2.8), 0.0, (1000.0,) * 3) == (0, 0, 0)


def test_attitude_control_converges_from_any_attitude():
    """AttitudeControlConvergence: gains (0.5, 0.6, 0.3), weight 0.4, from each of a set of attitudes to each of
    them, the state turned by the rate setpoint each step: the rate setpoint's norm falls and reaches the goal."""

    def quat(w, x, y, z):
        n = math.sqrt(w * w + x * x + y * y + z * z)
        return (w / n, x / n, y / n, z / n)

    attitudes = [quat(1, 0, 0, 0), quat(0, 1, 0, 0), quat(0, 0, 1, 0), quat(0, 0, 0, 1), quat(1, 1, 0, 0),
                 quat(1, 0, 1, 0), quat(1, 0, 0, 1), quat(0.698, 0.024, -0.681, -0.220)]  # fmt: skip
    for q0 in attitudes:
        for qd in attitudes:
            q, last = q0, math.inf
            for _ in range(100):
                rate = px4.attitude_control(q, qd, NAN, (0.5, 0.6, 0.3 / 0.4), 0.4, (100.0,) * 3)
                norm = math.sqrt(sum(r * r for r in rate))
                assert norm <= last + 1e-9
                last = norm
                angle = norm
                turn = (1.0, 0.0, 0.0, 0.0) if angle < 1e-12 else (math.cos(angle / 2), *(
                    r / angle * math.sin(angle / 2) for r in rate))  # fmt: skip
                q = px4._multiply(q, turn)
            assert last < 1e-3


def test_px4_flies_the_x500_circle_within_1_m_rms():
    x500 = load_preset("x500")
    results, _ = run_offline(x500, ["px4"], trajectory="circle")
    res = results["px4"]
    assert res.diverged_at is None and res.controller_failed_at is None and np.isfinite(res.forces).all()
    track = tracking(results)["px4"]
    assert track["horizontal_rms"] < 1.0 and track["altitude_rms"] < 1.0
