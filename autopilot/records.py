"""What the ground-station links ask of the vehicle, as typed records: the receiver (:mod:`autopilot.receiver`) turns
each MAVLink message into one, and the handler of its type takes it from there (:class:`Routes`). PX4's
``mavlink_receiver`` does the same with uORB topics (``trajectory_setpoint``, ``vehicle_command``, …).

Frames and units: positions local NED [m] from the local origin (altitudes up [m] above it), velocities [m/s],
accelerations [m/s²], angles [rad]; NaN where a field is not set; ``wall`` the receiver's wall clock [s].
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from autopilot.setpoints import INT32_MAX
from quadsitl import wire


@dataclass(frozen=True)
class TrajectorySetpoint:
    """SET_POSITION_TARGET_LOCAL_NED or _GLOBAL_INT, validated and in local NED (:func:`autopilot.setpoints.
    position_target`): ``horizontal`` (x, y, vx, vy, ax, ay), ``vertical`` (altitude, climb rate, its rate),
    ``heading`` (yaw, yaw rate); a group the type_mask ignores whole is None (it stays as it was)."""

    horizontal: tuple[float, float, float, float, float, float] | None
    vertical: tuple[float, float, float] | None
    heading: tuple[float, float] | None
    wall: float


@dataclass(frozen=True)
class AttitudeSetpoint:
    """SET_ATTITUDE_TARGET's attitude (roll, pitch, yaw), within the tilt limit, and its normalised collective thrust
    (0..1, −1..1 on reversible motors; NaN: the type_mask ignores it, and the vertical setpoint stays as it was)."""

    roll: float
    pitch: float
    yaw: float
    wall: float
    thrust: float = math.nan


@dataclass(frozen=True)
class ManualControl:
    """MANUAL_CONTROL's sticks, as PX4's ``manual_control_setpoint`` reads them: pitch (x: forward +), roll (y: right
    +) and yaw (r: right +) in −1..1, throttle (z 0..1000 → −1..1: 0 at the centre); an axis MANUAL_CONTROL marks
    invalid (INT16_MAX) is centred."""

    pitch: float
    roll: float
    throttle: float
    yaw: float
    wall: float


@dataclass(frozen=True)
class FollowTarget:
    """FOLLOW_TARGET, as PX4 reads it (its position and velocity; the rest unused): follow-me's target in local NED
    (x, y [m], altitude [m] above the local origin), its velocity (north, east, up [m/s]; NaN: not reported)."""

    x: float
    y: float
    altitude: float
    vx: float
    vy: float
    climb: float
    wall: float


@dataclass(frozen=True)
class Command:
    """COMMAND_LONG or COMMAND_INT: the command id, params 1–7 (COMMAND_INT's 5–7 are x, y, z), its frame (COMMAND_LONG:
    a global frame, AMSL), who sent it and the link it came on (SET_MESSAGE_INTERVAL applies to that link)."""

    command: int
    params: tuple[float, float, float, float, float, float, float]
    frame: int
    is_int: bool  # COMMAND_INT: x, y are latitude, longitude in 1e7 deg (INT32_MAX: not given)
    source: tuple[int, int]
    link: Any

    def param(self, n: int) -> float:
        """Param ``n`` (1–7)."""
        return self.params[n - 1]

    def location(self) -> tuple[float, float, float, int]:
        """(latitude, longitude [deg], altitude [m], frame): COMMAND_INT's x, y and z, or COMMAND_LONG's params 5–7.
        NaN where not given."""
        x, y, z = self.params[4:]
        if self.is_int:
            lat = math.nan if x == INT32_MAX else x * 1e-7
            lon = math.nan if y == INT32_MAX else y * 1e-7
            return lat, lon, z, self.frame
        return x, y, z, self.frame


@dataclass(frozen=True)
class ModeRequest:
    """SET_MODE: PX4's custom mode (None: not one we fly) and the raw custom_mode, to say which."""

    mode: wire.Mode | None
    custom_mode: int


@dataclass(frozen=True)
class ParamRequest:
    """PARAM_REQUEST_LIST (``name`` None) or PARAM_REQUEST_READ (by name, or by ``index`` when it is ≥ 0)."""

    name: str | None
    index: int = -1


@dataclass(frozen=True)
class ParamSet:
    """PARAM_SET: a parameter's new value, and who sent it (system, component: a refusal's PARAM_ERROR goes to it)."""

    name: str
    value: float
    source: tuple[int, int] = (0, 0)


@dataclass(frozen=True)
class MissionMessage:
    """A mission-protocol message for this vehicle (:mod:`autopilot.mission_protocol`): its id, its sender
    ``(system, component)`` and its fields by pymavlink's names."""

    msg_id: int
    sender: tuple[int, int]
    fields: dict


@dataclass(frozen=True)
class FileTransfer:
    """FILE_TRANSFER_PROTOCOL: the request's payload and who sent it."""

    payload: bytes
    source: tuple[int, int]


@dataclass(frozen=True)
class LogRequest:
    """LOG_REQUEST_LIST, LOG_REQUEST_DATA, LOG_REQUEST_END or LOG_ERASE for this vehicle (:mod:`autopilot.
    log_protocol`): its id, its fields by pymavlink's names, and the link it came on (the data goes back on it)."""

    msg_id: int
    fields: dict
    link: Any


@dataclass(frozen=True)
class GroundHeartbeat:
    """A ground station's HEARTBEAT (MAV_TYPE_GCS): the datalink is alive."""

    wall: float


Record = (
    TrajectorySetpoint
    | AttitudeSetpoint
    | ManualControl
    | FollowTarget
    | Command
    | ModeRequest
    | ParamRequest
    | ParamSet
    | MissionMessage
    | FileTransfer
    | LogRequest
    | GroundHeartbeat
)


@dataclass
class Routes:
    """Who takes each record, wired once by the process (:mod:`autopilot.process`)."""

    trajectory: Callable[[TrajectorySetpoint], None]
    attitude: Callable[[AttitudeSetpoint], None]
    manual_control: Callable[[ManualControl], None]
    follow_target: Callable[[FollowTarget], None]
    command: Callable[[Command], None]
    mode: Callable[[ModeRequest], None]
    param_request: Callable[[ParamRequest], None]
    param_set: Callable[[ParamSet], None]
    mission: Callable[[MissionMessage], None]
    file_transfer: Callable[[FileTransfer], None]
    log: Callable[[LogRequest], None]
    ground_heartbeat: Callable[[GroundHeartbeat], None]

    def deliver(self, record: Record) -> None:
        """``record`` to the handler of its type."""
        getattr(self, _ROUTE[type(record)])(record)


_ROUTE = {
    TrajectorySetpoint: "trajectory",
    AttitudeSetpoint: "attitude",
    ManualControl: "manual_control",
    FollowTarget: "follow_target",
    Command: "command",
    ModeRequest: "mode",
    ParamRequest: "param_request",
    ParamSet: "param_set",
    MissionMessage: "mission",
    FileTransfer: "file_transfer",
    LogRequest: "log",
    GroundHeartbeat: "ground_heartbeat",
}


@dataclass
class Counters:
    """The input counters SYS_STATUS reports (errors_comm, errors_count1..4)."""

    comm: int = 0  # ground-station datagrams that are not MAVLink or fail their CRC
    unknown: int = 0  # well-formed messages we do not handle (ignored)
    refused: int = 0  # setpoints and parameter values refused by validation
    plant: int = 0  # plant-link datagrams that are corrupt, non-finite, or from a stranger
    not_for_us: int = 0  # messages addressed to another system or component (ignored)

    def as_tuple(self) -> tuple[int, int, int, int, int]:
        return self.comm, self.unknown, self.refused, self.plant, self.not_for_us
