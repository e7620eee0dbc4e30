"""One MAVLink link's services composed behind a single ``handle``/``poll`` pair: what the IO shell talks to.

The shell owns one ``LinkServices`` per link (the API port and the ground-station port, sitl/process/ports.py), feeds it
every decoded message with the simulation time, calls ``poll`` on its loop, and sends the messages of the returned
``Send`` effects back on the same link. Vehicle-wide state (parameters, mission, modes) lives in the vehicle and the
``ParamStore``, so several links see one drone. This module also holds the two services too small for a module of
their own: TIMESYNC and PING answers, and peer heartbeat tracking.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Final

from pymavlink.dialects.v20 import common as mavlink

from sitl.autopilot.vehicle_api import VehicleApi
from sitl.params import ParamStore
from sitl.protocol.commands import CommandService
from sitl.protocol.core import (
    Effect,
    Identity,
    MAVLinkMessage,
    Peer,
    PeerInputError,
    Send,
    Service,
    check_now,
    message_id,
    read_int,
    source_of,
)
from sitl.protocol.images import ImageService, ImageSource
from sitl.protocol.mission import MissionServer
from sitl.protocol.offboard import OffboardService
from sitl.protocol.params import ParamService
from sitl.protocol.statustext import StatusTextEncoder
from sitl.protocol.telemetry import DEFAULT_RATES_HZ, PollShare, TelemetryScheduler

PEER_TIMEOUT_S: Final = 3.0  # a peer is gone after this long without a HEARTBEAT (MAVSDK uses 3 s as well)


class TimesyncService:
    """Answers TIMESYNC requests (tc1 == 0) with our clock in nanoseconds, as PX4 does; ignores answers."""

    handles: frozenset[int] = frozenset({mavlink.MAVLINK_MSG_ID_TIMESYNC})

    def handle(self, msg: MAVLinkMessage, now_s: float) -> list[Effect]:
        now_s = check_now(now_s)
        try:
            tc1 = read_int(msg, "tc1")
            ts1 = read_int(msg, "ts1", lo=-(2**63), hi=2**63 - 1)
        except PeerInputError:
            return []
        if tc1 != 0:
            return []
        return [Send(mavlink.MAVLink_timesync_message(int(now_s * 1e9), ts1))]

    def poll(self, now_s: float) -> list[Effect]:
        check_now(now_s)
        return []


class PingService:
    """Answers PING requests (target 0/0) by echoing them back to the sender, as PX4 does; ignores answers."""

    handles: frozenset[int] = frozenset({mavlink.MAVLINK_MSG_ID_PING})

    def handle(self, msg: MAVLinkMessage, now_s: float) -> list[Effect]:
        check_now(now_s)
        try:
            if read_int(msg, "target_system") != 0 or read_int(msg, "target_component") != 0:
                return []
            source = source_of(msg)
            time_usec = read_int(msg, "time_usec", lo=0, hi=2**64 - 1)
            seq = read_int(msg, "seq", lo=0, hi=2**32 - 1)
        except PeerInputError:
            return []
        return [Send(mavlink.MAVLink_ping_message(time_usec, seq, source.sysid & 0xFF, source.compid & 0xFF))]

    def poll(self, now_s: float) -> list[Effect]:
        check_now(now_s)
        return []


@dataclass(frozen=True, slots=True)
class PeerInfo:
    peer: Peer
    mav_type: int
    last_heartbeat_s: float


class PeerMonitor:
    """Remembers who sends HEARTBEATs on this link (ground stations, companion computers, other drones), and tells
    the vehicle of each ground-station HEARTBEAT: PX4's datalink-loss failsafe watches exactly those."""

    handles: frozenset[int] = frozenset({mavlink.MAVLINK_MSG_ID_HEARTBEAT})

    def __init__(self, identity: Identity, vehicle: VehicleApi | None = None) -> None:
        self._identity = identity
        self._vehicle = vehicle
        self._peers: dict[Peer, PeerInfo] = {}

    def handle(self, msg: MAVLinkMessage, now_s: float) -> list[Effect]:
        now_s = check_now(now_s)
        try:
            source = source_of(msg)
            mav_type = read_int(msg, "type", lo=0, hi=255)
        except PeerInputError:
            return []
        if source.sysid != self._identity.sysid:
            self._peers[source] = PeerInfo(source, mav_type, now_s)
            if mav_type == mavlink.MAV_TYPE_GCS and self._vehicle is not None:
                self._vehicle.note_gcs_heartbeat(now_s)
        return []

    def poll(self, now_s: float) -> list[Effect]:
        now_s = check_now(now_s)
        for peer in [p for p, info in self._peers.items() if now_s - info.last_heartbeat_s > PEER_TIMEOUT_S]:
            del self._peers[peer]
        return []

    def alive(self, now_s: float) -> list[PeerInfo]:
        return [info for info in self._peers.values() if now_s - info.last_heartbeat_s <= PEER_TIMEOUT_S]

    def gcs_connected(self, now_s: float) -> bool:
        return any(info.mav_type == mavlink.MAV_TYPE_GCS for info in self.alive(now_s))


class LinkServices:
    """All services of one link. ``handle``/``poll`` never raise for anything a peer sends."""

    def __init__(
        self,
        identity: Identity,
        vehicle: VehicleApi,
        params: ParamStore,
        *,
        rates_hz: Mapping[int, float] = DEFAULT_RATES_HZ,
        neighbours: Service | None = None,
        share: PollShare | None = None,
        images: ImageSource | None = None,
    ) -> None:
        """``share``: one ``PollShare`` for all links of a drone, opened around a poll of them all; ``neighbours``:
        the service that takes other systems' positions (a ``NeighbourTable``, or a ``NeighbourFeed`` into one);
        ``images``: what the drone's camera sees, for MAVLink image requests (none: every request gets an empty
        answer)."""
        self.identity = identity
        text = StatusTextEncoder()
        self.telemetry = TelemetryScheduler(identity, vehicle, rates_hz=rates_hz, statustext=text, share=share)
        self.commands = CommandService(identity, vehicle, self.telemetry, statustext=text)
        self.params = ParamService(identity, params, statustext=text)
        self.mission = MissionServer(identity, vehicle, statustext=text)
        self.offboard = OffboardService(identity, vehicle, statustext=text)
        self.timesync = TimesyncService()
        self.ping = PingService()
        self.peers = PeerMonitor(identity, vehicle)
        self.images = ImageService(images if images is not None else lambda _kind, _quality: None)
        self._services: tuple[Service, ...] = (
            self.commands,
            self.params,
            self.mission,
            self.offboard,
            self.timesync,
            self.ping,
            self.peers,
            self.images,
            self.telemetry,
            *((neighbours,) if neighbours is not None else ()),
        )
        # The services a poll asks: TIMESYNC and PING are answered as they arrive and have nothing to time out.
        self._polled = tuple(s for s in self._services if s is not self.timesync and s is not self.ping)
        self._own = Peer(identity.sysid, identity.compid)
        self._routes: dict[int, Service] = {}
        for service in self._services:
            for msg_id in service.handles:
                self._routes[msg_id] = service

    def handle(self, msg: MAVLinkMessage, now_s: float) -> list[Effect]:
        """Route one received message to the service that owns its type; unknown types are ignored."""
        now_s = check_now(now_s)
        msg_id = message_id(msg)
        service = self._routes.get(msg_id)
        if service is None:
            return []
        try:
            source = source_of(msg)
        except PeerInputError:
            return []
        if source == self._own:
            return []  # our own message echoed back (a shared socket, a router loop)
        out = service.handle(msg, now_s)
        if service is self.commands:
            # Arm/disarm/mode changes must reach clients at once: HEARTBEAT right behind the ACK.
            out.extend(self.telemetry.state_change_effects(now_s))
        return out

    def take_position(self, msg: MAVLinkMessage, now_s: float) -> None:
        """A GLOBAL_POSITION_INT, as ``handle`` takes one (to the service that takes positions, our own echo left
        out; it is answered with nothing), without the routing: a swarm drone receives its neighbours' relayed
        reports by the hundred a second, and the routing cost more than the table's work."""
        service = self._routes.get(mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT)
        own = self._own
        if service is not None and (msg.get_srcSystem() != own.sysid or msg.get_srcComponent() != own.compid):
            service.handle(msg, now_s)

    def poll(self, now_s: float) -> list[Effect]:
        """Timeouts, retries, parameter streaming and telemetry due at ``now_s``."""
        now_s = check_now(now_s)
        out: list[Effect] = []
        for service in self._polled:
            out.extend(service.poll(now_s))
        return out

    def statustext(self, severity: int, text: str) -> list[Effect]:
        """STATUSTEXT for an autopilot event (the shell forwards each vehicle event to every link)."""
        return self.telemetry.statustext(severity, text)
