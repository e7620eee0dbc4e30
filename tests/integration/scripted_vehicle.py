"""A vehicle the simulation does not run, played by a plain pymavlink script: what a real drone on a radio looks like
to the ground station (a HEARTBEAT at 1 Hz, GLOBAL_POSITION_INT at 10 Hz), and nothing of it reaches the simulated
world except through MAVLink.

It flies a scripted path (a function of wall time since ``start``: paced swarms keep wall time), answers nothing, and
can fall silent on request (a cut link).
"""

from __future__ import annotations

import math
import socket
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

from pymavlink.dialects.v20 import common as mavlink

from gcs.flight.geodesy import GeoPoint, NedFrame

Path = Callable[[float], tuple[float, float, float]]  # seconds since start -> NED metres from the origin


def back_and_forth(start_ne_m: tuple[float, float], end_ne_m: tuple[float, float], alt_m: float,
                   speed_mps: float) -> Path:  # fmt: skip
    """Along the segment from start to end and back, at ``speed_mps``, ``alt_m`` above the origin."""
    (n0, e0), (n1, e1) = start_ne_m, end_ne_m
    length = math.hypot(n1 - n0, e1 - e0)

    def at(t_s: float) -> tuple[float, float, float]:
        s = (speed_mps * t_s) % (2.0 * length)
        f = (s if s <= length else 2.0 * length - s) / length
        return (n0 + f * (n1 - n0), e0 + f * (e1 - e0), -alt_m)

    return at


@dataclass
class ScriptedVehicle:
    """Sends as sysid ``sysid`` to ``port`` on 127.0.0.1 (where ``swarm --attach udpin:127.0.0.1:PORT`` listens)."""

    sysid: int
    port: int
    origin: GeoPoint
    path: Path
    rate_hz: float = 10.0
    autopilot: int = mavlink.MAV_AUTOPILOT_PX4

    def __post_init__(self) -> None:
        self._sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._mav = mavlink.MAVLink(None, srcSystem=self.sysid, srcComponent=1)
        self._frame = NedFrame(self.origin)
        self._stop = threading.Event()
        self.silent = threading.Event()
        self._thread = threading.Thread(target=self._run, name=f"scripted-{self.sysid}", daemon=True)
        self.t0 = time.monotonic()
        self.sent_positions: list[tuple[float, tuple[float, float, float]]] = []  # (wall time, NED) of each report

    def start(self) -> ScriptedVehicle:
        self.t0 = time.monotonic()
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5)
        self._sock.close()

    def where(self, wall_s: float) -> tuple[float, float, float]:
        """Its NED position from the origin at monotonic time ``wall_s``."""
        return self.path(wall_s - self.t0)

    def _send(self, msg: mavlink.MAVLink_message) -> None:
        self._sock.sendto(msg.pack(self._mav), ("127.0.0.1", self.port))

    def _run(self) -> None:
        period = 1.0 / self.rate_hz
        next_beat = 0.0
        while not self._stop.wait(period):
            if self.silent.is_set():
                continue
            now = time.monotonic()
            t = now - self.t0
            if now >= next_beat:
                next_beat = now + 1.0
                self._send(mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_QUADROTOR, self.autopilot,
                                                             mavlink.MAV_MODE_FLAG_SAFETY_ARMED, 0,
                                                             mavlink.MAV_STATE_ACTIVE, 3))  # fmt: skip
            north, east, down = self.path(t)
            dt = 0.05
            n2, e2, d2 = self.path(t + dt)
            vel = ((n2 - north) / dt, (e2 - east) / dt, (d2 - down) / dt)
            geo = self._frame.geo_from_ned((north, east, down))
            self._send(mavlink.MAVLink_global_position_int_message(
                int(t * 1000) & 0xFFFFFFFF, round(geo.lat_deg * 1e7), round(geo.lon_deg * 1e7),
                round(geo.alt_amsl_m * 1e3), round(-down * 1e3), round(vel[0] * 100), round(vel[1] * 100),
                round(vel[2] * 100), 0))  # fmt: skip
            self.sent_positions.append((now, (north, east, down)))
