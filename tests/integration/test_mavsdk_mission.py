"""A waypoint mission through MAVSDK's Mission plugin, then return to launch.

Missions exercise the longest protocol exchange a client has with the drone: the upload handshake (which MAVSDK
refuses outright unless AUTOPILOT_VERSION advertises MISSION_INT), the translation of one MAVSDK item into several
MAVLink items (a speed change becomes its own DO_CHANGE_SPEED), progress reporting through MISSION_CURRENT that
MAVSDK maps back to its own item numbers, and the end-of-mission state that ``is_mission_finished`` reads.
"""

from __future__ import annotations

import asyncio
import contextlib
import math

import pytest
from mavsdk.asyncio.plugins.mission import MissionItem, MissionPlan, MissionProgress
from mavsdk.asyncio.plugins.telemetry import FlightMode

from tests.integration.mavsdk_client import (
    Drone,
    call_within,
    connect,
    first_matching,
    recording,
    wait_flight_mode,
    wait_landed_and_disarmed,
    wait_ready_to_arm,
)
from tests.integration.vehicle_link import VehicleLink

# Against a drone in its own process only: a hosted drone answers clients alike, which the takeoff and landing of
# test_mavsdk_takeoff_land.py and test_pymavlink_flight.py hold against both kinds of vehicle.
pytestmark = [pytest.mark.timeout(120), pytest.mark.parametrize("vehicle", ["process"], indirect=True)]

EARTH_RADIUS_M = 6_378_137.0
MISSION_ALT_M = 5.0
RTL_ALT_M = 6.0  # low, to keep the return short
OFFSETS_NE_M = [(8.0, 0.0), (8.0, 8.0), (0.0, 8.0), (-4.0, 4.0)]  # a few metres apart around home
SLOW_ITEM = 1  # this item carries a speed change
SLOW_SPEED_MPS = 3.0
SPEED_TOLERANCE_MPS = 0.5
SIM_S_MISSION = 60.0


def _offset(lat_deg: float, lon_deg: float, north_m: float, east_m: float) -> tuple[float, float]:
    dlat = math.degrees(north_m / EARTH_RADIUS_M)
    dlon = math.degrees(east_m / (EARTH_RADIUS_M * math.cos(math.radians(lat_deg))))
    return lat_deg + dlat, lon_deg + dlon


def _waypoints(home_lat_deg: float, home_lon_deg: float) -> list[MissionItem]:
    items = []
    for index, (north_m, east_m) in enumerate(OFFSETS_NE_M):
        lat, lon = _offset(home_lat_deg, home_lon_deg, north_m, east_m)
        items.append(
            MissionItem(
                latitude_deg=lat,
                longitude_deg=lon,
                relative_altitude_m=MISSION_ALT_M,
                speed_m_s=SLOW_SPEED_MPS if index == SLOW_ITEM else float("nan"),
                is_fly_through=False,
                gimbal_pitch_deg=float("nan"),
                gimbal_yaw_deg=float("nan"),
                camera_action=MissionItem.CameraAction.NONE,
                loiter_time_s=0.0,
                acceptance_radius_m=1.0,
                yaw_deg=float("nan"),
                vehicle_action=MissionItem.VehicleAction.NONE,
            )
        )
    return items


async def _record_speeds_by_item(drone: Drone, progress: list[MissionProgress], into: list[tuple[int, float]]) -> None:
    """(item being flown to, horizontal ground speed) for every velocity update, from the latest progress report."""
    async with contextlib.aclosing(drone.telemetry.subscribe_velocity_ned()) as velocities:
        async for v in velocities:
            if progress:
                into.append((progress[-1].current, math.hypot(v.north_m_s, v.east_m_s)))


async def test_four_waypoint_mission_is_flown_item_by_item_then_return_to_launch_lands_and_disarms(
    vehicle: VehicleLink,
) -> None:
    async with connect(vehicle.mavsdk_url, vehicle.sysid) as drone:
        # GIVEN a healthy drone on the ground, its home known, a low return altitude,
        # and a mission of 4 waypoints around home, one of them with a speed change
        await wait_ready_to_arm(drone, vehicle.wall_s(10))
        home = await first_matching(
            drone.telemetry.subscribe_home, lambda h: math.isfinite(h.latitude_deg), vehicle.wall_s(5), "home"
        )
        await drone.action.set_return_to_launch_altitude(RTL_ALT_M)
        assert await drone.action.get_return_to_launch_altitude() == pytest.approx(RTL_ALT_M)
        plan = MissionPlan(_waypoints(home.latitude_deg, home.longitude_deg))

        # WHEN the mission is uploaded
        await call_within(drone.mission.upload_mission(plan), 15.0, "mission upload")
        # THEN it downloads back as the same 4 waypoints
        downloaded = await call_within(drone.mission.download_mission(), 15.0, "mission download")
        assert len(downloaded.mission_items) == len(OFFSETS_NE_M)
        for sent, got in zip(plan.mission_items, downloaded.mission_items, strict=True):
            assert got.latitude_deg == pytest.approx(sent.latitude_deg, abs=1e-7)
            assert got.longitude_deg == pytest.approx(sent.longitude_deg, abs=1e-7)
            assert got.relative_altitude_m == pytest.approx(MISSION_ALT_M, abs=0.01)
        assert downloaded.mission_items[SLOW_ITEM].speed_m_s == pytest.approx(SLOW_SPEED_MPS)

        # WHEN the drone is armed and the mission started
        async with recording(drone.mission.subscribe_mission_progress) as progress:
            speeds: list[tuple[int, float]] = []
            speed_recorder = asyncio.create_task(_record_speeds_by_item(drone, progress, speeds))
            try:
                await drone.action.arm()
                await drone.mission.start_mission()
                await wait_flight_mode(drone, FlightMode.MISSION, vehicle.wall_s(3))
                # THEN it reports the mission finished within the expected time
                await first_matching(
                    drone.mission.subscribe_mission_progress,
                    lambda p: p.current == p.total == len(OFFSETS_NE_M),
                    vehicle.wall_s(SIM_S_MISSION),
                    "mission progress 4 of 4",
                )
                assert await drone.mission.is_mission_finished()
            finally:
                speed_recorder.cancel()
                with contextlib.suppress(asyncio.CancelledError):
                    await speed_recorder
        # AND the progress went through every item in order, always out of 4
        reports = [(p.current, p.total) for p in progress]
        currents = [current for current, _ in reports]
        assert {total for _, total in reports} == {len(OFFSETS_NE_M)}, reports
        assert currents == sorted(currents), f"progress went backwards: {reports}"
        assert {1, 2, 3, 4} <= set(currents), f"items missing from the progress reports: {reports}"
        # AND after the waypoint with the speed change, the drone kept to the new speed
        slow_legs = [speed for current, speed in speeds if SLOW_ITEM < current < len(OFFSETS_NE_M)]
        assert slow_legs, f"no velocity seen on the legs after item {SLOW_ITEM}"
        assert max(slow_legs) <= SLOW_SPEED_MPS + SPEED_TOLERANCE_MPS, f"flew at {max(slow_legs):.2f} m/s"

        # WHEN it is told to return to launch
        await drone.action.return_to_launch()
        # THEN it flies home, lands and disarms
        await wait_flight_mode(drone, FlightMode.RETURN_TO_LAUNCH, vehicle.wall_s(3))
        await wait_landed_and_disarmed(drone, vehicle.wall_s(60))
        here = await drone.telemetry.position()
        north_m = math.radians(here.latitude_deg - home.latitude_deg) * EARTH_RADIUS_M
        east_m = (
            math.radians(here.longitude_deg - home.longitude_deg)
            * EARTH_RADIUS_M
            * math.cos(math.radians(home.latitude_deg))
        )
        assert math.hypot(north_m, east_m) < 2.0, f"landed {north_m:.1f} m N, {east_m:.1f} m E of home"
