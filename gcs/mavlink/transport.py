"""The ground station's MAVLink socket: one UDP port every drone's ground-station link streams to.

Drones are told (``sitl --gcs-remote``) to send to this port; each drone's address is learned from its datagrams and
messages to a drone go back to that address, routed by system id, as a MAVLink router does. One parser per source
address keeps a drone's byte stream separate from the others'. The supervisor identifies itself as system 255,
component 190 (MAV_COMP_ID_MISSIONPLANNER), like a ground station.

Traffic that need not leave at once (setpoint streams, relayed positions, the copy for another ground station) is
queued per address and sent by ``flush`` as few datagrams as possible, several MAVLink frames in each (every MAVLink
parser reads a datagram as a byte stream, so frames may share one). A drone then wakes once for a whole tick's worth
of traffic instead of once per message: on a busy machine a wake-up costs a drone more than handling the message.
"""

from __future__ import annotations

import socket
import time
from typing import Any

from pymavlink.dialects.v20 import common as mavlink

from gcs.mavlink import signing
from gcs.mavlink.wire import read_datagram
from swarmcommon.datagrams import datagrams

GCS_SYSID = 255
GCS_COMPID = mavlink.MAV_COMP_ID_MISSIONPLANNER

Address = tuple[str, int]
# Datagrams one ``receive`` reads at most. Drones that together send faster than the supervisor parses (fifty
# drones on two busy cores) would otherwise keep one call reading for ever, and with it the timers, the setpoint
# streams and the signal handling of the loop that called it; what is left waits for the next call, and what the
# socket buffer cannot hold is dropped, as any UDP link drops under overload.
MAX_RECEIVE_DATAGRAMS = 256


class GcsSocket:
    def __init__(self, bind: Address = ("127.0.0.1", 0), signing_key: bytes | None = None,
                 sysid: int = GCS_SYSID) -> None:  # fmt: skip
        """``signing_key``: sign every frame this socket packs (gcs/mavlink/signing.py); relayed and forwarded frames
        pass unchanged, with their own signatures. ``sysid``: the ground station's own system id (255 unless a
        QGroundControl beside it uses that)."""
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4 << 20)
        self.sock.bind(bind)
        self.sock.setblocking(False)
        self.sysid = sysid
        self._encoder = mavlink.MAVLink(None, srcSystem=sysid, srcComponent=GCS_COMPID)
        self.signing_key = signing_key
        if signing_key is not None:
            signing.enable(self._encoder, signing_key, time.time())
        self._parsers: dict[Address, mavlink.MAVLink] = {}
        self.addresses: dict[int, Address] = {}  # sysid -> where its link lives
        self._outbox: dict[Address, list[bytes]] = {}
        self.datagrams_sent = 0
        # Datagrams sent to and read from each address (lockstep delivery: gcs/fleet/swarm.py compares them with the
        # drones' own counts)
        self.sent_to: dict[Address, int] = {}
        self.received_from: dict[Address, int] = {}

    @property
    def port(self) -> int:
        return int(self.sock.getsockname()[1])

    def receive(self, max_datagrams: int = MAX_RECEIVE_DATAGRAMS) -> list[tuple[Any, Address]]:
        """The messages waiting on the socket with their senders, from at most ``max_datagrams`` datagrams
        (non-blocking), bad data dropped."""
        return [(msg, address) for address, messages in self.receive_datagrams(max_datagrams) for msg in messages]

    def receive_datagrams(self, max_datagrams: int = MAX_RECEIVE_DATAGRAMS) -> list[tuple[Address, list[Any]]]:
        """As ``receive``, one entry per datagram (its sender and messages): lockstep delivery takes a drone's
        datagrams up to the count it had sent at the gate, and keeps the rest for the next frame."""
        out: list[tuple[Address, list[Any]]] = []
        for _ in range(max_datagrams):
            try:
                data, address = self.sock.recvfrom(65535)
            except (BlockingIOError, InterruptedError):
                return out
            except OSError:
                continue
            addr = (address[0], address[1])
            self.received_from[addr] = self.received_from.get(addr, 0) + 1
            messages = read_datagram(data)  # the drones' telemetry, by precomputed layouts (gcs/mavlink/wire.py)
            if messages is None:
                messages = self._parse(addr, data)
            kept = []
            for msg in messages:
                if msg.get_type() == "BAD_DATA":
                    continue
                if msg.get_srcComponent() == 1:
                    self.addresses[msg.get_srcSystem()] = addr
                kept.append(msg)
            out.append((addr, kept))
        return out

    def _parse(self, addr: Address, data: bytes) -> list[Any]:
        """A datagram the fast reader left alone, through pymavlink's parser for its sender ([] when it raises)."""
        parser = self._parsers.get(addr)
        if parser is None or parser.buf_len() > 0:
            # A datagram holds whole frames, so a parser left holding part of one (a truncated datagram) holds
            # nothing of value: a fresh one keeps that fragment from corrupting the sender's next frame.
            parser = self._parsers[addr] = mavlink.MAVLink(None)
            parser.robust_parsing = True
        try:
            return parser.parse_buffer(data) or []
        except Exception:  # a misbehaving peer must not take the ground station down
            self._parsers.pop(addr, None)
            return []

    def pack(self, msg: Any) -> bytes:
        if self.signing_key is not None:
            signing.refresh(self._encoder, time.time())
        data: bytes = msg.pack(self._encoder)
        self._encoder.seq = (self._encoder.seq + 1) % 256
        return data

    def send(self, sysid: int, msg: Any) -> bool:
        """Send to one drone at once (after anything queued: a command must not overtake the setpoints streamed
        before it, or OFFBOARD is refused for want of a setpoint); False when that drone has not been heard yet."""
        address = self.addresses.get(sysid)
        if address is None:
            return False
        if self._outbox:
            self.flush()
        return self.send_raw(self.pack(msg), address)

    def send_raw(self, data: bytes, address: Address) -> bool:
        try:
            self.sock.sendto(data, address)
        except OSError:
            return False
        self.datagrams_sent += 1
        self.sent_to[address] = self.sent_to.get(address, 0) + 1
        return True

    def queue(self, sysid: int, msg: Any) -> bool:
        """Queue a message for one drone until the next ``flush``; False when that drone has not been heard yet."""
        address = self.addresses.get(sysid)
        if address is None:
            return False
        self.queue_raw(self.pack(msg), address)
        return True

    def queue_raw(self, data: bytes, address: Address) -> None:
        self._outbox.setdefault(address, []).append(data)

    @property
    def queued(self) -> bool:
        return bool(self._outbox)

    def flush(self) -> None:
        """Send everything queued: per address, whole frames packed in order into datagrams of <= MAX_BATCH_BYTES."""
        outbox, self._outbox = self._outbox, {}
        for address, frames in outbox.items():
            for data in datagrams(frames):
                self.send_raw(data, address)

    def close(self) -> None:
        self.sock.close()
