"""The ground station's fast reader (gcs/mavlink/wire.py) gives what pymavlink's parser gives, for every message class
of the dialect (arrays and texts too), signed and unsigned, several frames to a datagram, with random field values; and
leaves everything else to pymavlink (None)."""

from __future__ import annotations

import math
import random
import select
import socket
import struct
import time
from typing import Any

import pytest
from pymavlink.dialects.v20 import common as mavlink

from gcs.mavlink import signing
from gcs.mavlink.transport import GcsSocket
from gcs.mavlink.wire import _READERS, _crc, _crc_pymavlink, read_datagram

pytestmark = pytest.mark.timeout(60)

_INTS = {"int8_t": 8, "int16_t": 16, "int32_t": 32, "int64_t": 64}


def _value(rng: random.Random, field_type: str) -> Any:
    if field_type in ("float", "double"):
        value = rng.choice((0.0, -0.0, math.nan, math.inf, 1e-40, rng.uniform(-1e6, 1e6), rng.uniform(-1.0, 1.0)))
        return struct.unpack("<f", struct.pack("<f", value))[0] if field_type == "float" else value
    if rng.random() < 0.25:
        return 0  # trailing zeros are trimmed from MAVLink 2 payloads
    if field_type.startswith("u"):
        return rng.randrange(2 ** _INTS[field_type[1:]])
    bits = _INTS[field_type]
    return rng.randrange(-(2 ** (bits - 1)), 2 ** (bits - 1))


def _field(rng: random.Random, field_type: str, length: int) -> Any:
    if field_type == "char":  # a text, often shorter than its field (MAVLink pads it with NULs)
        return bytes(rng.randrange(32, 127) for _ in range(rng.randrange(max(length, 1) + 1)))
    if length:
        return [_value(rng, field_type) for _ in range(length)]
    return _value(rng, field_type)


def _random(rng: random.Random, cls: type[Any]) -> Any:
    """A message of ``cls`` with random values (its constructor takes the fields in ``fieldnames`` order; the array
    lengths are listed in wire order)."""
    lengths = dict(zip(cls.ordered_fieldnames, cls.array_lengths, strict=True))
    return cls(*[_field(rng, t, lengths[n]) for n, t in zip(cls.fieldnames, cls.fieldtypes, strict=True)])


def _as_pymavlink_reads(data: bytes) -> list[Any]:
    parser = mavlink.MAVLink(None)
    parser.robust_parsing = True
    return parser.parse_buffer(data) or []


def _same(ours: Any, theirs: Any) -> None:
    assert type(ours) is type(theirs)
    assert repr([getattr(ours, n) for n in ours.fieldnames]) == repr([getattr(theirs, n) for n in theirs.fieldnames])
    assert ours.get_msgbuf() == theirs.get_msgbuf()
    assert ours._payload == theirs._payload and ours._crc == theirs._crc and ours._signed == theirs._signed
    assert vars(ours._header) == vars(theirs._header)
    assert (ours.get_srcSystem(), ours.get_srcComponent(), ours.get_seq()) == (
        theirs.get_srcSystem(), theirs.get_srcComponent(), theirs.get_seq(),
    )  # fmt: skip


def test_the_drones_telemetry_is_read_by_layouts() -> None:
    hot = (
        "HEARTBEAT",
        "SYS_STATUS",
        "GLOBAL_POSITION_INT",
        "LOCAL_POSITION_NED",
        "ATTITUDE",
        "COMMAND_ACK",
        "VFR_HUD",
        "EXTENDED_SYS_STATE",
        "ATTITUDE_QUATERNION",  # an array
        "STATUSTEXT",  # a text
    )
    for name in hot:
        assert getattr(mavlink, f"MAVLINK_MSG_ID_{name}") in _READERS, name


@pytest.mark.parametrize("signed", [False, True])
def test_every_message_reads_as_pymavlink_reads_it(signed: bool) -> None:
    rng = random.Random(7 + signed)
    sender = mavlink.MAVLink(None, srcSystem=42, srcComponent=1)
    if signed:
        signing.enable(sender, bytes(range(32)), 1_700_000_000.0)
    for msg_id, reader in sorted(_READERS.items()):
        for _ in range(3):
            sender.srcSystem, sender.srcComponent = rng.randrange(1, 255), rng.randrange(256)
            frames = [_random(rng, reader.cls).pack(sender) for _ in range(rng.randrange(1, 4))]
            datagram = b"".join(frames)
            ours, theirs = read_datagram(datagram), _as_pymavlink_reads(datagram)
            assert ours is not None, reader.cls.__name__
            assert len(ours) == len(theirs) == len(frames), msg_id
            for a, b in zip(ours, theirs, strict=True):
                _same(a, b)


def test_anything_else_is_left_to_pymavlink() -> None:
    rng = random.Random(3)
    sender = mavlink.MAVLink(None, srcSystem=7, srcComponent=1)
    good = mavlink.MAVLink_attitude_message(1, 0.1, 0.2, 0.3, 0.0, 0.0, 0.0).pack(sender)
    unknown = bytearray(good)
    unknown[7:10] = (60000).to_bytes(3, "little")  # a message id the dialect does not have
    bad_crc = bytearray(good)
    bad_crc[-1] ^= 0xFF
    for datagram in (
        bytes(unknown),
        good + bytes(unknown),  # one frame of a kind read here, one not: all of it goes to pymavlink
        bytes(bad_crc),
        good[:-1],  # truncated
        good + b"\x00",
        bytes(rng.randrange(256) for _ in range(40)),  # garbage
        b"\xfe" + good[1:],  # MAVLink 1 magic
    ):
        assert read_datagram(datagram) is None, datagram
    assert read_datagram(b"") == []


def test_the_checksum_without_fastcrc_is_pymavlinks() -> None:
    rng = random.Random(11)
    for _ in range(50):
        data = bytes(rng.randrange(256) for _ in range(rng.randrange(1, 60)))
        assert _crc_pymavlink(data, 0xFFFF) == mavlink.x25crc(data).crc == _crc(data, 0xFFFF)


def test_the_ground_station_socket_reads_both_ways_alike() -> None:
    # GIVEN a ground-station socket and a drone's datagrams, some read by layouts, some by pymavlink
    station = GcsSocket()
    drone = mavlink.MAVLink(None, srcSystem=9, srcComponent=1)
    out = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    out.bind(("127.0.0.1", 0))
    try:
        datagrams = [
            mavlink.MAVLink_attitude_message(5, 0.1, -0.2, 0.3, 0.0, 0.5, 0.0).pack(drone),
            mavlink.MAVLink_statustext_message(6, b"Takeoff detected").pack(drone),
            b"\x00\x01garbage",
            mavlink.MAVLink_heartbeat_message(2, 12, 209, 0, 4, 3).pack(drone),
        ]
        for d in datagrams:
            out.sendto(d, ("127.0.0.1", station.port))
        # WHEN it reads them THEN every message comes, in order, the garbage dropped, the drone's address learnt
        got: list[Any] = []
        deadline = time.monotonic() + 5.0
        while len(got) < 3 and (left_s := deadline - time.monotonic()) > 0:
            select.select([station.sock], [], [], left_s)  # until a datagram is there to read
            got.extend(msg for msg, _ in station.receive())
        assert [m.get_type() for m in got] == ["ATTITUDE", "STATUSTEXT", "HEARTBEAT"]
        assert station.addresses[9] == out.getsockname()
    finally:
        out.close()
        station.sock.close()
