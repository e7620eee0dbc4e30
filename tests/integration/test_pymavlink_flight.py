"""A classic pymavlink script flies the drone: heartbeat, arm, NAV_TAKEOFF to an AMSL altitude, LAND mode.

pymavlink clients differ from MAVSDK in ways that break vehicles: they target component 0, fill unused command
parameters with 0 rather than NaN, start in MAVLink 1, and switch modes through their own PX4 mode table
(``set_mode('LAND')`` sends DO_SET_MODE with main/sub mode numbers). This test keeps to that plain style.
"""

from __future__ import annotations

import contextlib
import time

import pytest
from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mavlink

from tests.integration.mavlink_client import (
    PX4_AUTO_LAND,
    command_long,
    heartbeat_armed,
    mavlink_connection,
    recv_until,
    wait_armable,
    wait_armed_state,
    wait_custom_mode,
    wait_relative_alt,
    wait_vehicle_heartbeat,
)
from tests.integration.vehicle_link import VehicleLink

pytestmark = pytest.mark.timeout(90)

TAKEOFF_REL_M = 3.0


def _arm_until_accepted(conn: mavutil.mavfile, timeout_s: float) -> None:
    """``arducopter_arm()`` as scripts do, resent until the drone accepts it (the pre-arm bit can lag arming)."""
    deadline = time.monotonic() + timeout_s
    last_ack = None
    while time.monotonic() < deadline:
        conn.arducopter_arm()
        with contextlib.suppress(AssertionError):
            last_ack = recv_until(
                conn, "COMMAND_ACK", lambda m: m.command == mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1.0, "arm ACK"
            )
            if last_ack.result == mavlink.MAV_RESULT_ACCEPTED:
                return
            time.sleep(0.2)
    raise AssertionError(f"arming not accepted within {timeout_s:.1f} s, last COMMAND_ACK: {last_ack}")


def test_pymavlink_script_arms_takes_off_to_an_amsl_altitude_lands_in_land_mode_and_disarms(
    vehicle: VehicleLink,
) -> None:
    with mavlink_connection(vehicle.pymavlink_url) as conn:
        # GIVEN a pymavlink connection that heard the drone's heartbeat, and the drone reporting itself armable
        hb = wait_vehicle_heartbeat(conn, vehicle.sysid, vehicle.wall_s(5))
        assert hb.autopilot == mavlink.MAV_AUTOPILOT_PX4 and hb.type == mavlink.MAV_TYPE_QUADROTOR
        assert hb.base_mode & mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, hb
        assert not heartbeat_armed(hb) and hb.system_status == mavlink.MAV_STATE_STANDBY, hb
        wait_armable(conn, vehicle.wall_s(10))

        # WHEN the script arms
        _arm_until_accepted(conn, vehicle.wall_s(5))
        # THEN the heartbeat shows it armed
        armed_hb = wait_armed_state(conn, True, vehicle.wall_s(3))
        assert conn.motors_armed()
        assert armed_hb.system_status == mavlink.MAV_STATE_ACTIVE, armed_hb

        # WHEN it sends NAV_TAKEOFF with param7 = ground AMSL + 3 m (all other params 0, as scripts send them)
        ground = recv_until(conn, "GLOBAL_POSITION_INT", lambda m: True, vehicle.wall_s(2), "GLOBAL_POSITION_INT")
        ground_amsl_m = (ground.alt - ground.relative_alt) / 1000.0
        ack = command_long(
            conn, mavlink.MAV_CMD_NAV_TAKEOFF, (0, 0, 0, 0, 0, 0, ground_amsl_m + TAKEOFF_REL_M), vehicle.wall_s(5)
        )
        # THEN it is accepted, addressed back to the script, and the drone climbs to 3 m above ground
        assert ack.result == mavlink.MAV_RESULT_ACCEPTED, f"takeoff refused: {ack}"
        assert (ack.target_system, ack.target_component) == (conn.mav.srcSystem, conn.mav.srcComponent), ack
        wait_relative_alt(conn, TAKEOFF_REL_M, 0.3, vehicle.wall_s(20))

        # WHEN the script switches to LAND with pymavlink's PX4 mode table
        conn.set_mode("LAND")
        # THEN the heartbeat shows AUTO.LAND, which pymavlink names LAND
        land_hb = wait_custom_mode(conn, PX4_AUTO_LAND, vehicle.wall_s(3), "AUTO.LAND")
        assert conn.flightmode == "LAND"
        assert land_hb.base_mode & mavlink.MAV_MODE_FLAG_AUTO_ENABLED, land_hb
        # AND after touchdown the armed bit clears by itself
        disarmed_hb = wait_armed_state(conn, False, vehicle.wall_s(30))
        assert disarmed_hb.system_status == mavlink.MAV_STATE_STANDBY, disarmed_hb
        landed = recv_until(conn, "EXTENDED_SYS_STATE", lambda m: True, vehicle.wall_s(3), "EXTENDED_SYS_STATE")
        assert landed.landed_state == mavlink.MAV_LANDED_STATE_ON_GROUND, landed
