"""Modes, arming, setpoints and failsafes: a pure state machine, fed with events and simulated time.

No I/O. The process shell calls ``arm``/``disarm``/``set_mode``/setpoint handlers when MAVLink says
so, and ``update`` once per control tick; it gets back the reference to fly (or ``None`` when
disarmed) and messages to announce in STATUSTEXT.

Rules:
- Boot: disarmed, HOLD. Arming is allowed in HOLD and OFFBOARD; arming into OFFBOARD needs a fresh
  setpoint stream. Switching to OFFBOARD needs a fresh setpoint stream (PX4 convention).
- Setpoint stream: SET_ATTITUDE_TARGET and SET_POSITION_TARGET_LOCAL_NED both feed it; it is fresh
  while the newest arrived within ``setpoint_timeout`` seconds of *simulated* time.
- OFFBOARD: altitude reference = the last z setpoint (the altitude held on entering offboard until
  one arrives); attitude reference = the last attitude setpoint (level, current heading until one does).
- Failsafe: in OFFBOARD, a stream older than the timeout switches to LAND and says so.
- HOLD: level attitude, heading and altitude as on entry. LAND: level, heading as on entry, altitude
  reference descending at ``land_speed`` to below the ground; touchdown (altitude < 5 cm, |climb| <
  0.1 m/s for ``landed_time``) disarms.

The per-tick part (:func:`update`) is compiled (:mod:`quadsitl.jit`) and works on the commander's state,
one float64 array with a name per index, so the autopilot's whole tick runs as one compiled call
(:mod:`autopilot.tick`). The events (arm, modes, setpoints, failsafes) are ordinary Python methods of
:class:`Commander` on the same array, and the messages to announce are Python strings.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from quadsitl.jit import jit
from quadsitl.state import Reference, VehicleState
from quadsitl.wire import Mode

FAILSAFE_NONE = 0
FAILSAFE_SETPOINT_LOST = 1
FAILSAFE_PLANT_LOST = 2
FAILSAFE_GCS_LOST = 3
DATALINK_ACTIONS = ("none", "hold", "land")  # NAV_DLL_ACT, as PX4 numbers its first ones
HOLD, OFFBOARD, LAND = int(Mode.HOLD), int(Mode.OFFBOARD), int(Mode.LAND)

# The commander's state array: flags and mode, the offboard setpoints (NaN: none yet), the time of the
# newest setpoint [s], the tick the current offboard flight started (−1: none), the reference held in
# hold and land, when the vehicle came to rest in land (NaN: it has not), the time and tick of the last
# update, the state it saw (altitude, climb rate [m/s], yaw), the settings the tick needs, and the
# reference to fly this tick (valid while armed).
(ARMED, MODE, FAILSAFE, ALT_SP, ROLL_SP, PITCH_SP, YAW_SP, LAST_SP_TIME, OFFBOARD_TICK, HOLD_ALT, HOLD_ROLL,
 HOLD_PITCH, HOLD_YAW, LANDED_SINCE, NOW, TICK, ALTITUDE, CLIMB_RATE, YAW, SETPOINT_TIMEOUT, LAND_SPEED,
 LANDED_TIME, LAND_TARGET, REF_ALT, REF_ROLL, REF_PITCH, REF_YAW, SIZE) = range(28)  # fmt: skip
# What update() reports for the shell to announce.
EVENT_NONE, EVENT_SETPOINT_LOST, EVENT_LANDED = 0, 1, 2


@dataclass
class CommanderSettings:
    setpoint_timeout: float = 1.0  # [s] simulated, like PX4's COM_OF_LOSS_T
    land_speed: float = 1.0  # [m/s]
    landed_time: float = 0.5  # [s]
    land_target: float = -0.5  # [m] the landing reference goes this far below the ground
    altitude_max: float = 1000.0  # [m] altitude setpoints above this (or below 0) are refused
    datalink_timeout: float = 10.0  # [s] wall, like PX4's COM_DL_LOSS_T: ground-station heartbeat loss
    datalink_action: int = 0  # index in DATALINK_ACTIONS, like PX4's NAV_DLL_ACT (0: do nothing)


@jit
def stream_fresh(cm: np.ndarray) -> bool:
    return cm[NOW] - cm[LAST_SP_TIME] <= cm[SETPOINT_TIMEOUT]


@jit
def enter(cm: np.ndarray, mode: int) -> None:
    """Switch to ``mode``; hold and land keep the altitude (not below the ground) and heading of now, level."""
    cm[MODE] = mode
    cm[LANDED_SINCE] = math.nan
    cm[OFFBOARD_TICK] = -1.0  # an offboard flight starts at the next tick (set in update)
    if mode == OFFBOARD:
        if math.isnan(cm[ALT_SP]):
            cm[ALT_SP] = cm[ALTITUDE]
    else:
        cm[HOLD_ALT], cm[HOLD_ROLL], cm[HOLD_PITCH], cm[HOLD_YAW] = max(cm[ALTITUDE], 0.0), 0.0, 0.0, cm[YAW]


@jit
def update(cm: np.ndarray, tick: int, now: float, altitude: float, climb_rate: float, yaw: float) -> int:
    """Advance to tick ``tick`` at simulated time ``now`` [s] with the measured altitude [m], climb rate
    [m/s] and yaw [rad]. While armed afterwards, cm[REF_ALT:REF_YAW + 1] is the reference to fly. Returns an
    EVENT_* for the shell to announce."""
    dt = max(now - cm[NOW], 0.0)
    cm[TICK], cm[NOW], cm[ALTITUDE], cm[CLIMB_RATE], cm[YAW] = tick, now, altitude, climb_rate, yaw
    if cm[ARMED] == 0.0:
        return EVENT_NONE
    event = EVENT_NONE
    mode = cm[MODE]
    if mode == OFFBOARD and cm[OFFBOARD_TICK] < 0.0:
        cm[OFFBOARD_TICK] = tick
    if mode == OFFBOARD and not stream_fresh(cm):
        cm[FAILSAFE] = FAILSAFE_SETPOINT_LOST
        event = EVENT_SETPOINT_LOST
        enter(cm, LAND)
        mode = LAND
    if mode == OFFBOARD:
        roll, pitch = (0.0, 0.0) if math.isnan(cm[ROLL_SP]) else (cm[ROLL_SP], cm[PITCH_SP])
        cm[REF_ALT], cm[REF_ROLL], cm[REF_PITCH] = cm[ALT_SP], roll, pitch
        cm[REF_YAW] = cm[HOLD_YAW] if math.isnan(cm[YAW_SP]) else cm[YAW_SP]
        return event
    if mode == LAND:
        # The descending reference: from the altitude on entry, at land_speed, down to land_target.
        cm[HOLD_ALT] = max(cm[LAND_TARGET], cm[HOLD_ALT] - cm[LAND_SPEED] * dt)
        if altitude < 0.05 and abs(climb_rate) < 0.1:
            if math.isnan(cm[LANDED_SINCE]):
                cm[LANDED_SINCE] = now
            elif now - cm[LANDED_SINCE] >= cm[LANDED_TIME]:
                cm[ARMED] = 0.0
                cm[OFFBOARD_TICK] = -1.0
                return EVENT_LANDED
        else:
            cm[LANDED_SINCE] = math.nan
    cm[REF_ALT], cm[REF_ROLL], cm[REF_PITCH], cm[REF_YAW] = cm[HOLD_ALT], cm[HOLD_ROLL], cm[HOLD_PITCH], cm[HOLD_YAW]
    return event


class Commander:
    """The modes, arming, setpoints and failsafes of one vehicle (see the module's docstring): events are
    methods, the tick is :meth:`update` (or :func:`update` on ``self.cm`` from compiled code)."""

    def __init__(self, settings: CommanderSettings | None = None) -> None:
        self.cm = np.zeros(SIZE)
        self.cm[[ALT_SP, ROLL_SP, PITCH_SP, YAW_SP, LANDED_SINCE]] = math.nan
        self.cm[LAST_SP_TIME] = -1e9
        self.cm[OFFBOARD_TICK] = -1.0
        self.settings = settings or CommanderSettings()
        self.messages: list[tuple[int, str]] = []  # (MAV_SEVERITY, text) to announce

    # ---- the state, by name --------------------------------------------------------------------

    @property
    def settings(self) -> CommanderSettings:
        return self._settings

    @settings.setter
    def settings(self, settings: CommanderSettings) -> None:
        self._settings = settings
        cm = self.cm
        cm[SETPOINT_TIMEOUT], cm[LAND_SPEED] = settings.setpoint_timeout, settings.land_speed
        cm[LANDED_TIME], cm[LAND_TARGET] = settings.landed_time, settings.land_target

    @property
    def armed(self) -> bool:
        return bool(self.cm[ARMED])

    @property
    def mode(self) -> Mode:
        return Mode(int(self.cm[MODE]))

    @property
    def failsafe(self) -> int:
        return int(self.cm[FAILSAFE])

    @property
    def offboard_tick(self) -> int:
        return int(self.cm[OFFBOARD_TICK])

    @property
    def now(self) -> float:
        return float(self.cm[NOW])

    @property
    def last_setpoint_time(self) -> float:
        return float(self.cm[LAST_SP_TIME])

    @last_setpoint_time.setter
    def last_setpoint_time(self, t: float) -> None:
        self.cm[LAST_SP_TIME] = t

    @property
    def altitude_setpoint(self) -> float | None:
        return None if math.isnan(self.cm[ALT_SP]) else float(self.cm[ALT_SP])

    @property
    def attitude_setpoint(self) -> tuple[float, float, float] | None:
        """(roll, pitch, yaw) [rad] of the last attitude setpoint; None before the first."""
        return None if math.isnan(self.cm[ROLL_SP]) else tuple(self.cm[ROLL_SP : YAW_SP + 1].tolist())

    @property
    def hold(self) -> Reference:
        """The reference held in hold and land."""
        return Reference._make(self.cm[HOLD_ALT : HOLD_YAW + 1].tolist())

    @property
    def reference(self) -> Reference:
        """The reference of the last tick (valid while armed)."""
        return Reference._make(self.cm[REF_ALT : REF_YAW + 1].tolist())

    # ---- events --------------------------------------------------------------------------------

    def stream_fresh(self) -> bool:
        return bool(stream_fresh(self.cm))

    def on_attitude_setpoint(self, roll: float | None, pitch: float | None, yaw: float | None) -> None:
        """A SET_ATTITUDE_TARGET (None for an axis the type_mask ignores)."""
        old = self.attitude_setpoint or (0.0, 0.0, float(self.cm[YAW]))
        self.cm[ROLL_SP] = old[0] if roll is None else roll
        self.cm[PITCH_SP] = old[1] if pitch is None else pitch
        self.cm[YAW_SP] = old[2] if yaw is None else yaw
        self.cm[LAST_SP_TIME] = self.cm[NOW]

    def on_altitude_setpoint(self, altitude: float | None) -> None:
        """A SET_POSITION_TARGET_LOCAL_NED (None when z is ignored: still counts for the stream)."""
        if altitude is not None:
            self.cm[ALT_SP] = altitude
        self.cm[LAST_SP_TIME] = self.cm[NOW]

    def arm(self) -> tuple[bool, str]:
        if self.armed:
            return True, ""
        if self.mode == Mode.OFFBOARD and not self.stream_fresh():
            return False, "Arming denied: no offboard setpoint stream"
        if self.mode == Mode.LAND:
            return False, "Arming denied: landing"
        self.cm[ARMED] = 1.0
        self.cm[FAILSAFE] = FAILSAFE_NONE
        enter(self.cm, int(self.cm[MODE]))
        self.messages.append((6, "Armed"))
        return True, ""

    def disarm(self, reason: str = "Disarmed") -> None:
        if self.armed:
            self.cm[ARMED] = 0.0
            self.cm[OFFBOARD_TICK] = -1.0
            self.messages.append((6, reason))

    def plant_lost(self) -> None:
        """No vehicle state arrives: flying blind. Armed, switch to LAND (it resumes when states do)."""
        self.messages.append((2, "Plant link lost: no vehicle state"))
        if self.armed:
            self.cm[FAILSAFE] = FAILSAFE_PLANT_LOST
            if self.mode != Mode.LAND:
                enter(self.cm, LAND)
                self.messages.append((2, "Failsafe: landing"))

    def datalink_lost(self, seconds: float) -> None:
        """No ground-station heartbeat for ``seconds``: the configured action (NAV_DLL_ACT)."""
        action = DATALINK_ACTIONS[self.settings.datalink_action]
        self.messages.append((2, f"Ground station lost: no heartbeat for {seconds:g} s; action: {action}"))
        if self.armed and action != "none":
            self.cm[FAILSAFE] = FAILSAFE_GCS_LOST
            mode = HOLD if action == "hold" else LAND
            if self.cm[MODE] != mode:
                enter(self.cm, mode)

    def datalink_restored(self) -> None:
        self.messages.append((5, "Ground station back"))

    def plant_restored(self) -> None:
        self.messages.append((5, "Plant link restored"))

    def set_mode(self, mode: Mode) -> tuple[bool, str]:
        if mode == self.mode:
            return True, ""
        if mode == Mode.OFFBOARD and not self.stream_fresh():
            return False, "Offboard denied: no setpoint stream"
        enter(self.cm, int(mode))
        self.messages.append((6, f"Mode {mode.name.lower()}"))
        return True, ""

    # ---- once per tick -------------------------------------------------------------------------

    def announce(self, event: int) -> None:
        """The messages of an update()'s event."""
        if event == EVENT_SETPOINT_LOST:
            self.messages.append(
                (2, f"Failsafe: offboard setpoints lost for {self.settings.setpoint_timeout:g} s, landing")
            )
        elif event == EVENT_LANDED:
            self.messages.append((6, "Landed, disarmed"))

    def update(self, tick: int, now: float, state: VehicleState) -> Reference | None:
        """Advance to tick ``tick`` at simulated time ``now`` [s] with the measured state. Returns the
        reference to fly, or None when disarmed."""
        self.announce(update(self.cm, tick, float(now), float(state.altitude), float(state.climb_rate),
                             float(state.yaw)))  # fmt: skip
        return self.reference if self.armed else None
