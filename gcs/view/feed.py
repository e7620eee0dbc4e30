"""Feeds the live view from a running swarm: at most ``RATE_HZ`` frames a wall-clock second, whatever the pace.

Called from the supervisor's tick (``swarm fly``, ``swarm up``). Building a frame reads what the ground station
already holds; at a lockstep pace of 10x only one tick in many builds one.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterable
from typing import Any, Final

import numpy as np

from gcs.fleet.swarm import Swarm
from gcs.flight.behaviours import pairwise_offsets
from gcs.flight.frames import Targets, Vec3
from gcs.mavlink.images import ImageAssembler, image_request
from gcs.record.metrics import AIRBORNE_HEIGHT_M, LiveMetrics
from gcs.record.recording import ObstacleShape
from gcs.view.scene import frame
from gcs.view.server import RATE_HZ, ViewServer

RTF_SMOOTHING: Final = 0.2  # weight of the newest reading in the real-time factor shown
CAMERA_RATE_HZ: Final = 2.0  # images asked of a drone whose camera a page shows, per wall second
CAMERA_MESSAGES: Final = frozenset({"DATA_TRANSMISSION_HANDSHAKE", "ENCAPSULATED_DATA"})


class FramePacer:
    """When frames are due: on a grid of periods of the wall clock, so that ticks that do not fall on it (the
    supervisor's 20 Hz, jittered) still give ``rate_hz`` frames a second; more than a period late (a slow tick, a
    pause with nobody watching), the grid starts again from now."""

    def __init__(self, rate_hz: float) -> None:
        self.period_s = 1.0 / rate_hz
        self._next_s = -math.inf

    def due(self, wall_s: float) -> bool:
        if wall_s < self._next_s:
            return False
        late = wall_s - self._next_s >= self.period_s
        self._next_s = wall_s + self.period_s if late else self._next_s + self.period_s
        return True


class ViewFeed:
    """One swarm into one view server."""

    def __init__(self, server: ViewServer, swarm: Swarm, targets: Targets, obstacles: Iterable[ObstacleShape] = (),
                 clock: Callable[[], float] = time.monotonic, live: LiveMetrics | None = None) -> None:  # fmt: skip
        """What it reads: the swarm's picture, fleet view, losses and attached vehicles, and ``targets``, each
        drone's slot (the setpoint streamer's, never the streamer); ``live``: the flight recorder's running metrics,
        whose minimum separation (over every sample, as the report's) the header shows; without it, the minimum over
        the frames built."""
        self.server = server
        self.swarm = swarm
        self.targets = targets
        self.live = live
        self.min_separation_m: float | None = None
        self.obstacles = tuple(obstacles)
        self.clock = clock
        self._last_wall_s = -math.inf
        self._pacer = FramePacer(RATE_HZ)
        self._last_time_s = math.nan
        self._rtf: float | None = None
        self._images = ImageAssembler()
        self._next_request_s: dict[int, float] = {}  # sysid -> wall time its camera may be asked again
        swarm.router.listeners.append(self._on_message)

    def _on_message(self, msg: Any, now_s: float) -> None:
        if msg.get_type() in CAMERA_MESSAGES and (image := self._images.feed(msg, now_s)) is not None:
            self.server.publish_image(image)

    def _ask_cameras(self, wall_s: float) -> None:
        """Ask each drone whose camera a page is showing for its next image, CAMERA_RATE_HZ at most."""
        for sysid in self.server.cameras_wanted(wall_s):
            if wall_s >= self._next_request_s.get(sysid, -math.inf) and sysid in self.swarm.fleet.drones:
                self._next_request_s[sysid] = wall_s + 1.0 / CAMERA_RATE_HZ
                self.swarm.router.send(sysid, image_request())

    def tick(self, time_s: float) -> None:
        """The mission time now; a frame goes out if the last is a frame period old (wall clock) and a page is
        watching: nobody watching, the view costs the swarm nothing."""
        wall = self.clock()
        if not self.server.watched(wall) or not self._pacer.due(wall):
            return
        if math.isfinite(self._last_wall_s) and math.isfinite(self._last_time_s) and wall > self._last_wall_s:
            reading = (time_s - self._last_time_s) / (wall - self._last_wall_s)
            self._rtf = reading if self._rtf is None else self._rtf + RTF_SMOOTHING * (reading - self._rtf)
        self._last_wall_s, self._last_time_s = wall, time_s
        self.server.publish(self.build(time_s))
        self._ask_cameras(wall)

    def build(self, time_s: float) -> dict[str, object]:
        swarm = self.swarm
        attached, losses = swarm.attachments.vehicles, swarm.liveness.losses
        positions: dict[int, Vec3] = {}
        homes: dict[int, Vec3] = {}
        picture = swarm.picture  # an attached vehicle where it says it is; a drone through its local frame
        for sysid in swarm.fleet.drones:
            placed = picture.placed(sysid)
            if placed is not None:
                positions[sysid] = placed.pos_ned_m
            home = picture.home(sysid) if sysid not in attached else None
            if home is not None:
                homes[sysid] = home
        airborne = [p for s, p in positions.items() if s not in losses and s not in attached
                    and swarm.fleet.drones[s].armed and homes.get(s, p)[2] - p[2] > AIRBORNE_HEIGHT_M]  # fmt: skip
        separation = _separation(airborne)
        if self.live is not None:
            self.min_separation_m = self.live.status().min_separation_m
        elif separation is not None and (self.min_separation_m is None or separation < self.min_separation_m):
            self.min_separation_m = separation
        return frame(time_s=time_s, drones=swarm.fleet.drones, positions_ned_m=positions, homes_ned_m=homes,
                     slots_ned_m=self.targets(time_s),
                     lost=[*losses, *(s for s, v in attached.items() if v.lost)], now_s=swarm.clock.now(),
                     separation_m=separation, min_separation_m=self.min_separation_m, realtime_factor=self._rtf,
                     obstacles=self.obstacles, external=attached)  # fmt: skip


def _separation(points: list[Vec3]) -> float | None:
    """The smallest distance between two of the points (None for fewer than two)."""
    if len(points) < 2:
        return None
    _, dist = pairwise_offsets(np.array(points, dtype=np.float64))
    return float(dist.min())
