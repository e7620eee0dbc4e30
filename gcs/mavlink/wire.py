"""The ground station's own fast reading of the datagrams its drones send: MAVLink 2 frames of fixed-size numeric
messages decoded with layouts precomputed from pymavlink's classes, without pymavlink's byte-by-byte parser.

A supervisor reads every drone's telemetry (HEARTBEAT, SYS_STATUS, GLOBAL_POSITION_INT, LOCAL_POSITION_NED,
ATTITUDE, ...) at its stream rates, and in lockstep it reads them once a frame: through pymavlink's state machine that
was about a fifth of its CPU at nine drones. Here a datagram is split into frames by their headers, each frame's
CRC (with the message's CRC extra) is checked with the same C routine pymavlink uses, and its payload is unpacked by
the class's own ``struct`` layout into an object of the class, with the header, buffer and CRC pymavlink's parser
would give it (a signed frame keeps its signature in the buffer; like the ground station's parsers, nothing checks
it here). A datagram with anything else in it (MAVLink 1, an unknown message, a text or array field, a bad CRC, a
truncated frame, garbage) returns None, and the caller gives the whole datagram to pymavlink's parser, so unusual
input is treated exactly as it always was.

This is written apart from the drone's own reader (sitl/protocol/framing.py) on purpose: the two sides decode each
other's bytes, and a decoding bug shared by both would cancel out in every test (docs/architecture.md).
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Final

from pymavlink.dialects.v20 import common as mavlink

_HEADER: Final = struct.Struct("<BBBBBBBHB")  # magic, length, incompat, compat, seq, sysid, compid, id (24 bits)
_CRC: Final = struct.Struct("<H")
_HEADER_LEN: Final = _HEADER.size
_SIGNED: Final = mavlink.MAVLINK_IFLAG_SIGNED
_SIGNATURE_LEN: Final = mavlink.MAVLINK_SIGNATURE_BLOCK_LEN


def _crc_pymavlink(data: bytes, crc: int) -> int:
    """pymavlink's own X.25 checksum object, where its C routine (fastcrc) is not installed."""
    checksum = mavlink.x25crc()
    checksum.crc = crc
    checksum.accumulate(data)
    return int(checksum.crc)


_crc: Callable[[bytes, int], int] = getattr(mavlink, "mcrf4xx", None) or _crc_pymavlink


@dataclass(frozen=True, slots=True)
class _Reader:
    """How to read one message class: its constructor, CRC extra, payload layout and the order of its arguments."""

    cls: type[Any]
    crc_extra: bytes
    payload: struct.Struct
    arg_order: tuple[int, ...]  # constructor argument k is unpacked value arg_order[k]


def _reader(cls: type[Any]) -> _Reader | None:
    """A reader for a class of numbers only (no text, no arrays); None for any other."""
    if "char" in cls.fieldtypes or any(cls.array_lengths):
        return None
    return _Reader(cls=cls, crc_extra=bytes((cls.crc_extra,)), payload=cls.unpacker, arg_order=tuple(cls.orders))


_READERS: Final[dict[int, _Reader]] = {
    msg_id: reader for msg_id, cls in mavlink.mavlink_map.items() if (reader := _reader(cls)) is not None
}


def read_datagram(data: bytes) -> list[Any] | None:
    """Every message of a datagram made only of well-formed MAVLink 2 frames of numeric messages, in order; None
    when any byte of it is anything else."""
    messages: list[Any] = []
    end = len(data)
    start = 0
    while start < end:
        if end - start < _HEADER_LEN + 2 or data[start] != mavlink.PROTOCOL_MARKER_V2:
            return None
        _magic, length, incompat, compat, seq, sysid, compid, id_low, id_high = _HEADER.unpack_from(data, start)
        if incompat not in (0, _SIGNED):
            return None
        msg_id = id_low | id_high << 16
        reader = _READERS.get(msg_id)
        if reader is None or length > reader.payload.size:
            return None
        payload_end = start + _HEADER_LEN + length
        frame_end = payload_end + 2 + (_SIGNATURE_LEN if incompat else 0)
        if frame_end > end:
            return None
        crc = _CRC.unpack_from(data, payload_end)[0]
        if _crc(data[start + 1 : payload_end] + reader.crc_extra, 0xFFFF) != crc:
            return None
        # MAVLink 2 drops a payload's trailing zero bytes: put them back before unpacking the class's layout.
        values = reader.payload.unpack(data[start + _HEADER_LEN : payload_end] + bytes(reader.payload.size - length))
        msg = reader.cls(*[values[k] for k in reader.arg_order])
        buffer = bytearray(data[start:frame_end])
        # What pymavlink's decode sets on a message (its payload slice starts at byte 6, for MAVLink 2 too).
        msg._signed = False
        msg._msgbuf = buffer
        msg._payload = buffer[6 : payload_end - start]
        msg._crc = crc
        msg._header = mavlink.MAVLink_header(msg_id, incompat, compat, length, seq, sysid, compid)
        messages.append(msg)
        start = frame_end
    return messages
