"""The ground station's outbox: queued traffic leaves as few datagrams as possible, frames whole and in order."""

from __future__ import annotations

import socket
from collections.abc import Iterator

import pytest
from pymavlink.dialects.v20 import common as mavlink

from gcs.mavlink.transport import GcsSocket
from swarmcommon.datagrams import MAX_BATCH_BYTES


@pytest.fixture
def pair() -> Iterator[tuple[GcsSocket, socket.socket]]:
    gcs = GcsSocket()
    drone = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    drone.bind(("127.0.0.1", 0))
    drone.settimeout(2.0)
    gcs.addresses[7] = drone.getsockname()
    try:
        yield gcs, drone
    finally:
        gcs.close()
        drone.close()


def _datagrams(sock: socket.socket) -> list[bytes]:
    out = [sock.recv(65535)]
    sock.settimeout(0.05)
    try:
        while True:
            out.append(sock.recv(65535))
    except TimeoutError:
        return out


def _parse(data: bytes) -> list[object]:
    parser = mavlink.MAVLink(None)
    return [m for m in parser.parse_buffer(data) or [] if m.get_type() != "BAD_DATA"]


def _setpoint(k: int) -> mavlink.MAVLink_message:
    return mavlink.MAVLink_set_position_target_local_ned_message(k, 7, 1, 1, 0, float(k), 0, 0, 0, 0, 0, 0, 0, 0, 0, 0)


def test_queued_frames_leave_in_one_datagram_in_order(pair: tuple[GcsSocket, socket.socket]) -> None:
    gcs, drone = pair
    for k in range(5):
        assert gcs.queue(7, _setpoint(k))
    assert gcs.queued
    assert gcs.datagrams_sent == 0  # nothing leaves before the flush
    gcs.flush()
    assert not gcs.queued
    datagrams = _datagrams(drone)
    assert len(datagrams) == 1
    assert [m.time_boot_ms for m in _parse(datagrams[0])] == [0, 1, 2, 3, 4]


def test_a_large_batch_is_split_at_frame_boundaries(pair: tuple[GcsSocket, socket.socket]) -> None:
    gcs, drone = pair
    n = 120  # 120 frames of 63 bytes: more than five datagrams' worth
    for k in range(n):
        gcs.queue(7, _setpoint(k))
    gcs.flush()
    datagrams = _datagrams(drone)
    assert len(datagrams) > 1
    assert all(len(d) <= MAX_BATCH_BYTES for d in datagrams)
    frames = [m for d in datagrams for m in _parse(d)]  # every datagram parses on its own: no frame is cut
    assert [m.time_boot_ms for m in frames] == list(range(n))


def test_an_unknown_drone_is_not_queued(pair: tuple[GcsSocket, socket.socket]) -> None:
    gcs, _drone = pair
    assert not gcs.queue(99, _setpoint(0))
    assert not gcs.queued


def test_a_message_sent_at_once_leaves_after_what_was_queued_before_it(pair: tuple[GcsSocket, socket.socket]) -> None:
    gcs, drone = pair
    gcs.queue(7, _setpoint(1))
    gcs.send(7, _setpoint(2))
    assert not gcs.queued
    frames = [m for d in _datagrams(drone) for m in _parse(d)]
    assert [m.time_boot_ms for m in frames] == [1, 2]


def test_receive_reads_a_bounded_number_of_datagrams_per_call() -> None:
    """A flood must not keep one call reading for ever: the caller's loop gets back control, nothing is lost."""
    gcs = GcsSocket()
    drone = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    encoder = mavlink.MAVLink(None, srcSystem=7, srcComponent=1)
    try:
        for k in range(25):
            drone.sendto(_setpoint(k).pack(encoder), ("127.0.0.1", gcs.port))
        first = gcs.receive(max_datagrams=10)
        rest = gcs.receive(max_datagrams=100)
        assert [m.time_boot_ms for m, _ in first] == list(range(10))
        assert [m.time_boot_ms for m, _ in rest] == list(range(10, 25))
        assert gcs.receive() == []
    finally:
        gcs.close()
        drone.close()


def test_a_truncated_datagram_does_not_cost_the_senders_next_frame() -> None:
    """A datagram holds whole frames: the fragment a cut datagram leaves must not swallow the next one's bytes."""
    gcs = GcsSocket()
    drone = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    encoder = mavlink.MAVLink(None, srcSystem=7, srcComponent=1)
    try:
        # GIVEN a drone whose first datagram was cut in the middle of a frame
        drone.sendto(_setpoint(1).pack(encoder)[:20], ("127.0.0.1", gcs.port))
        # WHEN its next datagram holds two whole frames
        drone.sendto(_setpoint(2).pack(encoder) + _setpoint(3).pack(encoder), ("127.0.0.1", gcs.port))
        # THEN both arrive
        messages = gcs.receive()
        assert [m.time_boot_ms for m, _ in messages] == [2, 3]
    finally:
        gcs.close()
        drone.close()
