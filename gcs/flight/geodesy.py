"""The ground station's own geodesy: geodetic points and local NED frames around them (WGS84).

The ground station predicts each drone's local coordinates of a geodetic point (gcs/flight/frames.py), so it must use
the same *definition* of a local frame as the drones: the one the MAVLink contract of this project states (PX4's local
frame, with down the altitude difference):

- down  = reference altitude - altitude;
- north, east = the projection onto the reference's tangent plane of the point's footprint at the reference
  altitude, i.e. of ``(lat, lon, reference altitude)`` on the WGS84 ellipsoid.

The *implementation* is deliberately the ground station's own and written differently from the drone's
(sitl/dynamics/geodesy.py): a rotation of the Earth-centred, Earth-fixed difference vector into the reference's NED
axes one way, and back through ECEF with an ECEF-to-geodetic solution the other way (the drone inverts by
Newton steps on its forward projection). Were both sides to share one module, a projection bug would move the
ground station's setpoints and the drone's reports alike and cancel out in every test; two implementations of one
definition agree to micrometres at swarm distances (tests/unit/test_gcs_geodesy.py), and a bug in either shows.
Altitudes are heights above the ellipsoid (the simulation does not model the geoid).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

WGS84_A_M = 6378137.0  # semi-major axis
WGS84_F = 1.0 / 298.257223563  # flattening
_E2 = WGS84_F * (2.0 - WGS84_F)  # first eccentricity squared
_B_M = WGS84_A_M * (1.0 - WGS84_F)  # semi-minor axis
_EP2 = _E2 / (1.0 - _E2)  # second eccentricity squared
# ECEF -> geodetic: each fixed-point step on the latitude shrinks its error by about e^2 (0.0067); from Bowring's
# starting value, which is within 1e-9 rad near the surface, three steps reach the limit of double precision.
_LATITUDE_STEPS = 3
# Back from NED: the footprint's height is corrected along the reference's down axis; each step shrinks the height
# error by about (d / R)^2, so two steps are exact to double precision within hundreds of kilometres.
_FOOTPRINT_STEPS = 3

Vec3 = tuple[float, float, float]


@dataclass(frozen=True, slots=True, kw_only=True)
class GeoPoint:
    """A geodetic position: latitude and longitude in degrees, altitude in metres (treated as ellipsoidal)."""

    lat_deg: float
    lon_deg: float
    alt_amsl_m: float


# The default swarm origin (Zurich, 488 m): where ``swarm up/fly`` place the swarm unless told otherwise.
DEFAULT_ORIGIN = GeoPoint(lat_deg=47.397742, lon_deg=8.545594, alt_amsl_m=488.0)


def _ecef(lat_rad: float, lon_rad: float, alt_m: float) -> Vec3:
    sin_lat = math.sin(lat_rad)
    n = WGS84_A_M / math.sqrt(1.0 - _E2 * sin_lat * sin_lat)
    r = (n + alt_m) * math.cos(lat_rad)
    return (r * math.cos(lon_rad), r * math.sin(lon_rad), (n * (1.0 - _E2) + alt_m) * sin_lat)


def _geodetic(x: float, y: float, z: float) -> Vec3:
    """Latitude, longitude (radians) and ellipsoidal height (m) of an ECEF point away from the Earth's axis."""
    lon = math.atan2(y, x)
    p = math.hypot(x, y)
    beta = math.atan2(z * WGS84_A_M, p * _B_M)  # Bowring's parametric latitude
    lat = math.atan2(z + _EP2 * _B_M * math.sin(beta) ** 3, p - _E2 * WGS84_A_M * math.cos(beta) ** 3)
    for _ in range(_LATITUDE_STEPS):
        sin_lat = math.sin(lat)
        n = WGS84_A_M / math.sqrt(1.0 - _E2 * sin_lat * sin_lat)
        step = math.atan2(z + _E2 * n * sin_lat, p)
        if step == lat:  # a fixed point: every further step gives these bits again
            break
        lat = step
    sin_lat, cos_lat = math.sin(lat), math.cos(lat)
    n = WGS84_A_M / math.sqrt(1.0 - _E2 * sin_lat * sin_lat)
    # the better conditioned of the two height formulas for this latitude
    height = p / cos_lat - n if abs(cos_lat) > 0.5 else z / sin_lat - n * (1.0 - _E2)
    return lat, lon, height


class NedFrame:
    """Local NED metres around a reference point (see the module docstring for the definition)."""

    __slots__ = ("_axes", "_origin", "_ref")

    def __init__(self, origin: GeoPoint) -> None:
        if not (-90.0 < origin.lat_deg < 90.0) or not math.isfinite(origin.lon_deg + origin.alt_amsl_m):
            raise ValueError(f"origin must lie strictly between the poles, with finite values: {origin}")
        self._origin = origin
        lat, lon = math.radians(origin.lat_deg), math.radians(origin.lon_deg)
        sl, cl, so, co = math.sin(lat), math.cos(lat), math.sin(lon), math.cos(lon)
        # rows: the north, east and down unit vectors of the reference, in ECEF
        self._axes = ((-sl * co, -sl * so, cl), (-so, co, 0.0), (-cl * co, -cl * so, -sl))
        self._ref = _ecef(lat, lon, origin.alt_amsl_m)

    @property
    def origin(self) -> GeoPoint:
        return self._origin

    def ned_from_geo(self, point: GeoPoint) -> Vec3:
        """NED metres of a geodetic point."""
        x, y, z = _ecef(math.radians(point.lat_deg), math.radians(point.lon_deg), self._origin.alt_amsl_m)
        rx, ry, rz = self._ref
        dx, dy, dz = x - rx, y - ry, z - rz
        (nx, ny, nz), (ex, ey, _), _ = self._axes
        return (nx * dx + ny * dy + nz * dz, ex * dx + ey * dy, self._origin.alt_amsl_m - point.alt_amsl_m)

    def geo_from_ned(self, ned_m: Sequence[float]) -> GeoPoint:
        """The geodetic point of NED metres: the footprint is found on the reference-altitude surface along the
        reference's down axis, then given the altitude that ``down`` says."""
        north, east, down = float(ned_m[0]), float(ned_m[1]), float(ned_m[2])
        if not math.isfinite(north + east + down):
            raise ValueError(f"NED position must be finite, got {(north, east, down)}")
        (nx, ny, nz), (ex, ey, ez), (dx, dy, dz) = self._axes
        rx, ry, rz = self._ref
        bx, by, bz = rx + north * nx + east * ex, ry + north * ny + east * ey, rz + north * nz + east * ez
        below = 0.0  # metres along the reference's down axis to the footprint
        lat = lon = 0.0
        for _ in range(_FOOTPRINT_STEPS):
            lat, lon, height = _geodetic(bx + below * dx, by + below * dy, bz + below * dz)
            error = height - self._origin.alt_amsl_m
            if error == 0.0:  # on the surface: every further step gives these bits again
                break
            below += error
        lon_deg = (math.degrees(lon) + 180.0) % 360.0 - 180.0
        return GeoPoint(lat_deg=math.degrees(lat), lon_deg=lon_deg, alt_amsl_m=self._origin.alt_amsl_m - down)


def ned_from_geo(point: GeoPoint, origin: GeoPoint) -> Vec3:
    """NED metres of ``point`` around ``origin``; build a NedFrame once when converting often."""
    return NedFrame(origin).ned_from_geo(point)


def geo_from_ned(ned_m: Sequence[float], origin: GeoPoint) -> GeoPoint:
    """The geodetic point of NED metres around ``origin``; build a NedFrame once when converting often."""
    return NedFrame(origin).geo_from_ned(ned_m)


def wrap_pi(angle_rad: float) -> float:
    """An angle wrapped to [-pi, pi)."""
    return (angle_rad + math.pi) % (2 * math.pi) - math.pi
