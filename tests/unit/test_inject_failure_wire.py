"""MAV_CMD_INJECT_FAILURE and ground-station HEARTBEATs on the wire, and a link fault silencing real UDP links."""

from __future__ import annotations

import math
import socket
import time

import pytest
from pymavlink.dialects.v20 import common as mavlink

from sitl.autopilot.vehicle_api import CommandOutcome, CommandResult, InjectFailure
from sitl.faults.failures import FailureType, FailureUnit, FaultError, FaultState, apply_request, decode_request
from sitl.params import ParamStore
from sitl.process.mavlink_io import LinkConfig, MavlinkEndpoint
from sitl.protocol import Identity
from sitl.protocol.core import MAVLinkMessage
from sitl.protocol.testing import FakeVehicle, Wire, of_type
from tests.unit.test_protocol_commands import MAVSDK, SYSID, Rig, long

pytestmark = pytest.mark.timeout(30)

INJECT = mavlink.MAV_CMD_INJECT_FAILURE


def test_accepted_injection_is_announced_before_its_ack() -> None:
    rig = Rig()
    rig.vehicle.refuse(InjectFailure, CommandResult.ACCEPTED, "Injected: motor off, instances 1")
    out = rig.send(long(INJECT, 101, 1, 1))
    assert [m.get_type() for m in out][:2] == ["STATUSTEXT", "COMMAND_ACK"]
    assert out[0].text == "Injected: motor off, instances 1" and out[1].result == mavlink.MAV_RESULT_ACCEPTED
    assert rig.vehicle.requests[-1] == InjectFailure(unit=101, failure_type=1, instance=1)


def test_refused_injection_is_denied_with_the_reason_and_nan_instance_means_all() -> None:
    rig = Rig()
    rig.vehicle.refuse(InjectFailure, CommandResult.DENIED, "Failure injection disabled")
    out = rig.send(long(INJECT, 4, 1, float("nan")))
    (ack,) = of_type(out, "COMMAND_ACK")
    assert ack.result == mavlink.MAV_RESULT_DENIED
    assert [m.text for m in of_type(out, "STATUSTEXT")] == ["Failure injection disabled"]
    assert rig.vehicle.requests[-1] == InjectFailure(unit=4, failure_type=1, instance=0)


def test_gcs_heartbeats_reach_the_vehicle_and_others_do_not() -> None:
    rig = Rig()
    rig.send(mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0, 3))
    t_gcs = rig.now_s
    rig.send(mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_PX4, 0, 0, 0, 3))
    assert rig.vehicle.gcs_heartbeats == [t_gcs]


def test_fault_decoding_and_state() -> None:
    request = decode_request(101, 1, 0)
    state, text = apply_request(FaultState(), request, rotor_count=4, battery_level=2, battery_thresholds={})
    assert state.motors_off == frozenset(range(4)) and text == "Injected: motor off, all instances"
    glitch = decode_request(int(FailureUnit.SENSOR_GPS), int(FailureType.WRONG), 0)
    state, _ = apply_request(state, glitch, rotor_count=4, battery_level=2, battery_thresholds={})
    assert state.gps.value == "glitch" and state.motors_off == frozenset(range(4))  # faults accumulate
    for unit, kind, unsupported in ((1, 1, True), (101, 4, True), (105, 4, True), (None, 1, False)):
        try:
            decode_request(unit, kind, 0)
        except FaultError as exc:
            assert exc.unsupported is unsupported
        else:
            raise AssertionError(f"unit {unit} type {kind} accepted")
    battery = decode_request(100, 4, 0)
    state, text = apply_request(FaultState(), battery, rotor_count=4, battery_level=1,
                                battery_thresholds={"BAT_LOW_THR": 0.15})  # fmt: skip
    assert state.battery_remaining == pytest.approx(0.14) and text == "Injected: battery wrong, all instances"


def _recv_all(sock: socket.socket, seconds: float, endpoint: MavlinkEndpoint, now_s: float) -> int:
    """Datagrams ``sock`` receives while the endpoint is driven for ``seconds`` of wall time."""
    count = 0
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        endpoint.receive(now_s)
        endpoint.poll(now_s)
        now_s += 0.02
        try:
            while sock.recv(65535):
                count += 1
        except BlockingIOError:
            pass
        time.sleep(0.02)
    return count


def test_a_link_fault_silences_every_link_after_the_accepting_reply() -> None:
    vehicle = FakeVehicle()
    clients = [socket.socket(socket.AF_INET, socket.SOCK_DGRAM) for _ in range(2)]
    for c in clients:
        c.bind(("127.0.0.1", 0))
        c.setblocking(False)
    links = [LinkConfig(name=f"link{i}", bind=("127.0.0.1", 0), remote=c.getsockname()) for i, c in enumerate(clients)]
    endpoint = MavlinkEndpoint(Identity(sysid=SYSID), vehicle, ParamStore(()), links)
    try:
        assert all(_recv_all(c, 0.3, endpoint, 1.0) > 0 for c in clients)  # both links stream
        # The vehicle accepts a link fault; the client hears the ACK, then nothing on either link.
        vehicle.refuse(InjectFailure, CommandResult.ACCEPTED, "Injected: mavlink_signal off, all instances")
        original = vehicle.command

        def command(request: object, now_s: float) -> CommandOutcome:
            outcome = original(request, now_s)  # type: ignore[arg-type]
            vehicle.link_silent_until_s = math.inf
            return outcome

        vehicle.command = command  # type: ignore[method-assign]
        wire = Wire(*MAVSDK)
        clients[0].sendto(wire(long(INJECT, 105, 1, 0)).get_msgbuf(), ("127.0.0.1", endpoint.links[0].port))
        time.sleep(0.05)
        endpoint.receive(2.0)
        replies: list[MAVLinkMessage] = []
        parser = mavlink.MAVLink(None)
        try:
            while data := clients[0].recv(65535):
                replies += parser.parse_buffer(data) or []
        except BlockingIOError:
            pass
        assert [m.result for m in of_type(replies, "COMMAND_ACK")] == [mavlink.MAV_RESULT_ACCEPTED]
        assert endpoint.silenced
        sent_at_silence = [link.sent for link in endpoint.links]
        # Whatever a client sends now is read and dropped, unanswered.
        for _ in range(3):
            clients[1].sendto(wire(long(mavlink.MAV_CMD_REQUEST_MESSAGE, 0)).get_msgbuf(),
                              ("127.0.0.1", endpoint.links[1].port))  # fmt: skip
        endpoint.statustext(2, "nobody hears this")
        assert [_recv_all(c, 0.4, endpoint, 3.0) for c in clients] == [0, 0]
        assert [link.sent for link in endpoint.links] == sent_at_silence
        assert endpoint.links[1].received == 0  # drained unparsed
    finally:
        endpoint.close()
        for c in clients:
            c.close()
