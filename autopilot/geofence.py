"""The geofence, as PX4's navigator checks it (``src/modules/navigator/geofence.cpp``): the vehicle must stay within
GF_MAX_HOR_DIST of home and GF_MAX_VER_DIST above it (each 0: no limit), inside at least one of the inclusion
polygons and circles when there are any, and outside every exclusion polygon and circle. Compiled and pure: the
fence lives in the commander's state array (after its declared state, :data:`FENCE_AT`), in the local frame; the
commander checks it every tick and takes GF_ACTION's action (:func:`autopilot.commander.update`).

A fence item is :data:`FENCE_ITEM` numbers: its kind (:data:`POLYGON_INCLUSION` .. :data:`CIRCLE_EXCLUSION`, the
MAV_CMD_NAV_FENCE_* command less 5000), a polygon's vertex count or a circle's radius [m], and x, y [m, NED] (a
vertex, or a circle's centre). A polygon's vertices follow each other, in order."""

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
    SIZE,
    X,
    Y,
)
from autopilot.mission_protocol import MAX_FENCE_ITEMS, MissionItem
from quadsitl.jit import jit

FENCE_ITEM = 4  # kind, vertex count or radius, x, y
FENCE_AT = SIZE  # where the fence's items start in the commander's array
CM_SIZE = SIZE + MAX_FENCE_ITEMS * FENCE_ITEM  # the commander's array, its fence included
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
def breach(cm: np.ndarray) -> int:
    """How the vehicle (its last state seen, cm[X], cm[Y], cm[ALTITUDE]) breaches the geofence: BREACH_*, or 0."""
    if cm[GF_MAX_HOR] > 0.0 and math.hypot(cm[X] - cm[HOME_X], cm[Y] - cm[HOME_Y]) > cm[GF_MAX_HOR]:
        return BREACH_DISTANCE
    if cm[GF_MAX_VER] > 0.0 and cm[ALTITUDE] - cm[HOME_ALT] > cm[GF_MAX_VER]:
        return BREACH_HEIGHT
    if cm[FENCE_N] > 0.0:
        return fence_breach(cm, cm[X], cm[Y])
    return 0
