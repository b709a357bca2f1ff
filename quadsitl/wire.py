"""MAVLink on the wire between the processes (DESIGN.md §4), in one place.

Plant → autopilot, once a tick: ``ODOMETRY`` (all float32): ``time_usec`` = simulated time, position in
``MAV_FRAME_LOCAL_NED``, quaternion [w, x, y, z] FRD → NED, velocity in NED (``child_frame_id`` =
``MAV_FRAME_LOCAL_NED``), body rates p, q, r (FRD).

Autopilot → plant, once a tick: ``HIL_ACTUATOR_CONTROLS`` with ``time_usec`` echoing the state it answers
and ``controls[0..3]`` = F_j / F_max for motors 1..4 (eq (8) numbering): in [0, 1], or [−1, 1] for
reversible (ideal) actuators.

Ground station ↔ autopilot: PX4 conventions (custom modes below, COMMAND_LONG/ACK, setpoints).
"""

from __future__ import annotations

import math
from enum import IntEnum

from pymavlink.dialects.v20 import common as mavlink

from quadsitl.frames import (
    body_rates_to_euler_rates,
    euler_rates_to_body_rates,
    euler_to_quaternion,
    quaternion_to_euler,
)
from quadsitl.state import VehicleState

PLANT_SYSTEM_ID = 1
PLANT_COMPONENT_ID = mavlink.MAV_COMP_ID_USER1  # the simulator, as PX4's SIH/Gazebo bridges use a separate component
AUTOPILOT_COMPONENT_ID = mavlink.MAV_COMP_ID_AUTOPILOT1
GCS_SYSTEM_ID = 255
GCS_COMPONENT_ID = mavlink.MAV_COMP_ID_MISSIONPLANNER

_NAN21 = [math.nan] + [0.0] * 20


class Mode(IntEnum):
    """The autopilot's flight modes and their PX4 custom-mode encoding (main << 16 | sub << 24)."""

    HOLD = 0  # PX4 auto/loiter: level attitude, hold altitude
    OFFBOARD = 1  # PX4 offboard: external attitude and altitude setpoints
    LAND = 2  # PX4 auto/land: level, descend, disarm on touchdown

    @property
    def px4_custom_mode(self) -> int:
        return {Mode.HOLD: (4 << 16) | (3 << 24), Mode.OFFBOARD: 6 << 16, Mode.LAND: (4 << 16) | (6 << 24)}[self]

    @classmethod
    def from_px4(cls, custom_mode: int) -> Mode | None:
        main, sub = (custom_mode >> 16) & 0xFF, (custom_mode >> 24) & 0xFF
        if main == 6:
            return cls.OFFBOARD
        if main == 4 and sub == 3:
            return cls.HOLD
        if main == 4 and sub == 6:
            return cls.LAND
        return None


def link(system: int, component: int) -> mavlink.MAVLink:
    """A MAVLink 2 encoder/decoder (no file: ``msg.pack(link)`` gives bytes, ``link.parse_buffer`` reads)."""
    mav = mavlink.MAVLink(None, srcSystem=system, srcComponent=component)
    mav.robust_parsing = True
    return mav


def state_message(time_usec: int, s: VehicleState) -> mavlink.MAVLink_odometry_message:
    """The plant's state as ODOMETRY (Euler-angle rates converted to body rates with eq (1))."""
    q = euler_to_quaternion(s.roll, s.pitch, s.yaw)
    p, qr, r = euler_rates_to_body_rates(s.roll, s.pitch, s.roll_dot, s.pitch_dot, s.yaw_dot)
    return mavlink.MAVLink_odometry_message(
        time_usec, mavlink.MAV_FRAME_LOCAL_NED, mavlink.MAV_FRAME_LOCAL_NED,
        s.x, s.y, s.z, q, s.vx, s.vy, s.vz, p, qr, r, _NAN21, _NAN21, 0, mavlink.MAV_ESTIMATOR_TYPE_NAIVE, 100,
    )  # fmt: skip


def state_from_message(m: mavlink.MAVLink_odometry_message) -> VehicleState:
    """ODOMETRY → VehicleState (body rates → Euler-angle rates with the inverse of eq (1))."""
    roll, pitch, yaw = quaternion_to_euler(*m.q)
    rd, pd, yd = body_rates_to_euler_rates(roll, pitch, m.rollspeed, m.pitchspeed, m.yawspeed)
    return VehicleState(m.x, m.y, m.z, m.vx, m.vy, m.vz, roll, pitch, yaw, rd, pd, yd)


def actuator_message(
    time_usec: int, forces: tuple[float, float, float, float], max_thrust: float, armed: bool
) -> mavlink.MAVLink_hil_actuator_controls_message:
    """Motor forces [N] → HIL_ACTUATOR_CONTROLS with controls[j] = F_j / F_max."""
    controls = [f / max_thrust for f in forces] + [0.0] * 12
    mode = mavlink.MAV_MODE_FLAG_SAFETY_ARMED if armed else 0
    return mavlink.MAVLink_hil_actuator_controls_message(time_usec, controls, mode, 0)


def forces_from_message(m: mavlink.MAVLink_hil_actuator_controls_message, max_thrust: float) -> tuple[float, ...]:
    """HIL_ACTUATOR_CONTROLS → commanded motor forces [N]."""
    c = m.controls
    return (c[0] * max_thrust, c[1] * max_thrust, c[2] * max_thrust, c[3] * max_thrust)


def tick_of(time_usec: int, period: float) -> int:
    """The control tick a ``time_usec`` stamp belongs to."""
    return round(time_usec * 1e-6 / period)


def usec_of(tick: int, period: float) -> int:
    return round(tick * period * 1e6)
