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
"""

from __future__ import annotations

from dataclasses import dataclass

from quadsitl.state import Reference, VehicleState
from quadsitl.wire import Mode

FAILSAFE_NONE = 0
FAILSAFE_SETPOINT_LOST = 1
FAILSAFE_PLANT_LOST = 2
FAILSAFE_GCS_LOST = 3
DATALINK_ACTIONS = ("none", "hold", "land")  # NAV_DLL_ACT, as PX4 numbers its first ones


@dataclass
class CommanderSettings:
    setpoint_timeout: float = 1.0  # [s] simulated, like PX4's COM_OF_LOSS_T
    land_speed: float = 1.0  # [m/s]
    landed_time: float = 0.5  # [s]
    land_target: float = -0.5  # [m] the landing reference goes this far below the ground
    altitude_max: float = 1000.0  # [m] altitude setpoints above this (or below 0) are refused
    datalink_timeout: float = 10.0  # [s] wall, like PX4's COM_DL_LOSS_T: ground-station heartbeat loss
    datalink_action: int = 0  # index in DATALINK_ACTIONS, like PX4's NAV_DLL_ACT (0: do nothing)


class Commander:
    def __init__(self, settings: CommanderSettings | None = None) -> None:
        self.settings = settings or CommanderSettings()
        self.armed = False
        self.mode = Mode.HOLD
        self.failsafe = FAILSAFE_NONE
        self.altitude_setpoint: float | None = None
        self.attitude_setpoint: tuple[float, float, float] | None = None  # roll, pitch, yaw
        self.last_setpoint_time = -1e9
        self.offboard_tick = -1
        self.hold = Reference()
        self.landed_since: float | None = None
        self.messages: list[tuple[int, str]] = []  # (MAV_SEVERITY, text) to announce
        self.now = 0.0
        self.tick = 0
        self.state = VehicleState()

    # ---- events --------------------------------------------------------------------------------

    def stream_fresh(self) -> bool:
        return self.now - self.last_setpoint_time <= self.settings.setpoint_timeout

    def on_attitude_setpoint(self, roll: float | None, pitch: float | None, yaw: float | None) -> None:
        """A SET_ATTITUDE_TARGET (None for an axis the type_mask ignores)."""
        old = self.attitude_setpoint or (0.0, 0.0, self.state.yaw)
        self.attitude_setpoint = (
            old[0] if roll is None else roll,
            old[1] if pitch is None else pitch,
            old[2] if yaw is None else yaw,
        )
        self.last_setpoint_time = self.now

    def on_altitude_setpoint(self, altitude: float | None) -> None:
        """A SET_POSITION_TARGET_LOCAL_NED (None when z is ignored: still counts for the stream)."""
        if altitude is not None:
            self.altitude_setpoint = altitude
        self.last_setpoint_time = self.now

    def arm(self) -> tuple[bool, str]:
        if self.armed:
            return True, ""
        if self.mode == Mode.OFFBOARD and not self.stream_fresh():
            return False, "Arming denied: no offboard setpoint stream"
        if self.mode == Mode.LAND:
            return False, "Arming denied: landing"
        self.armed = True
        self.failsafe = FAILSAFE_NONE
        self._enter(self.mode)
        self.messages.append((6, "Armed"))
        return True, ""

    def disarm(self, reason: str = "Disarmed") -> None:
        if self.armed:
            self.armed = False
            self.offboard_tick = -1
            self.messages.append((6, reason))

    def plant_lost(self) -> None:
        """No vehicle state arrives: flying blind. Armed, switch to LAND (it resumes when states do)."""
        self.messages.append((2, "Plant link lost: no vehicle state"))
        if self.armed:
            self.failsafe = FAILSAFE_PLANT_LOST
            if self.mode != Mode.LAND:
                self._enter(Mode.LAND)
                self.messages.append((2, "Failsafe: landing"))

    def datalink_lost(self, seconds: float) -> None:
        """No ground-station heartbeat for ``seconds``: the configured action (NAV_DLL_ACT)."""
        action = DATALINK_ACTIONS[self.settings.datalink_action]
        self.messages.append((2, f"Ground station lost: no heartbeat for {seconds:g} s; action: {action}"))
        if self.armed and action != "none":
            self.failsafe = FAILSAFE_GCS_LOST
            mode = Mode.HOLD if action == "hold" else Mode.LAND
            if self.mode != mode:
                self._enter(mode)

    def datalink_restored(self) -> None:
        self.messages.append((5, "Ground station back"))

    def plant_restored(self) -> None:
        self.messages.append((5, "Plant link restored"))

    def set_mode(self, mode: Mode) -> tuple[bool, str]:
        if mode == self.mode:
            return True, ""
        if mode == Mode.OFFBOARD and not self.stream_fresh():
            return False, "Offboard denied: no setpoint stream"
        self._enter(mode)
        self.messages.append((6, f"Mode {mode.name.lower()}"))
        return True, ""

    def _enter(self, mode: Mode) -> None:
        s = self.state
        self.mode = mode
        self.landed_since = None
        self.offboard_tick = -1  # an offboard flight starts at the next tick (set in update)
        if mode == Mode.OFFBOARD:
            if self.altitude_setpoint is None:
                self.altitude_setpoint = s.altitude
        else:
            self.hold = Reference(max(s.altitude, 0.0), 0.0, 0.0, s.yaw)

    # ---- once per tick -------------------------------------------------------------------------

    def update(self, tick: int, now: float, state: VehicleState) -> Reference | None:
        """Advance to tick ``tick`` at simulated time ``now`` [s] with the measured state. Returns the
        reference to fly, or None when disarmed."""
        dt = max(now - self.now, 0.0)
        self.tick, self.now, self.state = tick, now, state
        if not self.armed:
            return None
        if self.mode == Mode.OFFBOARD and self.offboard_tick < 0:
            self.offboard_tick = tick
        if self.mode == Mode.OFFBOARD and not self.stream_fresh():
            self.failsafe = FAILSAFE_SETPOINT_LOST
            self.messages.append(
                (2, f"Failsafe: offboard setpoints lost for {self.settings.setpoint_timeout:g} s, landing")
            )
            self._enter(Mode.LAND)
        if self.mode == Mode.OFFBOARD:
            roll, pitch, yaw = self.attitude_setpoint or (0.0, 0.0, self.hold.yaw)
            return Reference(self.altitude_setpoint, roll, pitch, yaw)  # type: ignore[arg-type]
        if self.mode == Mode.LAND:
            return self._land(now, dt, state)
        return self.hold

    def _land(self, now: float, dt: float, state: VehicleState) -> Reference | None:
        st = self.settings
        # The descending reference: from the altitude on entry, at land_speed, down to land_target.
        self.hold = self.hold._replace(altitude=max(st.land_target, self.hold.altitude - st.land_speed * dt))
        if state.altitude < 0.05 and abs(state.climb_rate) < 0.1:
            if self.landed_since is None:
                self.landed_since = now
            elif now - self.landed_since >= st.landed_time:
                self.disarm("Landed, disarmed")
                return None
        else:
            self.landed_since = None
        return self.hold
