"""Fence uploads (mission type 1) through the mission server, and their conversion to local geofence zones."""

from __future__ import annotations

import math

import pytest
from pymavlink.dialects.v20 import common as mavlink

from sitl.autopilot.geofence import CircleZone, FenceKind, PolygonZone
from sitl.autopilot.vehicle_api import SetFence, SetMission
from sitl.protocol.fence import to_geofence, validate_fence
from sitl.protocol.mission import item_from_message
from tests.unit.test_protocol_mission import ACCEPTED, SYSID, Harness

FENCE = mavlink.MAV_MISSION_TYPE_FENCE
GLOBAL_INT = mavlink.MAV_FRAME_GLOBAL_INT
LAT0, LON0 = 473977420, 85455940


def vertex(seq: int, count: float, lat_e7: int, lon_e7: int, command: int = 5001) -> mavlink.MAVLink_message:
    return mavlink.MAVLink_mission_item_int_message(
        SYSID, 1, seq, GLOBAL_INT, command, 0, 1, count, 0, 0, 0, lat_e7, lon_e7, 0, FENCE
    )


def circle(seq: int, radius_m: float, command: int = 5003) -> mavlink.MAVLink_message:
    return mavlink.MAVLink_mission_item_int_message(
        SYSID, 1, seq, GLOBAL_INT, command, 0, 1, radius_m, 0, 0, 0, LAT0, LON0, 0, FENCE
    )


def square(first_seq: int = 0, command: int = 5001, count: int = 4) -> list[mavlink.MAVLink_message]:
    corners = [
        (LAT0 - 900, LON0 - 1300),
        (LAT0 - 900, LON0 + 1300),
        (LAT0 + 900, LON0 + 1300),
        (LAT0 + 900, LON0 - 1300),
    ]
    return [vertex(first_seq + i, count, lat, lon, command) for i, (lat, lon) in enumerate(corners)]


def test_polygon_and_circle_fence_round_trip_and_clear() -> None:
    h = Harness()
    items = [*square(), circle(4, 3.0, command=5004)]
    assert h.upload(items, FENCE) == ACCEPTED
    assert [type(r) for r in h.vehicle.requests] == [SetFence]  # the mission is untouched
    back = h.download(FENCE)
    assert [(m.command, m.param1, m.x, m.y, m.mission_type) for m in back] == [
        (m.command, m.param1, m.x, m.y, FENCE) for m in items
    ]
    assert h.download(0) == []  # a fence is not a mission
    (ack,) = h.send(mavlink.MAVLink_mission_clear_all_message(SYSID, 1, FENCE))
    assert (ack.type, ack.mission_type) == (ACCEPTED, FENCE)
    assert h.vehicle.fence == [] and h.download(FENCE) == []


def test_clear_all_of_type_all_clears_mission_and_fence() -> None:
    h = Harness()
    assert h.upload(square(), FENCE) == ACCEPTED
    (ack,) = h.send(mavlink.MAVLink_mission_clear_all_message(SYSID, 1, mavlink.MAV_MISSION_TYPE_ALL))
    assert ack.type == ACCEPTED
    assert [type(r) for r in h.vehicle.requests] == [SetFence, SetFence, SetMission]
    assert h.vehicle.fence == []


@pytest.mark.parametrize(
    ("items", "result"),
    [
        # a polygon announcing 2 vertices: refused on that item, as PX4 refuses a polygon of fewer than 3
        ([vertex(0, 2, LAT0, LON0), vertex(1, 2, LAT0 + 900, LON0)], mavlink.MAV_MISSION_INVALID_PARAM1),
        # 4 vertices announced, 3 given
        (square()[:3], mavlink.MAV_MISSION_ERROR),
        # counts that disagree inside one polygon
        ([*square()[:2], *square(count=5)[2:]], mavlink.MAV_MISSION_ERROR),
        # inclusion and exclusion vertices mixed in one polygon
        ([*square()[:2], *square(command=5002)[2:]], mavlink.MAV_MISSION_ERROR),
        # a circle without a radius
        ([circle(0, 0.0)], mavlink.MAV_MISSION_INVALID_PARAM1),
        # a mission command in a fence
        ([mavlink.MAVLink_mission_item_int_message(SYSID, 1, 0, GLOBAL_INT, 16, 0, 1, 0, 0, 0, 0, LAT0, LON0, 5,
                                                   FENCE)], mavlink.MAV_MISSION_UNSUPPORTED),
    ],
)  # fmt: skip
def test_bad_fences_are_refused_with_the_mission_result_and_change_nothing(items: list, result: int) -> None:
    h = Harness()
    assert h.upload(items, FENCE) == result
    assert h.vehicle.requests == [] and h.vehicle.fence == []


def test_fence_converts_to_local_zones() -> None:
    items = [item_from_message(m, mavlink.MAVLINK_MSG_ID_MISSION_ITEM_INT) for m in [*square(), circle(4, 3.0)]]
    assert validate_fence(items) == (ACCEPTED, "")
    # A flat-earth conversion around LAT0/LON0: enough to check that zones keep order, kind and radius.
    scale = 1e-7 * math.pi / 180 * 6_371_000.0

    def ne_of(lat: float, lon: float) -> tuple[float, float]:
        return ((lat * 1e7 - LAT0) * scale, (lon * 1e7 - LON0) * scale * math.cos(math.radians(47.4)))

    fence = to_geofence(items, ne_of)
    polygon, disc = fence.zones
    assert isinstance(polygon, PolygonZone) and polygon.kind is FenceKind.INCLUSION
    assert len(polygon.vertices_ne_m) == 4 and polygon.contains(0.0, 0.0) and not polygon.contains(20.0, 0.0)
    assert isinstance(disc, CircleZone) and disc.radius_m == 3.0 and disc.centre_ne_m == pytest.approx((0.0, 0.0))
    assert fence.breach((0.0, 0.0, -2.0), (0.0, 0.0, 0.0)) is None
    assert fence.breach((15.0, 0.0, -2.0), (0.0, 0.0, 0.0)) == "Outside the geofence"
