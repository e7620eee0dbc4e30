"""A writer for .tlog files, the MAVLink telemetry log QGroundControl records and pymavlink's tools read.

Keeping the raw packets of a flight lets anyone replay or inspect it with standard tools (QGroundControl,
``mavlogdump.py``, ``mavplayback.py``) independently of our own recording. The format has no header: each record is
the receive time as an 8-byte big-endian unsigned integer of microseconds since the Unix epoch, followed by one
complete MAVLink packet (v1 or v2) as it was on the wire, except that a signed packet is logged unsigned (its
signature dropped, as the MAVLink signing specification asks of logs: gcs/mavlink/signing.py). Readers find the packet's
length by parsing it, so a record must hold exactly one whole packet.

The writer takes the time from its caller (no clock of its own), so logs are reproducible and tests need no sleeping.
"""

from __future__ import annotations

import operator
import struct
from pathlib import Path
from types import TracebackType
from typing import BinaryIO

from gcs.mavlink.signing import without_signature

_TIMESTAMP = struct.Struct(">Q")
_MAVLINK_STX = (0xFE, 0xFD)  # start bytes of MAVLink 1 and MAVLink 2 packets


class TlogWriter:
    """Appends timestamped MAVLink packets to a .tlog file (created or truncated on opening).

    Use as a context manager, or call ``close()``. Not thread-safe: write from one task.
    """

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self._file: BinaryIO | None = self.path.open("wb")
        self.records_written = 0

    def write(self, packet_bytes: bytes, unix_time_us: int) -> None:
        """Log one whole MAVLink packet received (or sent) at ``unix_time_us`` microseconds since the epoch."""
        if self._file is None:
            raise ValueError(f"tlog {self.path} is closed")
        if not packet_bytes or packet_bytes[0] not in _MAVLINK_STX:
            raise ValueError("not a MAVLink packet: expected it to start with 0xFE or 0xFD")
        time_us = operator.index(unix_time_us)  # integers only: a float here is a units mistake
        if not 0 <= time_us < 2**64:
            raise ValueError(f"timestamp {time_us} us is out of range for a tlog record")
        self._file.write(_TIMESTAMP.pack(time_us) + without_signature(bytes(packet_bytes)))
        self.records_written += 1

    def flush(self) -> None:
        """Push buffered records to the operating system (e.g. before another process reads the log)."""
        if self._file is not None:
            self._file.flush()

    def close(self) -> None:
        if self._file is not None:
            self._file.close()
            self._file = None

    @property
    def closed(self) -> bool:
        return self._file is None

    def __enter__(self) -> TlogWriter:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        self.close()
