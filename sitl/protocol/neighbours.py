"""What a drone knows of its neighbours: positions relayed over MAVLink, each with its age.

The ground station forwards every drone's GLOBAL_POSITION_INT to the others unchanged (original system id kept, as a
MAVLink router does), so a neighbour is exactly what that drone reports of itself. This table is the only source of
neighbour positions for the autopilot besides its camera; it never reads the simulation's shared world.
Entries expire after ``NEIGHBOUR_TIMEOUT_S`` without news, so a lost relay shows as an empty table, not stale data.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

from pymavlink.dialects.v20 import common as mavlink

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


class NeighbourTable:
    """A service on every link: GLOBAL_POSITION_INT from other systems updates the (shared) table."""

    handles: frozenset[int] = frozenset({mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT})

    def __init__(self, own_sysid: int) -> None:
        self.own_sysid = own_sysid
        self._entries: dict[int, Neighbour] = {}
        self.updates = 0

    def handle(self, msg: MAVLinkMessage, now_s: float) -> list[Effect]:
        now_s = check_now(now_s)
        try:
            source = source_of(msg)
            if source.sysid == self.own_sysid:
                return []
            lat = read_int(msg, "lat", lo=-900_000_000, hi=900_000_000)
            lon = read_int(msg, "lon", lo=-1_800_000_000, hi=1_800_000_000)
            alt = read_int(msg, "alt", lo=-(2**31), hi=2**31 - 1)
            vx, vy, vz = (read_int(msg, f, lo=-32768, hi=32767) for f in ("vx", "vy", "vz"))
            boot_ms = read_int(msg, "time_boot_ms", lo=0, hi=2**32 - 1)
        except PeerInputError:
            return []
        self._entries[source.sysid] = Neighbour(
            sysid=source.sysid,
            lat_deg=lat * 1e-7,
            lon_deg=lon * 1e-7,
            alt_amsl_m=alt * 1e-3,
            vel_ned_mps=(vx * 0.01, vy * 0.01, vz * 0.01),
            sender_time_s=boot_ms * 1e-3,
            received_s=now_s,
        )
        self.updates += 1
        return []

    def poll(self, now_s: float) -> list[Effect]:
        now_s = check_now(now_s)
        stale = [s for s, n in self._entries.items() if n.age_s(now_s) > NEIGHBOUR_TIMEOUT_S]
        for sysid in stale:
            del self._entries[sysid]
        return []

    def entries(self, now_s: float) -> list[Neighbour]:
        """Current neighbours (none older than the timeout), by system id."""
        return [n for _, n in sorted(self._entries.items()) if n.age_s(now_s) <= NEIGHBOUR_TIMEOUT_S]
