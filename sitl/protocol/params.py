"""The parameter service: PARAM_REQUEST_LIST / PARAM_REQUEST_READ / PARAM_SET over a ``ParamStore``.

Behaviour follows PX4's parameter manager:
- INT32 parameters travel bytewise: the int's four bytes are the ``param_value`` float field (PX4 advertises
  PARAM_ENCODE_BYTEWISE). The bytes are packed and read exactly, never through a Python float, because a float32
  signalling NaN would be quieted on the way and silently change the integer.
- Every successful or refused PARAM_SET is answered with PARAM_VALUE carrying the stored value and the parameter's
  own type (MAVSDK calls a set successful only when that echo matches what it sent). A refusal leaves the store
  unchanged and adds a STATUSTEXT with the reason.
- Unknown names get no PARAM_VALUE, only a STATUSTEXT "[pm] unknown param: NAME"; clients time out as with PX4.
- PARAM_REQUEST_LIST streams the table paced in simulation time (``PARAM_LIST_RATE_HZ``, bursts of at most
  ``PARAM_LIST_BURST`` per poll) so a UDP socket buffer never overflows; a new request restarts the stream.

One leniency beyond PX4: pymavlink scripts often send an integer as a plain float (1.0 for 1). When the bytewise
reading of an INT parameter is out of range but the float value is an in-range integer, the float value is used.
"""

from __future__ import annotations

import math
import struct
from typing import Final

from pymavlink.dialects.v20 import common as mavlink

from sitl.params import MAX_NAME_LEN, ParamError, ParamStore, ParamType
from sitl.protocol.core import (
    Effect,
    Identity,
    MAVLinkMessage,
    PeerInputError,
    Send,
    addressed_to,
    check_now,
    float_bits,
    message_id,
    payload_prefix,
    read_float,
    read_int,
    read_text,
)
from sitl.protocol.statustext import Severity, StatusTextEncoder

PARAM_LIST_RATE_HZ: Final = 500.0  # PARAM_VALUEs per simulated second while streaming the whole table
PARAM_LIST_BURST: Final = 20  # at most this many in one poll
HASH_CHECK_NAME: Final = "_HASH_CHECK"  # QGroundControl's cache handshake; a PARAM_SET of it stops the stream

_INT_TYPES: Final = {
    mavlink.MAV_PARAM_TYPE_UINT8: ("<B", 1),
    mavlink.MAV_PARAM_TYPE_INT8: ("<b", 1),
    mavlink.MAV_PARAM_TYPE_UINT16: ("<H", 2),
    mavlink.MAV_PARAM_TYPE_INT16: ("<h", 2),
    mavlink.MAV_PARAM_TYPE_UINT32: ("<I", 4),
    mavlink.MAV_PARAM_TYPE_INT32: ("<i", 4),
}


class ParamValueMessage(mavlink.MAVLink_param_value_message):
    """PARAM_VALUE whose value field is packed from an exact 32-bit pattern (see the module docstring)."""

    def __init__(self, param_id: str, value_bits: int, param_type: int, param_count: int, param_index: int) -> None:
        value = struct.unpack("<f", struct.pack("<I", value_bits))[0]
        super().__init__(param_id.encode("ascii"), value, param_type, param_count, param_index)
        self.value_bits = value_bits

    def pack(self, mav: object, force_mavlink1: bool = False) -> bytes:
        payload = struct.pack(
            "<IHH16sB", self.value_bits, self.param_count, self.param_index, self._param_id_raw, self.param_type
        )
        return bytes(self._pack(mav, self.crc_extra, payload, force_mavlink1=force_mavlink1))


def encode_value(value: float, param_type: ParamType) -> tuple[int, int]:
    """(bits for the param_value field, MAV_PARAM_TYPE) for a stored value."""
    if param_type is ParamType.INT:
        return struct.unpack("<I", struct.pack("<i", int(value)))[0], mavlink.MAV_PARAM_TYPE_INT32
    return float_bits(value), mavlink.MAV_PARAM_TYPE_REAL32


def decode_bits(bits: int, mav_param_type: int) -> float:
    """The number a PARAM_SET carries: bytewise integer for integer types, float32 otherwise."""
    int_format = _INT_TYPES.get(mav_param_type)
    raw = struct.pack("<I", bits & 0xFFFFFFFF)
    if int_format is not None:
        fmt, size = int_format
        return float(struct.unpack(fmt, raw[:size])[0])
    return float(struct.unpack("<f", raw)[0])


def _value_bits(msg: MAVLinkMessage) -> int:
    """The exact bits of PARAM_SET.param_value (first payload field), falling back to the decoded float."""
    prefix = payload_prefix(msg, 4)
    if prefix is not None and message_id(msg) == mavlink.MAVLINK_MSG_ID_PARAM_SET:
        return int(struct.unpack("<I", prefix)[0])
    value = read_float(msg, "param_value")
    try:
        return float_bits(value)
    except (OverflowError, struct.error) as exc:
        raise PeerInputError(f"param_value {value!r} is not a float32") from exc


class ParamService:
    """The PARAM_* microservice for one link, over the vehicle's single parameter table."""

    handles: frozenset[int] = frozenset(
        {
            mavlink.MAVLINK_MSG_ID_PARAM_REQUEST_LIST,
            mavlink.MAVLINK_MSG_ID_PARAM_REQUEST_READ,
            mavlink.MAVLINK_MSG_ID_PARAM_SET,
        }
    )

    def __init__(
        self,
        identity: Identity,
        store: ParamStore,
        *,
        statustext: StatusTextEncoder | None = None,
        list_rate_hz: float = PARAM_LIST_RATE_HZ,
        list_burst: int = PARAM_LIST_BURST,
    ) -> None:
        self._identity = identity
        self._store = store
        self._statustext = statustext or StatusTextEncoder()
        self._list_rate_hz = list_rate_hz
        self._list_burst = max(1, list_burst)
        self._list_next: int | None = None  # index of the next PARAM_VALUE of a running list, None when idle
        self._tokens = 0.0
        self._last_poll_s: float | None = None

    @property
    def listing(self) -> bool:
        """True while a PARAM_REQUEST_LIST is being answered."""
        return self._list_next is not None

    # ---- the service interface -----------------------------------------------------------------------------
    def handle(self, msg: MAVLinkMessage, now_s: float) -> list[Effect]:
        check_now(now_s)
        msg_id = message_id(msg)
        try:
            if msg_id not in self.handles or not addressed_to(msg, self._identity):
                return []
            if msg_id == mavlink.MAVLINK_MSG_ID_PARAM_REQUEST_LIST:
                self._list_next = 0
                self._tokens = float(self._list_burst)
                return []
            if msg_id == mavlink.MAVLINK_MSG_ID_PARAM_REQUEST_READ:
                return self._read(msg)
            return self._set(msg)
        except PeerInputError:
            return []  # PX4 drops what it cannot parse; the client times out and retries

    def poll(self, now_s: float) -> list[Effect]:
        now_s = check_now(now_s)
        elapsed = 0.0 if self._last_poll_s is None else max(0.0, now_s - self._last_poll_s)
        self._last_poll_s = now_s
        if self._list_next is None:
            return []
        self._tokens = min(float(self._list_burst), self._tokens + elapsed * self._list_rate_hz)
        out: list[Effect] = []
        while self._list_next is not None and self._tokens >= 1.0:
            if self._list_next >= len(self._store):
                self._list_next = None
                break
            out.append(Send(self.param_value(self._store.name_at(self._list_next))))
            self._list_next += 1
            self._tokens -= 1.0
        if self._list_next is not None and self._list_next >= len(self._store):
            self._list_next = None
        return out

    def param_value(self, name: str) -> MAVLinkMessage:
        """PARAM_VALUE for one stored parameter."""
        definition = self._store.definition(name)
        bits, mav_type = encode_value(self._store[name], definition.type)
        return ParamValueMessage(name, bits, mav_type, len(self._store), self._store.index_of(name))

    # ---- requests ------------------------------------------------------------------------------------------
    def _unknown(self, what: str) -> list[Effect]:
        return [Send(m) for m in self._statustext.encode(Severity.INFO, f"[pm] unknown param: {what}")]

    def _read(self, msg: MAVLinkMessage) -> list[Effect]:
        index = read_int(msg, "param_index", lo=-(2**15), hi=2**15 - 1)
        if index >= 0:
            if index >= len(self._store):
                return [Send(m) for m in self._statustext.encode(Severity.INFO, f"[pm] unknown param ID: {index}")]
            return [Send(self.param_value(self._store.name_at(index)))]
        name = read_text(msg, "param_id")[:MAX_NAME_LEN]
        if name == HASH_CHECK_NAME:
            return []  # no cached-parameter hash offered; QGroundControl then simply loads the list
        if name not in self._store:
            return self._unknown(name)
        return [Send(self.param_value(name))]

    def _set(self, msg: MAVLinkMessage) -> list[Effect]:
        name = read_text(msg, "param_id")[:MAX_NAME_LEN]
        if name == HASH_CHECK_NAME:
            self._list_next = None  # PX4: "whatever the value is, we're being told to stop sending"
            return []
        if name not in self._store:
            return self._unknown(name)
        bits = _value_bits(msg)
        mav_type = read_int(msg, "param_type", lo=0, hi=255)
        definition = self._store.definition(name)
        if definition.type is ParamType.INT:
            value = decode_bits(bits, mav_type if mav_type in _INT_TYPES else mavlink.MAV_PARAM_TYPE_INT32)
            as_float = read_float(msg, "param_value")
            bytewise_ok = definition.min <= value <= definition.max
            if not bytewise_ok and math.isfinite(as_float) and as_float.is_integer():
                value = as_float  # a client that sent the integer as a plain float (see the module docstring)
        else:
            value = decode_bits(bits, mavlink.MAV_PARAM_TYPE_REAL32)
        out: list[Effect] = []
        try:
            self._store.set(name, value)
        except ParamError as exc:
            out.extend(Send(m) for m in self._statustext.encode(Severity.CRITICAL, str(exc)))
        out.insert(0, Send(self.param_value(name)))
        return out
