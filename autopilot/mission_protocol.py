"""The vehicle side of the MAVLink mission protocol (mission_type 0), as a pure state machine: no I/O.

The process's shell hands it what arrived (plain values: the sender's ``(system, component)``, the fields of
the message by pymavlink's names, the wall time ``now`` [s]) and sends what it returns: a list of :class:`Out`,
each naming a message (pymavlink's message name), its target ``(system, component)`` (``None`` for a
broadcast) and its fields by pymavlink's names. :meth:`Out.kwargs` is what pymavlink's
``MAVLink_<name>_message`` constructor takes.

What it does, and where it follows PX4 (``src/modules/mavlink/mavlink_mission.cpp``, read for this) or
differs from it (docs/missions.md says the same for users):

- **Upload.** ``MISSION_COUNT`` → ``MISSION_REQUEST_INT`` for item 0 addressed to the sender, then for each
  next item as each arrives. The request is re-sent every :data:`RETRY_S` (PX4: 250 ms) while the wanted item
  does not come; after :data:`TIMEOUT_S` (PX4: 5 s) without a message from the partner the upload is dropped
  with ``MISSION_ACK`` OPERATION_CANCELLED (PX4 only says "Operation timeout" in a STATUSTEXT; we send both,
  so a client waiting for an ACK learns it at once). An item that is not the wanted one (a duplicate of the
  previous one, or one out of order) is ignored without an error, as PX4 does: the re-request timer asks again
  for the wanted one. (Answering each duplicate with an immediate re-request, as is sometimes done, makes a
  crossing of a timer re-request and a slow answer double every later item for the rest of the upload.)
  A legacy ``MISSION_ITEM`` (latitude and longitude in float degrees) is taken as well; as PX4 does, a client
  that answers with legacy items is then asked with legacy ``MISSION_REQUEST``. The new mission replaces the
  stored one only when its last item arrived and was valid: a half-uploaded mission never replaces it.
  ``count`` = 0 clears the mission. ``count`` > :data:`MAX_ITEMS` → NO_SPACE.
- **Items** are checked as they arrive (:func:`parse_item`); a refused item ends the upload with the matching
  ``MISSION_ACK`` error (UNSUPPORTED, UNSUPPORTED_FRAME, INVALID_PARAMx, INVALID), as PX4 does; nothing is
  accepted and skipped in silence.
- **A second client** sending ``MISSION_COUNT`` while an upload is in progress is answered with
  ``MISSION_ACK`` ERROR (PX4's answer) and the first upload continues. The partner itself sending a new
  ``MISSION_COUNT`` restarts its upload (PX4 answers ERROR and keeps the old transfer; restarting lets a
  client that gave up and started again succeed without waiting 5 s).
- **During a flown mission** (:attr:`MissionProtocol.busy_flying`, set by the shell while AUTO.MISSION flies
  it; not while paused), uploads, ``count`` = 0 and ``MISSION_CLEAR_ALL`` are refused with ``MISSION_ACK``
  DENIED, so the mission in flight never changes under the vehicle. PX4 accepts them and the navigator
  re-plans; we refuse until an executor exists that does that safely. Pause (hold), then upload.
- **Download.** ``MISSION_REQUEST_LIST`` → ``MISSION_COUNT``; then ``MISSION_REQUEST_INT`` (or legacy
  ``MISSION_REQUEST``) for any seq in any order, several at once (MAVProxy does so) → ``MISSION_ITEM_INT``
  (or ``MISSION_ITEM``) with ``current`` = 1 only for the current item. PX4 serves only the next or the
  previous seq and aborts otherwise; we serve any. A seq beyond the count → ``MISSION_ACK``
  INVALID_SEQUENCE, which ends that download (PX4 answers ERROR). The client's ``MISSION_ACK`` ends it; so
  does :data:`TIMEOUT_S` of silence. Each download serves a snapshot of the mission taken at
  ``MISSION_REQUEST_LIST``, one per client, so an upload from another client (or one completing) never mixes
  two missions in one download. Requests outside a download are ignored, as PX4 does.
- **The geofence** (mission_type 1) is uploaded, downloaded and cleared the same way, into its own store
  (:attr:`MissionProtocol.fence`): inclusion and exclusion polygons (``MAV_CMD_NAV_FENCE_POLYGON_VERTEX_*``, one
  item per vertex, param1 the vertex count) and circles (``MAV_CMD_NAV_FENCE_CIRCLE_*``, param1 the radius [m]),
  at most :data:`MAX_FENCE_ITEMS`. A polygon of fewer than 3 vertices is refused with ERROR as PX4 refuses it; a
  circle's radius that is not a number > 0 with INVALID_PARAM1; and, when its last item arrives, a polygon whose
  vertices do not come as its count says, or whose edges cross, with ERROR and a STATUSTEXT (PX4 leaves those to
  the ground station's editor): a fence refused leaves the stored one as it was. Uploads of it are taken during a
  flown mission (PX4 does too).
- **Rally points** (mission_type 2, ``MAV_CMD_NAV_RALLY_POINT``: a global position and altitude each, at most
  :data:`MAX_RALLY_POINTS`) likewise, into their own store (:attr:`MissionProtocol.rally`). A rally point outside
  the stored geofence refuses the upload with ERROR and a STATUSTEXT (the shell's ``rally_check`` says which; PX4
  does not check): a return must not lead out of the fence.
- **Other mission types** are answered with ``MISSION_ACK`` UNSUPPORTED carrying the same ``mission_type`` (for
  upload, download and clear), so MAVSDK and QGroundControl stop at once instead of waiting. ``MISSION_CLEAR_ALL``
  with mission_type ALL (255) clears the mission, the geofence and the rally points.
- **Current item.** ``MISSION_SET_CURRENT`` sets it within range and answers with ``MISSION_CURRENT``; out of
  range it changes nothing and says so in a STATUSTEXT (PX4 does the same; the message has no ACK).
  :meth:`MissionProtocol.do_set_mission_current` is ``MAV_CMD_DO_SET_MISSION_CURRENT``: FAILED out of range,
  as the MAVLink spec says, ``MISSION_CURRENT`` whether or not it changed.

``MISSION_CURRENT`` at 1 Hz is the shell's job: :meth:`MissionProtocol.mission_current_fields` builds its
fields. ``mission_state`` and ``current`` are the executor's (:mod:`autopilot.mission_executor`): the shell
copies them here with :meth:`MissionProtocol.set_progress`.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

Sender = tuple[int, int]
"""A MAVLink address: (system id, component id)."""

MISSION_TYPE_MISSION = 0
MISSION_TYPE_FENCE = 1
MISSION_TYPE_RALLY = 2
TYPE_NAMES = {MISSION_TYPE_FENCE: "Geofence", MISSION_TYPE_RALLY: "Rally point"}
MISSION_TYPE_ALL = 255

# MAV_MISSION_RESULT
ACCEPTED = 0
ERROR = 1
UNSUPPORTED_FRAME = 2
UNSUPPORTED = 3
NO_SPACE = 4
INVALID = 5
INVALID_PARAM1 = 6
INVALID_PARAM2 = 7
INVALID_PARAM3 = 8
INVALID_PARAM4 = 9
INVALID_PARAM5_X = 10
INVALID_PARAM6_Y = 11
INVALID_PARAM7 = 12
INVALID_SEQUENCE = 13
DENIED = 14
OPERATION_CANCELLED = 15

# MISSION_STATE
STATE_UNKNOWN = 0
STATE_NO_MISSION = 1
STATE_NOT_STARTED = 2
STATE_ACTIVE = 3
STATE_PAUSED = 4
STATE_COMPLETE = 5

# MAV_RESULT (for MAV_CMD_DO_SET_MISSION_CURRENT)
RESULT_ACCEPTED = 0
RESULT_FAILED = 4

# MAV_FRAME
FRAME_GLOBAL = 0
FRAME_MISSION = 2
FRAME_GLOBAL_RELATIVE_ALT = 3
FRAME_GLOBAL_INT = 5
FRAME_GLOBAL_RELATIVE_ALT_INT = 6
GLOBAL_FRAMES = frozenset({FRAME_GLOBAL, FRAME_GLOBAL_RELATIVE_ALT, FRAME_GLOBAL_INT, FRAME_GLOBAL_RELATIVE_ALT_INT})
_LEGACY_FRAME = {FRAME_GLOBAL_INT: FRAME_GLOBAL, FRAME_GLOBAL_RELATIVE_ALT_INT: FRAME_GLOBAL_RELATIVE_ALT}

# MAV_CMD: the commands a mission may hold
NAV_WAYPOINT = 16
NAV_LOITER_TIME = 19
NAV_RETURN_TO_LAUNCH = 20
NAV_LAND = 21
NAV_TAKEOFF = 22
NAV_DELAY = 93
DO_CHANGE_SPEED = 178
DO_SET_ROI_LOCATION = 195
DO_SET_ROI_NONE = 197
POSITION_COMMANDS = frozenset({NAV_WAYPOINT, NAV_LOITER_TIME, NAV_LAND, NAV_TAKEOFF})
"""Commands that fly to a position: they need a global frame and a valid latitude, longitude, altitude."""
CAMERA_NAMES = {
    202: "DO_DIGICAM_CONFIGURE", 203: "DO_DIGICAM_CONTROL", 205: "DO_MOUNT_CONTROL", 206: "DO_SET_CAM_TRIGG_DIST",
    214: "DO_SET_CAM_TRIGG_INTERVAL", 530: "SET_CAMERA_MODE", 531: "SET_CAMERA_ZOOM", 532: "SET_CAMERA_FOCUS",
    1000: "DO_GIMBAL_MANAGER_PITCHYAW", 2000: "IMAGE_START_CAPTURE", 2001: "IMAGE_STOP_CAPTURE",
    2003: "DO_TRIGGER_CONTROL", 2500: "VIDEO_START_CAPTURE", 2501: "VIDEO_STOP_CAPTURE",
}  # fmt: skip
CAMERA_COMMANDS = frozenset(CAMERA_NAMES)
"""Camera and gimbal items: the vehicle has neither, so each completes as it comes, as PX4's mission does with no
camera (it only forwards them); the mission says so once when it starts (autopilot.missions)."""
NO_POSITION_COMMANDS = frozenset({NAV_RETURN_TO_LAUNCH, NAV_DELAY, DO_CHANGE_SPEED, DO_SET_ROI_NONE}) | CAMERA_COMMANDS
"""Commands without a position: frame MISSION (2), or a global frame whose x, y, z are ignored."""
PLACE_COMMANDS = POSITION_COMMANDS | {DO_SET_ROI_LOCATION}
"""Commands that name a place (a global frame, a valid latitude, longitude): the positions and the region of
interest, which the vehicle faces on the following legs."""
SUPPORTED_COMMANDS = PLACE_COMMANDS | NO_POSITION_COMMANDS
FENCE_POLYGON_INCLUSION, FENCE_POLYGON_EXCLUSION = 5001, 5002  # MAV_CMD_NAV_FENCE_POLYGON_VERTEX_*
FENCE_CIRCLE_INCLUSION, FENCE_CIRCLE_EXCLUSION = 5003, 5004  # MAV_CMD_NAV_FENCE_CIRCLE_*
FENCE_POLYGONS = frozenset({FENCE_POLYGON_INCLUSION, FENCE_POLYGON_EXCLUSION})
FENCE_COMMANDS = FENCE_POLYGONS | {FENCE_CIRCLE_INCLUSION, FENCE_CIRCLE_EXCLUSION}
RALLY_POINT = 5100  # MAV_CMD_NAV_RALLY_POINT
STORED_TYPES = (MISSION_TYPE_MISSION, MISSION_TYPE_FENCE, MISSION_TYPE_RALLY)  # uploaded, downloaded and cleared

MAX_ITEMS = 500
"""The most items a mission may have; a longer upload is refused with NO_SPACE."""
MAX_FENCE_ITEMS = 64
"""The most items a geofence may have (PX4's on boards with little memory); the commander holds them in its state
array (:mod:`autopilot.geofence`)."""
MAX_RALLY_POINTS = 16
"""The most rally points; the commander holds them beside the fence."""
RETRY_S = 0.25
"""Re-send an upload's item request after this long without the wanted item [s] (PX4's 250 ms)."""
TIMEOUT_S = 5.0
"""Drop a transfer after this long without a message from its partner [s] (PX4's 5 s)."""
MAX_DOWNLOADS = 8
"""Downloads served at once (one per client); the least recently active one is dropped beyond it."""
UINT16_MAX = 65535

STATUSTEXT_CRITICAL = 2  # MAV_SEVERITY_CRITICAL, what PX4's send_statustext_critical uses


@dataclass(frozen=True)
class Out:
    """A message to send: its pymavlink name (``"MISSION_ACK"``), its target ``(system, component)`` or
    ``None`` for a message without target fields, and its other fields by pymavlink's names."""

    kind: str
    target: Sender | None
    fields: dict[str, Any] = field(default_factory=dict)

    def kwargs(self) -> dict[str, Any]:
        """All fields, the target's included, as pymavlink's ``MAVLink_<kind>_message`` takes them."""
        if self.target is None:
            return dict(self.fields)
        return {"target_system": self.target[0], "target_component": self.target[1], **self.fields}


@dataclass(frozen=True)
class MissionItem:
    """One stored mission item, as ``MISSION_ITEM_INT`` carries it.

    ``x``, ``y``: latitude and longitude [deg · 1e7] in a global frame (in frame MISSION, plain numbers);
    ``z``: altitude [m] (AMSL in frames 0 and 5, above home in 3 and 6). ``p1``–``p4``: the command's
    params (NAV_WAYPOINT: hold [s], acceptance radius [m], pass radius [m], yaw [deg] or NaN).
    ``current``: 1 for the item marked current when it was uploaded.
    """

    seq: int
    frame: int
    command: int
    current: int
    autocontinue: int
    p1: float
    p2: float
    p3: float
    p4: float
    x: int
    y: int
    z: float
    mission_type: int = MISSION_TYPE_MISSION

    @property
    def lat(self) -> float:
        """Latitude [deg] (meaningful in a global frame)."""
        return self.x * 1e-7

    @property
    def lon(self) -> float:
        """Longitude [deg] (meaningful in a global frame)."""
        return self.y * 1e-7

    def same_plan(self, other: MissionItem) -> bool:
        """Equal but for ``seq`` and ``current`` (what PX4's mission CRC covers), NaN equal to NaN."""

        def eq(a: float, b: float) -> bool:
            return a == b or (math.isnan(a) and math.isnan(b))

        return (self.frame, self.command, self.autocontinue, self.x, self.y) == (
            other.frame,
            other.command,
            other.autocontinue,
            other.x,
            other.y,
        ) and all(eq(a, b) for a, b in zip(self._floats(), other._floats()))

    def _floats(self) -> tuple[float, ...]:
        return (self.p1, self.p2, self.p3, self.p4, self.z)

    def message_fields(self, *, legacy: bool = False, current: int | None = None) -> dict[str, Any]:
        """The fields of ``MISSION_ITEM_INT`` (or, ``legacy``, of ``MISSION_ITEM``, latitude and longitude in
        float degrees and frames 5/6 as 0/3), targets excluded. ``current`` overrides the stored flag."""
        frame = self.frame
        if legacy:
            frame = _LEGACY_FRAME.get(frame, frame)
            scale = 1e-7 if self.frame in GLOBAL_FRAMES else 1.0
            x: float | int = self.x * scale
            y: float | int = self.y * scale
        else:
            x, y = self.x, self.y
        return {
            "seq": self.seq,
            "frame": frame,
            "command": self.command,
            "current": self.current if current is None else current,
            "autocontinue": self.autocontinue,
            "param1": self.p1,
            "param2": self.p2,
            "param3": self.p3,
            "param4": self.p4,
            "x": x,
            "y": y,
            "z": self.z,
            "mission_type": self.mission_type,
        }


class ItemRefusedError(ValueError):
    """An item the vehicle does not take; ``code`` is the ``MISSION_ACK`` type that says why."""

    def __init__(self, code: int, reason: str) -> None:
        super().__init__(reason)
        self.code = code


def _finite(v: float) -> bool:
    return math.isfinite(v)


def parse_item(fields: Mapping[str, Any], *, legacy: bool = False) -> MissionItem:
    """Check one uploaded item and store it as a :class:`MissionItem`; raise :class:`ItemRefusedError` if refused.

    ``fields``: a ``MISSION_ITEM_INT`` by pymavlink's field names (``msg.to_dict()`` will do), or with
    ``legacy`` a ``MISSION_ITEM`` (x, y in float degrees). The ``seq`` is not checked here (the upload does).
    """
    frame = int(fields["frame"])
    command = int(fields["command"])
    p = [float(fields[f"param{i}"]) for i in range(1, 5)]
    x, y, z = fields["x"], fields["y"], float(fields["z"])
    if command not in SUPPORTED_COMMANDS:
        raise ItemRefusedError(UNSUPPORTED, f"command {command} is not supported")
    if frame not in GLOBAL_FRAMES and frame != FRAME_MISSION:
        raise ItemRefusedError(UNSUPPORTED_FRAME, f"frame {frame} is not supported")
    if command in PLACE_COMMANDS and frame not in GLOBAL_FRAMES:
        raise ItemRefusedError(UNSUPPORTED_FRAME, f"command {command} needs a global frame, not {frame}")

    if command in PLACE_COMMANDS:
        xi, yi = _position(x, y, legacy)
        # NaN (QGroundControl's null): a waypoint keeps the altitude it is flown at; a region of interest has none
        keeps = command in (NAV_WAYPOINT, NAV_LOITER_TIME, DO_SET_ROI_LOCATION)
        if not (_finite(z) or (keeps and math.isnan(z))):
            raise ItemRefusedError(INVALID_PARAM7, "altitude is not a finite number (or NaN: the current one)")
    else:
        xi, yi = _ignored_xy(x, y, legacy, scale=frame in GLOBAL_FRAMES)
        z = z if _finite(z) else 0.0

    def need(ok: bool, code: int, reason: str) -> None:
        if not ok:
            raise ItemRefusedError(code, reason)

    if command == NAV_WAYPOINT:
        # NaN hold or radius: the default (no hold, NAV_ACC_RAD), as the MAVLink spec's NaN convention says
        need(math.isnan(p[0]) or (_finite(p[0]) and p[0] >= 0.0), INVALID_PARAM1, "hold time must be >= 0 s")
        need(math.isnan(p[1]) or (_finite(p[1]) and p[1] >= 0.0), INVALID_PARAM2, "acceptance radius must be >= 0 m")
        need(math.isnan(p[3]) or _finite(p[3]), INVALID_PARAM4, "yaw must be finite or NaN")
        need(
            math.isnan(p[2]) or p[2] == 0.0,
            INVALID_PARAM3,
            "pass radius must be 0 or NaN: a multicopter stops at each waypoint (its acceptance radius is param2)",
        )
    elif command == NAV_LOITER_TIME:
        need(_finite(p[0]) and p[0] >= 0.0, INVALID_PARAM1, "loiter time must be a number >= 0 s")
        need(math.isnan(p[1]) or p[1] in (0.0, 1.0), INVALID_PARAM2, "heading required must be 0 or 1")
        need(math.isnan(p[2]) or _finite(p[2]), INVALID_PARAM3, "loiter radius must be finite or NaN")
        need(math.isnan(p[3]) or _finite(p[3]), INVALID_PARAM4, "yaw must be finite or NaN")
    elif command in (NAV_TAKEOFF, NAV_LAND):
        need(math.isnan(p[3]) or _finite(p[3]), INVALID_PARAM4, "yaw must be finite or NaN")
    elif command == NAV_DELAY:
        need(_finite(p[0]) and p[0] >= 0.0, INVALID_PARAM1, "delay must be a number >= 0 s (no time of day)")
    elif command == DO_CHANGE_SPEED:
        need(_finite(p[0]) and p[0] in (0.0, 1.0, 2.0, 3.0), INVALID_PARAM1, "speed type must be 0-3")
        need(_finite(p[1]) and (p[1] >= 0.0 or p[1] in (-1.0, -2.0)), INVALID_PARAM2, "speed must be >= 0, -1 or -2")
    return MissionItem(
        seq=int(fields["seq"]),
        frame=frame,
        command=command,
        current=1 if int(fields.get("current", 0)) else 0,
        autocontinue=1 if int(fields.get("autocontinue", 1)) else 0,
        p1=p[0],
        p2=p[1],
        p3=p[2],
        p4=p[3],
        x=xi,
        y=yi,
        z=z,
    )


def _position(x: float, y: float, legacy: bool) -> tuple[int, int]:
    """Latitude and longitude as deg · 1e7, checked; from float degrees if ``legacy``."""
    if legacy:
        if not (_finite(x) and -90.0 <= x <= 90.0):
            raise ItemRefusedError(INVALID_PARAM5_X, "latitude must be within [-90, 90] deg")
        if not (_finite(y) and -180.0 <= y <= 180.0):
            raise ItemRefusedError(INVALID_PARAM6_Y, "longitude must be within [-180, 180] deg")
        return round(x * 1e7), round(y * 1e7)
    xi, yi = int(x), int(y)
    if not -900_000_000 <= xi <= 900_000_000:
        raise ItemRefusedError(INVALID_PARAM5_X, "latitude must be within [-90, 90] deg")
    if not -1_800_000_000 <= yi <= 1_800_000_000:
        raise ItemRefusedError(INVALID_PARAM6_Y, "longitude must be within [-180, 180] deg")
    return xi, yi


def _ignored_xy(x: float, y: float, legacy: bool, *, scale: bool) -> tuple[int, int]:
    """x, y of a command without position: kept as given when representable (scaled to deg · 1e7 from a
    legacy item's degrees in a global frame), else 0."""
    out = []
    for v in (x, y):
        v = float(v)
        if legacy and scale:
            v *= 1e7
        out.append(round(v) if _finite(v) and abs(v) < 2**31 else 0)
    return out[0], out[1]


def parse_fence_item(fields: Mapping[str, Any], *, legacy: bool = False) -> MissionItem:
    """Check one uploaded geofence item (a polygon's vertex or a circle) and store it as a :class:`MissionItem`;
    raise :class:`ItemRefusedError` if refused (the module's docstring says how). Its altitude is not used."""
    frame, command = int(fields["frame"]), int(fields["command"])
    p1 = float(fields["param1"])
    if command not in FENCE_COMMANDS:
        raise ItemRefusedError(UNSUPPORTED, f"command {command} is not a geofence item")
    if frame not in GLOBAL_FRAMES:
        raise ItemRefusedError(UNSUPPORTED_FRAME, f"frame {frame} is not a global frame")
    xi, yi = _position(fields["x"], fields["y"], legacy)
    if command in FENCE_POLYGONS:
        if not (_finite(p1) and p1 + 0.5 >= 3):  # PX4's rounding of the vertex count
            raise ItemRefusedError(ERROR, f"a polygon has at least 3 vertices, not {p1:g}")
        p1 = float(int(p1 + 0.5))
    elif not (_finite(p1) and p1 > 0.0):
        raise ItemRefusedError(INVALID_PARAM1, f"a circle's radius must be a number > 0 m, not {p1:g}")
    z = float(fields["z"])
    return MissionItem(seq=int(fields["seq"]), frame=frame, command=command, current=0, autocontinue=0, p1=p1,
                       p2=float(fields["param2"]) if _finite(float(fields["param2"])) else 0.0, p3=0.0, p4=0.0,
                       x=xi, y=yi, z=z if _finite(z) else 0.0, mission_type=MISSION_TYPE_FENCE)  # fmt: skip


def parse_rally_item(fields: Mapping[str, Any], *, legacy: bool = False) -> MissionItem:
    """Check one uploaded rally point and store it as a :class:`MissionItem`; raise :class:`ItemRefusedError` if
    refused: ``MAV_CMD_NAV_RALLY_POINT`` in a global frame, a valid position and a finite altitude."""
    frame, command = int(fields["frame"]), int(fields["command"])
    if command != RALLY_POINT:
        raise ItemRefusedError(UNSUPPORTED, f"command {command} is not a rally point")
    if frame not in GLOBAL_FRAMES:
        raise ItemRefusedError(UNSUPPORTED_FRAME, f"frame {frame} is not a global frame")
    xi, yi = _position(fields["x"], fields["y"], legacy)
    z = float(fields["z"])
    if not _finite(z):
        raise ItemRefusedError(INVALID_PARAM7, "altitude is not a finite number")
    return MissionItem(seq=int(fields["seq"]), frame=frame, command=command, current=0, autocontinue=0, p1=0.0, p2=0.0,
                       p3=0.0, p4=0.0, x=xi, y=yi, z=z, mission_type=MISSION_TYPE_RALLY)  # fmt: skip


def _crosses(a: tuple, b: tuple, c: tuple, d: tuple) -> bool:
    """Whether the segments ab and cd cross or touch (2-D points)."""

    def side(p: tuple, q: tuple, r: tuple) -> float:
        return (q[0] - p[0]) * (r[1] - p[1]) - (q[1] - p[1]) * (r[0] - p[0])

    d1, d2, d3, d4 = side(c, d, a), side(c, d, b), side(a, b, c), side(a, b, d)
    if ((d1 > 0) != (d2 > 0)) and ((d3 > 0) != (d4 > 0)) and d1 and d2 and d3 and d4:
        return True

    def on(p: tuple, q: tuple, r: tuple) -> bool:  # r on the segment pq, given collinear
        return min(p[0], q[0]) <= r[0] <= max(p[0], q[0]) and min(p[1], q[1]) <= r[1] <= max(p[1], q[1])

    return (d1 == 0 and on(c, d, a)) or (d2 == 0 and on(c, d, b)) or (d3 == 0 and on(a, b, c)) or (
        d4 == 0 and on(a, b, d))  # fmt: skip


def check_fence(items: Sequence[MissionItem]) -> str:
    """Why a whole geofence is refused ("" when it is taken): a polygon's vertices not as its count says (each the
    same command and count, that many in a row), or a polygon whose edges cross (a self-intersecting polygon has no
    inside)."""
    i = 0
    while i < len(items):
        first = items[i]
        if first.command not in FENCE_POLYGONS:
            i += 1
            continue
        n = int(first.p1)
        run = items[i : i + n]
        if len(run) < n or any((v.command, v.p1) != (first.command, first.p1) for v in run):
            return f"Geofence refused: the polygon at item {i} has not {n} vertices in a row"
        xy = [(v.x * 1e-7, v.y * 1e-7 * math.cos(math.radians(first.x * 1e-7))) for v in run]  # equirectangular
        for a in range(n):
            for b in range(a + 1, n):
                if b == a + 1 or (a == 0 and b == n - 1):
                    continue  # adjacent edges share a vertex
                if _crosses(xy[a], xy[(a + 1) % n], xy[b], xy[(b + 1) % n]):
                    return f"Geofence refused: the polygon at item {i} crosses itself (edges {a} and {b})"
        i += n
    return ""


@dataclass
class _Upload:
    partner: Sender
    count: int
    next_seq: int
    last_recv: float
    last_sent: float
    legacy: bool = False
    items: list[MissionItem] = field(default_factory=list)
    mission_type: int = MISSION_TYPE_MISSION


@dataclass
class _Download:
    items: tuple[MissionItem, ...]
    version: int
    current: int
    last_recv: float
    mission_type: int = MISSION_TYPE_MISSION


class MissionProtocol:
    """The vehicle's mission store and its protocol state: see the module's docstring for the rules.

    Every ``on_*`` method takes the sender's ``(system, component)`` and ``now``, wall time [s], and returns the
    messages to send. The shell filters by target (:func:`addressed_to`) before calling.
    """

    def __init__(self, rally_check: Callable[[tuple[MissionItem, ...]], str] | None = None) -> None:
        self.rally_check = rally_check
        """Why rally points are refused ("" when taken): the shell's check against the stored geofence."""
        self.items: tuple[MissionItem, ...] = ()
        """The stored mission: replaced only by a complete upload, a clear or ``count`` = 0."""
        self.current: int = 0
        """The current item's seq (the executor moves it; 0 with no mission)."""
        self.mission_state: int = STATE_NO_MISSION
        """MISSION_STATE: 1 none, 2 not started, 3 active, 4 paused, 5 complete (the executor updates it)."""
        self.mission_mode: int = 0
        """MISSION_CURRENT.mission_mode: 0 unknown, 1 in a mission mode, 2 suspended (the shell sets it)."""
        self.version: int = 0
        """Counts replacements of the stored mission (uploads that changed it, clears)."""
        self.busy_flying: bool = False
        """Set by the shell while a mission flies (not while paused): uploads and clears are then DENIED."""
        self.fence: tuple[MissionItem, ...] = ()
        """The stored geofence (mission_type 1): replaced by a complete upload, a clear or ``count`` = 0."""
        self.fence_version: int = 0
        """Counts replacements of the stored geofence."""
        self.rally: tuple[MissionItem, ...] = ()
        """The stored rally points (mission_type 2)."""
        self.rally_version: int = 0
        """Counts replacements of the stored rally points."""
        self._upload: _Upload | None = None
        self._last_upload: tuple[Sender, int, int] | None = None  # partner, last seq, mission type: a lost ACK
        self._downloads: dict[Sender, _Download] = {}

    # ---- helpers -------------------------------------------------------------------------------------

    @property
    def upload_in_progress(self) -> bool:
        """True while an upload is under way."""
        return self._upload is not None

    @staticmethod
    def _ack(to: Sender, result: int, mission_type: int = MISSION_TYPE_MISSION) -> Out:
        return Out("MISSION_ACK", to, {"type": result, "mission_type": mission_type})

    def _request(self, up: _Upload, now: float) -> Out:
        up.last_sent = now
        kind = "MISSION_REQUEST" if up.legacy else "MISSION_REQUEST_INT"
        return Out(kind, up.partner, {"seq": up.next_seq, "mission_type": up.mission_type})

    def mission_current_fields(self) -> dict[str, Any]:
        """The fields of ``MISSION_CURRENT``: ``total`` is UINT16_MAX with no mission (the MAVLink spec,
        PX4)."""
        return {
            "seq": self.current,
            "total": len(self.items) if self.items else UINT16_MAX,
            "mission_state": self.mission_state,
            "mission_mode": self.mission_mode,
        }

    def mission_current(self) -> Out:
        """A ``MISSION_CURRENT`` message (no target)."""
        return Out("MISSION_CURRENT", None, self.mission_current_fields())

    def _replace(self, items: tuple[MissionItem, ...], current: int) -> None:
        self.items = items
        self.current = current
        self.mission_state = STATE_NOT_STARTED if items else STATE_NO_MISSION
        self.version += 1

    def _replace_fence(self, items: tuple[MissionItem, ...]) -> None:
        self.fence = items
        self.fence_version += 1

    def _replace_rally(self, items: tuple[MissionItem, ...]) -> None:
        self.rally = items
        self.rally_version += 1

    def _replace_of(self, mission_type: int, items: tuple[MissionItem, ...]) -> None:
        """The geofence or the rally points replaced by ``items``."""
        if mission_type == MISSION_TYPE_FENCE:
            self._replace_fence(items)
        else:
            self._replace_rally(items)

    def stored(self, mission_type: int) -> tuple[MissionItem, ...]:
        """The items stored of ``mission_type`` (one of STORED_TYPES)."""
        return {MISSION_TYPE_FENCE: self.fence, MISSION_TYPE_RALLY: self.rally}.get(mission_type, self.items)

    def _unsupported(self, mission_type: int, what: str) -> Out:
        """The STATUSTEXT beside an UNSUPPORTED mission type: MAVSDK reports it as a bare ERROR (its geofence plugin
        maps UNSUPPORTED so), the text says why."""
        name = TYPE_NAMES.get(mission_type, f"Mission type {mission_type}")
        return self._statustext(f"{name} {what} refused: not supported")

    def _statustext(self, text: str) -> Out:
        return Out("STATUSTEXT", None, {"severity": STATUSTEXT_CRITICAL, "text": text})  # said in chunks

    # ---- upload --------------------------------------------------------------------------------------

    def on_count(self, sender: Sender, count: int, mission_type: int, now: float) -> list[Out]:
        """``MISSION_COUNT``: start an upload of ``count`` items of ``mission_type`` (0 clears what is stored)."""
        if mission_type not in STORED_TYPES:
            return [self._ack(sender, UNSUPPORTED, mission_type), self._unsupported(mission_type, "upload")]
        up = self._upload
        if up is not None and now - up.last_recv > TIMEOUT_S:
            out = self.tick(now)  # a stale upload not yet dropped by tick: drop it first
            return out + self.on_count(sender, count, mission_type, now)
        if up is not None and up.partner != sender:
            return [self._ack(sender, ERROR, mission_type)]  # PX4: another partner's upload is in progress
        other = mission_type != MISSION_TYPE_MISSION  # the geofence or the rally points
        if self.busy_flying and not other:
            return [self._ack(sender, DENIED)]
        if up is not None and up.next_seq == 0 and up.count == count and up.mission_type == mission_type:
            up.last_recv = now  # our first request was lost: ask again
            return [self._request(up, now)]
        self._upload = None
        limit = {MISSION_TYPE_FENCE: MAX_FENCE_ITEMS, MISSION_TYPE_RALLY: MAX_RALLY_POINTS}.get(mission_type, MAX_ITEMS)
        if count > limit:
            return [self._ack(sender, NO_SPACE, mission_type)]
        if count <= 0:
            self._last_upload = None
            if other:
                self._replace_of(mission_type, ())
                return [self._ack(sender, ACCEPTED, mission_type)]
            self._replace((), 0)
            return [self._ack(sender, ACCEPTED), self.mission_current()]
        self._upload = _Upload(partner=sender, count=count, next_seq=0, last_recv=now, last_sent=now,
                               mission_type=mission_type)  # fmt: skip
        return [self._request(self._upload, now)]

    def on_item(self, sender: Sender, fields: Mapping[str, Any], now: float, *, legacy: bool = False) -> list[Out]:
        """``MISSION_ITEM_INT`` (or, ``legacy``, ``MISSION_ITEM``): ``fields`` by pymavlink's names."""
        seq = int(fields["seq"])
        mission_type = int(fields.get("mission_type", MISSION_TYPE_MISSION))
        up = self._upload
        if up is None:
            last = self._last_upload
            if last is not None and last == (sender, seq, mission_type):
                return [self._ack(sender, ACCEPTED, mission_type)]  # the client missed our ACK: the last item again
            return [self._ack(sender, ERROR, mission_type)]  # PX4: no transfer
        if sender != up.partner:
            return []  # PX4: partner mismatch, ignored
        if mission_type != up.mission_type:
            return [self._ack(sender, ERROR, mission_type)]
        up.last_recv = now
        if seq != up.next_seq:
            return []  # a duplicate or out of order: ignored, the re-request timer asks for the wanted one
        parsers = {MISSION_TYPE_FENCE: parse_fence_item, MISSION_TYPE_RALLY: parse_rally_item}
        parse = parsers.get(mission_type, parse_item)
        try:
            item = parse(fields, legacy=legacy)
        except ItemRefusedError as e:
            self._upload = None
            what = TYPE_NAMES.get(mission_type, "Mission")
            return [self._ack(sender, e.code, mission_type), self._statustext(f"{what} item {seq} refused: {e}")]
        up.legacy = legacy
        up.items.append(item)
        up.next_seq += 1
        if up.next_seq < up.count:
            return [self._request(up, now)]
        return self._complete(up)

    def store_other(self, mission_type: int, items: tuple[MissionItem, ...]) -> str:
        """A whole geofence or set of rally points (each item parsed), as a completed upload stores it → why it is
        refused ("" when stored): a geofence's polygons checked (:func:`check_fence`), rally points by ``rally_check``.
        ``quadsitl sim`` stores a plan's so."""
        if mission_type == MISSION_TYPE_FENCE:
            reason = check_fence(items)
        else:
            reason = self.rally_check(items) if self.rally_check is not None else ""
        if not reason:
            self._replace_of(mission_type, items)
        return reason

    def store(self, items: tuple[MissionItem, ...]) -> None:
        """A whole mission, as a completed upload of new items stores it (``quadsitl sim`` stores its mission file
        so, each item first through :func:`parse_item`)."""
        marked = [it.seq for it in items if it.current]
        self._replace(items, marked[0] if marked else 0)

    def _complete(self, up: _Upload) -> list[Out]:
        self._upload = None
        items = tuple(up.items)
        if up.mission_type != MISSION_TYPE_MISSION:
            reason = self.store_other(up.mission_type, items)
            if reason:
                return [self._ack(up.partner, ERROR, up.mission_type), self._statustext(reason)]
            self._last_upload = (up.partner, up.count - 1, up.mission_type)
            return [self._ack(up.partner, ACCEPTED, up.mission_type)]
        self._last_upload = (up.partner, up.count - 1, up.mission_type)
        unchanged = len(items) == len(self.items) and all(a.same_plan(b) for a, b in zip(items, self.items))
        out = [self._ack(up.partner, ACCEPTED)]
        if not unchanged:  # as PX4: the same mission again keeps the current item and the state
            self.store(items)
            out.append(self.mission_current())
        else:
            self.items = items
        return out

    # ---- download ------------------------------------------------------------------------------------

    def on_request_list(self, sender: Sender, mission_type: int, now: float) -> list[Out]:
        """``MISSION_REQUEST_LIST``: start (or restart) this client's download → ``MISSION_COUNT``."""
        if mission_type not in STORED_TYPES:
            return [self._ack(sender, UNSUPPORTED, mission_type), self._unsupported(mission_type, "download")]
        self._downloads.pop(sender, None)
        if len(self._downloads) >= MAX_DOWNLOADS:
            oldest = min(self._downloads, key=lambda s: self._downloads[s].last_recv)
            del self._downloads[oldest]
        items = self.stored(mission_type)
        self._downloads[sender] = _Download(items, self.version, self.current, now, mission_type)
        return [Out("MISSION_COUNT", sender, {"count": len(items), "mission_type": mission_type})]

    def on_request(self, sender: Sender, seq: int, mission_type: int, now: float, *, legacy: bool = False) -> list[Out]:
        """``MISSION_REQUEST_INT`` (or, ``legacy``, ``MISSION_REQUEST``) for item ``seq`` of a download."""
        dl = self._downloads.get(sender)
        if dl is None or mission_type != dl.mission_type:
            return []  # PX4: no transfer, ignored
        dl.last_recv = now
        if not 0 <= seq < len(dl.items):
            del self._downloads[sender]
            return [self._ack(sender, INVALID_SEQUENCE, mission_type)]
        if mission_type != MISSION_TYPE_MISSION:
            fields = dl.items[seq].message_fields(legacy=legacy, current=0)
            return [Out("MISSION_ITEM" if legacy else "MISSION_ITEM_INT", sender, fields)]
        current = self.current if dl.version == self.version else dl.current
        fields = dl.items[seq].message_fields(legacy=legacy, current=1 if seq == current else 0)
        fields["autocontinue"] = 1
        return [Out("MISSION_ITEM" if legacy else "MISSION_ITEM_INT", sender, fields)]

    def on_ack(self, sender: Sender, result: int, mission_type: int, now: float) -> list[Out]:
        """``MISSION_ACK`` from a client: ends its download; CANCELLED from the upload's partner drops the
        upload; UNSUPPORTED from it switches between ``MISSION_REQUEST_INT`` and ``MISSION_REQUEST`` (PX4)."""
        if mission_type not in STORED_TYPES:
            return []
        dl = self._downloads.get(sender)
        if dl is not None and dl.mission_type == mission_type:
            del self._downloads[sender]
        up = self._upload
        if up is not None and up.partner == sender and up.mission_type == mission_type:
            if result == OPERATION_CANCELLED:
                self._upload = None
            elif result == UNSUPPORTED:
                up.legacy = not up.legacy
                up.last_recv = now
                return [self._request(up, now)]
        return []

    # ---- clear and current ---------------------------------------------------------------------------

    def on_clear_all(self, sender: Sender, mission_type: int, now: float) -> list[Out]:
        """``MISSION_CLEAR_ALL``: empty the mission (mission_type 0), the geofence (1), the rally points (2) or all
        (ALL), ACK ACCEPTED."""
        if mission_type not in (*STORED_TYPES, MISSION_TYPE_ALL):
            return [self._ack(sender, UNSUPPORTED, mission_type)]
        if mission_type in (MISSION_TYPE_FENCE, MISSION_TYPE_RALLY):
            self._replace_of(mission_type, ())
            return [self._ack(sender, ACCEPTED, mission_type)]
        if self.busy_flying:
            return [self._ack(sender, DENIED, mission_type)]
        if mission_type == MISSION_TYPE_ALL:
            self._replace_fence(())
            self._replace_rally(())
        self._replace((), 0)
        self._last_upload = None
        return [self._ack(sender, ACCEPTED, mission_type), self.mission_current()]

    def set_current(self, seq: int) -> bool:
        """Make ``seq`` the current item; False (nothing changes) if it is not an item of the mission."""
        if not 0 <= seq < len(self.items):
            return False
        self.current = seq
        return True

    def on_set_current(self, sender: Sender, seq: int, now: float) -> list[Out]:
        """``MISSION_SET_CURRENT``: ``MISSION_CURRENT`` if ``seq`` is in range, else a STATUSTEXT."""
        if self.set_current(seq):
            return [self.mission_current()]
        return [self._statustext(f"Mission: set current {seq} is not in the mission")]

    def do_set_mission_current(self, seq: int, reset: bool = False) -> tuple[int, list[Out]]:
        """``MAV_CMD_DO_SET_MISSION_CURRENT`` (param1 ``seq``, −1 keeps the current item; param2 ``reset``):
        the command's MAV_RESULT (FAILED out of range or with no mission) and ``MISSION_CURRENT`` on success,
        sent whether or not the item changed (the MAVLink spec). A reset of a complete mission pauses it."""
        if not self.items or not (seq == -1 or self.set_current(seq)):
            return RESULT_FAILED, []
        if reset and self.mission_state == STATE_COMPLETE:
            self.mission_state = STATE_PAUSED
        return RESULT_ACCEPTED, [self.mission_current()]

    def set_progress(self, current: int, mission_state: int) -> list[Out]:
        """The executor's ``current`` and ``mission_state`` (:mod:`autopilot.mission_executor`), copied here by
        the shell: a ``MISSION_CURRENT`` if either changed (PX4 sends it on change), else nothing."""
        if (current, mission_state) == (self.current, self.mission_state):
            return []
        self.current, self.mission_state = current, mission_state
        return [self.mission_current()]

    @staticmethod
    def item_reached(seq: int) -> Out:
        """A ``MISSION_ITEM_REACHED`` for item ``seq`` (no target)."""
        return Out("MISSION_ITEM_REACHED", None, {"seq": seq})

    # ---- time ----------------------------------------------------------------------------------------

    def tick(self, now: float) -> list[Out]:
        """Re-request the wanted item every :data:`RETRY_S`; drop transfers silent for :data:`TIMEOUT_S`
        (an upload with ``MISSION_ACK`` OPERATION_CANCELLED and a STATUSTEXT). Call it often (≥ 10 Hz)."""
        out: list[Out] = []
        up = self._upload
        if up is not None:
            if now - up.last_recv > TIMEOUT_S:
                self._upload = None
                out += [self._ack(up.partner, OPERATION_CANCELLED), self._statustext("Mission upload timed out")]
            elif now - up.last_sent >= RETRY_S:
                out.append(self._request(up, now))
        for s in [s for s, d in self._downloads.items() if now - d.last_recv > TIMEOUT_S]:
            del self._downloads[s]
        return out


def addressed_to(target_system: int, target_component: int, system: int, component: int) -> bool:
    """Whether a mission message's target is this vehicle: our system, and our component, the mission
    planner (190) or all (0), as PX4 checks."""
    return target_system == system and target_component in (component, 190, 0)
