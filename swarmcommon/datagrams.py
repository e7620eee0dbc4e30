"""How both sides address and pack UDP: ``HOST:PORT`` as the command lines take it, and MAVLink frames packed into
datagrams, whole frames, in order, as many as fit.

Every MAVLink parser reads a datagram as a byte stream, so frames may share one, as ArduPilot's and PX4's UDP links
do; one datagram instead of one per frame saves a system call on each side and, more costly on a busy machine, a
wake-up of the receiving process (docs/benchmarks.md)."""

from __future__ import annotations

from collections.abc import Iterable
from typing import Final

Address = tuple[str, int]

MAX_BATCH_BYTES: Final = 1400  # a datagram of several frames stays below a typical path MTU (1500 less IP/UDP headers)


def parse_host_port(text: str) -> Address | None:
    """``HOST:PORT`` with a port in 1..65535, or None when the text is not one."""
    host, sep, port = text.rpartition(":")
    if not sep or not host or not port.isdigit() or not 0 < int(port) < 65536:
        return None
    return host, int(port)


def datagrams(frames: Iterable[bytes], max_bytes: int = MAX_BATCH_BYTES) -> list[bytes]:
    """Whole frames packed in order into as few datagrams of at most ``max_bytes`` as they fit (a frame larger than
    that goes alone)."""
    out: list[bytes] = []
    batch = bytearray()
    for frame in frames:
        if batch and len(batch) + len(frame) > max_bytes:
            out.append(bytes(batch))
            batch.clear()
        batch += frame
    if batch:
        out.append(bytes(batch))
    return out
