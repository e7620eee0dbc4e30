"""Offboard position control through MAVSDK: the way companion computers and swarm planners fly the drone.

MAVSDK streams SET_POSITION_TARGET_LOCAL_NED at 20 Hz from its own thread and gives up silently if the drone's
heartbeat does not show OFFBOARD, so flying a square end to end checks the mode switch, the setpoint stream, the
heartbeat and the local position telemetry together.
"""

from __future__ import annotations

import pytest
from mavsdk.asyncio.plugins.offboard import PositionNedYaw
from mavsdk.asyncio.plugins.telemetry import FlightMode

from tests.integration.mavsdk_client import (
    Drone,
    connect,
    describe,
    distance_m,
    first_matching,
    take_off,
    wait_flight_mode,
    wait_landed_and_disarmed,
    wait_ready_to_arm,
)
from tests.integration.vehicle_link import VehicleLink

# Against a drone in its own process only: a hosted drone answers clients alike, which the takeoff and landing of
# test_mavsdk_takeoff_land.py and test_pymavlink_flight.py hold against both kinds of vehicle.
pytestmark = [pytest.mark.timeout(120), pytest.mark.parametrize("vehicle", ["process"], indirect=True)]

SQUARE_SIDE_M = 10.0
ALTITUDE_DOWN_M = -3.0  # NED: 3 m above the local origin
CORNER_TOLERANCE_M = 0.5
SIM_S_PER_LEG = 15.0  # 10 m at PX4-like offboard speeds, with settling


async def _fly_to(drone: Drone, target: tuple[float, float, float], timeout_s: float) -> None:
    north, east, down = target
    await drone.offboard.set_position_ned(PositionNedYaw(north, east, down, 0.0))

    def reached(pv: object) -> bool:
        p = pv.position  # type: ignore[attr-defined]
        return distance_m((p.north_m, p.east_m, p.down_m), target) <= CORNER_TOLERANCE_M

    await first_matching(
        drone.telemetry.subscribe_position_velocity_ned,
        reached,
        timeout_s,
        f"corner N {north:.1f} E {east:.1f} D {down:.1f} within {CORNER_TOLERANCE_M} m",
    )


async def test_offboard_position_setpoints_fly_a_10_m_square_reaching_every_corner_within_half_a_metre(
    vehicle: VehicleLink,
) -> None:
    async with connect(vehicle.mavsdk_url, vehicle.sysid) as drone:
        # GIVEN the drone hovering after a takeoff
        await wait_ready_to_arm(drone, vehicle.wall_s(10))
        await take_off(drone, vehicle.wall_s(20))
        start = (await drone.telemetry.position_velocity_ned()).position
        n0, e0 = start.north_m, start.east_m

        # WHEN offboard is started with a first setpoint where the drone already is (PX4 requires one before start)
        await drone.offboard.set_position_ned(PositionNedYaw(n0, e0, start.down_m, 0.0))
        await drone.offboard.start()
        # THEN the drone reports OFFBOARD
        await wait_flight_mode(drone, FlightMode.OFFBOARD, vehicle.wall_s(3))

        # WHEN the setpoint walks the corners of a 10 m square at 3 m altitude
        corners = [
            (n0, e0, ALTITUDE_DOWN_M),
            (n0 + SQUARE_SIDE_M, e0, ALTITUDE_DOWN_M),
            (n0 + SQUARE_SIDE_M, e0 + SQUARE_SIDE_M, ALTITUDE_DOWN_M),
            (n0, e0 + SQUARE_SIDE_M, ALTITUDE_DOWN_M),
            (n0, e0, ALTITUDE_DOWN_M),
        ]
        for corner in corners:
            # THEN every corner is reached within half a metre, still in OFFBOARD
            await _fly_to(drone, corner, vehicle.wall_s(SIM_S_PER_LEG))
            mode = await drone.telemetry.flight_mode()
            assert mode == FlightMode.OFFBOARD, f"left offboard at corner {corner}: {mode.name}"
        assert await drone.offboard.is_active()

        # WHEN offboard is stopped
        await drone.offboard.stop()
        # THEN the drone holds position instead of drifting or falling
        await wait_flight_mode(drone, FlightMode.HOLD, vehicle.wall_s(3))
        here = (await drone.telemetry.position_velocity_ned()).position
        assert distance_m((here.north_m, here.east_m, here.down_m), corners[-1]) <= 1.0, describe(here)

        # WHEN it lands
        await drone.action.land()
        # THEN it touches down and disarms
        await wait_landed_and_disarmed(drone, vehicle.wall_s(30))
