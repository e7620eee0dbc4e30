"""The ground station's own fast reading of the datagrams its drones send: MAVLink 2 frames of fixed-size numeric
messages decoded with layouts precomputed from pymavlink's classes, without pymavlink's byte-by-byte parser.

A supervisor reads every drone's telemetry (HEARTBEAT, SYS_STATUS, GLOBAL_POSITION_INT, LOCAL_POSITION_NED,
ATTITUDE, ...) at its stream rates, and in lockstep it reads them once a frame: through pymavlink's state machine that
was about a fifth of its CPU at nine drones. Here a datagram is split into frames by their headers, each frame's
CRC (with the message's CRC extra) is checked with the same C routine pymavlink uses, and its payload is unpacked by
the class's own ``struct`` layout into an object of the class, with the fields, header, buffer and CRC pymavlink's
parser would give it: its arrays as lists, its texts as bytes without their trailing NULs, as pymavlink's ``decode``
builds them (a signed frame keeps its signature in the buffer; like the ground station's parsers, nothing checks it
here). Every message of the dialect is read this way: ATTITUDE_QUATERNION, streamed at 10 Hz, has an array, and a
datagram holding one went to pymavlink's parser whole. A datagram with anything else in it (MAVLink 1, an unknown
message, a bad CRC, a truncated frame, garbage) returns None, and the caller gives the whole datagram to pymavlink's
parser, so unusual input is treated exactly as it always was.

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
    """How to read one message class: its constructor, CRC extra, payload layout and where each of its arguments
    lies among the unpacked values."""

    cls: type[Any]
    crc_extra: bytes
    payload: struct.Struct
    # Constructor argument k is unpacked value spans[k][0], or the list of spans[k][1] values from there (an array)
    spans: tuple[tuple[int, int], ...]
    arrays: bool  # any argument is an array or a text: the slow branch of ``_arguments``


def _reader(cls: type[Any]) -> _Reader:
    """A reader for ``cls``: its arguments found among the unpacked values as pymavlink's ``decode`` finds them (an
    array field's values follow one another; a text is one ``bytes`` value)."""
    lengths = list(cls.lengths)
    arrays = sum(lengths) != len(lengths) or "char" in cls.fieldtypes
    if arrays:
        spans = tuple((sum(lengths[:order]), lengths[order]) for order in cls.orders)
    else:  # every field one value: argument k is value orders[k]
        spans = tuple((order, 1) for order in cls.orders)
    return _Reader(cls=cls, crc_extra=bytes((cls.crc_extra,)), payload=cls.unpacker, spans=spans, arrays=arrays)


def _arguments(reader: _Reader, values: tuple[Any, ...]) -> list[Any]:
    """The constructor's arguments from a payload's unpacked values, as pymavlink's ``decode`` forms them."""
    if not reader.arrays:
        return [values[tip] for tip, _ in reader.spans]
    out: list[Any] = []
    for tip, length in reader.spans:
        value = values[tip]
        if isinstance(value, bytes):
            out.append(value.rstrip(b"\x00"))
        elif length == 1:
            out.append(value)
        else:
            out.append(list(values[tip : tip + length]))
    return out


_READERS: Final[dict[int, _Reader]] = {msg_id: _reader(cls) for msg_id, cls in mavlink.mavlink_map.items()}


def read_datagram(data: bytes) -> list[Any] | None:
    """Every message of a datagram made only of well-formed MAVLink 2 frames of the dialect's messages, in order;
    None when any byte of it is anything else."""
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
        msg = reader.cls(*_arguments(reader, values))
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
