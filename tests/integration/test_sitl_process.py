"""The ``sitl`` process as an operating-system citizen: it stops cleanly on signals and refuses a taken port.

A swarm supervisor, a test harness and a user at a terminal all stop drones with SIGINT or SIGTERM and start them
on ports that may already be in use; the drone must exit with status 0 and free its ports on a signal, and must
say in one line why it cannot start rather than run half-bound or print a traceback.
"""

from __future__ import annotations

import signal
import socket
import subprocess
import time

import pytest
from pymavlink.dialects.v20 import common as mavlink

from tests.integration.mavlink_client import mavlink_connection, wait_vehicle_heartbeat
from tests.integration.sitl_process import (
    LOOPBACK,
    DronePorts,
    InstanceAllocator,
    SpawnDrones,
    sitl_command,
    udp_port_is_free,
)
from tests.integration.vehicle_link import VehicleLink

pytestmark = [pytest.mark.sim_only, pytest.mark.timeout(60)]

STOP_WITHIN_S = 5.0


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_a_signal_stops_the_drone_with_exit_code_0_and_frees_its_ports(
    spawn_drones: SpawnDrones, sig: signal.Signals
) -> None:
    # GIVEN a running drone with a client talking to it
    (drone,) = spawn_drones()
    with mavlink_connection(VehicleLink.of(drone).pymavlink_url) as conn:
        wait_vehicle_heartbeat(conn, drone.sysid, 5.0)
    # WHEN it gets the signal
    drone.process.signal(sig)
    # THEN it exits with status 0 promptly, says why, and its ports can be bound again
    try:
        code = drone.process.wait(STOP_WITHIN_S)
    except subprocess.TimeoutExpired:
        pytest.fail(f"sitl did not exit within {STOP_WITHIN_S} s of {sig.name}:\n{drone.process.log_tail()}")
    assert code == 0, drone.process.log_tail()
    assert sig.name in drone.process.log_tail()
    assert udp_port_is_free(drone.ports.api_bind) and udp_port_is_free(drone.ports.gcs_bind)


def test_a_drone_whose_api_port_is_taken_exits_with_one_line_naming_the_port(
    instance_allocator: InstanceAllocator,
) -> None:
    # GIVEN a free instance whose API port someone else then binds
    (instance,) = instance_allocator.take()
    try:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as squatter:
            api_port = DronePorts(instance=instance).api_bind
            squatter.bind((LOOPBACK, api_port))
            # WHEN a drone is started on that instance
            result = subprocess.run(
                [*sitl_command(), "--instance", str(instance), "--no-gcs", "--speed", "4"],
                capture_output=True,
                text=True,
                timeout=30,
                stdin=subprocess.DEVNULL,
            )
    finally:
        instance_allocator.give_back(instance)
    # THEN it exits non-zero with one line on stderr that names the port, and no traceback
    assert result.returncode != 0, result
    errors = result.stderr.strip().splitlines()
    assert len(errors) == 1 and str(api_port) in errors[0], result.stderr
    assert "Traceback" not in result.stderr


def test_streams_due_together_leave_in_one_datagram_that_pymavlink_reads_whole(spawn_drones: SpawnDrones) -> None:
    """Telemetry due at the same tick (the four 10 Hz streams, with the 5 Hz ones every other tick) shares a
    datagram, as ArduPilot's UDP links pack frames: fewer system calls and wake-ups on both sides. Every frame must
    still reach a client that reads one message at a time."""
    (drone,) = spawn_drones()
    link = VehicleLink.of(drone)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as client:
        client.bind((LOOPBACK, drone.ports.api_remote))
        client.settimeout(5.0)
        parser = mavlink.MAVLink(None)
        frames_per_datagram: list[int] = []
        kinds: set[str] = set()
        end = time.monotonic() + link.window_s(2.0)
        while time.monotonic() < end:
            messages = [m for m in parser.parse_buffer(client.recv(65535)) or [] if m.get_type() != "BAD_DATA"]
            frames_per_datagram.append(len(messages))
            kinds |= {m.get_type() for m in messages}
    # THEN the 10 Hz streams arrive together, and there are far fewer datagrams than messages
    assert {"GLOBAL_POSITION_INT", "LOCAL_POSITION_NED", "ATTITUDE", "ATTITUDE_QUATERNION"} <= kinds, kinds
    assert max(frames_per_datagram) >= 4, frames_per_datagram
    assert len(frames_per_datagram) * 2 < sum(frames_per_datagram), frames_per_datagram
    # AND a pymavlink client reading one message at a time gets them all, in order
    with mavlink_connection(link.pymavlink_url) as conn:
        wait_vehicle_heartbeat(conn, drone.sysid, 5.0)
        seen: list[str] = []
        end = time.monotonic() + link.window_s(1.0)
        while time.monotonic() < end:
            msg = conn.recv_match(blocking=True, timeout=0.5)
            if msg is not None and msg.get_srcSystem() == drone.sysid:
                seen.append(msg.get_type())
    assert seen.count("GLOBAL_POSITION_INT") >= 8 and seen.count("ATTITUDE_QUATERNION") >= 8, seen
