"""Missions in the autopilot: the stored mission and its transfers (:mod:`autopilot.mission_protocol`), the executor
that flies it (:mod:`autopilot.mission_executor`) and the commander, joined. No sockets: the process hands it
what arrives and the vehicle's state, and sends the messages it returns (:class:`mission_protocol.Out`).

- AUTO.MISSION (``DO_SET_MODE`` 4/4, ``MAV_CMD_MISSION_START``): the commander's mode MISSION flies toward
  the targets the executor gives (:meth:`Commander.goto`); the mission's LAND and RTL items switch the
  commander to LAND and RTL, and the executor follows them until the vehicle is down.
- Leaving AUTO.MISSION for another mode (hold: MAVSDK's ``pause_mission``) pauses the mission at its current
  item; AUTO.MISSION again resumes it there. A completed mission starts over.
- A new upload (a new :attr:`MissionProtocol.version`) replaces the executor; uploads are refused while a
  mission flies (the protocol's ``busy_flying``), accepted while paused.
- ``MISSION_CURRENT`` on every change and ``MISSION_ITEM_REACHED`` when an item is reached.
"""

from __future__ import annotations

import math

import numpy as np

from autopilot import geofence
from autopilot import mission_protocol as mp
from autopilot.commander import ALTITUDE, CLIMB_RATE, TOUCHDOWN_ALT, TOUCHDOWN_CLIMB, VX, VY, YAW, Commander, X, Y
from autopilot.mission_executor import (
    Current,
    Goto,
    Hold,
    Land,
    MissionExecutor,
    Reached,
    ReturnToLaunch,
    Takeoff,
    VehicleNow,
)
from quadsitl.compiled_frames import geodetic_to_ned
from quadsitl.wire import Mode, mavlink


class ID:
    """The mission protocol's message ids."""

    MISSION_COUNT = mavlink.MAVLINK_MSG_ID_MISSION_COUNT
    MISSION_ITEM = mavlink.MAVLINK_MSG_ID_MISSION_ITEM
    MISSION_ITEM_INT = mavlink.MAVLINK_MSG_ID_MISSION_ITEM_INT
    MISSION_REQUEST_LIST = mavlink.MAVLINK_MSG_ID_MISSION_REQUEST_LIST
    MISSION_REQUEST = mavlink.MAVLINK_MSG_ID_MISSION_REQUEST
    MISSION_REQUEST_INT = mavlink.MAVLINK_MSG_ID_MISSION_REQUEST_INT
    MISSION_ACK = mavlink.MAVLINK_MSG_ID_MISSION_ACK
    MISSION_CLEAR_ALL = mavlink.MAVLINK_MSG_ID_MISSION_CLEAR_ALL
    MISSION_SET_CURRENT = mavlink.MAVLINK_MSG_ID_MISSION_SET_CURRENT


MAX_REACHED = 4096  # reached items kept for the mission document (a mission flown over and over keeps its first)
MESSAGES = frozenset(v for k, v in vars(ID).items() if k.startswith("MISSION_"))  # what Missions.on_message takes


class Missions:
    """One vehicle's missions: see the module's docstring. ``origin``: (latitude, longitude [deg], altitude AMSL
    [m]) of the local frame."""

    def __init__(self, origin: tuple[float, float, float], acceptance_radius: float = 2.0) -> None:
        self.protocol = mp.MissionProtocol(rally_check=self.rally_outside)
        self.origin = origin
        self.acceptance_radius = acceptance_radius
        self.executor: MissionExecutor | None = None
        self._version = -1
        self._fence_version = self._rally_version = 0  # what the commander was last given (sync)
        self.now = math.nan  # [s] simulated: the tick the executor last stepped at
        self.reached: list[tuple[int, float]] = []
        """(seq, simulated time [s] of the tick after which it was reached) of each MISSION_ITEM_REACHED since the
        vehicle last armed or the stored mission was replaced: the mission document carries them (a ground station's
        record, exact on any machine, where MISSION_ITEM_REACHED arrives when it arrives)."""
        self.flying = False
        """The executor is in charge (in MISSION, or in its own LAND/RTL): :meth:`step` it every control tick. A
        plain attribute: the process reads it after every tick."""

    def sync(self, c: Commander) -> None:
        """The commander given the stored geofence and rally points when either changed (an upload, a clear)."""
        p = self.protocol
        if p.fence_version != self._fence_version:
            self._fence_version = p.fence_version
            c.set_fence(self.fence_array())
        if p.rally_version != self._rally_version:
            self._rally_version = p.rally_version
            c.set_rally(self.rally_array())

    def _local(self, lat: float, lon: float) -> tuple[float, float]:
        return geodetic_to_ned(lat, lon, self.origin[0], self.origin[1])

    def fence_array(self) -> np.ndarray:
        """The stored geofence as the commander holds it (:func:`autopilot.geofence.items_to_array`), in the local
        frame of ``origin``."""
        return geofence.items_to_array(self.protocol.fence, self._local)

    def rally_array(self) -> np.ndarray:
        """The stored rally points as the commander holds them (:func:`autopilot.geofence.rally_to_array`)."""
        return geofence.rally_to_array(self.protocol.rally, self._local, self.origin[2])

    def fence_doc(self) -> list[dict]:
        """The geofence for maps (:func:`quadsitl.telemetry.encode_mission`'s ``fence``)."""
        a = self.fence_array().reshape(-1, geofence.FENCE_ITEM)
        return [{"kind": int(k), "size": float(n), "x": float(x), "y": float(y)} for k, n, x, y in a]

    def rally_doc(self) -> list[dict]:
        """The rally points for maps (:func:`quadsitl.telemetry.encode_mission`'s ``rally``)."""
        a = self.rally_array().reshape(-1, geofence.RALLY_ITEM)
        return [{"x": float(x), "y": float(y)} for x, y, _ in a]

    def rally_outside(self, items: tuple[mp.MissionItem, ...]) -> str:
        """Why rally points are refused: one outside the stored geofence's polygons and circles ("" when none)."""
        cm = np.zeros(geofence.CM_SIZE)
        geofence.set_fence(cm, self.fence_array())
        for item in items:
            if geofence.fence_breach(cm, *self._local(item.lat, item.lon)):
                return f"Rally point {item.seq} is outside the geofence: refused"
        return ""

    @staticmethod
    def vehicle(c: Commander) -> VehicleNow:
        """What the executor needs of the vehicle, from the commander's last tick."""
        cm = c.cm
        landed = cm[ALTITUDE] < TOUCHDOWN_ALT and abs(cm[CLIMB_RATE]) < TOUCHDOWN_CLIMB
        return VehicleNow(float(cm[X]), float(cm[Y]), float(cm[ALTITUDE]), float(cm[VX]), float(cm[VY]),
                          float(cm[CLIMB_RATE]), float(cm[YAW]), landed, c.armed)  # fmt: skip

    def _executor(self, c: Commander) -> MissionExecutor | None:
        if self.executor is None or self._version != self.protocol.version:
            self._version = self.protocol.version
            self.executor = None
            self.reached = []
            if self.protocol.items:
                self.executor = MissionExecutor(self.protocol.items, self.origin, c.home,
                                                acceptance_radius=self.acceptance_radius,
                                                takeoff_alt=c.settings.takeoff_alt,
                                                current=self.protocol.current)  # fmt: skip
        return self.executor

    def refusal(self, c: Commander) -> str:
        """Why AUTO.MISSION cannot start now ("" when it can): no mission, its first waypoint too far from home
        (PX4's checkHorizontalDistanceToFirstWaypoint, MIS_DIST_1WP), or an item outside the geofence
        (:meth:`first_item_outside_fence`)."""
        ex = self._executor(c)
        if ex is None:
            return "Mission denied: no mission uploaded"
        ex.home = c.home
        far = self.first_waypoint_distance(ex, c)
        if c.settings.dist_1wp > 0.0 and far >= c.settings.dist_1wp:
            return f"First waypoint far away from home: {far:.0f}m. Correct mission loaded?"
        outside = self.first_item_outside_fence(ex, c)
        if outside:
            return f"Geofence violation for waypoint {outside}"
        return ""

    @staticmethod
    def first_item_outside_fence(ex: MissionExecutor, c: Commander) -> int:
        """The first item (counted from 1, as PX4 says it) whose place is outside the geofence, beyond GF_MAX_HOR_DIST
        or above GF_MAX_VER_DIST, while the fence is checked (GF_ACTION not 0); 0 when none is (PX4's mission
        feasibility check, MissionFeasibilityChecker::checkGeofence: such a mission is not flown). A takeoff's altitude
        is checked above home; a landing where the vehicle is has no place of its own."""
        if c.settings.geofence_action == 0:
            return 0
        for i, item in enumerate(ex.items):
            if item.command == mp.NAV_TAKEOFF:
                x, y, altitude = c.home[0], c.home[1], ex.altitude_of(item)
            elif ex.has_place(item):
                x, y, altitude = ex.local(item)
            else:
                continue
            if geofence.point_breach(c.cm, float(x), float(y), float(altitude)):
                return i + 1
        return 0

    def start(self, c: Commander, now: float) -> tuple[bool, str, list[mp.Out]]:
        """AUTO.MISSION: (accepted, why not, messages). Needs a mission; flies it from its current item. Disarmed,
        as PX4, the mode is selected and the mission starts when the vehicle arms in it (:meth:`armed`): a ground
        station that selects the mode, then arms, has the flight start at the tick it armed at."""
        reason = self.refusal(c)
        if reason:
            return False, reason, []
        ex = self.executor
        if c.mode != Mode.MISSION:
            ok, reason = c.set_mode(Mode.MISSION)
            if not ok:
                return False, reason, []
        if not c.armed:
            return True, "", []
        ex.start(now, self.vehicle(c))
        self.now = now
        self.flying = True
        self._apply(c, ex.action)
        said = []
        cameras = sum(item.command in mp.CAMERA_COMMANDS for item in ex.items)
        if cameras:  # accepted as PX4 accepts them, and said: nothing here takes a picture
            text = f"Mission: {cameras} camera/gimbal items done as they come: no camera"
            said.append(mp.Out("STATUSTEXT", None, {"severity": mavlink.MAV_SEVERITY_INFO, "text": text}))
        return True, "", said + self._events(ex)

    def armed(self, c: Commander, now: float) -> list[mp.Out]:
        """The vehicle just armed: a new flight, whose items reached the mission document lists from none (a mission
        flown again and again never makes it longer); in AUTO.MISSION, the mission starts (its messages)."""
        self.reached = []
        if c.mode != Mode.MISSION:
            return []
        ok, reason, outs = self.start(c, now)
        if not ok:  # the arming check (commands.arm_disarm) asked :meth:`refusal` first: never here
            raise AssertionError(reason)
        return outs

    @staticmethod
    def first_waypoint_distance(ex: MissionExecutor, c: Commander) -> float:
        """The horizontal distance [m] from home to the mission's first item that flies to a place of its own (0:
        none does; a takeoff goes straight up, a landing may land where the vehicle is)."""
        for item in ex.items:
            if ex.has_place(item):
                x, y, _ = ex.local(item)
                return math.hypot(x - c.home[0], y - c.home[1])
        return 0.0

    def step(self, c: Commander, now: float) -> list[mp.Out]:
        """Once per control tick (cheap when nothing changes): the executor's next action to the commander, its
        events out; pauses the mission when another mode took over."""
        ex = self.executor
        if ex is None or not self.flying:
            return []
        ending = isinstance(ex.action, (Land, ReturnToLaunch))  # the mission's own land or return
        own = c.mode == Mode.MISSION or (c.mode in (Mode.LAND, Mode.RTL) and ending)
        if not own:  # the pilot took over (hold: pause_mission; or anything else): pause here
            self.flying = False
            ex.pause()
        elif not c.armed and not isinstance(ex.action, (Land, ReturnToLaunch)):
            self.flying = False  # disarmed in flight (forced): the mission stops where it is
            ex.pause()
        else:
            before = ex.action
            self.now = now
            action = ex.step(now, self.vehicle(c))
            if action is not before:
                self._apply(c, action)
            if ex.mission_state == mp.STATE_COMPLETE and not isinstance(action, (Land, ReturnToLaunch)):
                self.flying = False
            if ex.mission_state == mp.STATE_COMPLETE and not c.armed:
                self.flying = False
        self.protocol.busy_flying = self.flying and ex.mission_state == mp.STATE_ACTIVE
        self.protocol.mission_mode = 1 if c.mode == Mode.MISSION else 2 if self.flying else 0
        return self._events(ex)

    def on_message(self, msg_id: int, sender: tuple[int, int], f: dict, now: float) -> list[mp.Out]:
        """A mission-protocol message (its id, its sender ``(system, component)``, its fields by pymavlink's names) to
        the protocol's state machine at wall time ``now`` [s] → its answers."""
        p, legacy = self.protocol, msg_id in (ID.MISSION_ITEM, ID.MISSION_REQUEST)
        if msg_id == ID.MISSION_COUNT:
            return p.on_count(sender, f["count"], f["mission_type"], now)
        if msg_id in (ID.MISSION_ITEM_INT, ID.MISSION_ITEM):
            return p.on_item(sender, f, now, legacy=legacy)
        if msg_id == ID.MISSION_REQUEST_LIST:
            return p.on_request_list(sender, f["mission_type"], now)
        if msg_id in (ID.MISSION_REQUEST_INT, ID.MISSION_REQUEST):
            return p.on_request(sender, f["seq"], f["mission_type"], now, legacy=legacy)
        if msg_id == ID.MISSION_ACK:
            return p.on_ack(sender, f["type"], f["mission_type"], now)
        if msg_id == ID.MISSION_CLEAR_ALL:
            return p.on_clear_all(sender, f["mission_type"], now)
        return p.on_set_current(sender, f["seq"], now)  # MISSION_SET_CURRENT

    def plan(self, c: Commander) -> list[dict]:
        """Where each stored item flies, for maps (the ``quadsitl/<vehicle>/mission`` document of
        :mod:`quadsitl.telemetry`): seq, command, and local x, y NED [m] and altitude [m] as the executor reads
        them, NaN where the item has no place of its own (a takeoff or landing where the vehicle is, a delay, a
        speed change); a return to launch is home's x, y."""
        home = c.home
        ex = MissionExecutor(self.protocol.items, self.origin, home)  # only to read positions: no state changes
        nan, out = math.nan, []
        for item in ex.items:
            x = y = alt = nan
            if item.command == mp.NAV_RETURN_TO_LAUNCH:
                x, y = home[0], home[1]
            elif item.command in mp.POSITION_COMMANDS:
                alt = ex.local(item)[2] if item.command != mp.NAV_LAND else nan
                if not (item.command == mp.NAV_TAKEOFF or (item.command == mp.NAV_LAND and ex.land_here(item))):
                    x, y = ex.local(item)[:2]
            out.append({"seq": item.seq, "command": item.command, "x": x, "y": y, "altitude": alt})
        return out

    def _apply(self, c: Commander, a: object) -> None:
        if isinstance(a, Goto):
            c.goto(a.x, a.y, a.altitude, a.yaw, a.speed, a.climb, a.descent)
        elif isinstance(a, Takeoff):  # straight up at MPC_TKO_SPEED, as takeoff mode climbs
            x, y, _ = c.position_target_here()
            c.goto(x, y, a.altitude, math.nan, math.nan, c.settings.takeoff_speed)
        elif isinstance(a, Hold):
            c.goto(*c.position_target_here(), math.nan, math.nan)
        elif isinstance(a, Land):
            c.set_mode(Mode.LAND)
        elif isinstance(a, ReturnToLaunch):
            c.set_mode(Mode.RTL)

    def _events(self, ex: MissionExecutor) -> list[mp.Out]:
        out: list[mp.Out] = []
        for e in ex.events:
            if isinstance(e, Reached):
                out.append(self.protocol.item_reached(e.seq))
                if len(self.reached) < MAX_REACHED:
                    self.reached.append((e.seq, self.now))
            elif isinstance(e, Current):
                out += self.protocol.set_progress(e.seq, e.mission_state)
        ex.events.clear()
        return out
