"""The precomputed MAVLink 2 framing gives exactly pymavlink's bytes and messages, for every message class of the
dialect it lays out, with random field values (extremes, NaN and infinities included)."""

from __future__ import annotations

import math
import random
import struct
from typing import Any

import pytest
from pymavlink.dialects.v20 import common as mavlink

from sitl.protocol import framing
from sitl.protocol.framing import LAYOUTS, PARSED, crc_x25_table, layout_of, pack, parse_datagram

pytestmark = pytest.mark.timeout(60)

_INT_RANGES = {
    "int8_t": (-(2**7), 2**7 - 1),
    "uint8_t": (0, 2**8 - 1),
    "int16_t": (-(2**15), 2**15 - 1),
    "uint16_t": (0, 2**16 - 1),
    "int32_t": (-(2**31), 2**31 - 1),
    "uint32_t": (0, 2**32 - 1),
    "int64_t": (-(2**63), 2**63 - 1),
    "uint64_t": (0, 2**64 - 1),
}
_SPECIAL_FLOATS = (0.0, -0.0, math.nan, math.inf, -math.inf, 1e-40, 3.4e38, -3.4e38)


def _value(rng: random.Random, field_type: str) -> Any:
    if field_type in ("float", "double"):
        if rng.random() < 0.2:
            return rng.choice(_SPECIAL_FLOATS)
        value = rng.uniform(-1e6, 1e6) if rng.random() < 0.5 else rng.uniform(-1.0, 1.0)
        return struct.unpack("<f", struct.pack("<f", value))[0] if field_type == "float" else value
    lo, hi = _INT_RANGES[field_type]
    roll = rng.random()
    if roll < 0.2:
        return 0  # zeros at the end of the payload are trimmed: exercise the trimming
    if roll < 0.3:
        return rng.choice((lo, hi))
    return rng.randint(lo, hi)


def _random_message(rng: random.Random, cls: type[Any]) -> Any:
    counts = dict(zip(cls.ordered_fieldnames, cls.array_lengths, strict=True))  # array_lengths: wire order
    values = []
    for name, field_type in zip(cls.fieldnames, cls.fieldtypes, strict=True):
        count = counts[name]
        values.append([_value(rng, field_type) for _ in range(count)] if count else _value(rng, field_type))
    return cls(*values)


def _fields(msg: Any) -> str:
    return repr([getattr(msg, name) for name in msg.fieldnames])  # repr: NaN compares equal to NaN


def test_the_hot_messages_are_laid_out() -> None:
    hot = ("HEARTBEAT", "SYS_STATUS", "EXTENDED_SYS_STATE", "GPS_RAW_INT", "GLOBAL_POSITION_INT",
           "LOCAL_POSITION_NED", "ATTITUDE", "ATTITUDE_QUATERNION", "VFR_HUD", "ALTITUDE", "SYSTEM_TIME",
           "MISSION_CURRENT", "SET_POSITION_TARGET_LOCAL_NED", "COMMAND_ACK", "COMMAND_LONG")  # fmt: skip
    laid_out = {layout.cls.msgname for layout in LAYOUTS.values()}
    assert set(hot) <= laid_out
    assert "STATUSTEXT" not in laid_out and "PARAM_VALUE" not in laid_out  # text: pymavlink's packing


def test_every_laid_out_class_packs_to_pymavlinks_bytes() -> None:
    rng = random.Random(14)
    assert len(LAYOUTS) > 100
    for layout in LAYOUTS.values():
        for _ in range(40):
            msg = _random_message(rng, layout.cls)
            seq, sysid, compid = rng.randint(0, 255), rng.randint(1, 255), rng.randint(0, 255)
            encoder = mavlink.MAVLink(None, srcSystem=sysid, srcComponent=compid)
            encoder.seq = seq
            assert pack(layout, msg, seq, sysid, compid) == msg.pack(encoder), layout.cls.msgname


def test_an_all_zero_payload_keeps_one_byte() -> None:
    msg = mavlink.MAVLink_attitude_message(0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    layout = layout_of(msg)
    assert layout is not None
    frame = pack(layout, msg, 0, 1, 1)
    assert frame[1] == 1 and frame == msg.pack(mavlink.MAVLink(None, srcSystem=1, srcComponent=1))


def test_parsing_gives_pymavlinks_messages() -> None:
    rng = random.Random(41)
    classes = [layout.cls for layout in PARSED.values()]
    for _ in range(300):
        encoders = [mavlink.MAVLink(None, srcSystem=rng.randint(1, 255), srcComponent=1) for _ in range(3)]
        frames = []
        for _ in range(rng.randint(1, 6)):
            encoder = rng.choice(encoders)
            frames.append(_random_message(rng, rng.choice(classes)).pack(encoder))
            encoder.seq = (encoder.seq + 1) % 256
        data = b"".join(frames)
        fast = parse_datagram(data)
        parser = mavlink.MAVLink(None)
        parser.robust_parsing = True
        slow = parser.parse_buffer(data)
        assert fast is not None and slow is not None and len(fast) == len(slow)
        for a, b in zip(fast, slow, strict=True):
            assert type(a) is type(b)
            assert _fields(a) == _fields(b)
            assert vars(a.get_header()) == vars(b.get_header())
            assert (a.get_msgbuf(), a.get_payload(), a.get_crc(), a.get_type(), a.get_msgId(), a._signed) == (
                b.get_msgbuf(),
                b.get_payload(),
                b.get_crc(),
                b.get_type(),
                b.get_msgId(),
                b._signed,
            )


def test_anything_unusual_is_left_to_pymavlink() -> None:
    enc = mavlink.MAVLink(None, srcSystem=2, srcComponent=1)
    good = enc.global_position_int_encode(1, 2, 3, 4, 5, 6, 7, 8, 9).pack(enc)
    text = enc.statustext_encode(6, b"hello").pack(enc)
    v1 = enc.global_position_int_encode(1, 2, 3, 4, 5, 6, 7, 8, 9).pack(enc, force_mavlink1=True)
    array = enc.home_position_encode(1, 2, 3, 0, 0, 0, [1, 0, 0, 0], 0, 0, 0).pack(enc)
    bad_crc = good[:-1] + bytes((good[-1] ^ 1,))
    assert parse_datagram(good) is not None and parse_datagram(good + good) is not None
    assert parse_datagram(b"") == []
    for data in (good + text, good + v1, good + array, bad_crc, good + good[:5], b"\x00" + good, good + b"junk"):
        assert parse_datagram(data) is None, data
    signed = bytearray(good)
    signed[2] = mavlink.MAVLINK_IFLAG_SIGNED
    assert parse_datagram(bytes(signed)) is None


def test_the_table_crc_is_mavlinks_crc() -> None:
    rng = random.Random(3)
    for _ in range(200):
        data = bytes(rng.randrange(256) for _ in range(rng.randint(0, 80)))
        slow = mavlink.x25crc(data) if framing._mcrf4xx is None else None
        expected = slow.crc if slow is not None else framing.crc_x25(data, 0xFFFF)
        assert crc_x25_table(data) == expected
    assert crc_x25_table(b"123456789") == 0x6F91  # the CRC-16/MCRF4XX check value
