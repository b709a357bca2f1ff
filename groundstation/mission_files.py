"""Mission files for ``quadsitl fly --mission``: read and check them before anything starts (pure, no sockets).

Three formats, told apart by their content:

- **QGroundControl ``.plan``** (JSON; QGroundControl's documented plan file format): ``"fileType": "Plan"``,
  its ``"mission"`` object's ``"items"``. Each ``SimpleItem`` has ``command``, ``frame``, ``params`` (seven
  numbers or null, QGroundControl's NaN: params 5–7 are latitude, longitude, altitude; QGroundControl's older
  items: four params and a ``coordinate``) and ``autoContinue``.
  A survey or corridor scan (``ComplexItem``) is flown as the simple items QGroundControl saved in its
  ``TransectStyleComplexItem.Items`` (what it uploads); a structure scan, which has none saved, is refused.
  ``plannedHomePosition`` is where the vehicle is expected: ``fly`` and ``sim`` start it there unless ``--home``
  says otherwise. Geofence and rally points are ignored if empty, refused if not (the vehicle has no fence or
  rally types yet).
- **Waypoint CSV** with the header ``lat, lon, altitude`` (any order, plus optional ``hold`` [s],
  ``radius`` [m], ``yaw`` [deg]): one ``NAV_WAYPOINT`` per row at ``altitude`` above home (frame 6); an empty
  optional cell is the default (hold 0, the vehicle's acceptance radius, yaw toward the waypoint).
- **QGC WPL 110** (the plain-text format MAVProxy and QGroundControl write): ``QGC WPL 110`` then one
  tab-separated line per item ``index current frame command p1 p2 p3 p4 lat lon alt autocontinue``, the indices
  counting 0, 1, 2, ... Line 0 is the planned home (QGroundControl's loader and ArduPilot's convention: "planned home
  position is already in position 0"), used as a .plan's; the items are the lines after it.

Every item is checked by the vehicle's own check (:func:`autopilot.mission_protocol.parse_item`), so that a
file is refused here, with its file, item (or line), field and value, exactly when the vehicle would refuse
the upload.
"""

from __future__ import annotations

import csv
import json
import math
from dataclasses import dataclass
from pathlib import Path

from autopilot import mission_protocol as mp
from quadsitl.cli_util import UsageError
from quadsitl.frames import geodetic_to_ned

COMMAND_NAMES = {
    mp.NAV_WAYPOINT: "NAV_WAYPOINT",
    mp.NAV_LOITER_TIME: "NAV_LOITER_TIME",
    mp.NAV_RETURN_TO_LAUNCH: "NAV_RETURN_TO_LAUNCH",
    mp.NAV_LAND: "NAV_LAND",
    mp.NAV_TAKEOFF: "NAV_TAKEOFF",
    mp.NAV_DELAY: "NAV_DELAY",
    mp.DO_CHANGE_SPEED: "DO_CHANGE_SPEED",
    mp.DO_SET_ROI_LOCATION: "DO_SET_ROI_LOCATION",
    mp.DO_SET_ROI_NONE: "DO_SET_ROI_NONE",
    **mp.CAMERA_NAMES,
}
ALLOWED_COMMANDS = ", ".join(f"{c} ({n})" for c, n in sorted(COMMAND_NAMES.items()))
ALLOWED_FRAMES = "0, 3, 5, 6 (global; 2 for commands without a position)"
# The field a refused item's MISSION_ACK code points at: (its name, its index in params or None, what the
# vehicle allows there; None: the vehicle's reason says it).
_FIELD = {
    mp.UNSUPPORTED: ("command", None, f"one of {ALLOWED_COMMANDS}"),
    mp.UNSUPPORTED_FRAME: ("frame", None, ALLOWED_FRAMES),
    mp.INVALID_PARAM1: ("param1", 0, None),
    mp.INVALID_PARAM2: ("param2", 1, None),
    mp.INVALID_PARAM3: ("param3", 2, None),
    mp.INVALID_PARAM4: ("param4", 3, None),
    mp.INVALID_PARAM5_X: ("latitude (param5)", 4, None),
    mp.INVALID_PARAM6_Y: ("longitude (param6)", 5, None),
    mp.INVALID_PARAM7: ("altitude (param7)", 6, None),
}
POSITION_COMMANDS = mp.POSITION_COMMANDS
FINISHING_COMMANDS = frozenset({mp.NAV_RETURN_TO_LAUNCH, mp.NAV_LAND})

MISSION_DURATION = 900.0  # [s] simulated: the default bound on a mission's flight (--duration changes it)


class MissionFileError(UsageError):
    """A mission file that cannot be flown: one line naming the file, the item or line, the field and value."""


def usable_home(home: tuple[float, float, float] | None) -> tuple[float, float, float] | None:
    """A planned home (latitude, longitude [deg], altitude AMSL [m]) a vehicle can start at, or None: finite, on the
    globe, and not 0, 0 (what MAVProxy and QGroundControl write when they knew no home)."""
    if home is None or not all(math.isfinite(v) for v in home):
        return None
    lat, lon, _ = home
    return home if abs(lat) <= 90 and abs(lon) <= 180 and (lat, lon) != (0.0, 0.0) else None


@dataclass(frozen=True)
class Mission:
    """A checked mission: ``items`` as the vehicle stores them (seq 0..n-1), ready for ``MISSION_ITEM_INT``."""

    path: Path
    kind: str  # "plan", "csv" or "wpl"
    items: tuple[mp.MissionItem, ...]
    planned_home: tuple[float, float, float] | None = None  # a .plan's plannedHomePosition or a WPL file's line 0
    fence: tuple[mp.MissionItem, ...] = ()  # a .plan's geoFence, as the vehicle stores it (mission_type 1)
    rally: tuple[mp.MissionItem, ...] = ()  # a .plan's rallyPoints (mission_type 2)

    @property
    def lands(self) -> bool:
        """True if the mission ends by landing (its last item is NAV_LAND or NAV_RETURN_TO_LAUNCH)."""
        return bool(self.items) and self.items[-1].command in FINISHING_COMMANDS

    @property
    def flown(self) -> tuple[mp.MissionItem, ...]:
        """The items ``quadsitl fly`` and ``quadsitl sim`` give the vehicle: the file's, and after a mission that does
        not land by itself a NAV_LAND that lands where it ends (latitude and longitude 0: here), as MAVSDK appends a
        return for ``set_return_to_launch_after_mission``. The vehicle lands the tick its mission is complete, on any
        machine (a ground station that sends NAV_LAND when it sees the mission complete lands it later the busier
        its machine)."""
        if self.lands:
            return self.items
        land = mp.MissionItem(len(self.items), mp.FRAME_GLOBAL_RELATIVE_ALT_INT, mp.NAV_LAND, 0, 1, 0.0, 0.0, 0.0,
                              math.nan, 0, 0, 0.0)  # fmt: skip
        return (*self.items, land)


def _simple_items(path: Path, entries: list) -> list[tuple[str, dict]]:
    """A .plan's items as the simple items QGroundControl uploads, each with the words that name it: a survey's or
    corridor scan's (a ``ComplexItem`` with ``TransectStyleComplexItem.Items``, the waypoints and camera items
    QGroundControl generated and saved) in its place; another complex item (a structure scan, which QGroundControl
    generates only as it uploads) refused."""
    out = []
    for i, it in enumerate(entries):
        where = f"mission {path}, item {i}"
        if not isinstance(it, dict):
            raise MissionFileError(f"{where}: {it!r} is not an object; expected a SimpleItem")
        if it.get("type") != "ComplexItem":
            out.append((where, it))
            continue
        name = it.get("complexItemType", "complex item")
        inner = (it.get("TransectStyleComplexItem") or {}).get("Items")
        if not isinstance(inner, list) or not inner:
            raise MissionFileError(f"{where}, type: ComplexItem ({name}) has no saved items; allowed: SimpleItem, or "
                                   "a survey or corridor scan with its TransectStyleComplexItem.Items")  # fmt: skip
        for j, sub in enumerate(inner):
            if not isinstance(sub, dict) or sub.get("type") != "SimpleItem":
                raise MissionFileError(f"{where} ({name}), item {j}: {sub!r}; expected a SimpleItem")
            out.append((f"{where} ({name}), item {j}", sub))
    return out


def _num(v: object) -> float:
    """A JSON/CSV value as a float: null and an empty cell are NaN."""
    if v is None or (isinstance(v, str) and not v.strip()):
        return math.nan
    if isinstance(v, bool):
        raise ValueError
    return float(v)


def _fmt(v: float) -> str:
    return "NaN" if isinstance(v, float) and math.isnan(v) else f"{v:g}"


def check_item(where: str, seq: int, command: int, frame: int, params: list[float], autocontinue: bool = True):
    """The vehicle's check of one item; ``where`` names it ("mission F, item 3") in the error."""
    fields = {"seq": seq, "frame": frame, "command": command, "current": 0, "autocontinue": int(autocontinue)}
    fields.update({f"param{i + 1}": params[i] for i in range(4)})
    fields.update(x=params[4], y=params[5], z=params[6])
    try:
        return mp.parse_item(fields, legacy=True)
    except mp.ItemRefusedError as exc:
        field, index, allowed = _FIELD.get(exc.code, ("item", None, None))
        value = {"command": str(command), "frame": str(frame)}.get(field) if index is None else _fmt(params[index])
        name = COMMAND_NAMES.get(command, f"command {command}")
        reason = allowed or str(exc)
        raise MissionFileError(
            f"{where} ({name}), {field}: {value} is refused by the vehicle; allowed: {reason}"
        ) from None


def load(path: str | Path) -> Mission:
    """Read and check a mission file (``.plan``, waypoint CSV or QGC WPL 110); :class:`MissionFileError` if
    it cannot be flown."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8-sig")
    except OSError as exc:
        raise MissionFileError(f"--mission {str(path)!r}: cannot read it ({exc.strerror or exc})") from None
    except UnicodeDecodeError:
        raise MissionFileError(f"--mission {str(path)!r}: not a text file; expected a QGroundControl .plan "
                               "(JSON), a waypoint CSV (lat,lon,altitude) or a QGC WPL 110 file") from None  # fmt: skip
    head = text.lstrip()
    if head.startswith("{"):
        mission = _plan(path, text)
    elif head.startswith("QGC WPL"):
        mission = _wpl(path, text)
    else:
        mission = _csv(path, text)
    if not mission.items:
        raise MissionFileError(f"mission {path}: no mission items; a mission needs at least one")
    if len(mission.items) > mp.MAX_ITEMS:
        raise MissionFileError(f"mission {path}: {len(mission.items)} items; the vehicle takes at most {mp.MAX_ITEMS}")
    return mission


def _plan(path: Path, text: str) -> Mission:
    try:
        doc = json.loads(text)
    except json.JSONDecodeError as exc:
        raise MissionFileError(f"mission {path}, line {exc.lineno}: not valid JSON ({exc.msg})") from None
    if not isinstance(doc, dict) or doc.get("fileType") != "Plan":
        got = doc.get("fileType") if isinstance(doc, dict) else type(doc).__name__
        raise MissionFileError(f"mission {path}, fileType: {got!r}; expected 'Plan' (a QGroundControl .plan file)")
    mission = doc.get("mission")
    if not isinstance(mission, dict) or not isinstance(mission.get("items"), list):
        raise MissionFileError(f"mission {path}, mission.items: missing; expected a list of mission items")
    fence, rally = _fence(path, doc.get("geoFence")), _rally(path, doc.get("rallyPoints"))
    home = mission.get("plannedHomePosition")
    planned_home = None
    if isinstance(home, list) and len(home) == 3:
        try:
            planned_home = tuple(_num(v) for v in home)
        except (TypeError, ValueError):
            planned_home = None
    items = []
    for where, it in _simple_items(path, mission["items"]):
        kind = it.get("type")
        if kind != "SimpleItem":
            raise MissionFileError(f"{where}, type: {kind!r}; allowed: 'SimpleItem'")
        command, frame = it.get("command"), it.get("frame")
        for field, v in (("command", command), ("frame", frame)):
            if not isinstance(v, int) or isinstance(v, bool):
                raise MissionFileError(f"{where}, {field}: {v!r} is not an integer")
        params = it.get("params")
        coordinate = it.get("coordinate")  # QGroundControl's older items: four params, the place apart
        if isinstance(params, list) and len(params) == 4 and isinstance(coordinate, list) and len(coordinate) == 3:
            params = params + coordinate
        if not isinstance(params, list) or len(params) != 7:
            raise MissionFileError(f"{where}, params: {params!r}; expected a list of 7 numbers (or null), or 4 with "
                                   "a coordinate [latitude, longitude, altitude]")  # fmt: skip
        try:
            values = [_num(v) for v in params]
        except (TypeError, ValueError):
            bad = next(v for v in params if not _is_number(v))
            raise MissionFileError(f"{where}, params: {bad!r} is not a number (or null)") from None
        auto = it.get("autoContinue", True)
        if not isinstance(auto, bool):
            raise MissionFileError(f"{where}, autoContinue: {auto!r}; expected true or false")
        items.append(check_item(where, len(items), command, frame, values, auto))
    return Mission(path, "plan", tuple(items), usable_home(planned_home), fence, rally)


def _section(path: Path, name: str, doc: object, key: str) -> list:
    """A .plan section's list ``key`` (none: empty)."""
    if doc is None:
        return []
    if not isinstance(doc, dict):
        raise MissionFileError(f"mission {path}, {name}: {type(doc).__name__}; expected an object")
    entries = doc.get(key) or []
    if not isinstance(entries, list):
        raise MissionFileError(f"mission {path}, {name}.{key}: {entries!r}; expected a list")
    return entries


def _checked(where: str, parse, fields: dict) -> mp.MissionItem:
    try:
        return parse(fields)
    except mp.ItemRefusedError as exc:
        raise MissionFileError(f"{where}: {exc}") from None
    except (TypeError, ValueError):
        raise MissionFileError(f"{where}: {fields!r} is not a place (latitude, longitude numbers)") from None


def _place(where: str, point: object, n: int) -> list[float]:
    if not isinstance(point, list) or len(point) != n or not all(_is_number(v) and v is not None for v in point):
        raise MissionFileError(f"{where}: {point!r}; expected [{', '.join(('latitude', 'longitude', 'altitude')[:n])}]")
    return [float(v) for v in point]


def _fence(path: Path, doc: object) -> tuple[mp.MissionItem, ...]:
    """A .plan's ``geoFence`` (QGroundControl's: ``polygons`` of ``{"polygon": [[lat, lon], ...], "inclusion"}``,
    ``circles`` of ``{"circle": {"center": [lat, lon], "radius"}, "inclusion"}``) as the vehicle stores a fence,
    checked as its upload is (:func:`autopilot.mission_protocol.parse_fence_item`, ``check_fence``)."""
    items: list[mp.MissionItem] = []

    def item(where: str, command: int, p1: float, lat: float, lon: float) -> None:
        fields = {"seq": len(items), "frame": mp.FRAME_GLOBAL, "command": command, "param1": p1, "param2": 0.0,
                  "x": lat, "y": lon, "z": 0.0}  # fmt: skip
        items.append(_checked(where, lambda f: mp.parse_fence_item(f, legacy=True), fields))

    for i, entry in enumerate(_section(path, "geoFence", doc, "polygons")):
        where = f"mission {path}, geoFence.polygons[{i}]"
        vertices = entry.get("polygon") if isinstance(entry, dict) else None
        if not isinstance(vertices, list):
            raise MissionFileError(f'{where}: {entry!r}; expected {{"polygon": [[latitude, longitude], ...]}}')
        inclusion = entry.get("inclusion", True)
        command = mp.FENCE_POLYGON_INCLUSION if inclusion else mp.FENCE_POLYGON_EXCLUSION
        for j, vertex in enumerate(vertices):
            item(f"{where}.polygon[{j}]", command, float(len(vertices)), *_place(f"{where}.polygon[{j}]", vertex, 2))
    for i, entry in enumerate(_section(path, "geoFence", doc, "circles")):
        where = f"mission {path}, geoFence.circles[{i}]"
        circle = entry.get("circle") if isinstance(entry, dict) else None
        if not isinstance(circle, dict) or not _is_number(circle.get("radius")) or circle.get("radius") is None:
            raise MissionFileError(f"{where}: {entry!r}; expected {{\"circle\": {{\"center\": [latitude, "
                                   "longitude], \"radius\": metres}}}}")  # fmt: skip
        inclusion = entry.get("inclusion", True)
        command = mp.FENCE_CIRCLE_INCLUSION if inclusion else mp.FENCE_CIRCLE_EXCLUSION
        item(where, command, float(circle["radius"]), *_place(f"{where}.circle.center", circle.get("center"), 2))
    if len(items) > mp.MAX_FENCE_ITEMS:
        raise MissionFileError(f"mission {path}, geoFence: {len(items)} items; the vehicle takes at most "
                               f"{mp.MAX_FENCE_ITEMS}")  # fmt: skip
    reason = mp.check_fence(items)
    if reason:
        raise MissionFileError(f"mission {path}, geoFence: {reason}")
    return tuple(items)


def _rally(path: Path, doc: object) -> tuple[mp.MissionItem, ...]:
    """A .plan's ``rallyPoints`` (``points`` of [lat, lon, altitude above home]) as the vehicle stores them."""
    items = []
    for i, point in enumerate(_section(path, "rallyPoints", doc, "points")):
        where = f"mission {path}, rallyPoints.points[{i}]"
        lat, lon, alt = _place(where, point, 3)
        fields = {"seq": i, "frame": mp.FRAME_GLOBAL_RELATIVE_ALT, "command": mp.RALLY_POINT, "x": lat, "y": lon,
                  "z": alt}  # fmt: skip
        items.append(_checked(where, lambda f: mp.parse_rally_item(f, legacy=True), fields))
    if len(items) > mp.MAX_RALLY_POINTS:
        raise MissionFileError(f"mission {path}, rallyPoints: {len(items)} points; the vehicle takes at most "
                               f"{mp.MAX_RALLY_POINTS}")  # fmt: skip
    return tuple(items)


def _is_number(v: object) -> bool:
    try:
        _num(v)
    except (TypeError, ValueError):
        return False
    return True


CSV_REQUIRED = ("lat", "lon", "altitude")
CSV_OPTIONAL = ("hold", "radius", "yaw")


def _csv(path: Path, text: str) -> Mission:
    rows = list(csv.reader(text.splitlines()))
    header = [h.strip().lower() for h in rows[0]] if rows else []
    missing = [c for c in CSV_REQUIRED if c not in header]
    if missing:
        raise MissionFileError(
            f"mission {path}, line 1: header {','.join(header) or '(empty)'!r} lacks {', '.join(missing)}; expected "
            "a QGroundControl .plan (JSON), a QGC WPL 110 file, or a CSV with the header lat,lon,altitude "
            "(optional: hold,radius,yaw)"
        )
    col = {name: header.index(name) for name in CSV_REQUIRED + CSV_OPTIONAL if name in header}
    items = []
    for line, row in enumerate(rows[1:], start=2):
        if not any(cell.strip() for cell in row):
            continue
        where = f"mission {path}, line {line}"
        v = {}
        for name, j in col.items():
            cell = row[j].strip() if j < len(row) else ""
            if name in CSV_REQUIRED and not cell:
                raise MissionFileError(f"{where}, column {name}: missing; expected a number")
            try:
                v[name] = _num(cell)
            except ValueError:
                raise MissionFileError(f"{where}, column {name}: {cell!r} is not a number") from None
            if not (math.isfinite(v[name]) or (math.isnan(v[name]) and name in CSV_OPTIONAL)):
                raise MissionFileError(f"{where}, column {name}: {cell!r} is not a finite number")
        if v["altitude"] < 0:
            raise MissionFileError(f"{where}, column altitude: {v['altitude']:g}; allowed: >= 0 m above home")
        hold = v.get("hold", math.nan)
        params = [0.0 if math.isnan(hold) else hold, v.get("radius", math.nan), 0.0, v.get("yaw", math.nan),
                  v["lat"], v["lon"], v["altitude"]]  # fmt: skip
        items.append(check_item(where, len(items), mp.NAV_WAYPOINT, mp.FRAME_GLOBAL_RELATIVE_ALT_INT, params))
    return Mission(path, "csv", tuple(items))


def _wpl(path: Path, text: str) -> Mission:
    lines = text.splitlines()
    if lines[0].split() != ["QGC", "WPL", "110"]:
        raise MissionFileError(f"mission {path}, line 1: {lines[0].strip()!r}; allowed: 'QGC WPL 110'")
    items, home = [], None
    for line, raw in enumerate(lines[1:], start=2):
        if not raw.strip():
            continue
        where = f"mission {path}, line {line}"
        fields = raw.split()
        if len(fields) != 12:
            raise MissionFileError(f"{where}: {len(fields)} fields; expected 12 (index current frame command "
                                   "p1 p2 p3 p4 lat lon alt autocontinue)")  # fmt: skip
        try:
            index, _current, frame, command = (int(float(f)) for f in fields[:4])
            params = [float(f) for f in fields[4:11]]
            auto = int(float(fields[11]))
        except ValueError:
            raise MissionFileError(f"{where}: {raw.strip()!r} has a field that is not a number") from None
        expected = len(items) + (home is not None)
        if index != expected:
            raise MissionFileError(f"{where}, index: {index}; expected {expected} (the items in order from 0)")
        if index == 0:  # the planned home: not flown
            home = (params[4], params[5], params[6])
            continue
        items.append(check_item(f"{where} (item {index})", index - 1, command, frame, params, bool(auto)))
    if not items:
        raise MissionFileError(f"mission {path}: no mission items after the planned home (line 2)")
    return Mission(path, "wpl", tuple(items), planned_home=usable_home(home))


def nan_none(v: float) -> float | None:
    """JSON has no NaN: None (null) for it, as QGroundControl writes it."""
    return None if v != v else v


def report(mission: Mission, origin: tuple[float, float, float], reached: list[dict],
           disarmed_t: float | None) -> dict:  # fmt: skip
    """mission.json's document, as ``quadsitl fly`` and ``quadsitl sim`` write it: the items (with north, east [m]
    from ``origin`` (lat, lon [deg], alt [m AMSL]) for those with a position), each item's first reached time, the
    reached items in order (``reached``: {"seq", "t"} [s of the flight, 0 at arming]) and the time of the disarm
    (None: the flight was cut short)."""
    reached = [r for r in reached if r["seq"] < len(mission.items)]  # the file's items (not an appended landing)
    first: dict[int, float | None] = {}
    for r in reached:
        first.setdefault(r["seq"], r["t"])
    items = []
    for it in mission.items:
        d = {"seq": it.seq, "command": it.command, "name": COMMAND_NAMES.get(it.command), "frame": it.frame,
             "params": [nan_none(v) for v in (it.p1, it.p2, it.p3, it.p4)]}  # fmt: skip
        if it.command in POSITION_COMMANDS and (it.x or it.y or it.command != 21):
            north, east = geodetic_to_ned(it.lat, it.lon, origin[0], origin[1])
            d.update(lat=it.lat, lon=it.lon, altitude=it.z, north=round(north, 3), east=round(east, 3))
        d["reached_t"] = first.get(it.seq)
        items.append(d)
    return {
        "file": str(mission.path),
        "format": mission.kind,
        "origin": list(origin),
        "ends": "mission lands" if mission.lands else "landed where it ended (a NAV_LAND item after its last)",
        "items": items,
        "reached": list(reached),
        "all_reached_in_order": [r["seq"] for r in reached] == list(range(len(mission.items))),
        "disarmed_t": None if disarmed_t is None else round(disarmed_t, 6),
    }
