"""Flying a stored mission (AUTO.MISSION), as a pure state machine: no I/O, no compiled code.

Given the mission's items (:class:`autopilot.mission_protocol.MissionItem`), the local origin (latitude,
longitude [deg], altitude AMSL [m]) and home (local x, y NED [m], altitude [m]), :class:`MissionExecutor`
decides, tick by tick, what the vehicle flies, as PX4's navigator does for AUTO.MISSION
(``src/modules/navigator/mission.cpp``, ``mission_base.cpp``, ``mission_block.cpp``, read for this).

**The shell's part.** It calls :meth:`MissionExecutor.step` with the time and a :class:`VehicleNow`; the
returned :class:`Action` is what to fly. The same object comes back while nothing changes, so the shell
compares with ``is`` and calls the commander (``takeoff``, ``reposition``, ``set_mode``) only when a new one
arrives. Events to announce (:class:`Reached` → ``MISSION_ITEM_REACHED``, :class:`Current` → a changed
``MISSION_CURRENT``, :class:`Finished`) collect in :attr:`MissionExecutor.events` for the shell to drain.
A step costs a few float operations (no allocation while nothing changes): calling it every control tick
is fine; 10–50 Hz is enough (hold times are then resolved to the call period).

Rules, and where they come from:

- **Positions.** Latitude and longitude → local NED with :func:`quadsitl.frames.geodetic_to_ned` from the
  origin. Altitude by frame: 0 and 5 (AMSL) minus the origin's altitude; 3 and 6 (relative) plus home's
  altitude (PX4's ``get_absolute_altitude_for_item``).
- **NAV_WAYPOINT (16)** flies to the point. It is reached when horizontally within the acceptance radius (p2
  when > 0, else ``acceptance_radius``) and vertically within ``altitude_radius`` (PX4's ``NAV_MC_ALT_RAD``,
  0.8 m), and, when the item gives a yaw (p4, degrees), the heading is within ``yaw_error`` (PX4's
  ``MIS_YAW_ERR``, 12°; PX4 waits for it with ``MIS_YAW_TMT`` −1, as here). Then it holds p1 seconds (NaN:
  0) and the item completes: ``Reached(seq)`` is announced after the hold, as PX4 sets the reached item only
  when ``is_mission_item_reached_or_completed`` says so. A NaN yaw faces the waypoint (PX4's default
  ``MPC_YAW_MODE`` 0, "towards waypoint"): the leg's bearing from where the leg starts, when the leg is
  longer than the acceptance radius; a shorter leg keeps the heading.
- **Acceptance radius.** ``acceptance_radius`` defaults to 2 m, not PX4's ``NAV_ACC_RAD`` of 10 m: the
  auto modes' reference here stops on each target, so a 10 m radius only makes "reached" (and the next
  leg) come while the vehicle is still 10 m short, cutting corners that a test mission of 20–50 m legs is
  meant to fly. Pass 10.0 to have PX4's number.
- **NAV_TAKEOFF (22)**: landed, take off to the item's altitude, at least the ground plus
  ``takeoff_alt`` (``MIS_TAKEOFF_ALT``; PX4's ``calculate_takeoff_altitude``), straight up where the vehicle
  is; reached within ``altitude_radius``. Already flying: a waypoint at the current position and that
  altitude.
- **Starting from the ground without a takeoff item**: take off first to the first position item's
  altitude or the ground plus ``takeoff_alt``, whichever is higher (PX4's ``calculate_takeoff_altitude``
  with the mission's climb-before-start), then fly the item. The climb is not an item: nothing is
  announced for it.
- **NAV_LOITER_TIME (19)**: as a waypoint, its radius |p3| (when > 0) the acceptance radius, holding p1
  seconds; with p2 = 1 ("heading required") it then turns to face the next waypoint before it completes.
  **NAV_DELAY (93)**: hold where the vehicle is for p1 seconds (a time of day is refused at upload).
  **DO_CHANGE_SPEED (178)**: p2 > 0 is the speed of the following legs (p1 0, 1: horizontal; 2: climb; 3:
  descent), −1 no change, −2 (or 0) back to the default (NaN: the commander's ``MPC_XY_CRUISE``,
  ``MPC_Z_VEL_MAX_UP``, ``_DN``); it completes at once, as does any run of them, in the same step.
- **autocontinue 0**: the item is reached (announced), then held, the mission waiting on it, until
  :meth:`MissionExecutor.set_current` (PX4 loiters at such an item).
- **NAV_LAND (21)**: fly to the item's position at the current altitude (latitude and longitude both 0,
  or frame 2: where the vehicle is), then land; the item completes, and the mission finishes, on landing
  (disarming is the commander's). **NAV_RETURN_TO_LAUNCH (20)**: return (the commander's RTL), completing
  and finishing on landing. Either already landed: it completes at once.
- **End of the mission** without land or return: hold at the last waypoint; the state is complete (5) and
  ``current`` stays on the last item. Starting a complete mission again starts it from item 0.
- **Pause** (:meth:`MissionExecutor.pause`): hold, state paused (4). **Resume** (:meth:`resume`, or
  :meth:`start` again): fly the current item again from where the vehicle is (a hold that had begun starts
  over). :meth:`set_current` jumps: the next step flies that item (a complete mission becomes paused, as
  ``MAV_CMD_DO_SET_MISSION_CURRENT`` with reset does in :mod:`autopilot.mission_protocol`).

The executor owns ``current`` and ``mission_state``; the shell copies them to the
:class:`~autopilot.mission_protocol.MissionProtocol` with its :meth:`~MissionProtocol.set_progress`, which
returns a ``MISSION_CURRENT`` when they changed. The autopilot process runs it through :mod:`autopilot.missions`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

from autopilot import mission_protocol as mp
from autopilot.setpoints import local_altitude
from quadsitl.compiled_frames import geodetic_to_ned

NAN = math.nan
ACCEPTANCE_RADIUS = 2.0
"""Default horizontal acceptance radius [m] (PX4's NAV_ACC_RAD is 10 m; the module docstring says why not)."""
ALTITUDE_RADIUS = 0.8
"""Vertical acceptance radius [m]: PX4's NAV_MC_ALT_RAD."""
YAW_ERROR = math.radians(12.0)
"""Heading acceptance [rad] when an item gives a yaw: PX4's MIS_YAW_ERR (12°)."""
TAKEOFF_ALT = 2.5
"""MIS_TAKEOFF_ALT [m]: the least takeoff altitude above the ground."""


@dataclass(frozen=True)
class VehicleNow:
    """What the executor needs of the vehicle: position (x, y NED [m], altitude up [m]), velocity [m/s],
    heading [rad], whether it rests on the ground and whether it is armed."""

    x: float
    y: float
    altitude: float
    vx: float = 0.0
    vy: float = 0.0
    climb_rate: float = 0.0
    yaw: float = 0.0
    landed: bool = False
    armed: bool = True


# ---- what to fly ----------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class Goto:
    """Fly to (x, y NED [m], altitude [m]), heading ``yaw`` [rad] (NaN: keep it), at ``speed`` [m/s] (NaN: the
    commander's cruise speed). The shell: ``Commander.reposition(x, y, altitude, yaw, speed, hold=True)``."""

    x: float
    y: float
    altitude: float
    yaw: float = NAN
    speed: float = NAN
    climb: float = NAN  # [m/s] the climb and descent speeds (DO_CHANGE_SPEED 2, 3; NaN: MPC_Z_VEL_MAX_UP, _DN)
    descent: float = NAN


@dataclass(frozen=True, eq=False)
class Takeoff:
    """Take off straight up to ``altitude`` [m]: ``Commander.takeoff(altitude)``."""

    altitude: float


@dataclass(frozen=True, eq=False)
class Land:
    """Land where the vehicle is: ``Commander.set_mode(Mode.LAND)``."""


@dataclass(frozen=True, eq=False)
class ReturnToLaunch:
    """Return home and land: ``Commander.set_mode(Mode.RTL)``."""


@dataclass(frozen=True, eq=False)
class Hold:
    """Stop and hold where the vehicle can stop: ``Commander.set_mode(Mode.HOLD)``."""


Action = Goto | Takeoff | Land | ReturnToLaunch | Hold


# ---- what to announce -----------------------------------------------------------------------------------


@dataclass(frozen=True)
class Reached:
    """Item ``seq`` completed: ``MISSION_ITEM_REACHED``."""

    seq: int


@dataclass(frozen=True)
class Current:
    """The current item or the mission's state changed: ``MISSION_CURRENT``."""

    seq: int
    mission_state: int


@dataclass(frozen=True)
class Finished:
    """The mission ended (its last item completed, or a land or return landed)."""


Event = Reached | Current | Finished

# The phases of the current item.
_START, _CLIMB, _GO, _HOLDING, _DESCENDING, _DONE, _WAITING = range(7)
# DO_CHANGE_SPEED's speed types (p1) → the executor's attribute they set: air and ground speed, climb, descent.
SPEED_TYPES = ("speed", "speed", "climb", "descent")
ROI_STEP = math.radians(2.0)  # [rad] the heading toward a region of interest is re-aimed when it moves this much


class MissionExecutor:
    """Flies a mission: see the module's docstring for the rules.

    ``items``: the mission; ``origin``: (latitude [deg], longitude [deg], altitude AMSL [m]) of the local
    frame; ``home``: (x, y NED [m], altitude [m]) in it. The radii and ``takeoff_alt`` are PX4's parameters
    (``NAV_ACC_RAD``, ``NAV_MC_ALT_RAD``, ``MIS_YAW_ERR``, ``MIS_TAKEOFF_ALT``).
    """

    def __init__(
        self,
        items: Sequence[mp.MissionItem],
        origin: tuple[float, float, float],
        home: tuple[float, float, float] = (0.0, 0.0, 0.0),
        *,
        acceptance_radius: float = ACCEPTANCE_RADIUS,
        altitude_radius: float = ALTITUDE_RADIUS,
        yaw_error: float = YAW_ERROR,
        takeoff_alt: float = TAKEOFF_ALT,
        current: int = 0,
    ) -> None:
        self.items = tuple(items)
        self.origin = origin
        self.home = home
        self.acceptance_radius = acceptance_radius
        self.altitude_radius = altitude_radius
        self.yaw_error = yaw_error
        self.takeoff_alt = takeoff_alt
        self.current = current if 0 <= current < len(self.items) else 0
        """The current item's seq (0 with no mission)."""
        self.mission_state = mp.STATE_NOT_STARTED if self.items else mp.STATE_NO_MISSION
        """MISSION_STATE: 1 none, 2 not started, 3 active, 4 paused, 5 complete."""
        self.speed = NAN
        """The horizontal speed of the legs [m/s] (DO_CHANGE_SPEED; NaN: the commander's cruise speed)."""
        self.climb = self.descent = NAN
        """The climb and descent speeds of the legs [m/s] (DO_CHANGE_SPEED types 2 and 3; NaN: the limits')."""
        self.roi: tuple[float, float] | None = None
        """The region of interest (x, y NED [m]) the vehicle faces (DO_SET_ROI_LOCATION; None: DO_SET_ROI_NONE)."""
        self.events: list[Event] = []
        """What to announce, in order; the shell takes and clears them."""
        self.action: Action = Hold()
        """What to fly now (the last :meth:`step`'s answer)."""
        self._phase = _START
        self._target: Goto | None = None
        self._since = NAN  # when the hold of the current item began [s]
        self._climb_alt = NAN
        self._target_alt = NAN  # the altitude of the last goto [m]: a waypoint without one keeps it

    # ---- commands --------------------------------------------------------------------------------------

    def local(self, item: mp.MissionItem) -> tuple[float, float, float]:
        """An item's position in the local frame: (x, y NED [m], altitude [m])."""
        lat0, lon0, _ = self.origin
        x, y = geodetic_to_ned(item.lat, item.lon, lat0, lon0)
        return x, y, self.altitude_of(item)

    def altitude_of(self, item: mp.MissionItem) -> float:
        """An item's altitude in the local frame [m]: AMSL frames minus the origin's, relative ones plus home's."""
        return local_altitude(item.frame, item.z, self.origin[2], self.home[2])

    def start(self, now: float, vehicle: VehicleNow) -> bool:
        """AUTO.MISSION / MAV_CMD_MISSION_START: fly (or resume) the mission from the current item; a complete
        mission starts over from item 0. False with no mission."""
        if not self.items:
            return False
        if self.mission_state == mp.STATE_COMPLETE:
            self.current = 0
            self._phase = _START
        if self.mission_state == mp.STATE_PAUSED:
            self._restart_item()
            if self._phase == _CLIMB:  # the commander takes off only from the ground: climb on with a goto
                self.action = Goto(vehicle.x, vehicle.y, self._climb_alt)
        self._set_state(mp.STATE_ACTIVE)
        self.step(now, vehicle)
        return True

    def pause(self) -> Action:
        """Hold where the vehicle can stop; the current item stays current. Returns what to fly (a new
        :class:`Hold` when the mission was active), for the shell to hand the commander at once."""
        if self.mission_state == mp.STATE_ACTIVE:
            self._set_state(mp.STATE_PAUSED)
            self.action = Hold()
        return self.action

    def resume(self, now: float, vehicle: VehicleNow) -> bool:
        """Continue a paused mission with its current item."""
        return self.mission_state == mp.STATE_PAUSED and self.start(now, vehicle)

    def set_current(self, seq: int) -> bool:
        """Jump to item ``seq``: the next step flies it. False (nothing changes) outside the mission."""
        if not 0 <= seq < len(self.items):
            return False
        self.current = seq
        self._restart_item()
        if self.mission_state == mp.STATE_COMPLETE:
            self.mission_state = mp.STATE_PAUSED
        self._announce_current()
        return True

    def _restart_item(self) -> None:
        if self._phase != _CLIMB:
            self._phase = _START
        self._target = None
        self._since = NAN

    def _set_state(self, state: int) -> None:
        if state != self.mission_state:
            self.mission_state = state
            self._announce_current()

    def _announce_current(self) -> None:
        self.events.append(Current(self.current, self.mission_state))

    # ---- the tick --------------------------------------------------------------------------------------

    def step(self, now: float, vehicle: VehicleNow) -> Action:
        """What to fly now; the same object as the last call's while it does not change."""
        if self.mission_state != mp.STATE_ACTIVE:
            return self.action
        for _ in range(len(self.items) + 1):  # items that complete at once run on in the same step
            if not self._advance(now, vehicle):
                break
        return self.action

    def _advance(self, now: float, v: VehicleNow) -> bool:
        """Run the current item; True if it completed (the next one should run at once)."""
        item = self.items[self.current]
        cmd = item.command
        if self._phase == _WAITING:  # reached, autocontinue 0: held until the current item is set
            return False
        if self._phase == _START:
            self._begin(item, v)
        if self._phase == _CLIMB:
            if v.altitude < self._climb_alt - self.altitude_radius:
                return False
            self._phase = _START
            self._begin(item, v)
        if cmd == mp.DO_SET_ROI_LOCATION:
            self.roi = self.local(item)[:2]
            return self._complete()
        if cmd == mp.DO_SET_ROI_NONE:
            self.roi = None
            return self._complete()
        if cmd in mp.CAMERA_COMMANDS:  # no camera, no gimbal: done as it comes (the mission said so at start)
            return self._complete()
        if self.roi is not None and self._phase in (_GO, _HOLDING) and math.isnan(self._yaw(item)):
            self._face_roi(v)
        if cmd == mp.DO_CHANGE_SPEED:
            name = SPEED_TYPES[int(item.p1)]
            if item.p2 > 0.0:
                setattr(self, name, item.p2)
            elif item.p2 != -1.0:
                setattr(self, name, NAN)
            return self._complete()
        if cmd == mp.NAV_DELAY:
            if now - self._since_now(now) < max(item.p1, 0.0):
                return False
            return self._complete()
        if cmd in (mp.NAV_RETURN_TO_LAUNCH, mp.NAV_LAND) and self._phase == _DESCENDING:
            if v.landed:
                return self._complete(finished=True)
            return False
        if cmd == mp.NAV_LAND and self._phase == _GO:
            t = self._target
            assert t is not None
            if math.hypot(v.x - t.x, v.y - t.y) <= self.acceptance_radius:
                self._phase = _DESCENDING
                self.action = Land()
            return False
        if self._phase == _GO:
            if not self._position_reached(item, v):
                return False
            self._phase = _HOLDING
            self._since = now
        if self._phase == _HOLDING:
            hold = 0.0 if math.isnan(item.p1) or cmd == mp.NAV_TAKEOFF else item.p1
            if now - self._since < hold:
                return False
            if cmd == mp.NAV_LOITER_TIME and item.p2 == 1.0 and not self._heading_out(v):
                return False
            return self._complete()
        return False

    def _heading_out(self, v: VehicleNow) -> bool:
        """NAV_LOITER_TIME with p2 = 1 ("heading required"): leave only once facing the next position item (turned to
        it here, at the heading rate limit); True when there is none, or once within ``yaw_error`` of it."""
        nxt = next((i for i in self.items[self.current + 1 :] if i.command in (mp.NAV_WAYPOINT, mp.NAV_LOITER_TIME)),
                   None)  # fmt: skip
        if nxt is None:
            return True
        x, y, _ = self.local(nxt)
        if math.hypot(x - v.x, y - v.y) <= self._radius(nxt):
            return True
        bearing = math.atan2(y - v.y, x - v.x)
        t = self._target
        assert t is not None
        if t.yaw != bearing:
            self._goto(Goto(t.x, t.y, t.altitude, bearing, t.speed, t.climb, t.descent))
        return abs((v.yaw - bearing + math.pi) % (2.0 * math.pi) - math.pi) <= self.yaw_error

    def _since_now(self, now: float) -> float:
        if math.isnan(self._since):
            self._since = now
        return self._since

    def _begin(self, item: mp.MissionItem, v: VehicleNow) -> None:
        """Start flying ``item``: choose the action (and, from the ground, climb first)."""
        cmd = item.command
        self._since = NAN
        self._phase = _GO
        flying = not v.landed
        if cmd == mp.NAV_TAKEOFF:
            alt = self.altitude_of(item)
            if flying:
                self._goto(Goto(v.x, v.y, alt, self._yaw(item), self.speed, self.climb, self.descent))
            else:
                self._goto(Goto(v.x, v.y, max(alt, max(v.altitude, 0.0) + self.takeoff_alt), NAN, NAN))
                self.action = Takeoff(self._target.altitude)  # type: ignore[union-attr]
            return
        if cmd in mp.NO_POSITION_COMMANDS - {mp.NAV_RETURN_TO_LAUNCH} or cmd == mp.DO_SET_ROI_LOCATION:
            if cmd == mp.NAV_DELAY and not isinstance(self.action, Hold):
                self.action = Hold()
            return
        if not flying:
            if cmd == mp.NAV_RETURN_TO_LAUNCH or (cmd == mp.NAV_LAND and self.land_here(item)):
                self._phase = _DESCENDING  # already on the ground: completes at once
                return
            alt = self._first_position_altitude()
            self._climb_alt = max(alt, max(v.altitude, 0.0) + self.takeoff_alt)
            self._phase = _CLIMB
            self.action = Takeoff(self._climb_alt)
            return
        if cmd == mp.NAV_RETURN_TO_LAUNCH:
            self._phase = _DESCENDING
            self.action = ReturnToLaunch()
            return
        if cmd == mp.NAV_LAND:
            if self.land_here(item):
                self._target = Goto(v.x, v.y, v.altitude)
                self._phase = _DESCENDING
                self.action = Land()
            else:
                x, y, _ = self.local(item)
                self._goto(Goto(x, y, v.altitude, self._leg_yaw(item, v, x, y), self.speed, self.climb, self.descent))
            return
        x, y, alt = self.local(item)
        if math.isnan(alt):  # no altitude given (null): the one the vehicle is flying at
            alt = self._target_alt if math.isfinite(self._target_alt) else v.altitude
        self._goto(Goto(x, y, alt, self._leg_yaw(item, v, x, y), self.speed, self.climb, self.descent))

    def _goto(self, g: Goto) -> None:
        self._target = g
        self.action = g
        if math.isfinite(g.altitude):
            self._target_alt = g.altitude

    def _face_roi(self, v: VehicleNow) -> None:
        """Point the heading at the region of interest from where the vehicle is (PX4 with MIS_MNT_YAW_CTL 0: the
        vehicle yaws toward it), a new goto when the bearing has moved by more than ROI_STEP."""
        t = self._target
        if t is None or self.roi is None:
            return
        dx, dy = self.roi[0] - v.x, self.roi[1] - v.y
        if math.hypot(dx, dy) < 1.0:  # over it: any heading
            return
        bearing = math.atan2(dy, dx)
        if math.isnan(t.yaw) or abs((bearing - t.yaw + math.pi) % (2.0 * math.pi) - math.pi) > ROI_STEP:
            self._goto(Goto(t.x, t.y, t.altitude, bearing, t.speed, t.climb, t.descent))

    @staticmethod
    def land_here(item: mp.MissionItem) -> bool:
        """A NAV_LAND item lands where the vehicle is (frame MISSION, or latitude and longitude both 0)."""
        return item.frame == mp.FRAME_MISSION or (item.x == 0 and item.y == 0)

    @classmethod
    def has_place(cls, item: mp.MissionItem) -> bool:
        """The item flies to a place of its own: a waypoint, a loiter, or a landing not where the vehicle is (a
        takeoff goes straight up)."""
        return item.command in (mp.NAV_WAYPOINT, mp.NAV_LOITER_TIME) or (
            item.command == mp.NAV_LAND and not cls.land_here(item)
        )

    @staticmethod
    def _yaw(item: mp.MissionItem) -> float:
        return math.radians(item.p4) if math.isfinite(item.p4) else NAN

    def _radius(self, item: mp.MissionItem) -> float:
        """The horizontal acceptance radius [m]: a waypoint's p2, a loiter's |p3| (its radius), when > 0."""
        given = (
            item.p2 if item.command == mp.NAV_WAYPOINT else abs(item.p3) if item.command == mp.NAV_LOITER_TIME else 0
        )
        return given if math.isfinite(given) and given > 0.0 else self.acceptance_radius

    def _leg_yaw(self, item: mp.MissionItem, v: VehicleNow, x: float, y: float) -> float:
        """The item's yaw, or (NaN) the bearing of the leg when it is longer than the acceptance radius."""
        yaw = self._yaw(item)
        if math.isnan(yaw) and self.roi is not None:
            return math.atan2(self.roi[1] - v.y, self.roi[0] - v.x)
        if math.isnan(yaw) and math.hypot(x - v.x, y - v.y) > self._radius(item):
            yaw = math.atan2(y - v.y, x - v.x)
        return yaw

    def _first_position_altitude(self) -> float:
        """The altitude of the first item from the current one that flies to a position (NaN: none)."""
        for item in self.items[self.current :]:
            if item.command in (mp.NAV_WAYPOINT, mp.NAV_LOITER_TIME, mp.NAV_TAKEOFF):
                alt = self.altitude_of(item)
                return alt if math.isfinite(alt) else -math.inf
            if item.command in (mp.NAV_LAND, mp.NAV_RETURN_TO_LAUNCH):
                break
        return -math.inf

    def _position_reached(self, item: mp.MissionItem, v: VehicleNow) -> bool:
        t = self._target
        assert t is not None
        if abs(v.altitude - t.altitude) > self.altitude_radius:
            return False
        if item.command != mp.NAV_TAKEOFF and math.hypot(v.x - t.x, v.y - t.y) > self._radius(item):
            return False
        yaw = self._yaw(item)
        if not math.isnan(yaw):
            err = (v.yaw - yaw + math.pi) % (2.0 * math.pi) - math.pi
            if abs(err) > self.yaw_error:
                return False
        return True

    def _complete(self, *, finished: bool = False) -> bool:
        """The current item completed: announce it, go on to the next (or finish; or, autocontinue 0 and more items to
        come, hold there until the current item is set, as PX4's loiter at such an item). True to run on."""
        self.events.append(Reached(self.current))
        if not finished and self.items[self.current].autocontinue == 0 and self.current + 1 < len(self.items):
            self._phase = _WAITING
            return False
        self._since = NAN
        self._target = None
        self._phase = _START
        if finished or self.current + 1 >= len(self.items):
            self._phase = _DONE
            self.mission_state = mp.STATE_COMPLETE
            self._announce_current()
            self.events.append(Finished())
            if not finished:
                self.action = Hold()
            return False
        self.current += 1
        self._announce_current()
        return True
