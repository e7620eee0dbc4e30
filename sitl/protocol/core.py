"""Shared plumbing of the MAVLink services: identity, effects, errors and safe reading of peer messages.

Every service in this package is sans-IO: ``handle(msg, now_s)`` and ``poll(now_s)`` return a list of effects and
never touch a socket or a clock. Messages in are pymavlink message objects from any dialect (services dispatch on
``get_msgId()`` and read fields by name, so ``common``, ``ardupilotmega`` or ``all`` decoders all work); messages
out are built from ``pymavlink.dialects.v20.common`` classes and carry no source address: the IO shell packs them
with a ``MAVLink`` instance whose ``srcSystem``/``srcComponent`` are the vehicle's identity.

Two error types, kept apart on purpose:
- ``ProtocolUsageError``: our own code called a service wrongly (not a message, a non-finite time). It escapes.
- ``PeerInputError``: a peer sent something unusable. The field readers here raise it and each service's single
  entry point turns it into a rejection on the wire or silently drops the message. It never escapes ``handle()``.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Final, Protocol, TypeAlias

from pymavlink.dialects.v20 import common as mavlink

MAVLinkMessage: TypeAlias = Any  # a pymavlink MAVLink_message of any dialect (pymavlink ships no type stubs)

INT32_MAX: Final = 0x7FFFFFFF
UINT16_MAX: Final = 0xFFFF
INT16_MAX: Final = 0x7FFF
FLOAT32_MAX: Final = 3.4028234663852886e38


class ProtocolError(Exception):
    """Base of every error this package declares."""


class ProtocolUsageError(ProtocolError):
    """A service was used wrongly by our own code (for example ``handle()`` given something that is no message)."""


class PeerInputError(ProtocolError):
    """A peer's message is malformed; caught inside the services and answered with a rejection or ignored."""


@dataclass(frozen=True, slots=True, kw_only=True)
class Identity:
    """Who this vehicle is on the wire (PX4 SITL: sysid = instance + 1, autopilot component 1)."""

    sysid: int
    compid: int = mavlink.MAV_COMP_ID_AUTOPILOT1
    mav_type: int = mavlink.MAV_TYPE_QUADROTOR
    autopilot: int = mavlink.MAV_AUTOPILOT_PX4

    def __post_init__(self) -> None:
        if not (1 <= self.sysid <= 255 and 1 <= self.compid <= 255):
            raise ProtocolUsageError(f"sysid/compid must be 1..255, got {self.sysid}/{self.compid}")


@dataclass(frozen=True, slots=True)
class Peer:
    """The source address of a received message."""

    sysid: int
    compid: int


@dataclass(frozen=True, slots=True)
class Send:
    """Send ``msg`` on the link whose ``handle()``/``poll()`` returned this effect."""

    msg: MAVLinkMessage


Effect: TypeAlias = Send


class Service(Protocol):
    """What every service offers the link that owns it."""

    @property
    def handles(self) -> frozenset[int]:
        """MAVLink message ids this service wants to see."""
        ...

    def handle(self, msg: MAVLinkMessage, now_s: float) -> list[Effect]: ...

    def poll(self, now_s: float) -> list[Effect]: ...


# ---- checks on what our own caller passes ------------------------------------------------------------------
def check_now(now_s: float) -> float:
    """Validate a time argument: simulation seconds, finite."""
    if isinstance(now_s, bool) or not isinstance(now_s, int | float) or not math.isfinite(now_s):
        raise ProtocolUsageError(f"now_s must be a finite number of seconds, got {now_s!r}")
    return float(now_s)


def message_id(msg: MAVLinkMessage) -> int:
    """The MAVLink message id of a pymavlink message; ProtocolUsageError for anything else."""
    get_id = getattr(msg, "get_msgId", None)
    if not callable(get_id) or not callable(getattr(msg, "get_header", None)):
        raise ProtocolUsageError(f"expected a pymavlink message, got {type(msg).__name__}")
    msg_id = get_id()
    if not isinstance(msg_id, int):
        raise ProtocolUsageError(f"message id of {type(msg).__name__} is not an int")
    return msg_id


def source_of(msg: MAVLinkMessage) -> Peer:
    """Sender address from the message header (0/0 for a message built locally and never packed)."""
    try:
        sysid, compid = msg.get_srcSystem(), msg.get_srcComponent()
    except AttributeError as exc:
        raise ProtocolUsageError(f"message {type(msg).__name__} has no header") from exc
    if not isinstance(sysid, int) or not isinstance(compid, int):
        raise PeerInputError("source address is not an integer")
    return Peer(sysid, compid)


# ---- reading peer fields defensively -----------------------------------------------------------------------
def read_int(msg: MAVLinkMessage, name: str, *, lo: int | None = None, hi: int | None = None) -> int:
    """An integer field; PeerInputError if missing, of another type or outside [lo, hi]."""
    value = getattr(msg, name, None)
    if isinstance(value, bool) or not isinstance(value, int):
        raise PeerInputError(f"field {name} is not an integer: {value!r}")
    if (lo is not None and value < lo) or (hi is not None and value > hi):
        raise PeerInputError(f"field {name}={value} outside [{lo}, {hi}]")
    return value


def read_float(msg: MAVLinkMessage, name: str) -> float:
    """A float field (NaN allowed, the caller decides); PeerInputError if missing or not a number."""
    value = getattr(msg, name, None)
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise PeerInputError(f"field {name} is not a number: {value!r}")
    return float(value)


def read_floats(msg: MAVLinkMessage, name: str, count: int) -> tuple[float, ...]:
    """A float array field of exactly ``count`` numbers."""
    value = getattr(msg, name, None)
    if not isinstance(value, Sequence) or isinstance(value, str | bytes) or len(value) != count:
        raise PeerInputError(f"field {name} is not an array of {count} numbers")
    out = []
    for v in value:
        if isinstance(v, bool) or not isinstance(v, int | float):
            raise PeerInputError(f"field {name} holds a non-number: {v!r}")
        out.append(float(v))
    return tuple(out)


def read_text(msg: MAVLinkMessage, name: str) -> str:
    """A char[] field as text, cut at the first NUL (pymavlink already decodes received ones to str)."""
    value = getattr(msg, name, None)
    if isinstance(value, bytes | bytearray):
        value = bytes(value).decode("ascii", errors="replace")
    if not isinstance(value, str):
        raise PeerInputError(f"field {name} is not text: {value!r}")
    return value.split("\x00", 1)[0]


def addressed_to(
    msg: MAVLinkMessage, identity: Identity, *, any_component: bool = False, also_components: Sequence[int] = ()
) -> bool:
    """True when target_system is 0 or ours and target_component is 0, ours or one of ``also_components``.

    Several vehicles may share one client socket, so a vehicle must ignore messages meant for another system.
    """
    target_system = read_int(msg, "target_system")
    if target_system not in (0, identity.sysid):
        return False
    if any_component:
        return True
    target_component = read_int(msg, "target_component")
    return target_component in (0, identity.compid) or target_component in also_components


# ---- values for outgoing fields (struct.pack raises on out-of-range values, so clamp before building) ------
def f32(value: float) -> float:
    """A float32-packable value: NaN and infinities pass, finite values beyond float32 saturate."""
    if -FLOAT32_MAX <= value <= FLOAT32_MAX:  # the common case first, in one comparison (NaN fails it)
        return value
    if math.isnan(value) or math.isinf(value):
        return value
    return FLOAT32_MAX if value > 0.0 else -FLOAT32_MAX


def to_int(value: float, lo: int, hi: int, unknown: int) -> int:
    """Round half away from zero and clamp to [lo, hi]; ``unknown`` for NaN/inf."""
    if not math.isfinite(value):
        return unknown
    rounded = math.floor(value + 0.5) if value >= 0 else -math.floor(0.5 - value)
    return lo if rounded < lo else hi if rounded > hi else rounded


def param_to_int(value: float) -> int | None:
    """A float command parameter that carries an integer (PX4 rounds), or None when NaN/inf/out of int32."""
    if not math.isfinite(value) or abs(value) > INT32_MAX:
        return None
    return to_int(value, -INT32_MAX - 1, INT32_MAX, 0)


def float_bits(value: float) -> int:
    """The uint32 bit pattern of a float32 value."""
    return int(struct.unpack("<I", struct.pack("<f", f32(value)))[0])


def bits_to_float(bits: int) -> float:
    """The float32 value of a uint32 bit pattern (signalling NaNs come back quieted; keep the bits if they matter)."""
    return float(struct.unpack("<f", struct.pack("<I", bits & 0xFFFFFFFF))[0])


def payload_prefix(msg: MAVLinkMessage, size: int) -> bytes | None:
    """The first ``size`` payload bytes of a received message, zero-padded (MAVLink 2 trims trailing zeros).

    Lets a service read a float field's exact bits: converting a float32 signalling NaN to a Python float quiets it,
    which would corrupt an INT32 parameter sent bytewise. None when the message was never on a wire.
    """
    buf = getattr(msg, "get_msgbuf", None)
    raw = buf() if callable(buf) else None
    if not isinstance(raw, bytes | bytearray) or len(raw) < 3:
        return None
    if raw[0] == mavlink.PROTOCOL_MARKER_V2:
        header_len, payload_len = 10, raw[1]
    elif raw[0] == mavlink.PROTOCOL_MARKER_V1:
        header_len, payload_len = 6, raw[1]
    else:
        return None
    payload = bytes(raw[header_len : header_len + payload_len])
    return (payload + bytes(size))[:size]
