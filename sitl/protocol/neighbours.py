"""What a drone knows of its neighbours: their own position reports, each with where it came from and its age.

A neighbour's GLOBAL_POSITION_INT reaches a drone two ways: forwarded unchanged by the ground station's relay
(original system id kept, as a MAVLink router does), or heard directly from the neighbour's radio over the
drone-to-drone mesh (sitl/world/mesh.py). Any other system that sends one on a MAVLink link (the API link: a client, a
vehicle sharing a radio) is a neighbour too, counted apart as ``link``. Either way a neighbour is exactly
what that drone reports of itself. This table is the only source of neighbour positions for the autopilot besides
its camera; it never reads the simulation's shared world.

With both ways on, the same report may arrive twice, and a late copy of an old one after a newer one: an entry is
replaced only by a report the neighbour sent later (its time_boot_ms), whichever way it came, so a relayed copy
delayed by the ground station cannot push back a newer one heard over the mesh. Entries expire after
``NEIGHBOUR_TIMEOUT_S`` without news, so a lost relay (or a neighbour out of radio range) shows as an empty table,
not stale data. A neighbour that reboots (its clock starting again from zero) is believed again once its old entry
has expired.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Final, Literal

import numpy as np
import numpy.typing as npt
from pymavlink.dialects.v20 import common as mavlink

from sitl.kernels import neighbours as nk
from sitl.mathutil import fast_constructor
from sitl.protocol.core import Effect, MAVLinkMessage, PeerInputError, check_now, read_int, source_of
from sitl.protocol.framing import FRAME_MEMO_SIZE

NEIGHBOUR_TIMEOUT_S: Final = 3.0

NeighbourSource = Literal["relay", "link", "mesh"]
RELAY: Final[NeighbourSource] = "relay"  # on the ground-station link: the supervisor's relay
LINK: Final[NeighbourSource] = "link"  # on another MAVLink link (the API link): a client, another vehicle
MESH: Final[NeighbourSource] = "mesh"  # heard from the neighbour's own radio (sitl/world/mesh.py)
SOURCES: Final[tuple[NeighbourSource, ...]] = (RELAY, LINK, MESH)
_SOURCE_INDEX: Final = {source: k for k, source in enumerate(SOURCES)}  # a row's ``E_SOURCE``


@dataclass(frozen=True, slots=True, kw_only=True)
class Neighbour:
    sysid: int
    lat_deg: float
    lon_deg: float
    alt_amsl_m: float
    vel_ned_mps: tuple[float, float, float]
    sender_time_s: float  # the neighbour's own time_boot_ms, in seconds
    received_s: float  # our simulation time when it arrived
    source: NeighbourSource = RELAY  # the way the report came
    cooperative: bool = True  # a swarm neighbour (it avoids in turn); False: traffic from ADSB_VEHICLE
    # how old the sender's own knowledge was when it sent the report (traffic's ``tslc``: a vehicle the ground station
    # no longer hears, reported where it was last known); collision prevention widens its keep-out with it
    stale_s: float = 0.0
    # The same figures as one row (sitl/kernels/neighbours.py ``E_*``), made with the record: what the drone's
    # conversion into its frame reads, for every entry at once (``NeighbourTable.entry_rows``).
    row: tuple[float, ...] = field(default=(), compare=False, repr=False)

    def age_s(self, now_s: float) -> float:
        return now_s - self.received_s


_fast_neighbour = fast_constructor(Neighbour)


def _new_neighbour(*, sysid: int, lat_deg: float, lon_deg: float, alt_amsl_m: float,
                   vel_ned_mps: tuple[float, float, float], sender_time_s: float, received_s: float,
                   source: NeighbourSource, cooperative: bool, stale_s: float) -> Neighbour:  # fmt: skip
    """A record and its row."""
    vn, ve, vd = vel_ned_mps
    row = (lat_deg, lon_deg, alt_amsl_m, vn, ve, vd, sender_time_s, received_s, stale_s, 1.0 if cooperative else 0.0,
           float(sysid), float(_SOURCE_INDEX[source]))  # fmt: skip
    return _fast_neighbour(sysid=sysid, lat_deg=lat_deg, lon_deg=lon_deg, alt_amsl_m=alt_amsl_m,
                           vel_ned_mps=vel_ned_mps, sender_time_s=sender_time_s, received_s=received_s, source=source,
                           cooperative=cooperative, stale_s=stale_s, row=row)  # fmt: skip


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


@dataclass(frozen=True, slots=True, kw_only=True)
class SourceCounts:
    """What one source brought to the table: reports taken, and the ages of its entries when the table was read."""

    updates: int = 0  # reports that replaced an entry (or made one)
    age_sum_s: float = 0.0  # since it arrived, over the entries of this source handed out by ``entries``
    sent_age_sum_s: float = 0.0  # since the neighbour sent it (its time_boot_ms: one clock in lockstep)
    age_samples: int = 0

    @property
    def mean_age_s(self) -> float:
        return self.age_sum_s / self.age_samples if self.age_samples else 0.0

    @property
    def mean_sent_age_s(self) -> float:
        """How old the reports were when used, counted from their sending: the way's own delay included (the
        relay's hop through the supervisor, the mesh's quantum, the link model's latency). Paced, each drone's
        clock starts at its own boot, so this is off by the difference of their start-ups."""
        return self.sent_age_sum_s / self.age_samples if self.age_samples else 0.0


# ADSB_VEHICLE flags a traffic report needs: where it is, and how it moves.
_TRAFFIC_WHERE: Final = mavlink.ADSB_FLAGS_VALID_COORDS | mavlink.ADSB_FLAGS_VALID_ALTITUDE
_TRAFFIC_MOTION: Final = mavlink.ADSB_FLAGS_VALID_HEADING | mavlink.ADSB_FLAGS_VALID_VELOCITY


def _traffic_fields(msg: MAVLinkMessage) -> tuple[int, int, int, int, float, float, float, int] | None:
    """An ADSB_VEHICLE as (ICAO address, lat, lon degE7, altitude mm, velocity NED m/s, tslc s), or None when it
    does not say where the vehicle is; PeerInputError for a field out of its range. Without a valid heading and
    velocity it is taken to stand still (avoided in full all the same)."""
    flags = read_int(msg, "flags", lo=0, hi=0xFFFF)
    if flags & _TRAFFIC_WHERE != _TRAFFIC_WHERE:
        return None
    icao = read_int(msg, "ICAO_address", lo=0, hi=2**32 - 1)
    lat = read_int(msg, "lat", lo=-900_000_000, hi=900_000_000)
    lon = read_int(msg, "lon", lo=-1_800_000_000, hi=1_800_000_000)
    alt = read_int(msg, "altitude", lo=-(2**31), hi=2**31 - 1)
    tslc = read_int(msg, "tslc", lo=0, hi=255)
    vn = ve = vd = 0.0
    if flags & _TRAFFIC_MOTION == _TRAFFIC_MOTION:
        heading = math.radians(read_int(msg, "heading", lo=0, hi=35999) * 0.01)
        speed = read_int(msg, "hor_velocity", lo=0, hi=0xFFFF) * 0.01
        vn, ve = speed * math.cos(heading), speed * math.sin(heading)
        vd = -read_int(msg, "ver_velocity", lo=-32768, hi=32767) * 0.01
    return icao, lat, lon, alt, vn, ve, vd, tslc


def neighbour_of(msg: MAVLinkMessage, now_s: float, source: NeighbourSource) -> Neighbour | None:
    """The record a GLOBAL_POSITION_INT or an ADSB_VEHICLE makes, arriving at ``now_s`` from ``source``; None for
    one that says nothing usable (a field missing or out of range, traffic without a position). Whether the table
    takes it (its own report, an older one) is the table's to say."""
    if msg.get_msgId() == mavlink.MAVLINK_MSG_ID_ADSB_VEHICLE:
        try:
            fields = _traffic_fields(msg)
        except PeerInputError:
            return None
        if fields is None:
            return None
        icao, lat, lon, alt, vn, ve, vd, tslc = fields
        return _new_neighbour(sysid=icao, lat_deg=lat * 1e-7, lon_deg=lon * 1e-7, alt_amsl_m=alt * 1e-3,
                              vel_ned_mps=(vn, ve, vd), sender_time_s=now_s - tslc, received_s=now_s, source=source,
                              cooperative=False, stale_s=float(tslc))  # fmt: skip
    try:
        sender = source_of(msg).sysid
        # Not plain ints in range: the field-by-field checks say which, or accept what they accept.
        lat, lon, alt, vx, vy, vz, boot_ms = _plain_fields(msg) or _checked_fields(msg)
    except PeerInputError:
        return None
    return _new_neighbour(sysid=sender, lat_deg=lat * 1e-7, lon_deg=lon * 1e-7, alt_amsl_m=alt * 1e-3,
                          vel_ned_mps=(vx * 0.01, vy * 0.01, vz * 0.01), sender_time_s=boot_ms * 1e-3,
                          received_s=now_s, source=source, cooperative=True, stale_s=0.0)  # fmt: skip


class SharedReports:
    """The neighbour records the drones of one process make alike, made once (``neighbour_of``).

    The relay forwards each report byte for byte to every drone it matters to, the host's links parse equal frames
    into one message object (sitl/protocol/framing.py ``FrameMemo``), and the host's drones read their sockets at one
    simulated time: so each of them would make the same record of it. Each table still decides for itself whether
    to take it. Emptied whole when full, as the frame memo."""

    __slots__ = ("_records", "hits")

    def __init__(self) -> None:
        # by the message's identity (the entry keeps the message, so the identity stays its own), time and source
        self._records: dict[tuple[int, float, NeighbourSource], tuple[MAVLinkMessage, Neighbour | None]] = {}
        self.hits = 0

    def record(self, msg: MAVLinkMessage, now_s: float, source: NeighbourSource) -> Neighbour | None:
        key = (id(msg), now_s, source)
        known = self._records.get(key)
        if known is not None and known[0] is msg:
            self.hits += 1
            return known[1]
        report = neighbour_of(msg, now_s, source)
        if len(self._records) >= FRAME_MEMO_SIZE:
            self._records.clear()
        self._records[key] = (msg, report)
        return report


class NeighbourTable:
    """One table per drone: GLOBAL_POSITION_INT from other systems updates it, each link through its own
    ``NeighbourFeed`` (the source it counts as), the mesh radio through ``receive`` with ``source=MESH``.

    ADSB_VEHICLE updates it too, as traffic: a vehicle the ground station reports that does not avoid in turn (an
    intruder attached to the swarm, gcs/fleet/attach.py), keyed by its ICAO address (the ground station gives its
    sysid) and aged from its ``tslc``. PX4 takes traffic the same way, from an ADS-B receiver or a ground station."""

    handles: frozenset[int] = frozenset(
        {mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT, mavlink.MAVLINK_MSG_ID_ADSB_VEHICLE}
    )

    def __init__(self, own_sysid: int, shared: SharedReports | None = None) -> None:
        """``shared``: the records of the process's other drones, when it hosts several (``SharedReports``)."""
        self.own_sysid = own_sysid
        self._shared = shared
        self._entries: dict[int, Neighbour] = {}
        # No entry arrived before this time (a lower bound: an entry refreshed later only makes it older than need
        # be): while it is within the timeout of now, nothing can have expired and ``poll`` need not look. Polled at
        # every pass of the loop, the look over a crowd's table cost more than the table's updates.
        self._oldest_received_s = math.inf
        self.updates = 0
        self.stale = 0  # reports not newer than the entry they would replace (a second copy, or overtaken)
        self._updates = dict.fromkeys(SOURCES, 0)
        # The ages of the entries handed out, by source (``SOURCES`` order; sitl/kernels/neighbours.py ``A_*``):
        # counted where the table is read, by ``entries`` or by the kernel that reads ``entry_rows``
        self.ages = np.zeros((len(SOURCES), nk.AGES_SIZE))

    def handle(self, msg: MAVLinkMessage, now_s: float) -> list[Effect]:
        """A report that came over the ground-station link (the relay)."""
        self.receive(msg, now_s, RELAY)
        return []

    def receive(self, msg: MAVLinkMessage, now_s: float, source: NeighbourSource) -> None:
        """A neighbour's report, from ``source``; taken when it is newer than the entry it would replace."""
        now_s = check_now(now_s)
        shared = self._shared
        report = shared.record(msg, now_s, source) if shared is not None else neighbour_of(msg, now_s, source)
        if report is not None and report.sysid != self.own_sysid:
            self._take(report)

    def _take(self, report: Neighbour) -> None:
        """A report into the table, unless its entry holds one sent as late or later (a copy, or overtaken). Traffic
        comes only from the ground station, one report per vehicle at a time and never a copy: each replaces its
        entry (a vehicle it no longer hears is reported again where it was last known, its ``tslc`` whole seconds
        growing, so its time may step back by a fraction of a second)."""
        now_s = report.received_s
        known = self._entries.get(report.sysid)
        if (known is not None and report.cooperative and report.sender_time_s <= known.sender_time_s
                and known.age_s(now_s) <= NEIGHBOUR_TIMEOUT_S):  # fmt: skip
            self.stale += 1
            return
        self._entries[report.sysid] = report
        if now_s < self._oldest_received_s:
            self._oldest_received_s = now_s
        self.updates += 1
        self._updates[report.source] += 1

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
        """Current neighbours (none older than the timeout), by system id. Their ages are counted per source: the
        table is read where it is used (collision prevention's 20 Hz look), so the mean is the age at use."""
        out = [n for _, n in sorted(self._entries.items()) if n.age_s(now_s) <= NEIGHBOUR_TIMEOUT_S]
        ages = self.ages
        for n in out:  # as sitl/kernels/neighbours.py ``relay_rows`` counts them
            k = _SOURCE_INDEX[n.source]
            ages[k, nk.A_AGE] += now_s - n.received_s
            ages[k, nk.A_SENT_AGE] += now_s - n.sender_time_s
            ages[k, nk.A_SAMPLES] += 1.0
        return out

    def entry_rows(self) -> npt.NDArray[np.float64]:
        """Every entry's row (sitl/kernels/neighbours.py ``E_*``), in sysid order, old ones too: for a reader that
        filters them by age and counts their ages into ``ages`` itself, as ``entries`` does (``relay_rows``)."""
        rows = [n.row for _, n in sorted(self._entries.items())]
        return np.array(rows, dtype=np.float64).reshape(-1, nk.ENTRY_SIZE)

    def counts(self) -> dict[NeighbourSource, SourceCounts]:
        """What each source brought, for the drone's log and the flight report."""
        ages = self.ages.tolist()
        return {
            s: SourceCounts(
                updates=self._updates[s],
                age_sum_s=ages[k][nk.A_AGE],
                sent_age_sum_s=ages[k][nk.A_SENT_AGE],
                age_samples=int(ages[k][nk.A_SAMPLES]),
            )
            for k, s in enumerate(SOURCES)
        }


class NeighbourFeed:
    """A link's service that feeds the drone's one table, counting what it brings as ``source``."""

    handles: frozenset[int] = NeighbourTable.handles

    def __init__(self, table: NeighbourTable, source: NeighbourSource) -> None:
        self.table = table
        self.source = source

    def handle(self, msg: MAVLinkMessage, now_s: float) -> list[Effect]:
        self.table.receive(msg, now_s, self.source)
        return []

    def poll(self, now_s: float) -> list[Effect]:
        return self.table.poll(now_s)
