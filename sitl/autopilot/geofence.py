"""Geofence geometry: is a local position inside the fence the ground station uploaded? Pure, no IO.

A fence arrives over MAVLink as a mission of type 1 (MAV_MISSION_TYPE_FENCE): polygon vertices
(NAV_FENCE_POLYGON_VERTEX_INCLUSION/EXCLUSION, 5001/5002, param1 = vertex count) and circles
(NAV_FENCE_CIRCLE_INCLUSION/EXCLUSION, 5003/5004, param1 = radius). The wire side turns them into zones in the
vehicle's local frame (north/east metres); this module only answers the geometric question, as PX4's Geofence
does with its stored polygons and circles:

- inside an EXCLUSION zone is a breach;
- with one or more INCLUSION zones, being outside all of them is a breach (PX4 treats several inclusion zones as a
  union: the vehicle may be in any of them);
- GF_MAX_HOR_DIST / GF_MAX_VER_DIST (0 = off) bound the horizontal distance from home and the height above home.

Fence zones are vertical prisms: PX4 fences have no altitude limits of their own (GF_MAX_VER_DIST is the ceiling).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import Enum


class FenceKind(Enum):
    INCLUSION = "inclusion"  # the vehicle must stay inside
    EXCLUSION = "exclusion"  # the vehicle must stay outside


@dataclass(frozen=True, slots=True, kw_only=True)
class PolygonZone:
    kind: FenceKind
    vertices_ne_m: tuple[tuple[float, float], ...]  # local north/east, in upload order, at least 3

    def contains(self, north_m: float, east_m: float) -> bool:
        """Even-odd rule (a ray cast to the east): exact for simple polygons, which is what PX4 accepts."""
        inside = False
        vertices = self.vertices_ne_m
        n0, e0 = vertices[-1]
        for n1, e1 in vertices:
            if (n1 > north_m) != (n0 > north_m):
                east_at = e1 + (north_m - n1) * (e0 - e1) / (n0 - n1)
                if east_m < east_at:
                    inside = not inside
            n0, e0 = n1, e1
        return inside


@dataclass(frozen=True, slots=True, kw_only=True)
class CircleZone:
    kind: FenceKind
    centre_ne_m: tuple[float, float]
    radius_m: float

    def contains(self, north_m: float, east_m: float) -> bool:
        return math.hypot(north_m - self.centre_ne_m[0], east_m - self.centre_ne_m[1]) <= self.radius_m


FenceZone = PolygonZone | CircleZone


@dataclass(frozen=True, slots=True, kw_only=True)
class Geofence:
    """The zones of one uploaded fence (empty: no zones, only the distance limits apply)."""

    zones: tuple[FenceZone, ...] = ()

    def breach(
        self,
        pos_ned_m: tuple[float, float, float],
        home_ned_m: tuple[float, float, float],
        max_hor_dist_m: float = 0.0,
        max_ver_dist_m: float = 0.0,
    ) -> str | None:
        """Why the position breaches the fence (one line, for a STATUSTEXT), or None when it does not.

        Distance limits of 0 or less are off, as PX4's GF_MAX_HOR_DIST and GF_MAX_VER_DIST."""
        north, east, down = pos_ned_m
        if max_hor_dist_m > 0.0 and math.hypot(north - home_ned_m[0], east - home_ned_m[1]) > max_hor_dist_m:
            return "Maximum distance from home exceeded"
        if max_ver_dist_m > 0.0 and home_ned_m[2] - down > max_ver_dist_m:
            return "Maximum altitude exceeded"
        inclusions = [z for z in self.zones if z.kind is FenceKind.INCLUSION]
        if inclusions and not any(z.contains(north, east) for z in inclusions):
            return "Outside the geofence"
        for zone in self.zones:
            if zone.kind is FenceKind.EXCLUSION and zone.contains(north, east):
                return "Inside an exclusion zone of the geofence"
        return None
