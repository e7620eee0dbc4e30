"""Fault injection and fence uploads against a real ``sitl`` process: pymavlink for INJECT_FAILURE, MAVSDK for the fence
round trip.

Policy: drones of these tests use leased instances (tests/integration/instances.py, the ``world_drone`` fixture: the
block of ``instance_allocator``, the test's seed); each drone is stopped by PID and reaped at the end, its shared
world unlinked. A drone's body in the shared world is ground truth, read to show that a drone whose links went silent
still flies.
"""

from __future__ import annotations

import contextlib
import time
from multiprocessing import resource_tracker

import pytest
from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mavlink

from sitl.world.shared import ALT, TIME, VALID, SharedWorld
from tests.integration.mavlink_client import (
    arm_and_take_off,
    command_long,
    mavlink_connection,
    recv_until,
    set_param,
    wait_vehicle_heartbeat,
)
from tests.integration.mavsdk_client import call_within, connect, first_matching
from tests.integration.sitl_process import SitlDrone, WorldDrone
from tests.integration.vehicle_link import VehicleLink

pytestmark = [pytest.mark.sim_only]

INJECT = mavlink.MAV_CMD_INJECT_FAILURE


@pytest.fixture(scope="module", autouse=True)
def _shared_memory_tracker() -> None:
    """Python tracks shared memory (the test's world) with a helper process that lives as long as the test run:
    started before the suite's per-test leak check takes its list of children, it is not counted as a leak."""
    resource_tracker.ensure_running()


def drone_in_world(
    world_drone: WorldDrone, speed_factor: float = 4.0
) -> contextlib.AbstractContextManager[tuple[SitlDrone, SharedWorld]]:
    """A drone of the test (``world_drone``: an instance of the leased block, the test's seed), publishing its body
    to a fresh shared world."""
    return world_drone(speed_factor=speed_factor)


@pytest.mark.timeout(90)
def test_inject_failure_is_denied_unless_enabled_and_a_link_fault_silences_a_drone_that_flies_on(
    world_drone: WorldDrone,
) -> None:
    with (
        drone_in_world(world_drone) as (drone, world),
        mavlink_connection(VehicleLink.of(drone).pymavlink_url) as conn,
    ):
        wait_vehicle_heartbeat(conn, drone.sysid, 10.0)
        # GIVEN the default SYS_FAILURE_EN = 0  WHEN a motor failure is injected  THEN DENIED, with PX4's text
        ack = command_long(conn, INJECT, (101, 1, 1))
        assert ack.result == mavlink.MAV_RESULT_DENIED
        recv_until(conn, "STATUSTEXT", lambda m: m.text == "Failure injection disabled", 3.0, "refusal text")
        # GIVEN failure injection enabled and the drone hovering
        set_param(conn, "SYS_FAILURE_EN", 1, integer=True)
        arm_and_take_off(conn, 40.0)
        # WHEN an unsupported failure is injected  THEN UNSUPPORTED
        assert command_long(conn, INJECT, (0, 1, 0)).result == mavlink.MAV_RESULT_UNSUPPORTED  # gyro off
        # WHEN the MAVLink signal is cut  THEN the injection is announced and accepted...
        conn.mav.command_long_send(conn.target_system, 0, INJECT, 0, 105, 1, 0, 0, 0, 0, 0)
        text = recv_until(conn, "STATUSTEXT", lambda m: "mavlink_signal off" in m.text, 3.0, "injection text")
        assert text.text == "Injected: mavlink_signal off, all instances"
        ack = recv_until(conn, "COMMAND_ACK", lambda m: m.command == INJECT, 3.0, "injection ACK")
        assert ack.result == mavlink.MAV_RESULT_ACCEPTED
        row = world.table[drone.ports.instance]
        assert row[VALID] == 1.0
        t_silent, alt_silent = float(row[TIME]), float(row[ALT])
        # ...and then nothing more arrives from the drone, whatever is sent to it
        time.sleep(0.2)  # let datagrams already in flight land
        while conn.recv_match(blocking=False) is not None:
            pass
        heard = []
        end = time.monotonic() + 2.0
        while time.monotonic() < end:
            conn.mav.command_long_send(conn.target_system, 0, mavlink.MAV_CMD_REQUEST_MESSAGE, 0, 0, 0, 0, 0, 0, 0, 0)
            msg = conn.recv_match(blocking=True, timeout=0.25)
            if msg is not None and msg.get_srcSystem() == drone.sysid:
                heard.append(msg.get_type())
        assert heard == []
        # THEN the drone flies on: its body advanced in time and held its altitude (Hold after takeoff)
        assert drone.process.alive()
        assert float(row[TIME]) - t_silent > 2.0, (t_silent, float(row[TIME]))
        assert abs(float(row[ALT]) - alt_silent) < 0.5, (alt_silent, float(row[ALT]))
    assert "MAVLink signal lost (injected failure)" in drone.process.log_tail(60)


def _download_fence(conn: mavutil.mavfile) -> list[mavlink.MAVLink_mission_item_int_message]:
    fence = mavlink.MAV_MISSION_TYPE_FENCE
    conn.mav.mission_request_list_send(conn.target_system, 1, fence)
    count = recv_until(conn, "MISSION_COUNT", lambda m: m.mission_type == fence, 5.0, "fence MISSION_COUNT").count
    items = []
    for seq in range(count):
        conn.mav.mission_request_int_send(conn.target_system, 1, seq, fence)
        items.append(recv_until(conn, "MISSION_ITEM_INT", lambda m: bool(m.seq == seq), 5.0, f"fence item {seq}"))  # noqa: B023
    conn.mav.mission_ack_send(conn.target_system, 1, mavlink.MAV_MISSION_ACCEPTED, fence)
    return items


def _upload_fence(conn: mavutil.mavfile, items: list[mavlink.MAVLink_mission_item_int_message]) -> int:
    """MISSION_COUNT of type FENCE, answer each request; the result of the final MISSION_ACK."""
    fence = mavlink.MAV_MISSION_TYPE_FENCE
    conn.mav.mission_count_send(conn.target_system, 1, len(items), fence)
    while True:
        msg = recv_until(conn, ["MISSION_REQUEST_INT", "MISSION_ACK"], lambda m: m.mission_type == fence, 5.0, "fence")
        if msg.get_type() == "MISSION_ACK":
            return int(msg.type)
        conn.mav.send(items[msg.seq])


@pytest.mark.timeout(60)
def test_pymavlink_fence_upload_download_refusal_and_clear(world_drone: WorldDrone) -> None:
    fence = mavlink.MAV_MISSION_TYPE_FENCE
    lat, lon = 473977420, 85455940

    def vertex(seq: int, count: int, d_lat: int, d_lon: int) -> mavlink.MAVLink_mission_item_int_message:
        return mavlink.MAVLink_mission_item_int_message(
            0, 1, seq, mavlink.MAV_FRAME_GLOBAL, mavlink.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION, 0, 1,
            count, 0, 0, 0, lat + d_lat, lon + d_lon, 0, fence,
        )  # fmt: skip

    with (
        drone_in_world(world_drone) as (drone, _world),
        mavlink_connection(VehicleLink.of(drone).pymavlink_url) as conn,
    ):
        wait_vehicle_heartbeat(conn, drone.sysid, 10.0)
        triangle = [vertex(0, 3, -900, -900), vertex(1, 3, -900, 900), vertex(2, 3, 900, 0)]
        for item in triangle:
            item.target_system = drone.sysid
        assert _upload_fence(conn, triangle) == mavlink.MAV_MISSION_ACCEPTED
        back = _download_fence(conn)
        assert [(m.command, m.param1, m.x, m.y) for m in back] == [(m.command, m.param1, m.x, m.y) for m in triangle]
        # A polygon of two vertices is refused, and the stored fence is kept.
        pair = [vertex(0, 2, 0, 0), vertex(1, 2, 900, 0)]
        for item in pair:
            item.target_system = drone.sysid
        assert _upload_fence(conn, pair) == mavlink.MAV_MISSION_INVALID_PARAM1
        assert len(_download_fence(conn)) == 3
        conn.mav.mission_clear_all_send(conn.target_system, 1, fence)
        ack = recv_until(conn, "MISSION_ACK", lambda m: m.mission_type == fence, 5.0, "fence clear ACK")
        assert ack.type == mavlink.MAV_MISSION_ACCEPTED and _download_fence(conn) == []


@pytest.mark.timeout(90)
async def test_mavsdk_uploads_downloads_and_clears_a_fence_and_injects_a_failure(world_drone: WorldDrone) -> None:
    from mavsdk.asyncio.plugins.failure import FailureAsync, FailureType, FailureUnit
    from mavsdk.asyncio.plugins.geofence import Circle, FenceType, GeofenceAsync, GeofenceData, Point, Polygon
    from mavsdk.asyncio.plugins.telemetry import FixType

    with drone_in_world(world_drone) as (drone, _world):
        link = VehicleLink.of(drone)
        async with connect(link.mavsdk_url, drone.sysid) as client:
            geofence = GeofenceAsync(client.system)
            lat, lon = 47.397742, 8.545594  # PX4 SITL's home
            square = [Point(lat - d_lat, lon + d_lon) for d_lat, d_lon in
                      ((-1e-4, -1e-4), (-1e-4, 1e-4), (1e-4, 1e-4), (1e-4, -1e-4))]  # fmt: skip
            data = GeofenceData(
                polygons=[Polygon(square, FenceType.INCLUSION)],
                circles=[Circle(Point(lat + 5e-5, lon), 3.0, FenceType.EXCLUSION)],
            )
            await call_within(geofence.upload_geofence(data), 10.0, "upload_geofence")
            back = await call_within(geofence.download_geofence(), 10.0, "download_geofence")
            assert len(back.polygons) == 1 and len(back.circles) == 1
            assert back.polygons[0].fence_type == FenceType.INCLUSION and len(back.polygons[0].points) == 4
            assert back.polygons[0].points[2].latitude_deg == pytest.approx(square[2].latitude_deg, abs=1e-7)
            assert back.circles[0].radius == pytest.approx(3.0) and back.circles[0].fence_type == FenceType.EXCLUSION
            await call_within(geofence.clear_geofence(), 10.0, "clear_geofence")
            after_clear = await call_within(geofence.download_geofence(), 10.0, "download after clear")
            assert after_clear.polygons == [] and after_clear.circles == []
            # MAVSDK's failure plugin reads SYS_FAILURE_EN when it starts (and refuses by itself, DISABLED, while it
            # is 0): enable injection first, as PX4's docs say. The drone's own refusal is the pymavlink test's.
            await call_within(client.param.set_param_int("SYS_FAILURE_EN", 1), 10.0, "set SYS_FAILURE_EN")
            failure = FailureAsync(client.system)
            await call_within(failure.inject(FailureUnit.SENSOR_GPS, FailureType.OFF, 0), 10.0, "inject")
            no_fix = await first_matching(
                client.telemetry.subscribe_gps_info, lambda g: g.num_satellites == 0, 5.0, "no sats"
            )
            assert no_fix.fix_type == FixType.NO_FIX
