"""STATUSTEXT: how the vehicle tells a human why something was refused or what just happened.

A STATUSTEXT carries at most 50 bytes. Longer texts are split MAVLink-2 style: every chunk carries the same non-zero
``id`` and an increasing ``chunk_seq``, and the last chunk is shorter than 50 bytes (a NUL ends it), which MAVSDK
and QGroundControl reassemble. Very long texts are truncated first so one event cannot flood the link.
"""

from __future__ import annotations

from enum import IntEnum

from pymavlink.dialects.v20 import common as mavlink

from sitl.protocol.core import MAVLinkMessage

TEXT_FIELD_BYTES = 50
MAX_TEXT_BYTES = 200  # four chunks; PX4 limits its log texts to about this length as well
_ELLIPSIS = b"..."


class Severity(IntEnum):
    """MAV_SEVERITY."""

    EMERGENCY = mavlink.MAV_SEVERITY_EMERGENCY
    ALERT = mavlink.MAV_SEVERITY_ALERT
    CRITICAL = mavlink.MAV_SEVERITY_CRITICAL
    ERROR = mavlink.MAV_SEVERITY_ERROR
    WARNING = mavlink.MAV_SEVERITY_WARNING
    NOTICE = mavlink.MAV_SEVERITY_NOTICE
    INFO = mavlink.MAV_SEVERITY_INFO
    DEBUG = mavlink.MAV_SEVERITY_DEBUG


def _clean(text: str) -> bytes:
    """Printable ASCII only: non-ASCII becomes '?', control characters become spaces."""
    raw = text.encode("ascii", errors="replace")
    return bytes(b if 0x20 <= b < 0x7F else 0x20 for b in raw).strip()


class StatusTextEncoder:
    """Builds STATUSTEXT messages; owns the chunk-id counter so concurrent long texts do not mix."""

    def __init__(self) -> None:
        self._next_id = 1

    def encode(self, severity: int, text: str) -> list[MAVLinkMessage]:
        """One message for a short text, several chunks for a long one, none for an empty one."""
        sev = int(severity) if 0 <= int(severity) <= 7 else int(Severity.INFO)
        data = _clean(text)
        if not data:
            return []
        if len(data) > MAX_TEXT_BYTES:
            data = data[: MAX_TEXT_BYTES - len(_ELLIPSIS)] + _ELLIPSIS
        if len(data) <= TEXT_FIELD_BYTES:
            return [mavlink.MAVLink_statustext_message(sev, data, 0, 0)]
        chunk_id = self._next_id
        self._next_id = self._next_id % 0xFFFF + 1  # never 0: 0 means "single chunk"
        chunks = [data[i : i + TEXT_FIELD_BYTES] for i in range(0, len(data), TEXT_FIELD_BYTES)]
        if len(chunks[-1]) == TEXT_FIELD_BYTES:
            chunks.append(b"")  # the receiver only knows the text ended when a chunk is shorter than the field
        return [mavlink.MAVLink_statustext_message(sev, c, chunk_id, i) for i, c in enumerate(chunks)]
