"""Conversion between the local NED frame anchored at home and geodetic coordinates (WGS84).

The plant turns JSBSim's geodetic position into the local NED position the rest of the drone works in, and the
MAVLink layer turns local positions back into latitude and longitude (GLOBAL_POSITION_INT, mission items).
Both must use the same definition, which is this module.

Definition (chosen so that the ground, which JSBSim places at constant height above the ellipsoid, is at
down = 0 everywhere, like PX4's local frame where down is the negated height above the reference):

- down  = home altitude - altitude (altitude difference along the local vertical, not along home's vertical);
- north, east = the projection onto home's tangent plane of the point's footprint at home altitude, i.e. of
  ``(lat, lon, home altitude)`` on the WGS84 ellipsoid (an orthographic azimuthal projection).

Horizontal coordinates differ from geodesic distances by about d^3 / (6 R^2): under a millimetre at 5 km. The
forward conversion is closed form; the inverse iterates to below a micrometre (it converges by a factor d / R
per iteration). Valid for distances up to a few hundred kilometres and away from the poles. Altitudes are
heights above the ellipsoid; this module does not model the geoid, so ``alt_amsl_m`` is treated as ellipsoidal
height throughout the simulation.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from sitl.dynamics.plant import GeoPoint
from sitl.mathutil import Vec3

WGS84_A_M = 6378137.0
WGS84_F = 1.0 / 298.257223563
WGS84_E2 = WGS84_F * (2.0 - WGS84_F)
ONE_MINUS_E2 = 1.0 - WGS84_E2

_INVERSE_TOLERANCE_M = 1e-7
_INVERSE_MAX_ITERATIONS = 8


class LocalFrame:
    """The NED frame anchored at one home point; precomputes what every conversion needs."""

    __slots__ = ("_alt0", "_cos_lat0", "_cos_lon0", "_home", "_sin_lat0", "_sin_lon0", "_x0", "_y0", "_z0")

    def __init__(self, home: GeoPoint) -> None:
        if not (-90.0 < home.lat_deg < 90.0) or not math.isfinite(home.lon_deg) or not math.isfinite(home.alt_amsl_m):
            raise ValueError(f"home must have a latitude strictly between the poles and finite values: {home}")
        self._home = home
        self._alt0 = home.alt_amsl_m
        lat0 = math.radians(home.lat_deg)
        lon0 = math.radians(home.lon_deg)
        self._sin_lat0 = math.sin(lat0)
        self._cos_lat0 = math.cos(lat0)
        self._sin_lon0 = math.sin(lon0)
        self._cos_lon0 = math.cos(lon0)
        self._x0, self._y0, self._z0 = _ecef(self._sin_lat0, self._cos_lat0, self._sin_lon0, self._cos_lon0, self._alt0)

    @property
    def home(self) -> GeoPoint:
        return self._home

    @property
    def conversion(self) -> tuple[float, ...]:
        """What ``ned_from_geodetic_rad`` computes with, in the order sitl/kernels/neighbours.py ``F_*`` reads it:
        home's ECEF position, the sine and cosine of its latitude and longitude, its altitude, then the ellipsoid's
        semi-major axis, eccentricity squared and one less that."""
        return (self._x0, self._y0, self._z0, self._sin_lat0, self._cos_lat0, self._sin_lon0, self._cos_lon0,
                self._alt0, WGS84_A_M, WGS84_E2, ONE_MINUS_E2)  # fmt: skip

    def ned_from_geodetic_rad(self, lat_rad: float, lon_rad: float, alt_m: float) -> tuple[float, float, float]:
        """NED metres of a geodetic position given in radians (the plant's per-step path)."""
        sin_lat = math.sin(lat_rad)
        # _ecef(sin_lat, cos(lat), sin(lon), cos(lon), home altitude), written out: this runs every physics step.
        n = WGS84_A_M / math.sqrt(1.0 - WGS84_E2 * sin_lat * sin_lat)
        alt0 = self._alt0
        r = (n + alt0) * math.cos(lat_rad)
        x = r * math.cos(lon_rad)
        y = r * math.sin(lon_rad)
        z = (n * ONE_MINUS_E2 + alt0) * sin_lat
        dx = x - self._x0
        dy = y - self._y0
        dz = z - self._z0
        t = self._cos_lon0 * dx + self._sin_lon0 * dy
        north = -self._sin_lat0 * t + self._cos_lat0 * dz
        east = -self._sin_lon0 * dx + self._cos_lon0 * dy
        return (north, east, alt0 - alt_m)

    def ned_from_geo(self, point: GeoPoint) -> tuple[float, float, float]:
        return self.ned_from_geodetic_rad(math.radians(point.lat_deg), math.radians(point.lon_deg), point.alt_amsl_m)

    def geo_from_ned(self, ned_m: Sequence[float] | Vec3) -> GeoPoint:
        north, east, down = float(ned_m[0]), float(ned_m[1]), float(ned_m[2])
        if not (math.isfinite(north) and math.isfinite(east) and math.isfinite(down)):
            raise ValueError(f"NED position must be finite, got {(north, east, down)}")
        lat0 = math.radians(self._home.lat_deg)
        lat = lat0 + north / (_meridian_radius(self._sin_lat0) + self._alt0)
        lon = math.radians(self._home.lon_deg) + east / ((_normal_radius(self._sin_lat0) + self._alt0) * self._cos_lat0)
        for _ in range(_INVERSE_MAX_ITERATIONS):
            n_est, e_est, _ = self.ned_from_geodetic_rad(lat, lon, self._alt0)
            dn = north - n_est
            de = east - e_est
            if abs(dn) < _INVERSE_TOLERANCE_M and abs(de) < _INVERSE_TOLERANCE_M:
                break
            sin_lat = math.sin(lat)
            lat += dn / (_meridian_radius(sin_lat) + self._alt0)
            lon += de / ((_normal_radius(sin_lat) + self._alt0) * math.cos(lat))
        lon_deg = (math.degrees(lon) + 180.0) % 360.0 - 180.0
        return GeoPoint(lat_deg=math.degrees(lat), lon_deg=lon_deg, alt_amsl_m=self._alt0 - down)


def _normal_radius(sin_lat: float) -> float:
    """Prime-vertical radius of curvature N(lat)."""
    return WGS84_A_M / math.sqrt(1.0 - WGS84_E2 * sin_lat * sin_lat)


def _meridian_radius(sin_lat: float) -> float:
    """Meridional radius of curvature M(lat)."""
    w2 = 1.0 - WGS84_E2 * sin_lat * sin_lat
    return WGS84_A_M * (1.0 - WGS84_E2) / (w2 * math.sqrt(w2))


def _ecef(sin_lat: float, cos_lat: float, sin_lon: float, cos_lon: float, alt_m: float) -> tuple[float, float, float]:
    n = _normal_radius(sin_lat)
    r = (n + alt_m) * cos_lat
    return (r * cos_lon, r * sin_lon, (n * (1.0 - WGS84_E2) + alt_m) * sin_lat)


def ecef_from_geo(point: GeoPoint) -> tuple[float, float, float]:
    """Earth-centred, Earth-fixed metres of a geodetic point (exact WGS84)."""
    lat = math.radians(point.lat_deg)
    lon = math.radians(point.lon_deg)
    return _ecef(math.sin(lat), math.cos(lat), math.sin(lon), math.cos(lon), point.alt_amsl_m)


def ned_from_geo(point: GeoPoint, home: GeoPoint) -> tuple[float, float, float]:
    """NED metres of ``point`` relative to ``home``. Build a LocalFrame once instead when converting often."""
    return LocalFrame(home).ned_from_geo(point)


def geo_from_ned(ned_m: Sequence[float] | Vec3, home: GeoPoint) -> GeoPoint:
    """Geodetic position of a NED offset from ``home``. Build a LocalFrame once when converting often."""
    return LocalFrame(home).geo_from_ned(ned_m)
