"""The ground station's MAVLink socket: one UDP port every drone's ground-station link streams to.

Drones are told (``sitl --gcs-remote``) to send to this port; each drone's address is learned from its datagrams and
messages to a drone go back to that address, routed by system id, as a MAVLink router does. One parser per source
address keeps a drone's byte stream separate from the others'. The supervisor identifies itself as system 255,
component 190 (MAV_COMP_ID_MISSIONPLANNER), like a ground station.
"""

from __future__ import annotations

import socket
from typing import Any

from pymavlink.dialects.v20 import common as mavlink

from sitl.mavlink_io import reset_parser

GCS_SYSID = 255
GCS_COMPID = mavlink.MAV_COMP_ID_MISSIONPLANNER

Address = tuple[str, int]


class GcsSocket:
    def __init__(self, bind: Address = ("127.0.0.1", 0)) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4 << 20)
        self.sock.bind(bind)
        self.sock.setblocking(False)
        self._encoder = mavlink.MAVLink(None, srcSystem=GCS_SYSID, srcComponent=GCS_COMPID)
        self._parsers: dict[Address, mavlink.MAVLink] = {}
        self.addresses: dict[int, Address] = {}  # sysid -> where its link lives

    @property
    def port(self) -> int:
        return int(self.sock.getsockname()[1])

    def receive(self) -> list[tuple[Any, Address]]:
        """Every message waiting on the socket with its sender (non-blocking), bad data dropped."""
        out: list[tuple[Any, Address]] = []
        while True:
            try:
                data, address = self.sock.recvfrom(65535)
            except (BlockingIOError, InterruptedError):
                return out
            except OSError:
                continue
            addr = (address[0], address[1])
            parser = self._parsers.get(addr)
            if parser is None:
                parser = self._parsers[addr] = mavlink.MAVLink(None)
                parser.robust_parsing = True
            reset_parser(parser)
            try:
                messages = parser.parse_buffer(data) or []
            except Exception:  # a misbehaving peer must not take the ground station down
                self._parsers.pop(addr, None)
                continue
            for msg in messages:
                if msg.get_type() == "BAD_DATA":
                    continue
                if msg.get_srcComponent() == 1:
                    self.addresses[msg.get_srcSystem()] = addr
                out.append((msg, addr))

    def pack(self, msg: Any) -> bytes:
        data: bytes = msg.pack(self._encoder)
        self._encoder.seq = (self._encoder.seq + 1) % 256
        return data

    def send(self, sysid: int, msg: Any) -> bool:
        """Send to one drone; False when that drone has not been heard yet."""
        address = self.addresses.get(sysid)
        if address is None:
            return False
        return self.send_raw(self.pack(msg), address)

    def send_raw(self, data: bytes, address: Address) -> bool:
        try:
            self.sock.sendto(data, address)
        except OSError:
            return False
        return True

    def close(self) -> None:
        self.sock.close()
