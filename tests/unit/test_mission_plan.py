"""Uploaded MISSION_ITEM_INTs turned into local navigation items: frames, altitudes, "stay here", each command."""

from __future__ import annotations

import math
from typing import Any

import pytest
from pymavlink.dialects.v20 import common as mavlink

from sitl.autopilot.mission_plan import NavItem, NavKind, to_nav_items
from sitl.autopilot.vehicle_api import MissionItem
from sitl.dynamics.geodesy import geo_from_ned
from sitl.dynamics.plant import DEFAULT_HOME, GeoPoint

pytestmark = pytest.mark.timeout(10)

ORIGIN = DEFAULT_HOME  # 488 m AMSL
HOME_ALT_AMSL_M = 490.0  # home 2 m above the local origin (e.g. armed after the barometer settled)
RELATIVE = mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT
AMSL = mavlink.MAV_FRAME_GLOBAL_INT
DEGE7_M = 0.02  # a degE7 step is about 1.1 cm


def _latlon_e7(north_m: float, east_m: float) -> tuple[int, int]:
    point = geo_from_ned((north_m, east_m, 0.0), ORIGIN)
    return round(point.lat_deg * 1e7), round(point.lon_deg * 1e7)


def _item(command: int, seq: int = 0, frame: int = RELATIVE, **fields: Any) -> MissionItem:
    return MissionItem(seq=seq, frame=frame, command=command, **fields)


def _one(item: MissionItem, home_alt_amsl_m: float = HOME_ALT_AMSL_M) -> NavItem:
    (nav,) = to_nav_items([item], ORIGIN, home_alt_amsl_m)
    return nav


def _waypoint(north_m: float, east_m: float, z: float, frame: int = RELATIVE, **params: Any) -> MissionItem:
    x, y = _latlon_e7(north_m, east_m)
    return MissionItem(seq=0, frame=frame, command=mavlink.MAV_CMD_NAV_WAYPOINT, x=x, y=y, z=z, **params)


# ---- frames and coordinates ----------------------------------------------------------------------------------------
def test_relative_altitude_is_above_home_and_lat_lon_become_north_east_of_the_origin() -> None:
    # GIVEN a waypoint 10 m north, 20 m east, 15 m above home (home 2 m above the origin)
    nav = _one(_waypoint(10.0, 20.0, 15.0))
    # THEN its local target is north 10, east 20, down -(15 + 2)
    assert nav.kind is NavKind.WAYPOINT
    assert nav.target_ned_m == pytest.approx((10.0, 20.0, -17.0), abs=DEGE7_M)


def test_amsl_altitude_does_not_depend_on_home() -> None:
    # GIVEN a waypoint at 500 m AMSL, 12 m above the 488 m origin
    item = _waypoint(-30.0, 5.0, 500.0, frame=AMSL)
    # THEN the target is 12 m above the origin whatever home's altitude is
    for home_alt in (488.0, 490.0, 520.0):
        assert _one(item, home_alt).target_ned_m == pytest.approx((-30.0, 5.0, -12.0), abs=DEGE7_M)


def test_the_same_relative_altitude_follows_home() -> None:
    item = _waypoint(0.0, 0.0, 10.0)
    low, high = _one(item, 488.0), _one(item, 498.0)
    assert low.target_ned_m[2] == pytest.approx(-10.0)
    assert high.target_ned_m[2] == pytest.approx(-20.0)


def test_lat_lon_zero_means_stay_where_the_vehicle_is() -> None:
    nav = _one(_item(mavlink.MAV_CMD_NAV_WAYPOINT, x=0, y=0, z=8.0))
    north, east, down = nav.target_ned_m
    assert math.isnan(north) and math.isnan(east)
    assert down == pytest.approx(-(8.0 + HOME_ALT_AMSL_M - ORIGIN.alt_amsl_m))


def test_a_non_global_frame_leaves_the_whole_target_unset() -> None:
    nav = _one(_item(mavlink.MAV_CMD_NAV_WAYPOINT, frame=mavlink.MAV_FRAME_MISSION, x=1, y=2, z=3.0))
    assert all(math.isnan(c) for c in nav.target_ned_m)


def test_sequence_numbers_and_order_are_kept() -> None:
    items = [_item(mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH, seq=s, frame=mavlink.MAV_FRAME_MISSION) for s in range(4)]
    assert [nav.seq for nav in to_nav_items(items, ORIGIN, HOME_ALT_AMSL_M)] == [0, 1, 2, 3]


def test_origin_elsewhere_shifts_the_targets() -> None:
    origin = GeoPoint(lat_deg=-33.0, lon_deg=151.0, alt_amsl_m=10.0)
    point = geo_from_ned((40.0, -25.0, 0.0), origin)
    item = _item(mavlink.MAV_CMD_NAV_WAYPOINT, x=round(point.lat_deg * 1e7), y=round(point.lon_deg * 1e7), z=5.0)
    (nav,) = to_nav_items([item], origin, 10.0)
    assert nav.target_ned_m == pytest.approx((40.0, -25.0, -5.0), abs=DEGE7_M)


# ---- each command --------------------------------------------------------------------------------------------------
def test_waypoint_carries_hold_time_acceptance_radius_and_yaw() -> None:
    nav = _one(_waypoint(5.0, 0.0, 10.0, param1=3.0, param2=2.5, param4=90.0))
    assert nav.hold_s == 3.0
    assert nav.acceptance_radius_m == 2.5
    assert nav.yaw_rad == pytest.approx(math.pi / 2)


def test_waypoint_without_those_parameters_uses_the_defaults() -> None:
    nav = _one(_waypoint(5.0, 0.0, 10.0, param1=0.0, param2=0.0))  # param4 unset (NaN)
    assert nav.hold_s == 0.0
    assert math.isnan(nav.acceptance_radius_m)  # NAV_ACC_RAD
    assert math.isnan(nav.yaw_rad)  # keep heading


def test_takeoff_and_land_items_keep_their_targets() -> None:
    x, y = _latlon_e7(3.0, 4.0)
    takeoff = _one(_item(mavlink.MAV_CMD_NAV_TAKEOFF, x=x, y=y, z=5.0))
    land = _one(_item(mavlink.MAV_CMD_NAV_LAND, x=x, y=y, z=0.0, param4=180.0))
    assert takeoff.kind is NavKind.TAKEOFF
    assert takeoff.target_ned_m == pytest.approx((3.0, 4.0, -7.0), abs=DEGE7_M)
    assert land.kind is NavKind.LAND
    assert land.target_ned_m[:2] == pytest.approx((3.0, 4.0), abs=DEGE7_M)
    assert land.yaw_rad == pytest.approx(math.pi)


def test_land_without_a_position_lands_where_the_vehicle_is() -> None:
    land = _one(_item(mavlink.MAV_CMD_NAV_LAND, x=0, y=0, z=0.0))
    assert math.isnan(land.target_ned_m[0]) and math.isnan(land.target_ned_m[1])


def test_return_to_launch_item() -> None:
    nav = _one(_item(mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH, frame=mavlink.MAV_FRAME_MISSION))
    assert nav.kind is NavKind.RTL


def test_loiter_time_holds_at_its_position_for_param1_seconds() -> None:
    x, y = _latlon_e7(-6.0, 2.0)
    nav = _one(_item(mavlink.MAV_CMD_NAV_LOITER_TIME, x=x, y=y, z=4.0, param1=7.5))
    assert nav.kind is NavKind.DELAY
    assert nav.hold_s == 7.5
    assert nav.target_ned_m == pytest.approx((-6.0, 2.0, -6.0), abs=DEGE7_M)


def test_nav_delay_holds_where_the_vehicle_is() -> None:
    nav = _one(_item(mavlink.MAV_CMD_NAV_DELAY, frame=mavlink.MAV_FRAME_MISSION, param1=4.0, x=123, y=456, z=9.0))
    assert nav.kind is NavKind.DELAY
    assert nav.hold_s == 4.0
    assert all(math.isnan(c) for c in nav.target_ned_m)


def test_a_negative_delay_means_no_delay() -> None:
    nav = _one(_item(mavlink.MAV_CMD_NAV_DELAY, frame=mavlink.MAV_FRAME_MISSION, param1=-1.0))
    assert nav.hold_s == 0.0


def test_loiter_unlimited_holds_at_its_position() -> None:
    x, y = _latlon_e7(1.0, 1.0)
    nav = _one(_item(mavlink.MAV_CMD_NAV_LOITER_UNLIM, x=x, y=y, z=3.0))
    assert nav.kind is NavKind.LOITER_UNLIMITED
    assert nav.target_ned_m == pytest.approx((1.0, 1.0, -5.0), abs=DEGE7_M)


@pytest.mark.parametrize("speed_type", [0.0, 1.0, math.nan])
def test_change_speed_sets_the_horizontal_speed(speed_type: float) -> None:
    nav = _one(_item(mavlink.MAV_CMD_DO_CHANGE_SPEED, frame=mavlink.MAV_FRAME_MISSION, param1=speed_type, param2=3.5))
    assert nav.kind is NavKind.SPEED
    assert nav.speed_mps == 3.5


def test_change_speed_minus_2_goes_back_to_the_default_speed() -> None:
    nav = _one(_item(mavlink.MAV_CMD_DO_CHANGE_SPEED, frame=mavlink.MAV_FRAME_MISSION, param1=1.0, param2=-2.0))
    assert nav.kind is NavKind.SPEED
    assert math.isnan(nav.speed_mps)  # the executor's "default speed"


def test_change_speed_minus_1_changes_nothing() -> None:
    # MAVLink: param2 = -1 is "no change"; it must not reset a speed set earlier in the mission.
    nav = _one(_item(mavlink.MAV_CMD_DO_CHANGE_SPEED, frame=mavlink.MAV_FRAME_MISSION, param1=1.0, param2=-1.0))
    assert nav.kind is NavKind.SKIP


@pytest.mark.parametrize("speed_type", [2.0, 3.0])
def test_change_of_climb_or_descent_speed_does_not_touch_the_horizontal_speed(speed_type: float) -> None:
    nav = _one(_item(mavlink.MAV_CMD_DO_CHANGE_SPEED, frame=mavlink.MAV_FRAME_MISSION, param1=speed_type, param2=1.0))
    assert nav.kind is NavKind.SKIP


@pytest.mark.parametrize(
    "command",
    [
        mavlink.MAV_CMD_DO_SET_SERVO,
        mavlink.MAV_CMD_CONDITION_YAW,
        mavlink.MAV_CMD_DO_SET_ROI_LOCATION,
        mavlink.MAV_CMD_DO_DIGICAM_CONTROL,
        mavlink.MAV_CMD_DO_MOUNT_CONTROL,
    ],
)
def test_commands_with_nothing_to_fly_are_skipped(command: int) -> None:
    assert _one(_item(command, frame=mavlink.MAV_FRAME_MISSION, param1=1.0)).kind is NavKind.SKIP
