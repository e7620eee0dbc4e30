"""Mission items as the autopilot flies them: MAVLink MISSION_ITEM_INT contents turned into local navigation steps.

The MAVLink mission server (sitl/protocol/mission.py) stores items exactly as uploaded, so a download returns what
was sent. The autopilot flies ``NavItem``s: each one a kind, a local NED target (NaN where the item leaves a
coordinate unset: "stay where you are"), and its timing. Converting here keeps geodesy out of the autopilot, whose
world is the local frame.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from enum import Enum

from pymavlink.dialects.v20 import common as mavlink

from sitl.autopilot.vehicle_api import MissionItem
from sitl.dynamics.geodesy import ned_from_geo
from sitl.dynamics.plant import GeoPoint

NAN3 = (math.nan, math.nan, math.nan)


class NavKind(Enum):
    WAYPOINT = "waypoint"
    TAKEOFF = "takeoff"
    LAND = "land"
    RTL = "rtl"
    DELAY = "delay"  # hold position for hold_s
    LOITER_UNLIMITED = "loiter"  # hold position until the mission is changed
    SPEED = "speed"  # change the cruise speed, then continue at once
    SKIP = "skip"  # accepted (gimbal, camera, ...) but nothing for this vehicle to do


@dataclass(frozen=True, slots=True, kw_only=True)
class NavItem:
    seq: int
    kind: NavKind
    target_ned_m: tuple[float, float, float] = NAN3  # NaN component: keep the current one
    hold_s: float = 0.0
    acceptance_radius_m: float = math.nan  # NaN: the NAV_ACC_RAD parameter
    yaw_rad: float = math.nan
    speed_mps: float = math.nan


def to_nav_items(items: Sequence[MissionItem], origin: GeoPoint, home_alt_amsl_m: float) -> tuple[NavItem, ...]:
    """Translate uploaded items into the local frame whose (0, 0, 0) is ``origin``."""
    return tuple(_to_nav(item, origin, home_alt_amsl_m) for item in items)


def _target(item: MissionItem, origin: GeoPoint, home_alt_amsl_m: float) -> tuple[float, float, float]:
    if not item.is_global:
        return NAN3  # PX4 multicopter missions use global frames only
    alt = item.z + home_alt_amsl_m if item.alt_is_relative_to_home else item.z
    down = origin.alt_amsl_m - alt if math.isfinite(alt) else math.nan
    if item.x == 0 and item.y == 0:
        return (math.nan, math.nan, down)  # no position: stay where the vehicle is
    north, east, _ = ned_from_geo(
        GeoPoint(lat_deg=item.lat_deg, lon_deg=item.lon_deg, alt_amsl_m=origin.alt_amsl_m), origin
    )
    return (north, east, down)


def _to_nav(item: MissionItem, origin: GeoPoint, home_alt: float) -> NavItem:
    cmd = item.command
    yaw = math.radians(item.param4) if math.isfinite(item.param4) else math.nan
    if cmd == mavlink.MAV_CMD_NAV_WAYPOINT:
        return NavItem(
            seq=item.seq,
            kind=NavKind.WAYPOINT,
            target_ned_m=_target(item, origin, home_alt),
            hold_s=item.param1 if math.isfinite(item.param1) and item.param1 > 0 else 0.0,
            acceptance_radius_m=item.param2 if math.isfinite(item.param2) and item.param2 > 0 else math.nan,
            yaw_rad=yaw,
        )
    if cmd == mavlink.MAV_CMD_NAV_TAKEOFF:
        return NavItem(seq=item.seq, kind=NavKind.TAKEOFF, target_ned_m=_target(item, origin, home_alt), yaw_rad=yaw)
    if cmd == mavlink.MAV_CMD_NAV_LAND:
        return NavItem(seq=item.seq, kind=NavKind.LAND, target_ned_m=_target(item, origin, home_alt), yaw_rad=yaw)
    if cmd == mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH:
        return NavItem(seq=item.seq, kind=NavKind.RTL)
    if cmd in (mavlink.MAV_CMD_NAV_LOITER_TIME, mavlink.MAV_CMD_NAV_DELAY):
        hold = item.param1 if math.isfinite(item.param1) and item.param1 > 0 else 0.0
        target = _target(item, origin, home_alt) if cmd == mavlink.MAV_CMD_NAV_LOITER_TIME else NAN3
        return NavItem(seq=item.seq, kind=NavKind.DELAY, target_ned_m=target, hold_s=hold)
    if cmd == mavlink.MAV_CMD_NAV_LOITER_UNLIM:
        return NavItem(seq=item.seq, kind=NavKind.LOITER_UNLIMITED, target_ned_m=_target(item, origin, home_alt))
    if cmd == mavlink.MAV_CMD_DO_CHANGE_SPEED:
        return _speed_change(item)
    return NavItem(seq=item.seq, kind=NavKind.SKIP)


# DO_CHANGE_SPEED param1: 0 airspeed and 1 ground speed are the horizontal speed on a multicopter; 2 climb and
# 3 descent speeds are not adjustable here (the command path answers UNSUPPORTED for them). Param2 -1 means
# "no change" and -2 "back to the default", as MAVLink defines them and as the command path handles them.
_HORIZONTAL_SPEED_TYPES = (0, 1)
SPEED_DEFAULT = -2.0


def _speed_change(item: MissionItem) -> NavItem:
    speed_type = round(item.param1) if math.isfinite(item.param1) else 1
    if speed_type in _HORIZONTAL_SPEED_TYPES:
        if math.isfinite(item.param2) and item.param2 > 0:
            return NavItem(seq=item.seq, kind=NavKind.SPEED, speed_mps=item.param2)
        if item.param2 == SPEED_DEFAULT:
            return NavItem(seq=item.seq, kind=NavKind.SPEED, speed_mps=math.nan)  # NaN: the default speed
    return NavItem(seq=item.seq, kind=NavKind.SKIP)  # no change (-1, unset) or a speed this vehicle cannot set
