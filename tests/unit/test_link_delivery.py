"""The link model on a drone's real UDP links: what it loses is never handled or sent, what it delays waits for
its simulated time, and a delay line hands out in delivery order."""

from __future__ import annotations

import selectors
import socket

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink

from sitl.params import ParamStore
from sitl.process.mavlink_io import LinkConfig, MavlinkEndpoint
from sitl.protocol import Identity
from sitl.protocol.testing import FakeVehicle, Wire
from sitl.world.linkmodel import DelayLine, LinkChannel, LinkImpairment
from tests.unit.test_protocol_commands import MAVSDK, SYSID

pytestmark = pytest.mark.timeout(30)


def test_a_delay_line_hands_out_what_is_due_in_delivery_order_and_ties_in_arrival_order() -> None:
    line: DelayLine[str] = DelayLine()
    for due_s, item in ((0.30, "c"), (0.10, "a"), (0.20, "b1"), (0.20, "b2")):
        line.push(due_s, item)
    assert line.next_due_s == pytest.approx(0.10)
    assert line.pop_due(0.05) == []
    assert line.pop_due(0.20) == ["a", "b1", "b2"]
    assert len(line) == 1 and line.pop_due(1.0) == ["c"] and line.next_due_s == float("inf")


def _channel(**settings: float) -> LinkChannel:
    return LinkChannel(LinkImpairment(**settings), np.random.default_rng(7))


class _Client:
    """A ground station on a loopback port of its own, speaking to one drone's link."""

    def __init__(self) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.setblocking(False)
        self.wire = Wire(*MAVSDK)

    def send(self, msg: mavlink.MAVLink_message, port: int) -> None:
        self.sock.sendto(self.wire(msg).get_msgbuf(), ("127.0.0.1", port))

    def replies(self) -> list[mavlink.MAVLink_message]:
        parser = mavlink.MAVLink(None)
        out: list[mavlink.MAVLink_message] = []
        try:
            while data := self.sock.recv(65535):
                out += parser.parse_buffer(data) or []
        except BlockingIOError:
            pass
        return out


def _endpoint(client: _Client) -> tuple[MavlinkEndpoint, FakeVehicle]:
    vehicle = FakeVehicle()
    link = LinkConfig(name="GCS", bind=("127.0.0.1", 0), remote=client.sock.getsockname())
    return MavlinkEndpoint(Identity(sysid=SYSID), vehicle, ParamStore(()), [link]), vehicle


def _await_readable(sock: socket.socket) -> None:
    """Until a datagram sent on loopback can be read (within a second)."""
    with selectors.DefaultSelector() as selector:
        selector.register(sock, selectors.EVENT_READ)
        assert selector.select(1.0), "nothing arrived"


def _gcs_heartbeat() -> mavlink.MAVLink_heartbeat_message:
    return mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0, 3)


def test_a_delayed_uplink_message_is_handled_at_its_delivery_time_and_a_lost_one_never() -> None:
    client = _Client()
    endpoint, vehicle = _endpoint(client)
    try:
        # GIVEN a drone whose ground-station link delivers 40 ms late
        endpoint.impair({("gcs", "up"): _channel(latency_ms=40.0)})
        # WHEN a ground-station HEARTBEAT arrives at t = 1.000 s
        client.send(_gcs_heartbeat(), endpoint.links[0].port)
        _await_readable(endpoint.links[0].sock)
        endpoint.receive(1.000)
        # THEN the vehicle hears it only at the first step at or after 1.040 s
        endpoint.deliver_due(1.036)
        assert vehicle.gcs_heartbeats == []
        endpoint.deliver_due(1.040)
        assert vehicle.gcs_heartbeats == [pytest.approx(1.040)]
        # AND with every frame lost, nothing more is heard
        endpoint.impair({("gcs", "up"): _channel(loss=1.0)})
        client.send(_gcs_heartbeat(), endpoint.links[0].port)
        _await_readable(endpoint.links[0].sock)
        endpoint.receive(2.0)
        endpoint.deliver_due(3.0)
        assert len(vehicle.gcs_heartbeats) == 1
        ((key, counts),) = endpoint.link_counters().items()
        assert key == ("gcs", "up") and counts.frames_offered == 1 and counts.lost_random == 1
    finally:
        endpoint.close()
        client.sock.close()


def test_downlink_frames_wait_in_the_outbox_until_their_time_and_lost_ones_are_never_sent() -> None:
    client = _Client()
    endpoint, _vehicle = _endpoint(client)
    try:
        # GIVEN a drone whose telemetry reaches the ground station 100 ms late
        endpoint.impair({("gcs", "down"): _channel(latency_ms=100.0)})
        # WHEN it polls its streams at t = 1.0 s
        link = endpoint.links[0]
        endpoint.poll(1.0)
        # THEN nothing has left yet; at 1.1 s everything polled at 1.0 s leaves at once
        assert link.sent == 0
        endpoint.deliver_due(1.099)
        assert link.sent == 0
        endpoint.deliver_due(1.1)
        assert link.sent > 0
        _await_readable(client.sock)
        sent = client.replies()
        assert "HEARTBEAT" in {m.get_type() for m in sent}
        counts = endpoint.link_counters()[("gcs", "down")]
        assert counts.delayed == counts.frames_offered == len(sent)
        assert counts.total_delay_s == pytest.approx(0.1 * len(sent))
    finally:
        endpoint.close()
        client.sock.close()


def test_neighbour_positions_go_through_the_neighbour_channel_whatever_link_brings_them() -> None:
    client = _Client()
    endpoint, vehicle = _endpoint(client)
    try:
        # GIVEN a perfect ground-station class and a neighbour class that loses everything
        endpoint.impair({("neighbour", "up"): _channel(loss=1.0)})
        # WHEN another drone's GLOBAL_POSITION_INT (relayed, its own sysid) and a ground-station HEARTBEAT arrive
        neighbour = Wire(SYSID + 1, 1)
        position = mavlink.MAVLink_global_position_int_message(1000, 473977420, 85455940, 491000, 3000, 0, 0, 0, 0)
        both = bytes(neighbour(position).get_msgbuf()) + bytes(client.wire(_gcs_heartbeat()).get_msgbuf())
        client.sock.sendto(both, ("127.0.0.1", endpoint.links[0].port))  # one datagram: both read at once
        _await_readable(endpoint.links[0].sock)
        endpoint.receive(1.0)
        # THEN the neighbour table stays empty while the HEARTBEAT went through untouched
        assert endpoint.neighbours.entries(1.0) == []
        assert vehicle.gcs_heartbeats == [pytest.approx(1.0)]
        counts = endpoint.link_counters()
        assert set(counts) == {("neighbour", "up")} and counts[("neighbour", "up")].lost_random == 1
        # AND with the neighbour class perfect again, the same report reaches the table
        endpoint.impair({})
        client.sock.sendto(neighbour(position).get_msgbuf(), ("127.0.0.1", endpoint.links[0].port))
        _await_readable(endpoint.links[0].sock)
        endpoint.receive(1.1)
        assert [n.sysid for n in endpoint.neighbours.entries(1.1)] == [SYSID + 1]
    finally:
        endpoint.close()
        client.sock.close()
