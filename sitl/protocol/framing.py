"""MAVLink 2 framing without pymavlink's generic machinery, for the messages a drone sends and receives most.

pymavlink packs a message by building a header object, re-checking the protocol version, copying the payload
twice and constructing a CRC object (about 5 us a frame), and parses a datagram one frame at a time through a
byte-stream state machine (about 11 us a frame). A drone sends some 130 telemetry frames a second and, in a swarm,
receives a relayed position from each neighbour at 10 Hz and a setpoint at 20 Hz, so both add up.

Here each message class whose fields are numbers or arrays of numbers (every hot one: HEARTBEAT, SYS_STATUS,
GPS_RAW_INT, GLOBAL_POSITION_INT, LOCAL_POSITION_NED, ATTITUDE, ATTITUDE_QUATERNION, VFR_HUD, HOME_POSITION,
SET_POSITION_TARGET_LOCAL_NED...) gets a precomputed layout: its payload ``struct.Struct`` and field order
(pymavlink's own, read from the class), its CRC extra and id. Packing is then one ``Struct.pack``, MAVLink 2's
trimming of trailing zero bytes, one header ``Struct.pack`` and one CRC-16/MCRF4XX (the X.25 CRC MAVLink uses,
through the same C implementation pymavlink uses when it is installed, else a table). The bytes are exactly
pymavlink's (tests/unit/test_framing.py packs every such message class of the dialect both ways with random field
values).

Parsing takes the fast path only for a datagram that is nothing but well-formed MAVLink 2 frames of classes
without arrays, with correct CRCs, unsigned or signed (the signature is kept in the frame's buffer for
sitl/protocol/signing.py to check, not checked here), and builds the objects pymavlink's parser without a key would
(fields, header, buffer, payload, CRC). Anything else (MAVLink 1, other incompatibility flags, an unknown id, text or
array fields, a bad CRC, a truncated frame, garbage) returns None and the caller hands the whole datagram to
pymavlink, so every unusual input is treated exactly as before.

Drones hosted by one process receive the same relayed position frames: the supervisor's relay forwards each report
byte for byte to every drone it matters to. A ``FrameMemo`` shared by the host's links parses such a frame once and
hands every drone the same message object (messages are read, never changed, by the services that take them).
"""

from __future__ import annotations

import operator
import struct
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, Final

from pymavlink.dialects.v20 import common as mavlink

from sitl.protocol.core import MAVLinkMessage

_HEADER: Final = struct.Struct("<BBBBBBBHB")  # magic, len, incompat, compat, seq, sysid, compid, id low 16, id high 8
_CRC: Final = struct.Struct("<H")
HEADER_LEN: Final = 10
MAGIC_V2: Final = mavlink.PROTOCOL_MARKER_V2
IFLAG_SIGNED: Final = mavlink.MAVLINK_IFLAG_SIGNED  # incompatibility flag: 13 signature bytes follow the CRC
SIGNATURE_LEN: Final = mavlink.MAVLINK_SIGNATURE_BLOCK_LEN  # link id 1 + timestamp 6 + signature 6


def _crc_table() -> tuple[int, ...]:
    table = []
    for byte in range(256):
        tmp = byte
        tmp = (tmp ^ (tmp << 4)) & 0xFF
        table.append(((tmp << 8) ^ (tmp << 3) ^ (tmp >> 4)) & 0xFFFF)
    return tuple(table)


_TABLE: Final = _crc_table()


def crc_x25_table(data: bytes, crc: int = 0xFFFF) -> int:
    """CRC-16/MCRF4XX (MAVLink's X.25 checksum) one table look-up per byte: the fallback without fastcrc."""
    table = _TABLE
    for byte in data:
        crc = (crc >> 8) ^ table[(byte ^ crc) & 0xFF]
    return crc


# pymavlink's dialect binds fastcrc's C implementation when it is installed (pymavlink depends on it).
_mcrf4xx: Callable[[bytes, int], int] | None = getattr(mavlink, "mcrf4xx", None)
crc_x25: Callable[[bytes, int], int] = _mcrf4xx if _mcrf4xx is not None else crc_x25_table


@dataclass(frozen=True, slots=True)
class Layout:
    """What packing or parsing one message class needs, taken from the pymavlink class itself."""

    cls: type[Any]
    msg_id: int
    crc_extra: int
    payload: struct.Struct
    fields: Callable[[Any], Sequence[Any]]  # the field values in wire order, arrays element by element
    wire_to_args: tuple[int, ...]  # constructor argument i is wire value wire_to_args[i] (no arrays)
    has_arrays: bool  # packed here, parsed by pymavlink
    id_low: int
    id_high: int


def _array_fields(names: Sequence[str], lengths: Sequence[int]) -> Callable[[Any], list[Any]]:
    """Field values with each numeric array spread over its elements, indexed as pymavlink's pack indexes them."""
    spec = tuple(zip(names, lengths, strict=True))

    def values(msg: Any) -> list[Any]:
        out: list[Any] = []
        for name, count in spec:
            value = getattr(msg, name)
            if count:
                out.extend(value[k] for k in range(count))
            else:
                out.append(value)
        return out

    return values


def _layout(cls: type[Any]) -> Layout | None:
    """The layout of a class whose fields are numbers or arrays of numbers; None for one with text."""
    if any(t == "char" for t in cls.fieldtypes) or len(cls.ordered_fieldnames) < 2:
        return None
    array_length = dict(zip(cls.ordered_fieldnames, cls.array_lengths, strict=True))  # pymavlink: in wire order
    has_arrays = any(array_length.values())
    fields: Callable[[Any], Sequence[Any]] = (
        _array_fields(cls.ordered_fieldnames, [array_length[n] for n in cls.ordered_fieldnames])
        if has_arrays
        else operator.attrgetter(*cls.ordered_fieldnames)
    )
    return Layout(
        cls=cls,
        msg_id=cls.id,
        crc_extra=cls.crc_extra,
        payload=cls.unpacker,
        fields=fields,
        wire_to_args=tuple(cls.orders),
        has_arrays=has_arrays,
        id_low=cls.id & 0xFFFF,
        id_high=cls.id >> 16,
    )


LAYOUTS: Final[dict[int, Layout]] = {
    msg_id: layout for msg_id, cls in mavlink.mavlink_map.items() if (layout := _layout(cls)) is not None
}
_BY_CLASS: Final[dict[type[Any], Layout]] = {layout.cls: layout for layout in LAYOUTS.values()}
PARSED: Final[dict[int, Layout]] = {msg_id: layout for msg_id, layout in LAYOUTS.items() if not layout.has_arrays}


def pack(layout: Layout, msg: MAVLinkMessage, seq: int, sysid: int, compid: int) -> bytes:
    """One MAVLink 2 frame of ``msg`` (unsigned), byte for byte what ``msg.pack(encoder)`` gives for an encoder with
    this ``seq``, ``sysid`` and ``compid``."""
    raw = layout.payload.pack(*layout.fields(msg))
    payload = raw.rstrip(b"\x00") or raw[:1]  # MAVLink 2 trims trailing zeros, keeping at least one byte
    header = _HEADER.pack(MAGIC_V2, len(payload), 0, 0, seq, sysid, compid, layout.id_low, layout.id_high)
    body = header[1:] + payload
    crc = crc_x25(body + bytes((layout.crc_extra,)), 0xFFFF)
    return header[:1] + body + _CRC.pack(crc)


def layout_of(msg: MAVLinkMessage) -> Layout | None:
    """The layout of a message object's class, when it has one (pymavlink's own class, not a subclass)."""
    return _BY_CLASS.get(type(msg))


# Frames a host's drones receive alike: the relay's position reports.
SHARED_IDS: Final = frozenset({mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT})
# Frames a memo keeps before it starts again: a host reads each report within a pass or two, so a few hundred cover
# a crowd's 10 Hz reports while bounding what is kept (the message objects, about a kilobyte each).
FRAME_MEMO_SIZE: Final = 512


class FrameMemo:
    """The messages parsed from frames a host's drones receive alike (``SHARED_IDS``), by the frame's bytes (header,
    payload, CRC and signature: equal bytes, equal message). Emptied whole when full."""

    __slots__ = ("_messages", "hits")

    def __init__(self) -> None:
        self._messages: dict[bytes, MAVLinkMessage] = {}
        self.hits = 0

    def get(self, frame: bytes) -> MAVLinkMessage | None:
        msg = self._messages.get(frame)
        if msg is not None:
            self.hits += 1
        return msg

    def put(self, frame: bytes, msg: MAVLinkMessage) -> None:
        if len(self._messages) >= FRAME_MEMO_SIZE:
            self._messages.clear()
        self._messages[frame] = msg


def parse_datagram(data: bytes, memo: FrameMemo | None = None) -> list[MAVLinkMessage] | None:
    """The messages of a datagram made only of well-formed MAVLink 2 frames this module lays out; None when any
    part of it is anything else (then the datagram is for pymavlink's parser). With a ``memo``, a frame of
    ``SHARED_IDS`` another drone of the host received already gives that drone's message object."""
    out: list[MAVLinkMessage] = []
    end = len(data)
    i = 0
    layouts = PARSED
    while i < end:
        if end - i < HEADER_LEN + 2 or data[i] != MAGIC_V2:
            return None
        _magic, mlen, incompat, compat, seq, sysid, compid, id_low, id_high = _HEADER.unpack_from(data, i)
        if incompat & ~IFLAG_SIGNED:
            return None
        signed = incompat == IFLAG_SIGNED
        layout = layouts.get(id_low | id_high << 16)
        crc_end = i + HEADER_LEN + mlen + 2
        frame_end = crc_end + SIGNATURE_LEN if signed else crc_end
        if layout is None or frame_end > end:
            return None
        key = None
        if memo is not None and layout.msg_id in SHARED_IDS:
            key = data[i:frame_end]
            known = memo.get(key)
            if known is not None:
                out.append(known)
                i = frame_end
                continue
        crc = _CRC.unpack_from(data, crc_end - 2)[0]
        if crc_x25(data[i + 1 : crc_end - 2] + bytes((layout.crc_extra,)), 0xFFFF) != crc:
            return None
        size = layout.payload.size
        payload = data[i + HEADER_LEN : crc_end - 2]
        if mlen > size:
            return None  # longer than the class: pymavlink cuts it, and so may we not
        wire = layout.payload.unpack(payload + bytes(size - mlen))
        msg = layout.cls(*[wire[k] for k in layout.wire_to_args])
        # What pymavlink's decode sets (its payload slice starts at 6 even for MAVLink 2: kept as it is).
        msgbuf = bytearray(data[i:frame_end] if key is None else key)
        msg._signed = False  # pymavlink's parser without a key says the same of a signed frame: it checked nothing
        msg._msgbuf = msgbuf
        msg._payload = msgbuf[6 : crc_end - i - 2]
        msg._crc = crc
        msg._header = mavlink.MAVLink_header(layout.msg_id, incompat, compat, mlen, seq, sysid, compid)
        if key is not None:
            assert memo is not None
            memo.put(key, msg)
        out.append(msg)
        i = frame_end
    return out
