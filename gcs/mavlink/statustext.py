"""Long STATUSTEXTs put back together, as QGroundControl does, and a simulated drone's contact read from its text
(pure).

MAVLink 2 cuts a text longer than the 50-byte field into chunks with one non-zero ``id`` and ``chunk_seq`` 0, 1, ...;
the chunk shorter than the field (empty when the text filled the last one exactly) ends it. A text with ``id`` 0 is
whole. Chunks of a text whose end never comes are dropped once ``MAX_PENDING`` newer texts of the same drone are
being put together.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
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


COLLISION_PREFIX: Final = "Collision"
# A simulated drone's report of a contact its world saw: "Collision with drone 2 at 0.61 m" (sitl/world/view.py); the
# distance is the centres' as the world measured it at physics rate, so at most the two collision radii together.
_CONTACT: Final = re.compile(r"^Collision with (drone|obstacle) (\d+)(?: at ([0-9]+(?:\.[0-9]+)?) m)?")


@dataclass(frozen=True, slots=True, kw_only=True)
class ContactText:
    """What a drone's collision STATUSTEXT says: the body it touched and how far apart the centres were."""

    drone: int | None  # the sysid of the drone touched, None for an obstacle
    obstacle: int | None  # the obstacle touched (1-based, as the mission numbers them), None for a drone
    distance_m: float | None  # None when the text gives none


def parse_contact(text: str) -> ContactText | None:
    """The contact a STATUSTEXT reports, or None when it reports none."""
    match = _CONTACT.match(text)
    if match is None:
        return None
    kind, number, distance = match.groups()
    return ContactText(drone=int(number) if kind == "drone" else None,
                       obstacle=int(number) if kind == "obstacle" else None,
                       distance_m=float(distance) if distance is not None else None)  # fmt: skip
