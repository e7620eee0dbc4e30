"""Long STATUSTEXTs put back together, as QGroundControl does (pure).

MAVLink 2 cuts a text longer than the 50-byte field into chunks with one non-zero ``id`` and ``chunk_seq`` 0, 1, ...;
the chunk shorter than the field (empty when the text filled the last one exactly) ends it. A text with ``id`` 0 is
whole. Chunks of a text whose end never comes are dropped once ``MAX_PENDING`` newer texts of the same drone are
being put together.
"""

from __future__ import annotations

from typing import Any, Final

TEXT_FIELD_CHARS: Final = 50
MAX_PENDING: Final = 8  # texts being put together per drone


class StatusTextAssembler:
    """Feed every STATUSTEXT; each whole text comes out once, when its last chunk arrives."""

    def __init__(self) -> None:
        self._pending: dict[tuple[int, int], dict[int, str]] = {}

    def feed(self, sysid: int, msg: Any) -> str | None:
        """The whole text ``msg`` completes, or None while chunks are missing."""
        text_id = getattr(msg, "id", 0)
        if not text_id:
            return str(msg.text)
        key = (sysid, text_id)
        chunks = self._pending.setdefault(key, {})
        chunks[int(msg.chunk_seq)] = str(msg.text)
        if len(msg.text) >= TEXT_FIELD_CHARS:
            mine = [k for k in self._pending if k[0] == sysid]
            for old in mine[:-MAX_PENDING]:
                del self._pending[old]
            return None
        del self._pending[key]
        return "".join(chunks[k] for k in sorted(chunks))
