"""NED <-> geodetic conversion: exact round trips and agreement with published lengths of a degree."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sitl.dynamics.geodesy import (
    WGS84_A_M,
    WGS84_E2,
    LocalFrame,
    ecef_from_geo,
    geo_from_ned,
    ned_from_geo,
)
from sitl.dynamics.plant import DEFAULT_HOME, GeoPoint

pytestmark = pytest.mark.timeout(10)

HOMES = [
    DEFAULT_HOME,
    GeoPoint(lat_deg=0.0, lon_deg=0.0, alt_amsl_m=0.0),
    GeoPoint(lat_deg=-33.8568, lon_deg=151.2153, alt_amsl_m=20.0),
    GeoPoint(lat_deg=64.1466, lon_deg=-21.9426, alt_amsl_m=-30.0),
    GeoPoint(lat_deg=10.0, lon_deg=179.9995, alt_amsl_m=1500.0),
]


def metres_per_degree_latitude(lat_deg: float) -> float:
    """Published series for the WGS84 ellipsoid (e.g. the 'Length of a degree of latitude' tables)."""
    phi = math.radians(lat_deg)
    return 111132.954 - 559.822 * math.cos(2 * phi) + 1.175 * math.cos(4 * phi)


def metres_per_degree_longitude(lat_deg: float) -> float:
    phi = math.radians(lat_deg)
    return 111412.84 * math.cos(phi) - 93.5 * math.cos(3 * phi) + 0.118 * math.cos(5 * phi)


def meridian_arc_m(lat0_deg: float, lat1_deg: float, alt_m: float) -> float:
    """Arc length along a meridian at constant height, by Simpson integration of the meridional radius."""
    n = 200
    a, b = math.radians(lat0_deg), math.radians(lat1_deg)
    h = (b - a) / n

    def radius(phi: float) -> float:
        w2 = 1.0 - WGS84_E2 * math.sin(phi) ** 2
        return WGS84_A_M * (1.0 - WGS84_E2) / w2**1.5 + alt_m

    total = radius(a) + radius(b)
    total += sum((4 if i % 2 else 2) * radius(a + i * h) for i in range(1, n))
    return total * h / 3


@pytest.mark.parametrize("home", HOMES, ids=lambda h: f"{h.lat_deg},{h.lon_deg}")
def test_home_is_the_origin(home: GeoPoint) -> None:
    np.testing.assert_allclose(ned_from_geo(home, home), (0.0, 0.0, 0.0), atol=1e-9)
    back = geo_from_ned((0.0, 0.0, 0.0), home)
    assert back.lat_deg == pytest.approx(home.lat_deg, abs=1e-12)
    assert back.lon_deg == pytest.approx(home.lon_deg, abs=1e-12)
    assert back.alt_amsl_m == home.alt_amsl_m


@pytest.mark.parametrize("home", HOMES, ids=lambda h: f"{h.lat_deg},{h.lon_deg}")
def test_ned_to_geodetic_and_back_is_exact_within_five_kilometres(home: GeoPoint) -> None:
    rng = np.random.default_rng(7)
    frame = LocalFrame(home)
    for ned in rng.uniform((-5000, -5000, -500), (5000, 5000, 50), size=(200, 3)):
        geo = frame.geo_from_ned(ned)
        np.testing.assert_allclose(frame.ned_from_geo(geo), ned, atol=1e-6)
        again = frame.geo_from_ned(frame.ned_from_geo(geo))
        assert again.lat_deg == pytest.approx(geo.lat_deg, abs=1e-11)
        assert again.lon_deg == pytest.approx(geo.lon_deg, abs=1e-11)
        assert -180.0 <= geo.lon_deg < 180.0


@pytest.mark.parametrize("lat_deg", [0.0, 30.0, 45.0, 47.397742, 60.0, -75.0])
def test_small_offsets_match_published_lengths_of_a_degree(lat_deg: float) -> None:
    home = GeoPoint(lat_deg=lat_deg, lon_deg=8.0, alt_amsl_m=0.0)
    step = 0.001  # about 100 m
    north, east, _ = ned_from_geo(GeoPoint(lat_deg=lat_deg + step, lon_deg=8.0, alt_amsl_m=0.0), home)
    assert north == pytest.approx(step * metres_per_degree_latitude(lat_deg + step / 2), abs=2e-3)
    assert abs(east) < 1e-9
    north, east, _ = ned_from_geo(GeoPoint(lat_deg=lat_deg, lon_deg=8.0 + step, alt_amsl_m=0.0), home)
    assert east == pytest.approx(step * metres_per_degree_longitude(lat_deg), abs=2e-3)
    # a parallel is a small circle of radius N cos(lat): going east along it bends towards the nearer pole by
    # r (1 - cos dlon) sin(lat) in home's tangent plane (half a millimetre here)
    phi = math.radians(lat_deg)
    radius = WGS84_A_M / math.sqrt(1.0 - WGS84_E2 * math.sin(phi) ** 2) * math.cos(phi)
    assert north == pytest.approx(radius * (1.0 - math.cos(math.radians(step))) * math.sin(phi), abs=1e-7)


def test_north_offset_equals_the_meridian_arc_within_a_millimetre_at_five_kilometres() -> None:
    home = GeoPoint(lat_deg=47.0, lon_deg=8.0, alt_amsl_m=500.0)
    north = 5000.0
    geo = geo_from_ned((north, 0.0, 0.0), home)
    assert meridian_arc_m(home.lat_deg, geo.lat_deg, home.alt_amsl_m) == pytest.approx(north, abs=1e-3)


def test_horizontal_distance_equals_the_straight_line_distance_at_home_altitude() -> None:
    home = DEFAULT_HOME
    frame = LocalFrame(home)
    a_ned = np.array((-1200.0, 800.0, 0.0))
    b_ned = np.array((900.0, -1500.0, 0.0))
    a = np.array(ecef_from_geo(frame.geo_from_ned(a_ned)), dtype=np.float64)
    b = np.array(ecef_from_geo(frame.geo_from_ned(b_ned)), dtype=np.float64)
    assert np.linalg.norm(b_ned - a_ned) == pytest.approx(np.linalg.norm(b - a), abs=0.01)


def test_down_is_the_altitude_difference() -> None:
    home = GeoPoint(lat_deg=47.0, lon_deg=8.0, alt_amsl_m=488.0)
    for down in (-120.0, 0.0, 3.5):
        geo = geo_from_ned((300.0, -400.0, down), home)
        assert geo.alt_amsl_m == pytest.approx(488.0 - down, abs=1e-12)
        assert ned_from_geo(geo, home)[2] == pytest.approx(down, abs=1e-12)


def test_longitude_wraps_across_the_antimeridian() -> None:
    home = GeoPoint(lat_deg=10.0, lon_deg=179.9995, alt_amsl_m=0.0)
    geo = geo_from_ned((0.0, 200.0, 0.0), home)
    assert geo.lon_deg < -179.99
    np.testing.assert_allclose(ned_from_geo(geo, home), (0.0, 200.0, 0.0), atol=1e-6)


def test_ecef_of_the_equator_and_pole_are_the_ellipsoid_axes() -> None:
    np.testing.assert_allclose(
        ecef_from_geo(GeoPoint(lat_deg=0.0, lon_deg=90.0, alt_amsl_m=0.0)), (0, WGS84_A_M, 0), atol=1e-6
    )
    polar_radius = WGS84_A_M * math.sqrt(1.0 - WGS84_E2)
    np.testing.assert_allclose(
        ecef_from_geo(GeoPoint(lat_deg=90.0, lon_deg=0.0, alt_amsl_m=10.0)),
        (0, 0, polar_radius + 10.0),
        atol=1e-6,
    )


def test_invalid_inputs_are_rejected() -> None:
    with pytest.raises(ValueError):
        LocalFrame(GeoPoint(lat_deg=90.0, lon_deg=0.0, alt_amsl_m=0.0))
    with pytest.raises(ValueError):
        LocalFrame(GeoPoint(lat_deg=float("nan"), lon_deg=0.0, alt_amsl_m=0.0))
    with pytest.raises(ValueError):
        geo_from_ned((float("nan"), 0.0, 0.0), DEFAULT_HOME)
