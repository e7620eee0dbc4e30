"""Robustness: whatever arrives on the wire, the services answer or ignore it and never raise.

Three kinds of input go through pymavlink's parser (``robust_parsing = True``) into a complete ``LinkServices``:
random bytes, well-formed messages of every handled type with arbitrary field values (NaN, infinities, huge counts,
out-of-range sequence numbers, foreign targets), and valid frames whose payload was mutated or truncated with the
CRC recomputed, so the parser accepts them. Time advances irregularly between messages so the retry and timeout
paths run too. Every effect produced must also pack, because the IO shell will pack it.

Objects built by buggy code (wrong attribute types, never packed) may only raise the declared ``ProtocolError``.
"""

from __future__ import annotations

import math
import struct
from typing import Any

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from pymavlink.dialects.v20 import common as mavlink

from sitl.params import ParamDef, ParamStore, ParamType
from sitl.protocol import Identity, LinkServices, ProtocolError
from sitl.protocol.core import Effect
from sitl.protocol.testing import FakeVehicle

SYSID = 1
HANDLED_TYPES = [
    mavlink.MAVLink_command_long_message,
    mavlink.MAVLink_command_int_message,
    mavlink.MAVLink_set_mode_message,
    mavlink.MAVLink_param_request_list_message,
    mavlink.MAVLink_param_request_read_message,
    mavlink.MAVLink_param_set_message,
    mavlink.MAVLink_mission_count_message,
    mavlink.MAVLink_mission_item_message,
    mavlink.MAVLink_mission_item_int_message,
    mavlink.MAVLink_mission_request_message,
    mavlink.MAVLink_mission_request_int_message,
    mavlink.MAVLink_mission_request_list_message,
    mavlink.MAVLink_mission_ack_message,
    mavlink.MAVLink_mission_clear_all_message,
    mavlink.MAVLink_mission_set_current_message,
    mavlink.MAVLink_set_position_target_local_ned_message,
    mavlink.MAVLink_set_position_target_global_int_message,
    mavlink.MAVLink_set_attitude_target_message,
    mavlink.MAVLink_timesync_message,
    mavlink.MAVLink_ping_message,
    mavlink.MAVLink_heartbeat_message,
    mavlink.MAVLink_statustext_message,  # not handled: must be ignored
]
INTERESTING_COMMANDS = [
    400, 22, 21, 20, 17, 176, 192, 178, 179, 300, 224, 185, 246, 34, 511, 510, 512, 520, 519, 410, 0, 65535
]  # fmt: skip
INT_RANGES = {
    "uint8_t": (0, 255),
    "int8_t": (-128, 127),
    "uint16_t": (0, 0xFFFF),
    "int16_t": (-(2**15), 2**15 - 1),
    "uint32_t": (0, 2**32 - 1),
    "int32_t": (-(2**31), 2**31 - 1),
    "uint64_t": (0, 2**64 - 1),
    "int64_t": (-(2**63), 2**63 - 1),
}
FLOATS = st.one_of(
    st.floats(width=32, allow_nan=True, allow_infinity=True),
    st.sampled_from([0.0, 1.0, -1.0, -2.0, 21196.0, 148.0, 242.0, 6.0, 4.0, 3.0, math.nan, 1e7, -1e30]),
)


def make_link() -> tuple[LinkServices, FakeVehicle]:
    vehicle = FakeVehicle()
    store = ParamStore(
        [
            ParamDef(name="MIS_TAKEOFF_ALT", default=2.5, min=0.5, max=100, unit="m", description=""),
            ParamDef(name="COM_ARM_WO_GPS", default=0, min=0, max=1, unit="", description="", type=ParamType.INT),
        ]
    )
    return LinkServices(Identity(sysid=SYSID), vehicle, store), vehicle


def field_strategy(name: str, ftype: str, array_len: int) -> st.SearchStrategy[Any]:
    if ftype == "char":
        names = st.sampled_from([b"MIS_TAKEOFF_ALT", b"COM_ARM_WO_GPS", b"_HASH_CHECK", b"", b"X" * array_len])
        return st.one_of(names, st.binary(max_size=array_len))
    if ftype in ("float", "double"):
        scalar = FLOATS
    else:
        lo, hi = INT_RANGES[ftype]
        scalar = st.integers(lo, hi)
        if name == "target_system":
            scalar = st.one_of(st.sampled_from([0, SYSID, SYSID, 2]), scalar)
        elif name == "target_component":
            scalar = st.one_of(st.sampled_from([0, 1, 1, 190, 100]), scalar)
        elif name == "command":
            scalar = st.one_of(st.sampled_from(INTERESTING_COMMANDS), scalar)
        elif name in ("seq", "count", "mission_type", "frame", "coordinate_frame", "param_index", "type"):
            scalar = st.one_of(st.integers(0, 6).filter(lambda v: lo <= v <= hi), st.sampled_from([lo, hi]), scalar)
    if array_len:
        return st.lists(scalar, min_size=array_len, max_size=array_len)
    return scalar


@st.composite
def messages(draw: st.DrawFn) -> Any:
    cls = draw(st.sampled_from(HANDLED_TYPES))
    lengths = dict(zip(cls.ordered_fieldnames, cls.array_lengths, strict=True))
    values = {
        name: draw(field_strategy(name, ftype, lengths[name]))
        for name, ftype in zip(cls.fieldnames, cls.fieldtypes, strict=True)
    }
    return cls(**values)


def frame_bytes(msg: Any, src: tuple[int, int], seq: int) -> bytes:
    mav = mavlink.MAVLink(None, srcSystem=src[0], srcComponent=src[1])
    mav.seq = seq
    return bytes(msg.pack(mav))


def mutate(frame: bytes, crc_extra: int, edits: list[tuple[int, int]], new_len: int | None) -> bytes:
    """Change payload bytes (and maybe the length) of a MAVLink 2 frame and make its CRC valid again."""
    header, payload = bytearray(frame[:10]), bytearray(frame[10:-2])
    for pos, value in edits:
        if payload:
            payload[pos % len(payload)] = value
    if new_len is not None:
        payload = (payload + bytes(255))[: max(1, new_len)]
    header[1] = len(payload)
    crc = mavlink.x25crc(bytes(header[1:]) + bytes(payload))
    crc.accumulate(struct.pack("B", crc_extra))
    return bytes(header) + bytes(payload) + struct.pack("<H", crc.crc)


def check_packable(effects: list[Effect], vehicle_mav: Any) -> None:
    for effect in effects:
        effect.msg.pack(vehicle_mav)


def feed(data: bytes, link: LinkServices, now_s: float, vehicle_mav: Any) -> None:
    parser = mavlink.MAVLink(None)
    parser.robust_parsing = True
    for msg in parser.parse_buffer(data) or []:
        check_packable(link.handle(msg, now_s), vehicle_mav)


FUZZ = settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])


@FUZZ
@given(chunks=st.lists(st.binary(min_size=0, max_size=300), min_size=1, max_size=8))
def test_random_bytes_never_raise(chunks: list[bytes]) -> None:
    link, _ = make_link()
    vehicle_mav = mavlink.MAVLink(None, srcSystem=SYSID, srcComponent=1)
    for i, chunk in enumerate(chunks):
        feed(chunk, link, 1.0 + i, vehicle_mav)
        check_packable(link.poll(1.5 + i), vehicle_mav)


@FUZZ
@given(
    script=st.lists(
        st.tuples(messages(), st.sampled_from([(245, 190), (255, 0), (SYSID, 1), (7, 1)]), st.floats(0.0, 3.0)),
        min_size=1,
        max_size=25,
    )
)
def test_arbitrary_field_values_in_valid_frames_never_raise(script: list[tuple[Any, tuple[int, int], float]]) -> None:
    # GIVEN a link  WHEN any sequence of well-formed messages with arbitrary values arrives, time moving on
    link, _ = make_link()
    vehicle_mav = mavlink.MAVLink(None, srcSystem=SYSID, srcComponent=1)
    now_s = 0.0
    for seq, (msg, src, dt_s) in enumerate(script):
        now_s += dt_s
        feed(frame_bytes(msg, src, seq % 256), link, now_s, vehicle_mav)
        # THEN nothing raises and every answer packs
        check_packable(link.poll(now_s), vehicle_mav)
    check_packable(link.poll(now_s + 30.0), vehicle_mav)


@FUZZ
@given(
    msg=messages(),
    edits=st.lists(st.tuples(st.integers(0, 254), st.integers(0, 255)), max_size=6),
    new_len=st.one_of(st.none(), st.integers(1, 255)),
)
def test_mutated_and_truncated_frames_with_valid_crc_never_raise(
    msg: Any, edits: list[tuple[int, int]], new_len: int | None
) -> None:
    link, _ = make_link()
    vehicle_mav = mavlink.MAVLink(None, srcSystem=SYSID, srcComponent=1)
    data = mutate(frame_bytes(msg, (245, 190), 0), msg.crc_extra, edits, new_len)
    feed(data, link, 1.0, vehicle_mav)
    check_packable(link.poll(2.0), vehicle_mav)


JUNK = st.one_of(
    st.none(), st.text(max_size=5), st.lists(st.integers(), max_size=3), st.floats(), st.integers(), st.booleans()
)


@FUZZ
@given(msg=messages(), field_index=st.integers(0, 30), junk=JUNK)
def test_objects_with_wrongly_typed_fields_raise_nothing_but_declared_errors(
    msg: Any, field_index: int, junk: Any
) -> None:
    # GIVEN a message object corrupted by our own buggy code, never packed
    setattr(msg, msg.fieldnames[field_index % len(msg.fieldnames)], junk)
    link, _ = make_link()
    vehicle_mav = mavlink.MAVLink(None, srcSystem=SYSID, srcComponent=1)
    # WHEN handled  THEN only a declared ProtocolError may escape
    try:
        check_packable(link.handle(msg, 1.0), vehicle_mav)
        check_packable(link.poll(5.0), vehicle_mav)
    except ProtocolError:
        pass
