"""Parameters through MAVSDK's Param plugin: listing, typed set and read-back, and refusal of bad values.

MAVSDK calls a set successful only when the echoed PARAM_VALUE carries the same value and type, and it decodes
INT32 values bytewise as PX4 sends them, so a drone that gets the encoding or the echo wrong fails here first.
Values changed by a test are put back, so the tests may also run against a long-lived external vehicle.
"""

from __future__ import annotations

import pytest
from mavsdk.asyncio.plugins.param import ParamError

from tests.integration.mavsdk_client import Drone, call_within, connect
from tests.integration.vehicle_link import VehicleLink

# Against a drone in its own process only: a hosted drone answers clients alike, which the takeoff and landing of
# test_mavsdk_takeoff_land.py and test_pymavlink_flight.py hold against both kinds of vehicle.
pytestmark = [pytest.mark.timeout(60), pytest.mark.parametrize("vehicle", ["process"], indirect=True)]

FLOAT_PARAM = "MPC_XY_CRUISE"
INT_PARAM = "COM_ARM_WO_GPS"
PARAM_CALL_TIMEOUT_S = 15.0  # MAVSDK's own retries (3 s per request, a few retries) end well before this


async def _get_float(drone: Drone, name: str) -> float:
    return float(await call_within(drone.param.get_param_float(name), PARAM_CALL_TIMEOUT_S, f"get {name}"))


async def _get_int(drone: Drone, name: str) -> int:
    return int(await call_within(drone.param.get_param_int(name), PARAM_CALL_TIMEOUT_S, f"get {name}"))


async def test_all_params_lists_int_and_float_parameters_with_their_values(vehicle: VehicleLink) -> None:
    async with connect(vehicle.mavsdk_url, vehicle.sysid) as drone:
        # GIVEN a connected drone
        # WHEN a client fetches the whole parameter table
        table = await call_within(drone.param.get_all_params(), 30.0, "get_all_params")
        ints = {p.name: p.value for p in table.int_params}
        floats = {p.name: p.value for p in table.float_params}
        # THEN it holds integer and float parameters, each under its own type, names unique
        assert ints and floats
        assert not set(ints) & set(floats), set(ints) & set(floats)
        assert INT_PARAM in ints and FLOAT_PARAM in floats
        assert "MIS_TAKEOFF_ALT" in floats and "RTL_RETURN_ALT" in floats
        # AND the listed values agree with single reads
        assert await _get_float(drone, FLOAT_PARAM) == pytest.approx(floats[FLOAT_PARAM])
        assert await _get_int(drone, INT_PARAM) == ints[INT_PARAM]
        assert all(len(name) <= 16 for name in (*ints, *floats))


async def test_float_and_int_params_set_over_mavlink_read_back_with_the_new_value(vehicle: VehicleLink) -> None:
    async with connect(vehicle.mavsdk_url, vehicle.sysid) as drone:
        # GIVEN the current values of a float and an int parameter
        old_float = await _get_float(drone, FLOAT_PARAM)
        old_int = await _get_int(drone, INT_PARAM)
        new_float = 7.5 if old_float != pytest.approx(7.5) else 6.5
        new_int = 1 - old_int if old_int in (0, 1) else 0
        try:
            # WHEN both are set to new values
            await call_within(drone.param.set_param_float(FLOAT_PARAM, new_float), PARAM_CALL_TIMEOUT_S, "set")
            await call_within(drone.param.set_param_int(INT_PARAM, new_int), PARAM_CALL_TIMEOUT_S, "set")
            # THEN reading them back gives the new values
            assert await _get_float(drone, FLOAT_PARAM) == pytest.approx(new_float)
            assert await _get_int(drone, INT_PARAM) == new_int
        finally:
            await drone.param.set_param_float(FLOAT_PARAM, old_float)
            await drone.param.set_param_int(INT_PARAM, old_int)
        # AND putting the old values back works as well
        assert await _get_float(drone, FLOAT_PARAM) == pytest.approx(old_float)
        assert await _get_int(drone, INT_PARAM) == old_int


@pytest.mark.sim_only  # PX4 itself accepts out-of-range values over MAVLink; refusing them is this drone's own rule
async def test_out_of_range_param_set_fails_and_leaves_the_value_unchanged(vehicle: VehicleLink) -> None:
    async with connect(vehicle.mavsdk_url, vehicle.sysid) as drone:
        # GIVEN the current values of a float and an int parameter
        old_float = await _get_float(drone, FLOAT_PARAM)
        old_int = await _get_int(drone, INT_PARAM)
        # WHEN each is set far outside its declared range
        # THEN the set fails
        with pytest.raises(ParamError):
            await call_within(drone.param.set_param_float(FLOAT_PARAM, 1000.0), PARAM_CALL_TIMEOUT_S, "set")
        with pytest.raises(ParamError):
            await call_within(drone.param.set_param_int(INT_PARAM, 7), PARAM_CALL_TIMEOUT_S, "set")
        # AND the drone kept the old values
        assert await _get_float(drone, FLOAT_PARAM) == pytest.approx(old_float)
        assert await _get_int(drone, INT_PARAM) == old_int
