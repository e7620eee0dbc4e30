"""What a drone knows of its neighbours: positions relayed over MAVLink, each with its age.

The ground station forwards every drone's GLOBAL_POSITION_INT to the others unchanged (original system id kept, as a
MAVLink router does), so a neighbour is exactly what that drone reports of itself. This table is the only source of
neighbour positions for the autopilot besides its camera; it never reads the simulation's shared world.
Entries expire after ``NEIGHBOUR_TIMEOUT_S`` without news, so a lost relay shows as an empty table, not stale data.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Final

from pymavlink.dialects.v20 import common as mavlink

from sitl.mathutil import fast_constructor
from sitl.protocol.core import Effect, MAVLinkMessage, PeerInputError, check_now, read_int, source_of

NEIGHBOUR_TIMEOUT_S: Final = 3.0


@dataclass(frozen=True, slots=True, kw_only=True)
class Neighbour:
    sysid: int
    lat_deg: float
    lon_deg: float
    alt_amsl_m: float
    vel_ned_mps: tuple[float, float, float]
    sender_time_s: float  # the neighbour's own time_boot_ms, in seconds
    received_s: float  # our simulation time when it arrived

    def age_s(self, now_s: float) -> float:
        return now_s - self.received_s


_new_neighbour = fast_constructor(Neighbour)


def _plain_fields(msg: MAVLinkMessage) -> tuple[int, int, int, int, int, int, int] | None:
    """The fields a neighbour needs when every one is a plain int within its range (what any parser gives for a
    well-formed GLOBAL_POSITION_INT, checked here in one pass as relayed positions arrive at 10 Hz per neighbour);
    None otherwise, and ``read_int`` then checks them one by one."""
    try:
        lat, lon, alt, vx, vy, vz, boot_ms = msg.lat, msg.lon, msg.alt, msg.vx, msg.vy, msg.vz, msg.time_boot_ms
    except AttributeError:
        return None
    if not (
        type(lat) is int
        and type(lon) is int
        and type(alt) is int
        and type(vx) is int
        and type(vy) is int
        and type(vz) is int
        and type(boot_ms) is int
        and -900_000_000 <= lat <= 900_000_000
        and -1_800_000_000 <= lon <= 1_800_000_000
        and -(2**31) <= alt <= 2**31 - 1
        and -32768 <= vx <= 32767
        and -32768 <= vy <= 32767
        and -32768 <= vz <= 32767
        and 0 <= boot_ms <= 2**32 - 1
    ):
        return None
    return lat, lon, alt, vx, vy, vz, boot_ms


def _checked_fields(msg: MAVLinkMessage) -> tuple[int, int, int, int, int, int, int]:
    """The same fields through ``read_int``: PeerInputError for a missing, non-integer or out-of-range one."""
    return (
        read_int(msg, "lat", lo=-900_000_000, hi=900_000_000),
        read_int(msg, "lon", lo=-1_800_000_000, hi=1_800_000_000),
        read_int(msg, "alt", lo=-(2**31), hi=2**31 - 1),
        read_int(msg, "vx", lo=-32768, hi=32767),
        read_int(msg, "vy", lo=-32768, hi=32767),
        read_int(msg, "vz", lo=-32768, hi=32767),
        read_int(msg, "time_boot_ms", lo=0, hi=2**32 - 1),
    )


class NeighbourTable:
    """A service on every link: GLOBAL_POSITION_INT from other systems updates the (shared) table."""

    handles: frozenset[int] = frozenset({mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT})

    def __init__(self, own_sysid: int) -> None:
        self.own_sysid = own_sysid
        self._entries: dict[int, Neighbour] = {}
        # No entry arrived before this time (a lower bound: an entry refreshed later only makes it older than need
        # be): while it is within the timeout of now, nothing can have expired and ``poll`` need not look. Polled at
        # every pass of the loop, the look over a crowd's table cost more than the table's updates.
        self._oldest_received_s = math.inf
        self.updates = 0

    def handle(self, msg: MAVLinkMessage, now_s: float) -> list[Effect]:
        now_s = check_now(now_s)
        try:
            source = source_of(msg)
            if source.sysid == self.own_sysid:
                return []
            # Not plain ints in range: the field-by-field checks say which, or accept what they accept.
            lat, lon, alt, vx, vy, vz, boot_ms = _plain_fields(msg) or _checked_fields(msg)
        except PeerInputError:
            return []
        self._entries[source.sysid] = _new_neighbour(
            sysid=source.sysid,
            lat_deg=lat * 1e-7,
            lon_deg=lon * 1e-7,
            alt_amsl_m=alt * 1e-3,
            vel_ned_mps=(vx * 0.01, vy * 0.01, vz * 0.01),
            sender_time_s=boot_ms * 1e-3,
            received_s=now_s,
        )
        if now_s < self._oldest_received_s:
            self._oldest_received_s = now_s
        self.updates += 1
        return []

    def poll(self, now_s: float) -> list[Effect]:
        now_s = check_now(now_s)
        if now_s - self._oldest_received_s <= NEIGHBOUR_TIMEOUT_S:
            return []  # every entry arrived at or after the oldest, so none is older than the timeout
        stale = [s for s, n in self._entries.items() if n.age_s(now_s) > NEIGHBOUR_TIMEOUT_S]
        for sysid in stale:
            del self._entries[sysid]
        self._oldest_received_s = min((n.received_s for n in self._entries.values()), default=math.inf)
        return []

    def entries(self, now_s: float) -> list[Neighbour]:
        """Current neighbours (none older than the timeout), by system id."""
        return [n for _, n in sorted(self._entries.items()) if n.age_s(now_s) <= NEIGHBOUR_TIMEOUT_S]
