"""MAVSDK's takeoff-and-land flow, as the official example runs it, against the drone on the wire.

This is the first thing any MAVSDK user does with a PX4 SITL: discover the system, wait for health, read the
takeoff and return altitudes (which fails unless both parameters are REAL32), arm, take off, land. If it does not
work unchanged, nothing else matters.
"""

from __future__ import annotations

import math

import pytest
from mavsdk.asyncio.plugins.telemetry import FlightMode, LandedState

from tests.integration.mavsdk_client import (
    connect,
    recording,
    take_off,
    wait_flight_mode,
    wait_landed_and_disarmed,
    wait_ready_to_arm,
)
from tests.integration.vehicle_link import VehicleLink

pytestmark = pytest.mark.timeout(90)


async def test_mavsdk_discovers_arms_takes_off_to_takeoff_altitude_lands_and_disarms(vehicle: VehicleLink) -> None:
    # GIVEN a MAVSDK ground station connected to the drone, with telemetry health all OK
    async with connect(vehicle.mavsdk_url, vehicle.sysid) as drone:
        await wait_ready_to_arm(drone, vehicle.wall_s(10))
        # WHEN it reads the takeoff and return altitudes
        takeoff_alt_m = await drone.action.get_takeoff_altitude()
        rtl_alt_m = await drone.action.get_return_to_launch_altitude()
        # THEN both are finite, positive numbers (MIS_TAKEOFF_ALT and RTL_RETURN_ALT, REAL32 parameters)
        assert math.isfinite(takeoff_alt_m) and takeoff_alt_m > 0, takeoff_alt_m
        assert math.isfinite(rtl_alt_m) and rtl_alt_m >= 0, rtl_alt_m

        assert await drone.telemetry.landed_state() == LandedState.ON_GROUND
        async with recording(drone.telemetry.subscribe_landed_state) as landed_states:
            # WHEN it arms and takes off
            reached_m = await take_off(drone, vehicle.wall_s(20))
            # THEN the drone climbs to the takeoff altitude and holds there, armed and in the air
            assert reached_m == pytest.approx(takeoff_alt_m, abs=0.3)
            assert await drone.telemetry.flight_mode() == FlightMode.HOLD
            assert await drone.telemetry.armed()
            assert await drone.telemetry.in_air()

            # WHEN it commands a landing
            await drone.action.land()
            # THEN the drone lands, reports being on the ground, and disarms by itself
            await wait_flight_mode(drone, FlightMode.LAND, vehicle.wall_s(3))
            await wait_landed_and_disarmed(drone, vehicle.wall_s(30))
        # AND its landed state went through every phase of the flight in order
        phases = [s for i, s in enumerate(landed_states) if i == 0 or s != landed_states[i - 1]]
        expected = [LandedState.TAKING_OFF, LandedState.IN_AIR, LandedState.LANDING, LandedState.ON_GROUND]
        assert _in_order(expected, phases), [p.name for p in phases]


def _in_order(wanted: list[LandedState], seen: list[LandedState]) -> bool:
    """True if ``wanted`` occurs in ``seen`` as a subsequence."""
    remaining = iter(seen)
    return all(any(s == w for s in remaining) for w in wanted)
