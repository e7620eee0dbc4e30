"""Where the flight tests find their vehicle: a drone this suite started, or one given with ``--vehicle``.

The flight tests only see a ``VehicleLink``: the connection URL in MAVSDK's and in pymavlink's spelling, the
system id when known, and the speed factor, which turns the simulated durations of a manoeuvre into the wall-clock
time limits the test waits for (client-side timeouts are wall clock, the vehicle's clock is simulation time).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Final

from tests.integration.sitl_process import LOOPBACK, SitlDrone

WALL_SLACK_S: Final = 10.0  # fixed allowance per wait: process scheduling, MAVSDK retries, a loaded CI machine
WALL_SLACK_FACTOR: Final = 2.0

_MAVSDK_URL = re.compile(r"^(?P<scheme>udpin|udpout|tcpin|tcpout|serial)://(?P<rest>.+)$")


class VehicleUrlError(ValueError):
    """A ``--vehicle`` value that is not a MAVSDK connection URL this suite can also give to pymavlink."""


def pymavlink_url(mavsdk_url: str) -> str:
    """Translate a MAVSDK connection URL into pymavlink's ``mavlink_connection`` device string.

    ``udpin://0.0.0.0:14540`` -> ``udpin:0.0.0.0:14540``, ``udpout://h:p`` -> ``udpout:h:p``,
    ``tcpout://h:p`` -> ``tcp:h:p``, ``tcpin://h:p`` -> ``tcpin:h:p``, ``serial:///dev/ttyX:57600`` ->
    ``/dev/ttyX,57600``.
    """
    match = _MAVSDK_URL.match(mavsdk_url)
    if match is None:
        raise VehicleUrlError(
            f"--vehicle must look like udpin://HOST:PORT, udpout://HOST:PORT, tcpout://HOST:PORT or "
            f"serial:///dev/DEVICE:BAUD, got {mavsdk_url!r}"
        )
    scheme, rest = match["scheme"], match["rest"]
    if scheme == "serial":
        device, _, baud = rest.rpartition(":")
        if not device or not baud.isdigit():
            raise VehicleUrlError(f"serial URL must be serial:///dev/DEVICE:BAUD, got {mavsdk_url!r}")
        return f"{device},{baud}"
    host, _, port = rest.rpartition(":")
    if not host or not port.isdigit():
        raise VehicleUrlError(f"{scheme} URL must be {scheme}://HOST:PORT, got {mavsdk_url!r}")
    return f"{'tcp' if scheme == 'tcpout' else scheme}:{host}:{port}"


@dataclass(frozen=True, slots=True, kw_only=True)
class VehicleLink:
    """How a test reaches its vehicle; ``drone`` is set only when this suite started the vehicle itself."""

    mavsdk_url: str
    pymavlink_url: str
    sysid: int | None  # None for an external vehicle: the first autopilot heard is the vehicle
    speed_factor: float
    drone: SitlDrone | None = None

    @classmethod
    def external(cls, mavsdk_url: str, speed_factor: float) -> VehicleLink:
        return cls(
            mavsdk_url=mavsdk_url,
            pymavlink_url=pymavlink_url(mavsdk_url),
            sysid=None,
            speed_factor=speed_factor,
        )

    @classmethod
    def of(cls, drone: SitlDrone) -> VehicleLink:
        # The suite's own client binds loopback only; the drone streams to 127.0.0.1:14540+i.
        port = drone.ports.api_remote
        return cls(
            mavsdk_url=f"udpin://{LOOPBACK}:{port}",
            pymavlink_url=f"udpin:{LOOPBACK}:{port}",
            sysid=drone.sysid,
            speed_factor=drone.speed_factor,
            drone=drone,
        )

    def window_s(self, sim_s: float) -> float:
        """Wall-clock length of an observation window covering ``sim_s`` seconds of the vehicle's time."""
        return sim_s / self.speed_factor

    def wall_s(self, sim_s: float) -> float:
        """Wall-clock limit for something the vehicle should do in ``sim_s`` seconds of its own time."""
        return sim_s / self.speed_factor * WALL_SLACK_FACTOR + WALL_SLACK_S
