"""The ground station's geodesy against the drone's: two implementations of one local-frame definition.

gcs/flight/geodesy.py and sitl/dynamics/geodesy.py are written independently (ECEF rotation and an ECEF-to-geodetic
solution on one side, a closed-form projection inverted by Newton steps on the other), so a projection bug in
either shows here instead of cancelling out in every flight.
"""

from __future__ import annotations

import math
import random

import pytest

from gcs.flight.geodesy import GeoPoint, NedFrame, geo_from_ned, ned_from_geo, wrap_pi
from sitl.dynamics.geodesy import LocalFrame
from sitl.dynamics.plant import GeoPoint as DroneGeoPoint

# Where swarms fly: the default origin, the equator, the southern hemisphere, far north, across the antimeridian.
ORIGINS = [
    GeoPoint(lat_deg=47.397742, lon_deg=8.545594, alt_amsl_m=488.0),
    GeoPoint(lat_deg=0.3, lon_deg=-78.5, alt_amsl_m=2800.0),
    GeoPoint(lat_deg=-33.9, lon_deg=151.2, alt_amsl_m=5.0),
    GeoPoint(lat_deg=69.6, lon_deg=18.9, alt_amsl_m=0.0),
    GeoPoint(lat_deg=-17.7, lon_deg=179.999, alt_amsl_m=20.0),
]
SWARM_RADIUS_M = 2000.0  # a formation, a leader-follower route, a mission's obstacles: well inside this
AGREE_M = 1e-5  # 10 micrometres: numerical noise, far below a millimetre; a definition or scale bug is metres


def _drone(point: GeoPoint) -> DroneGeoPoint:
    return DroneGeoPoint(lat_deg=point.lat_deg, lon_deg=point.lon_deg, alt_amsl_m=point.alt_amsl_m)


def _metres_apart(a: GeoPoint, b: DroneGeoPoint) -> float:
    north = math.radians(a.lat_deg - b.lat_deg) * 6.37e6
    dlon = (a.lon_deg - b.lon_deg + 180.0) % 360.0 - 180.0
    east = math.radians(dlon) * 6.37e6 * math.cos(math.radians(a.lat_deg))
    return math.hypot(north, east, a.alt_amsl_m - b.alt_amsl_m)


@pytest.mark.parametrize("origin", ORIGINS, ids=lambda o: f"{o.lat_deg:g},{o.lon_deg:g}")
def test_the_ground_station_and_the_drone_place_every_swarm_point_alike(origin: GeoPoint) -> None:
    rng = random.Random(14)
    ours, theirs = NedFrame(origin), LocalFrame(_drone(origin))
    for _ in range(500):
        ned = (rng.uniform(-SWARM_RADIUS_M, SWARM_RADIUS_M), rng.uniform(-SWARM_RADIUS_M, SWARM_RADIUS_M),
               rng.uniform(-300.0, 20.0))  # fmt: skip
        # GIVEN a swarm-frame point WHEN both sides turn it into latitude, longitude, altitude
        point = ours.geo_from_ned(ned)
        # THEN they agree to micrometres
        assert _metres_apart(point, theirs.geo_from_ned(ned)) < AGREE_M, ned
        # AND each side reads the other's point back to the same NED position
        assert math.dist(theirs.ned_from_geo(_drone(point)), ned) < AGREE_M, ned
        assert math.dist(ours.ned_from_geo(point), ned) < AGREE_M, ned


def test_the_definition_is_the_documented_one() -> None:
    origin = ORIGINS[0]
    # down is the altitude difference, whatever the distance
    assert ned_from_geo(GeoPoint(lat_deg=origin.lat_deg, lon_deg=origin.lon_deg, alt_amsl_m=500.0), origin)[2] == (
        pytest.approx(-12.0, abs=1e-9)
    )
    # one arc-second north is the meridian's radius of curvature times the angle (30.87 m at 47.4 deg)
    lat = math.radians(origin.lat_deg)
    e2 = 1.0 / 298.257223563 * (2.0 - 1.0 / 298.257223563)
    meridian_m = 6378137.0 * (1.0 - e2) / (1.0 - e2 * math.sin(lat) ** 2) ** 1.5
    north_point = GeoPoint(lat_deg=origin.lat_deg + 1.0 / 3600.0, lon_deg=origin.lon_deg, alt_amsl_m=488.0)
    north, east, down = ned_from_geo(north_point, origin)
    assert north == pytest.approx((meridian_m + origin.alt_amsl_m) * math.radians(1.0 / 3600.0), abs=1e-3)
    assert abs(east) < 1e-9 and down == pytest.approx(0.0, abs=1e-9)
    # and the module functions are the frame's
    assert geo_from_ned((10.0, -20.0, -3.0), origin) == NedFrame(origin).geo_from_ned((10.0, -20.0, -3.0))


def test_points_that_cannot_be_converted_are_refused() -> None:
    with pytest.raises(ValueError, match="poles"):
        NedFrame(GeoPoint(lat_deg=90.0, lon_deg=0.0, alt_amsl_m=0.0))
    with pytest.raises(ValueError, match="finite"):
        NedFrame(ORIGINS[0]).geo_from_ned((math.nan, 0.0, 0.0))


WRAPS = [(0.0, 0.0), (math.pi, -math.pi), (-math.pi, -math.pi), (4.5 * math.pi, 0.5 * math.pi), (-7.0, 2 * math.pi - 7)]


@pytest.mark.parametrize(("angle", "wrapped"), WRAPS)
def test_angles_wrap_to_minus_pi_up_to_pi(angle: float, wrapped: float) -> None:
    assert wrap_pi(angle) == pytest.approx(wrapped, abs=1e-12)


def _full_iterations(frame: NedFrame, ned_m: tuple[float, float, float]) -> GeoPoint:
    """``NedFrame.geo_from_ned`` with every step of both iterations taken, none stopped at its fixed point."""
    from gcs.flight import geodesy as g

    def geodetic(x: float, y: float, z: float) -> tuple[float, float, float]:
        lon, p = math.atan2(y, x), math.hypot(x, y)
        beta = math.atan2(z * g.WGS84_A_M, p * g._B_M)
        lat = math.atan2(z + g._EP2 * g._B_M * math.sin(beta) ** 3, p - g._E2 * g.WGS84_A_M * math.cos(beta) ** 3)
        for _ in range(g._LATITUDE_STEPS):
            sin_lat = math.sin(lat)
            lat = math.atan2(z + g._E2 * (g.WGS84_A_M / math.sqrt(1.0 - g._E2 * sin_lat * sin_lat)) * sin_lat, p)
        sin_lat, cos_lat = math.sin(lat), math.cos(lat)
        n = g.WGS84_A_M / math.sqrt(1.0 - g._E2 * sin_lat * sin_lat)
        return lat, lon, (p / cos_lat - n if abs(cos_lat) > 0.5 else z / sin_lat - n * (1.0 - g._E2))

    origin = frame.origin
    (nx, ny, nz), (ex, ey, ez), (dx, dy, dz) = frame._axes
    rx, ry, rz = frame._ref
    north, east, down = ned_m
    bx, by, bz = rx + north * nx + east * ex, ry + north * ny + east * ey, rz + north * nz + east * ez
    below = lat = lon = 0.0
    for _ in range(g._FOOTPRINT_STEPS):
        lat, lon, height = geodetic(bx + below * dx, by + below * dy, bz + below * dz)
        below += height - origin.alt_amsl_m
    return GeoPoint(lat_deg=math.degrees(lat), lon_deg=(math.degrees(lon) + 180.0) % 360.0 - 180.0,
                    alt_amsl_m=origin.alt_amsl_m - down)  # fmt: skip


@pytest.mark.parametrize("origin", ORIGINS)
def test_stopping_the_iterations_at_their_fixed_point_gives_the_bits_of_every_step(origin: GeoPoint) -> None:
    # GIVEN positions around an origin, near and far (the supervisor converts every setpoint of every drone)
    rng = random.Random(int(origin.lat_deg * 1000))
    frame = NedFrame(origin)
    for _ in range(2000):
        ned = (rng.uniform(-1.0, 1.0) * 10.0 ** rng.uniform(-2, 5), rng.uniform(-1.0, 1.0) * 10.0 ** rng.uniform(-2, 5),
               rng.uniform(-500.0, 50.0))  # fmt: skip
        # THEN the conversion stopped early is the conversion with every step taken, to the bit
        assert frame.geo_from_ned(ned) == _full_iterations(frame, ned)
