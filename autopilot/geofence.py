"""The geofence and the rally points.

The geofence, as PX4's navigator checks it (``src/modules/navigator/geofence.cpp``): the vehicle must stay within
GF_MAX_HOR_DIST of home and GF_MAX_VER_DIST above it (each 0: no limit), inside at least one of the inclusion
polygons and circles when there are any, and outside every exclusion polygon and circle. Compiled and pure: the
fence lives in the commander's state array (after its declared state, :data:`FENCE_AT`), in the local frame; the
commander checks it every tick and takes GF_ACTION's action (:func:`autopilot.commander.update`).

A fence item is :data:`FENCE_ITEM` numbers: its kind (:data:`POLYGON_INCLUSION` .. :data:`CIRCLE_EXCLUSION`, the
MAV_CMD_NAV_FENCE_* command less 5000), a polygon's vertex count or a circle's radius [m], and x, y [m, NED] (a
vertex, or a circle's centre). A polygon's vertices follow each other, in order.

The rally points (PX4's safe points) follow the fence in the array (:data:`RALLY_AT`), each x, y [m, NED] and its
altitude [m, up from the origin]. A return goes to the nearest of home and the rally points, as PX4's RTL_TYPE 0
(its default) does: chosen when it begins (:func:`return_destination`)."""

from __future__ import annotations

import math

import numpy as np

from autopilot.commander_state import (
    ALTITUDE,
    FENCE_N,
    GF_MAX_HOR,
    GF_MAX_VER,
    HOME_ALT,
    HOME_X,
    HOME_Y,
    RALLY_N,
    RTL_TO,
    RTL_X,
    RTL_Y,
    SIZE,
    X,
    Y,
)
from autopilot.mission_protocol import MAX_FENCE_ITEMS, MAX_RALLY_POINTS, MissionItem
from quadsitl.jit import jit

FENCE_ITEM = 4  # kind, vertex count or radius, x, y
FENCE_AT = SIZE  # where the fence's items start in the commander's array
RALLY_ITEM = 3  # x, y, altitude
RALLY_AT = FENCE_AT + MAX_FENCE_ITEMS * FENCE_ITEM  # where the rally points start
CM_SIZE = RALLY_AT + MAX_RALLY_POINTS * RALLY_ITEM  # the commander's array, its fence and rally points included
POLYGON_INCLUSION, POLYGON_EXCLUSION, CIRCLE_INCLUSION, CIRCLE_EXCLUSION = 1, 2, 3, 4
# What a breach is (cm[GF_BREACH]): beyond GF_MAX_HOR_DIST, above GF_MAX_VER_DIST, outside every inclusion, inside
# an exclusion
BREACH_DISTANCE, BREACH_HEIGHT, BREACH_OUTSIDE, BREACH_EXCLUDED = 1, 2, 3, 4
BREACHES = {BREACH_DISTANCE: "farther from home than GF_MAX_HOR_DIST",
            BREACH_HEIGHT: "higher above home than GF_MAX_VER_DIST", BREACH_OUTSIDE: "outside the fence",
            BREACH_EXCLUDED: "inside an exclusion zone"}  # fmt: skip


def items_to_array(items: tuple[MissionItem, ...], local) -> np.ndarray:
    """The fence items (as the mission protocol stores them, checked) as this module's numbers, each position in the
    local frame (``local(lat, lon)`` → x, y [m, NED])."""
    out = np.zeros(len(items) * FENCE_ITEM)
    for i, item in enumerate(items):
        x, y = local(item.lat, item.lon)
        out[i * FENCE_ITEM : (i + 1) * FENCE_ITEM] = (item.command - 5000, item.p1, x, y)
    return out


def set_fence(cm: np.ndarray, fence: np.ndarray) -> None:
    """The commander's fence replaced by ``fence`` (:func:`items_to_array`'s)."""
    cm[FENCE_AT : FENCE_AT + len(fence)] = fence
    cm[FENCE_N] = len(fence) // FENCE_ITEM


def rally_to_array(items: tuple[MissionItem, ...], local, origin_alt: float) -> np.ndarray:
    """The rally points (as the mission protocol stores them) as x, y [m, NED] (``local(lat, lon)``) and altitude
    [m, up from the origin at ``origin_alt`` AMSL; a relative frame's from home, taken as the origin's]."""
    out = np.zeros(len(items) * RALLY_ITEM)
    for i, item in enumerate(items):
        x, y = local(item.lat, item.lon)
        alt = item.z - origin_alt if item.frame in (0, 5) else item.z  # MAV_FRAME_GLOBAL(_INT): AMSL
        out[i * RALLY_ITEM : (i + 1) * RALLY_ITEM] = (x, y, alt)
    return out


def set_rally(cm: np.ndarray, rally: np.ndarray) -> None:
    """The commander's rally points replaced by ``rally`` (:func:`rally_to_array`'s)."""
    cm[RALLY_AT : RALLY_AT + len(rally)] = rally
    cm[RALLY_N] = len(rally) // RALLY_ITEM


@jit
def return_destination(cm: np.ndarray) -> None:
    """Where a return beginning now goes (cm[RTL_X], cm[RTL_Y], cm[RTL_TO]): the nearest of home and the rally
    points to the vehicle, home when as near (PX4's RTL_TYPE 0)."""
    x, y = cm[X], cm[Y]
    cm[RTL_X], cm[RTL_Y], cm[RTL_TO] = cm[HOME_X], cm[HOME_Y], 0.0
    best = (x - cm[HOME_X]) ** 2 + (y - cm[HOME_Y]) ** 2
    for k in range(int(cm[RALLY_N])):
        at = RALLY_AT + k * RALLY_ITEM
        d = (x - cm[at]) ** 2 + (y - cm[at + 1]) ** 2
        if d < best:
            best = d
            cm[RTL_X], cm[RTL_Y], cm[RTL_TO] = cm[at], cm[at + 1], float(k + 1)


@jit
def _in_polygon(cm: np.ndarray, first: int, n: int, x: float, y: float) -> bool:
    """Whether (x, y) is inside the polygon of ``n`` vertices from item ``first`` (ray casting, as PX4's
    insidePolygon: a point on an edge may fall either way)."""
    inside = False
    j = n - 1
    for i in range(n):
        a, b = FENCE_AT + (first + i) * FENCE_ITEM, FENCE_AT + (first + j) * FENCE_ITEM
        xi, yi, xj, yj = cm[a + 2], cm[a + 3], cm[b + 2], cm[b + 3]
        if (yi > y) != (yj > y) and x < (xj - xi) * (y - yi) / (yj - yi) + xi:
            inside = not inside
        j = i
    return inside


@jit
def fence_breach(cm: np.ndarray, x: float, y: float) -> int:
    """How (x, y) [m, NED] breaches the fence's polygons and circles: BREACH_OUTSIDE, BREACH_EXCLUDED or 0."""
    n = int(cm[FENCE_N])
    included = False
    inclusions = False
    i = 0
    while i < n:
        at = FENCE_AT + i * FENCE_ITEM
        kind = int(cm[at])
        if kind <= POLYGON_EXCLUSION:  # a polygon
            count = int(cm[at + 1])
            inside = _in_polygon(cm, i, count, x, y)
        else:
            count = 1
            dx, dy = x - cm[at + 2], y - cm[at + 3]
            inside = dx * dx + dy * dy <= cm[at + 1] * cm[at + 1]
        if kind in (POLYGON_INCLUSION, CIRCLE_INCLUSION):
            inclusions = True
            included = included or inside
        elif inside:
            return BREACH_EXCLUDED
        i += max(count, 1)
    if inclusions and not included:
        return BREACH_OUTSIDE
    return 0


@jit
def point_breach(cm: np.ndarray, x: float, y: float, altitude: float) -> int:
    """How a point (x, y [m, NED], ``altitude`` [m, up from the origin]) breaches the geofence: BREACH_*, or 0 (PX4's
    checkPointAgainstAllGeofences)."""
    if cm[GF_MAX_HOR] > 0.0 and math.hypot(x - cm[HOME_X], y - cm[HOME_Y]) > cm[GF_MAX_HOR]:
        return BREACH_DISTANCE
    if cm[GF_MAX_VER] > 0.0 and altitude - cm[HOME_ALT] > cm[GF_MAX_VER]:
        return BREACH_HEIGHT
    if cm[FENCE_N] > 0.0:
        return fence_breach(cm, x, y)
    return 0


@jit
def breach(cm: np.ndarray) -> int:
    """How the vehicle (its last state seen, cm[X], cm[Y], cm[ALTITUDE]) breaches the geofence: BREACH_*, or 0."""
    return point_breach(cm, cm[X], cm[Y], cm[ALTITUDE])
