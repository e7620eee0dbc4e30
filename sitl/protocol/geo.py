"""Geodetic <-> local NED conversion around a reference point, as PX4's ``map_projection`` does it.

PX4 projects latitude/longitude onto the local tangent plane with an azimuthal equidistant projection on a sphere of
radius 6371 km. Using the same projection keeps a global setpoint sent by a client and the local position the
vehicle reports consistent to well below a centimetre over the distances a swarm flies.
"""

from __future__ import annotations

import math
from typing import Final

EARTH_RADIUS_M: Final = 6_371_000.0  # PX4 CONSTANTS_RADIUS_OF_EARTH


def geo_to_ned(
    lat_deg: float, lon_deg: float, alt_amsl_m: float, ref_lat_deg: float, ref_lon_deg: float, ref_alt_amsl_m: float
) -> tuple[float, float, float]:
    """(north, east, down) in metres of a geodetic point relative to the reference point."""
    lat, lon = math.radians(lat_deg), math.radians(lon_deg)
    ref_lat, ref_lon = math.radians(ref_lat_deg), math.radians(ref_lon_deg)
    sin_lat, cos_lat = math.sin(lat), math.cos(lat)
    ref_sin, ref_cos = math.sin(ref_lat), math.cos(ref_lat)
    cos_d_lon = math.cos(lon - ref_lon)
    arg = max(-1.0, min(1.0, ref_sin * sin_lat + ref_cos * cos_lat * cos_d_lon))
    c = math.acos(arg)
    k = 1.0 if abs(c) < 1e-12 else c / math.sin(c)
    north = k * (ref_cos * sin_lat - ref_sin * cos_lat * cos_d_lon) * EARTH_RADIUS_M
    east = k * cos_lat * math.sin(lon - ref_lon) * EARTH_RADIUS_M
    return north, east, ref_alt_amsl_m - alt_amsl_m


def ned_to_geo(
    north_m: float, east_m: float, down_m: float, ref_lat_deg: float, ref_lon_deg: float, ref_alt_amsl_m: float
) -> tuple[float, float, float]:
    """(lat_deg, lon_deg, alt_amsl_m) of a local NED point; the inverse of ``geo_to_ned``."""
    ref_lat, ref_lon = math.radians(ref_lat_deg), math.radians(ref_lon_deg)
    ref_sin, ref_cos = math.sin(ref_lat), math.cos(ref_lat)
    x, y = north_m / EARTH_RADIUS_M, east_m / EARTH_RADIUS_M
    c = math.hypot(x, y)
    if c < 1e-15:
        return ref_lat_deg, ref_lon_deg, ref_alt_amsl_m - down_m
    sin_c, cos_c = math.sin(c), math.cos(c)
    lat = math.asin(max(-1.0, min(1.0, cos_c * ref_sin + x * sin_c * ref_cos / c)))
    lon = ref_lon + math.atan2(y * sin_c, c * ref_cos * cos_c - x * ref_sin * sin_c)
    return math.degrees(lat), math.degrees(lon), ref_alt_amsl_m - down_m
