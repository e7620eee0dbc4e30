"""MAVLink over UDP for one drone: sockets, framing, and the routing of effects. The only IO of the protocol stack.

Each link (the API link on 14580+i and the ground-station link on 18570+i, PX4's SITL convention; from instance 40
on the API link is on 16000+i, sitl/process/ports.py) is a non-blocking UDP socket with its own ``LinkServices``. A link
streams to its configured remote from boot and also answers every address that has sent it something (PX4's
behaviour), so a client on any port is heard. Datagrams are parsed with pymavlink's robust parser: garbage becomes
"bad data" and is dropped; nothing a peer sends can raise out of here.

An injected MAVLink failure (FAILURE_UNIT_SYSTEM_MAVLINK_SIGNAL, see sitl/faults/failures.py) silences every link for
the rest of the process or for the time it asks, as a dead radio would: the reply that accepted the injection still
leaves, then nothing is sent, and whatever arrives is read and dropped unparsed (read, so that the loop's select does
not wake on it for ever). When the time is up the links simply work again, as a radio that comes back in range.
"""

from __future__ import annotations

import logging
import math
import socket
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import TYPE_CHECKING

from pymavlink.dialects.v20 import common as mavlink

from sitl.onboard.interface import GroundMessage
from sitl.params import ParamStore
from sitl.protocol import Identity, LinkServices, Send, VehicleApi, framing
from sitl.protocol.core import Effect, MAVLinkMessage
from sitl.protocol.images import EncodedImage, ImageSource
from sitl.protocol.neighbours import LINK, MESH, RELAY, NeighbourFeed, NeighbourTable
from sitl.protocol.signing import SIGN_CFG_PARAM, SigningGate, SigningState
from sitl.protocol.telemetry import PollShare
from sitl.world.linkmodel import DelayLine, Direction, LinkChannel, LinkClass, LinkCounters, counters_by_class
from swarmcommon.datagrams import datagrams

if TYPE_CHECKING:
    from sitl.world.mesh import MeshRadio

log = logging.getLogger(__name__)

Address = tuple[str, int]
MAX_DATAGRAM = 65535
MAX_LEARNED_PEERS = 8  # a few clients per link; the oldest is forgotten first
# Datagrams one ``receive`` reads at most (a whole supervisor tick is one or two). A peer that sends faster than the
# drone parses would otherwise keep the loop reading for ever, and the drone would stop flying; bounded, the loop
# steps its physics between reads and the socket buffer drops the excess, as a flooded radio link would.
MAX_RECEIVE_DATAGRAMS = 64
_POSITION_REPORT = mavlink.MAVLink_global_position_int_message


@dataclass(frozen=True, slots=True, kw_only=True)
class LinkConfig:
    name: str
    bind: Address
    remote: Address | None  # where to stream before anyone has spoken to us


def link_class_of(config: LinkConfig) -> LinkClass:
    """The link model's class of a link: the ground-station link is ``gcs``, any other a client's ``api``."""
    return "gcs" if config.name.lower() == "gcs" else "api"


class LinkError(OSError):
    """A link could not be opened (port in use, bad address); reported as one line by the CLI."""


def reset_parser(parser: mavlink.MAVLink) -> None:
    """Drop any partial frame a parser holds, so a truncated datagram cannot corrupt the next sender's frames."""
    parser.buf = bytearray()
    parser.buf_index = 0
    parser.expected_length = mavlink.HEADER_LEN_V1 + 2
    parser.have_prefix_error = False


class UdpLink:
    def __init__(
        self, config: LinkConfig, identity: Identity, services: LinkServices, *, signing: SigningState | None = None,
        link_id: int = 0, memo: framing.FrameMemo | None = None,
    ) -> None:  # fmt: skip
        """``signing``: the drone's signing state (its key signs what this link sends); ``link_id``: this link's
        id in the signatures (PX4 uses its MAVLink instance number); ``memo``: the frames the host's drones receive
        alike, parsed once (sitl/protocol/framing.py ``FrameMemo``)."""
        self.config = config
        self._memo = memo
        self.services = services
        self.signing = signing
        self.link_id = link_id
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 20)
            self.sock.bind(config.bind)
        except OSError as exc:
            self.sock.close()
            host, port = config.bind
            raise LinkError(f"{config.name} link cannot bind {host}:{port}: {exc.strerror}") from None
        self.sock.setblocking(False)
        self._encoder = mavlink.MAVLink(None, srcSystem=identity.sysid, srcComponent=identity.compid)
        self._parser = self._new_parser()
        self._peers: list[Address] = [config.remote] if config.remote is not None else []
        # The link model's channel for what this link sends (None: a perfect link), the frames it delays, and the
        # simulated time of what is being sent (set by the endpoint before it sends).
        self.channel: LinkChannel | None = None
        # Datagrams sent to and read from the configured remote (the supervisor, for a swarm's ground-station
        # link): lockstep delivery compares them with the other side's count (sitl/world/shared.py SUPERVISOR_SENT).
        self.to_remote = 0
        self.from_remote = 0
        self._outbox: DelayLine[bytes] = DelayLine()
        self.now_s = 0.0
        self.sent = 0
        self.received = 0
        self.bad = 0

    @staticmethod
    def _new_parser() -> mavlink.MAVLink:
        parser = mavlink.MAVLink(None)
        parser.robust_parsing = True
        return parser

    @property
    def link_class(self) -> LinkClass:
        return link_class_of(self.config)

    @property
    def port(self) -> int:
        return int(self.sock.getsockname()[1])

    def _learn(self, address: Address) -> None:
        if address in self._peers:
            return
        self._peers.append(address)
        if len(self._peers) > MAX_LEARNED_PEERS:
            del self._peers[1 if self.config.remote is not None else 0]

    def receive(self) -> list[MAVLinkMessage]:
        """The messages that arrived since the last call, from at most MAX_RECEIVE_DATAGRAMS datagrams."""
        out: list[MAVLinkMessage] = []
        for _ in range(MAX_RECEIVE_DATAGRAMS):
            try:
                data, address = self.sock.recvfrom(MAX_DATAGRAM)
            except (BlockingIOError, InterruptedError):
                return out
            except OSError:  # e.g. ICMP port unreachable reported on a later call: not our problem
                continue
            self._learn((address[0], address[1]))
            if address == self.config.remote:
                self.from_remote += 1
            # The common datagram (relayed positions, setpoints, heartbeats) is parsed by precomputed layouts;
            # anything else goes to pymavlink's parser, as every datagram used to.
            messages = framing.parse_datagram(data, self._memo)
            if messages is not None:
                self.received += len(messages)
                out.extend(messages)
                continue
            reset_parser(self._parser)  # a datagram holds whole frames: nothing carries over from the last one
            try:
                messages = self._parser.parse_buffer(data) or []
            except Exception:  # a peer's bytes must never take the drone down
                self.bad += 1
                self._parser = self._new_parser()
                continue
            for msg in messages:
                if msg.get_type() == "BAD_DATA":
                    self.bad += 1
                else:
                    self.received += 1
                    out.append(msg)
        return out

    def drain(self) -> None:
        """Read and drop whatever arrived (a silenced link): at most MAX_RECEIVE_DATAGRAMS datagrams a call."""
        for _ in range(MAX_RECEIVE_DATAGRAMS):
            try:
                _data, address = self.sock.recvfrom(MAX_DATAGRAM)
            except (BlockingIOError, InterruptedError):
                return
            except OSError:
                continue
            if address == self.config.remote:
                self.from_remote += 1  # read, though dropped: lockstep delivery waits for nothing more

    def send(self, effects: Iterable[Effect]) -> None:
        """Send the messages among ``effects`` to every peer, together: the streams due at one poll (several share
        each 100 ms tick) or the replies to one message leave in one datagram per peer."""
        frames: list[bytes] = []
        encoder = self._encoder
        for effect in effects:
            if not isinstance(effect, Send):
                continue
            msg = effect.msg
            try:
                layout = framing.layout_of(msg)
                if layout is not None:  # the same bytes as pymavlink's packing, several times cheaper
                    frames.append(framing.pack(layout, msg, encoder.seq, encoder.srcSystem, encoder.srcComponent))
                else:
                    frames.append(msg.pack(encoder))
            except Exception:  # a message that cannot be packed is a bug, but not a crash
                log.exception("cannot pack %s", msg.get_type())
                continue
            encoder.seq = (encoder.seq + 1) % 256
        if not frames:
            return
        if self.signing is not None and self.signing.active:
            frames = self.signing.sign_frames(frames, self.link_id, time.time())
        if self.channel is not None:
            frames = self._through_channel(frames)
        self._send_frames(frames)

    def _through_channel(self, frames: list[bytes]) -> list[bytes]:
        """The frames the link model lets through now; the ones it delays wait in the outbox, the lost are gone."""
        assert self.channel is not None
        now_s = self.now_s
        out: list[bytes] = []
        for frame in frames:
            due_s = self.channel.transmit(now_s, len(frame))
            if due_s is None:
                continue
            if due_s <= now_s:
                out.append(frame)
            else:
                self._outbox.push(due_s, frame)
        return out

    def send_due(self, now_s: float) -> None:
        """Send the delayed frames whose time has come."""
        if self._outbox.next_due_s <= now_s:
            self._send_frames(self._outbox.pop_due(now_s))

    def _send_frames(self, frames: list[bytes]) -> None:
        if not frames:
            return
        for data in datagrams(frames) if len(frames) > 1 else frames:
            for address in self._peers:
                try:
                    self.sock.sendto(data, address)
                    self.sent += 1
                    if address == self.config.remote:
                        self.to_remote += 1
                except OSError:  # the peer's port is closed or the buffer is full: UDP drops, as the wire would
                    pass

    def close(self) -> None:
        self.sock.close()


class MavlinkEndpoint:
    """All links of one drone, driven by the runtime once per wake-up with the simulation time."""

    def __init__(
        self, identity: Identity, vehicle: VehicleApi, params: ParamStore, links: list[LinkConfig], *,
        signing_key: bytes | None = None, neighbours: NeighbourTable | None = None, camera: ImageSource | None = None,
        on_named_value: Callable[[GroundMessage], None] | None = None, mesh: MeshRadio | None = None,
        channels: dict[tuple[LinkClass, Direction], LinkChannel] | None = None, memo: framing.FrameMemo | None = None,
    ) -> None:  # fmt: skip
        """``signing_key``: sign everything sent with it from boot (SETUP_SIGNING may install one later);
        ``neighbours``: the drone's neighbour table (its own, when not given); ``camera``: what the drone's cameras
        see, for image requests; ``on_named_value``: where a NAMED_VALUE_FLOAT sent to the drone goes (an onboard
        behaviour); ``mesh``: the drone's mesh radio (``attach_mesh``); ``channels``: the link model's (``impair``);
        ``memo``: the frames the host's drones receive alike (``UdpLink``)."""
        self.links: list[UdpLink] = []
        self._vehicle = vehicle
        # One key and one set of incoming streams for all links, as PX4 keeps them; MAV_SIGN_CFG says whether
        # unsigned messages are dropped (sitl/protocol/signing.py).
        self.signing = SigningState(signing_key)
        self._gate = SigningGate(
            self.signing, identity.sysid, identity.compid, sign_cfg=lambda: int(params[SIGN_CFG_PARAM]),
            armed=lambda: vehicle.snapshot().armed,
        )  # fmt: skip
        self.silenced = False  # while an injected MAVLink failure is in force: nothing is sent or read
        # Where a NAMED_VALUE_FLOAT sent to this drone goes (an onboard behaviour's messages, sitl/onboard)
        self.on_named_value = on_named_value
        # What the drone's camera sees, for MAVLink image requests (sitl/protocol/images.py)
        self.camera = camera
        self._silent_until_s = -math.inf  # simulated time it ends (inf: for good)
        self._sysid = identity.sysid
        # The link model (``impair``): channels by class and direction, and what arrived but is delayed.
        self._channels: dict[tuple[LinkClass, Direction], LinkChannel] = {}
        self._inbox: DelayLine[tuple[UdpLink, MAVLinkMessage]] = DelayLine()
        self._delaying: list[UdpLink] = []  # the links whose sending goes through a channel
        # One table for the drone, fed by whichever link the relayed positions arrive on, and by the mesh radio.
        self.neighbours = neighbours if neighbours is not None else NeighbourTable(identity.sysid)
        self._identity = identity
        self.mesh: MeshRadio | None = None  # the drone-to-drone mesh radio (``attach_mesh``)
        self._mesh_link_id = 0
        self._mesh_seq = 0
        self._mesh_parser = UdpLink._new_parser()
        # One vehicle snapshot and one message per stream for all links at each poll (see PollShare).
        self._share = PollShare(vehicle)
        try:
            for link_id, config in enumerate(links):
                # Positions on the ground-station link are the supervisor's relay; on another link, a client's.
                feed = NeighbourFeed(self.neighbours, RELAY if link_class_of(config) == "gcs" else LINK)
                services = LinkServices(identity, vehicle, params, neighbours=feed, share=self._share,
                                        images=self._camera_image)  # fmt: skip
                self.links.append(UdpLink(config, identity, services, signing=self.signing, link_id=link_id, memo=memo))
        except LinkError:
            self.close()
            raise
        if mesh is not None:
            self.attach_mesh(mesh)
        if channels is not None:
            self.impair(channels)

    def _camera_image(self, kind: int, quality: int) -> EncodedImage | None:
        return self.camera(kind, quality) if self.camera is not None else None

    def sockets(self) -> list[socket.socket]:
        return [link.sock for link in self.links]

    def impair(self, channels: dict[tuple[LinkClass, Direction], LinkChannel]) -> None:
        """Put the link model's channels on this drone's links (sitl/world/linkmodel.py): each link sends through the
        down channel of its class; what arrives goes through the up channel of its class, except neighbours'
        positions, which go through the neighbour class's (they are neighbour traffic, whichever link brings them).
        A class without a channel is perfect."""
        self._channels = channels
        for link in self.links:
            link.channel = channels.get((link.link_class, "down"))
        self._delaying = [link for link in self.links if link.channel is not None]

    def attach_mesh(self, radio: MeshRadio) -> None:
        """Give the drone a mesh radio (sitl/world/mesh.py): its own position reports are broadcast on it at each poll
        that streams one, and what it hears goes to the neighbour table (``hear_mesh``). The radio is one more link
        of the drone, with its own sequence numbers and, when signing, its own link id in the signatures."""
        self.mesh = radio
        self._mesh_link_id = len(self.links)

    def _broadcast(self, msg: MAVLinkMessage, now_s: float) -> None:
        assert self.mesh is not None
        identity = self._identity
        layout = framing.layout_of(msg)
        try:
            if layout is not None:
                frame = framing.pack(layout, msg, self._mesh_seq, identity.sysid, identity.compid)
            else:
                frame = msg.pack(mavlink.MAVLink(None, srcSystem=identity.sysid, srcComponent=identity.compid))
        except Exception:  # a message that cannot be packed is a bug, but not a crash
            log.exception("cannot pack %s for the mesh", msg.get_type())
            return
        self._mesh_seq = (self._mesh_seq + 1) % 256
        if self.signing.active:
            frame = self.signing.sign_frames([frame], self._mesh_link_id, time.time())[0]
        self.mesh.broadcast(frame, now_s)

    def hear_mesh(self, now_s: float) -> None:
        """After every physics step: what the mesh radio heard by now into the neighbour table, through the signing
        gate as on any link (a drone that requires signing drops unsigned reports)."""
        mesh = self.mesh
        if mesh is None:
            return
        frames = mesh.after_step(now_s)
        if not frames or self.silenced:
            return  # a silenced drone's radio is dead: it hears nothing
        # The frames heard at one step parsed together, as a datagram of several frames is: one call, not one each.
        data = b"".join(frames)
        messages = framing.parse_datagram(data)
        if messages is None:
            reset_parser(self._mesh_parser)
            try:
                messages = [m for m in self._mesh_parser.parse_buffer(data) or [] if m.get_type() != "BAD_DATA"]
            except Exception:  # frames torn in the medium fail their CRC: not heard
                self._mesh_parser = UdpLink._new_parser()
                return
        for msg in messages:
            if msg.get_msgId() != mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT:
                continue
            admit, texts = self._gate.admit(msg, self._mesh_link_id)
            for _severity, text in texts:
                log.warning("mesh: %s", text)
            if admit:
                self.neighbours.receive(msg, now_s, MESH)

    def link_counters(self) -> dict[tuple[LinkClass, Direction], LinkCounters]:
        return counters_by_class(self._channels)

    def _up_channel(self, link: UdpLink, msg: MAVLinkMessage) -> LinkChannel | None:
        if msg.get_msgId() == mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT and msg.get_srcSystem() != self._sysid:
            return self._channels.get(("neighbour", "up"))
        return self._channels.get((link.link_class, "up"))

    def receive(self, now_s: float) -> None:
        if self._still_silent(now_s):
            for link in self.links:
                link.drain()
            return
        impaired = bool(self._channels)
        for link in self.links:
            link.now_s = now_s
            for msg in link.receive():
                channel = self._up_channel(link, msg) if impaired else None
                if channel is not None:
                    due_s = channel.transmit(now_s, len(msg.get_msgbuf()))
                    if due_s is None:
                        continue
                    if due_s > now_s:
                        self._inbox.push(due_s, (link, msg))
                        continue
                self._handle(link, msg, now_s)

    def deliver_due(self, now_s: float) -> None:
        """Hand the services what the link model delayed until now, and send what it held back; called after every
        physics step (a look at two queues when nothing waits), so a delay ends at a step, the same in every run."""
        if self._inbox.next_due_s <= now_s:
            for link, msg in self._inbox.pop_due(now_s):
                link.now_s = now_s
                self._handle(link, msg, now_s)
        for link in self._delaying:
            link.now_s = now_s
            link.send_due(now_s)

    def _handle(self, link: UdpLink, msg: MAVLinkMessage, now_s: float) -> None:
        if self.silenced:
            return  # arrived after the radio died
        if type(msg) is _POSITION_REPORT and self.signing.key is None:
            # Most of what a swarm drone receives: without a key the gate admits it, its one service answers
            # nothing, and it can neither be a behaviour's message nor silence the links.
            link.services.take_position(msg, now_s)
            return
        if not self._admitted(link, msg):
            return
        link.send(link.services.handle(msg, now_s))
        if self.on_named_value is not None and msg.get_msgId() == mavlink.MAVLINK_MSG_ID_NAMED_VALUE_FLOAT:
            self._named_value(msg, now_s)
        until_s = self._vehicle.mavlink_silent_until_s()
        if until_s > now_s:
            self._silence(until_s)

    def _named_value(self, msg: MAVLinkMessage, now_s: float) -> None:
        """A NAMED_VALUE_FLOAT for the onboard behaviour; one that is not a finite number with a name is dropped."""
        assert self.on_named_value is not None
        name, value = getattr(msg, "name", None), getattr(msg, "value", None)
        if isinstance(name, bytes):
            name = name.rstrip(b"\0").decode("ascii", "replace")
        if isinstance(name, str) and name and isinstance(value, float) and math.isfinite(value):
            self.on_named_value(GroundMessage(name=name.rstrip("\0"), value=value, time_s=now_s))

    def _admitted(self, link: UdpLink, msg: MAVLinkMessage) -> bool:
        """Whether signing lets ``msg`` through to the services; says once per link and reason why not."""
        admit, texts = self._gate.admit(msg, link.link_id)
        for severity, text in texts:
            log.log(logging.WARNING if severity <= mavlink.MAV_SEVERITY_WARNING else logging.INFO, "%s link: %s",
                    link.config.name, text)  # fmt: skip
            link.send(link.services.statustext(severity, text))
        return admit

    def _silence(self, until_s: float) -> None:
        self.silenced, self._silent_until_s = True, until_s
        lasting = "from now on" if math.isinf(until_s) else f"until t={until_s:.3f} s"
        log.warning("MAVLink signal lost (injected failure): all links silent %s", lasting)

    def _still_silent(self, now_s: float) -> bool:
        """Whether the links are silent at ``now_s``; the first call after an injected failure's time is up ends
        it, and says so."""
        if self.silenced and now_s >= self._silent_until_s:
            self.silenced = False
            log.warning("MAVLink signal back (the injected failure ended)")
        return self.silenced

    def poll(self, now_s: float) -> None:
        if self._still_silent(now_s):
            return
        self._share.open()
        report: MAVLinkMessage | None = None
        try:
            for link in self.links:
                link.now_s = now_s
                effects = link.services.poll(now_s)
                if self.mesh is not None and report is None:
                    report = _position_report(effects)
                link.send(effects)
        finally:
            self._share.close()
        if report is not None:
            self._broadcast(report, now_s)

    def statustext(self, severity: int, text: str) -> None:
        if self.silenced:
            return
        for link in self.links:
            link.send(link.services.statustext(severity, text))

    def close(self) -> None:
        for link in self.links:
            link.close()


def _position_report(effects: list[Effect]) -> MAVLinkMessage | None:
    """The drone's own GLOBAL_POSITION_INT among a poll's effects (the stream is due), or None."""
    for effect in effects:
        if isinstance(effect, Send) and effect.msg.get_msgId() == mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT:
            return effect.msg
    return None
