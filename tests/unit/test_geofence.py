"""Geofence geometry (sitl/autopilot/geofence.py): polygon and circle zones, inclusion and exclusion, distance
limits."""

from __future__ import annotations

import pytest

from sitl.autopilot.geofence import CircleZone, FenceKind, Geofence, PolygonZone

pytestmark = pytest.mark.timeout(10)

HOME = (0.0, 0.0, 0.0)
# An L-shaped (concave) polygon: the notch at north 5..10, east 5..10 is outside it.
L_SHAPE = ((0.0, 0.0), (10.0, 0.0), (10.0, 5.0), (5.0, 5.0), (5.0, 10.0), (0.0, 10.0))


@pytest.mark.parametrize(
    ("north_m", "east_m", "inside"),
    [(2.0, 2.0, True), (8.0, 2.0, True), (2.0, 8.0, True), (8.0, 8.0, False), (-1.0, 2.0, False), (2.0, 11.0, False)],
)
def test_a_concave_polygon_contains_exactly_its_inside(north_m: float, east_m: float, inside: bool) -> None:
    zone = PolygonZone(kind=FenceKind.INCLUSION, vertices_ne_m=L_SHAPE)
    assert zone.contains(north_m, east_m) is inside


def test_a_circle_contains_its_disc_boundary_included() -> None:
    zone = CircleZone(kind=FenceKind.INCLUSION, centre_ne_m=(10.0, -5.0), radius_m=3.0)
    assert zone.contains(10.0, -5.0) and zone.contains(13.0, -5.0)
    assert not zone.contains(13.01, -5.0)


def test_outside_every_inclusion_zone_is_a_breach_inside_any_of_them_is_not() -> None:
    fence = Geofence(
        zones=(
            CircleZone(kind=FenceKind.INCLUSION, centre_ne_m=(0.0, 0.0), radius_m=5.0),
            PolygonZone(kind=FenceKind.INCLUSION, vertices_ne_m=((20.0, 0.0), (30.0, 0.0), (30.0, 10.0))),
        )
    )
    assert fence.breach((1.0, 1.0, -3.0), HOME) is None
    assert fence.breach((28.0, 2.0, -3.0), HOME) is None
    assert fence.breach((10.0, 0.0, -3.0), HOME) == "Outside the geofence"


def test_inside_an_exclusion_zone_is_a_breach() -> None:
    fence = Geofence(zones=(CircleZone(kind=FenceKind.EXCLUSION, centre_ne_m=(5.0, 5.0), radius_m=2.0),))
    assert fence.breach((5.0, 6.0, -2.0), HOME) == "Inside an exclusion zone of the geofence"
    assert fence.breach((0.0, 0.0, -2.0), HOME) is None


def test_distance_limits_are_measured_from_home_and_zero_is_off() -> None:
    home = (100.0, 50.0, -10.0)  # home need not be the local origin
    fence = Geofence()
    assert fence.breach((104.0, 50.0, -10.0), home, max_hor_dist_m=5.0) is None
    assert fence.breach((106.0, 50.0, -10.0), home, max_hor_dist_m=5.0) == "Maximum distance from home exceeded"
    assert fence.breach((100.0, 50.0, -14.0), home, max_ver_dist_m=5.0) is None
    assert fence.breach((100.0, 50.0, -16.0), home, max_ver_dist_m=5.0) == "Maximum altitude exceeded"
    assert fence.breach((1000.0, 50.0, -1000.0), home) is None  # both limits off
