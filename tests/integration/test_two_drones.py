"""Two drones side by side, as the swarm runs them: separate identities, separate ports, separate commands.

One ground station (a single MAVSDK instance) talks to both at once. MAVSDK may send a message on every
connection, so a drone that ignores ``target_system`` would arm or change parameters when its neighbour is told
to; that is exactly what a swarm cannot afford.
"""

from __future__ import annotations

import asyncio
import socket
import time

import pytest
from pymavlink.dialects.v20 import common as mavlink

from tests.integration.mavsdk_client import (
    connect_many,
    recording,
    take_off,
    wait_landed_and_disarmed,
    wait_ready_to_arm,
)
from tests.integration.sitl_process import LOOPBACK, SitlDrone, SpawnDrones
from tests.integration.vehicle_link import VehicleLink

pytestmark = [pytest.mark.sim_only, pytest.mark.timeout(120)]

LISTEN_S = 1.0
B_RTL_ALT_M = 7.0


def _sources_heard(sock: socket.socket, listen_s: float) -> set[tuple[int, int]]:
    """(sysid, compid) of every MAVLink message arriving on ``sock`` within ``listen_s``."""
    parser = mavlink.MAVLink(None)
    parser.robust_parsing = True
    heard: set[tuple[int, int]] = set()
    deadline = time.monotonic() + listen_s
    while (remaining := deadline - time.monotonic()) > 0:
        sock.settimeout(remaining)
        try:
            data = sock.recv(65535)
        except TimeoutError:
            break
        heard.update((m.get_srcSystem(), m.get_srcComponent()) for m in parser.parse_buffer(data) or [])
    return heard


def _api_sources(drone: SitlDrone, listen_s: float) -> set[tuple[int, int]]:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind((LOOPBACK, drone.ports.api_remote))
        return _sources_heard(sock, listen_s)


async def test_two_drones_have_distinct_sysids_and_ports_and_only_the_commanded_one_flies(
    spawn_drones: SpawnDrones,
) -> None:
    # GIVEN two drones on adjacent instances a and a+1
    a, b = spawn_drones(2)
    assert b.ports.instance == a.ports.instance + 1
    # THEN each streams on its own API port and its own ground-station link, with its own sysid only
    assert a.sysid != b.sysid
    assert _api_sources(a, LISTEN_S / a.speed_factor + 0.5) == {(a.sysid, 1)}
    assert _api_sources(b, LISTEN_S / b.speed_factor + 0.5) == {(b.sysid, 1)}
    assert _sources_heard(a.gcs_sink, 0.5) == {(a.sysid, 1)}
    assert _sources_heard(b.gcs_sink, 0.5) == {(b.sysid, 1)}

    link_a, link_b = VehicleLink.of(a), VehicleLink.of(b)
    async with connect_many([(link_a.mavsdk_url, a.sysid), (link_b.mavsdk_url, b.sysid)]) as (drone_a, drone_b):
        # GIVEN one ground station connected to both, both healthy
        await asyncio.gather(
            wait_ready_to_arm(drone_a, link_a.wall_s(10)), wait_ready_to_arm(drone_b, link_b.wall_s(10))
        )
        rtl_alt_a_m = await drone_a.action.get_return_to_launch_altitude()
        async with (
            recording(drone_b.telemetry.subscribe_armed) as b_armed,
            recording(drone_b.telemetry.subscribe_in_air) as b_in_air,
        ):
            # WHEN only drone a is armed and told to take off, and only drone b gets a new RTL altitude
            await take_off(drone_a, link_a.wall_s(20))
            await drone_b.action.set_return_to_launch_altitude(B_RTL_ALT_M)
            # THEN drone a flies, and drone b took the new parameter while drone a kept its own
            assert await drone_a.telemetry.in_air()
            assert await drone_b.action.get_return_to_launch_altitude() == pytest.approx(B_RTL_ALT_M)
            assert await drone_a.action.get_return_to_launch_altitude() == pytest.approx(rtl_alt_a_m)

            # WHEN drone a lands
            await drone_a.action.land()
            await wait_landed_and_disarmed(drone_a, link_a.wall_s(30))
        # THEN drone b stayed on the ground and disarmed the whole time
        assert b_armed and b_in_air, "no telemetry from drone b while drone a flew"
        assert not any(b_armed), f"drone b armed while only drone a was commanded: {b_armed}"
        assert not any(b_in_air), f"drone b was in the air: {b_in_air}"
        assert a.process.alive() and b.process.alive()
