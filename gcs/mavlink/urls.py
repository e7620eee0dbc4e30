"""Connection URLs of a MAVLink vehicle, in both spellings users know, as pymavlink's device strings.

pymavlink (MAVProxy, the ``mavlink_connection`` of every script) writes ``udpin:0.0.0.0:14560``, ``udpout:HOST:PORT``,
``tcp:HOST:PORT``, ``tcpin:HOST:PORT`` and ``/dev/ttyUSB0,57600``; MAVSDK writes ``udpin://0.0.0.0:14560``,
``udpout://HOST:PORT``, ``tcpout://HOST:PORT`` (``tcp://`` in its older releases), ``tcpin://HOST:PORT`` and
``serial:///dev/ttyUSB0:57600``. Both name the same links; a vehicle the ground station attaches is opened with
pymavlink, so either spelling becomes pymavlink's. A bad URL is one line (``UrlError``). Pure: nothing is opened.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Final, Literal

Kind = Literal["udpin", "udpout", "tcp", "tcpin", "serial"]

DEFAULT_BAUD: Final = 57600  # a SiK telemetry radio's default
_MAVSDK: Final = re.compile(r"^(?P<scheme>[a-z]+)://(?P<rest>.*)$")
_PYMAVLINK: Final = re.compile(r"^(?P<scheme>udpin|udpout|udp|tcp|tcpin):(?P<rest>[^/].*)$")
_SCHEMES: Final[dict[str, Kind]] = {
    "udpin": "udpin",
    "udp": "udpin",  # MAVSDK's older spelling of a port to listen on, and pymavlink's
    "udpout": "udpout",
    "tcp": "tcp",
    "tcpout": "tcp",
    "tcpin": "tcpin",
}
USAGE: Final = (
    "udpin:HOST:PORT, udpout:HOST:PORT, tcp:HOST:PORT, tcpin:HOST:PORT or /dev/DEVICE[,BAUD] (pymavlink), or "
    "udpin://HOST:PORT, udpout://HOST:PORT, tcpout://HOST:PORT, tcpin://HOST:PORT or serial:///dev/DEVICE[:BAUD] "
    "(MAVSDK)"
)


class UrlError(ValueError):
    """Not a vehicle URL; the message is one line."""


@dataclass(frozen=True, slots=True)
class VehicleUrl:
    """A parsed URL: how pymavlink opens it (``device``), its kind, and where (host and port, or serial device and
    baud rate)."""

    device: str
    kind: Kind
    host: str
    port: int  # the baud rate for a serial link

    def describe(self) -> str:
        return f"{self.host},{self.port}" if self.kind == "serial" else f"{self.kind}:{self.host}:{self.port}"


def _host_port(text: str, url: str) -> tuple[str, int]:
    host, sep, port = text.rpartition(":")
    if not sep or not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise UrlError(f"{url!r} is no vehicle URL: want HOST:PORT with a port in 1..65535 ({USAGE})")
    return host, int(port)


def _serial(device: str, baud: str, url: str) -> VehicleUrl:
    if not device or (baud and not baud.isdigit()) or (baud and int(baud) <= 0):
        raise UrlError(f"{url!r} is no serial URL: want /dev/DEVICE[,BAUD] or serial:///dev/DEVICE[:BAUD]")
    rate = int(baud) if baud else DEFAULT_BAUD
    return VehicleUrl(device=f"{device},{rate}", kind="serial", host=device, port=rate)


def parse_vehicle_url(url: str) -> VehicleUrl:
    """Either spelling, as pymavlink opens it; UrlError (one line) for anything else."""
    text = url.strip()
    if m := _MAVSDK.match(text):
        scheme, rest = m["scheme"], m["rest"]
        if scheme == "serial":
            device, sep, baud = rest.rpartition(":")
            return _serial(device if sep else rest, baud if sep else "", url)
        kind = _SCHEMES.get(scheme)
        if kind is None:
            raise UrlError(f"{url!r}: no link of scheme {scheme!r} ({USAGE})")
        host, port = _host_port(rest, url)
        return VehicleUrl(device=f"{kind}:{host}:{port}", kind=kind, host=host, port=port)
    if m := _PYMAVLINK.match(text):
        kind = _SCHEMES[m["scheme"]]
        host, port = _host_port(m["rest"], url)
        return VehicleUrl(device=f"{kind}:{host}:{port}", kind=kind, host=host, port=port)
    if text.startswith("/dev/") or re.match(r"^COM\d+", text):
        device, _sep, baud = text.partition(",")
        return _serial(device, baud, url)
    raise UrlError(f"{url!r} is no vehicle URL ({USAGE})")
