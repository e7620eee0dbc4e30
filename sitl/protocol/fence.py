"""Geofence items of the mission protocol (mission type 1): validation as PX4 does it, and conversion to zones.

A fence is a list of MISSION_ITEM_INT with global coordinates:
- NAV_FENCE_POLYGON_VERTEX_INCLUSION / _EXCLUSION (5001 / 5002): one item per vertex, param1 = the polygon's vertex
  count, repeated on each of its vertices; a polygon is that many consecutive items of the same command;
- NAV_FENCE_CIRCLE_INCLUSION / _EXCLUSION (5003 / 5004): one item, x/y the centre, param1 = the radius in metres.

Pure: ``to_geofence`` takes the geodetic-to-local conversion as a function, so this module needs no frame.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Final

from pymavlink.dialects.v20 import common as mavlink

from sitl.autopilot.geofence import CircleZone, FenceKind, FenceZone, Geofence, PolygonZone
from sitl.autopilot.vehicle_api import GLOBAL_FRAMES, MissionItem

POLYGON_COMMANDS: Final = {
    mavlink.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION: FenceKind.INCLUSION,
    mavlink.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION: FenceKind.EXCLUSION,
}
CIRCLE_COMMANDS: Final = {
    mavlink.MAV_CMD_NAV_FENCE_CIRCLE_INCLUSION: FenceKind.INCLUSION,
    mavlink.MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION: FenceKind.EXCLUSION,
}
MIN_POLYGON_VERTICES: Final = 3

NeOfGeo = Callable[[float, float], tuple[float, float]]  # (lat_deg, lon_deg) -> local (north_m, east_m)


def validate_fence_item(item: MissionItem) -> int:
    """MAV_MISSION_RESULT for one fence item on its own: ACCEPTED, or why it is refused."""
    if item.command not in POLYGON_COMMANDS and item.command not in CIRCLE_COMMANDS:
        return int(mavlink.MAV_MISSION_UNSUPPORTED)
    if item.frame not in GLOBAL_FRAMES:
        return int(mavlink.MAV_MISSION_UNSUPPORTED_FRAME)
    if not -900_000_000 <= item.x <= 900_000_000:
        return int(mavlink.MAV_MISSION_INVALID_PARAM5_X)
    if not -1_800_000_000 <= item.y <= 1_800_000_000:
        return int(mavlink.MAV_MISSION_INVALID_PARAM6_Y)
    p1 = item.param1
    if item.command in POLYGON_COMMANDS:
        if not (math.isfinite(p1) and p1.is_integer() and p1 >= MIN_POLYGON_VERTICES):
            return int(mavlink.MAV_MISSION_INVALID_PARAM1)
    elif not (math.isfinite(p1) and p1 > 0.0):
        return int(mavlink.MAV_MISSION_INVALID_PARAM1)
    return int(mavlink.MAV_MISSION_ACCEPTED)


def validate_fence(items: Sequence[MissionItem]) -> tuple[int, str]:
    """MAV_MISSION_RESULT of a whole fence and, when refused, one line saying why.

    Each item must be valid on its own and every polygon must be exactly as long as its vertices announce: a run of
    vertices shorter or longer than its param1, or mixing inclusion and exclusion, is MAV_MISSION_ERROR."""
    i = 0
    while i < len(items):
        item = items[i]
        result = validate_fence_item(item)
        if result != mavlink.MAV_MISSION_ACCEPTED:
            return result, f"Fence item {i} rejected (MAV_MISSION_RESULT {result})"
        if item.command in CIRCLE_COMMANDS:
            i += 1
            continue
        count = int(item.param1)
        run = items[i : i + count]
        if len(run) < count or any(v.command != item.command or v.param1 != item.param1 for v in run):
            return int(mavlink.MAV_MISSION_ERROR), f"Fence polygon at item {i}: {count} vertices announced, not given"
        i += count
    return int(mavlink.MAV_MISSION_ACCEPTED), ""


def to_geofence(items: Sequence[MissionItem], ne_of: NeOfGeo) -> Geofence:
    """The zones of a fence that ``validate_fence`` accepted, in the local frame ``ne_of`` maps into."""
    zones: list[FenceZone] = []
    i = 0
    while i < len(items):
        item = items[i]
        if item.command in CIRCLE_COMMANDS:
            zones.append(
                CircleZone(
                    kind=CIRCLE_COMMANDS[item.command],
                    centre_ne_m=ne_of(item.lat_deg, item.lon_deg),
                    radius_m=float(item.param1),
                )
            )
            i += 1
            continue
        count = int(item.param1)
        vertices = tuple(ne_of(v.lat_deg, v.lon_deg) for v in items[i : i + count])
        zones.append(PolygonZone(kind=POLYGON_COMMANDS[item.command], vertices_ne_m=vertices))
        i += count
    return Geofence(zones=tuple(zones))
