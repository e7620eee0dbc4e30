"""The swarm-frame picture of every vehicle: where each one is and how it moves, in the one frame the ground station
plans in, as of each vehicle's latest telemetry message.

The fleet view (gcs/fleet/telemetry.py) keeps what each vehicle says in its own terms: a simulated drone its
LOCAL_POSITION_NED in the local frame anchored where it booted, an attached vehicle its GLOBAL_POSITION_INT. Every
reader of positions (the streamer planning a formation, the recorder's samples, the live view, the invariants, the
API's ``DroneState``, ``swarm status``) wants the swarm frame (NED metres from the swarm's origin). This is the one
place that converts, and the only owner of each drone's local frame.

A drone's frame is fixed by its first HOME_POSITION and kept: PX4 moves home when it arms, but the drone's local
origin does not move, and a frame built from the home it had at boot converts its LOCAL_POSITION_NED exactly as
before. A drone is in the picture once its home and a finite position are known; an attached vehicle once it reports
a finite geodetic position (its velocity is its report's, already NED).
"""

from __future__ import annotations

import math
from collections.abc import Container, Iterable
from dataclasses import dataclass
from typing import Any

from gcs.fleet.telemetry import DroneView, Fleet
from gcs.flight.behaviours import SwarmState
from gcs.flight.frames import DroneFrame, SwarmFrame, Vec3, origin_from_home
from gcs.flight.geodesy import GeoPoint

NAN3: Vec3 = (math.nan, math.nan, math.nan)
_MOVES = frozenset({"LOCAL_POSITION_NED", "GLOBAL_POSITION_INT"})  # what changes a vehicle's place or velocity


@dataclass(frozen=True, slots=True)
class Placed:
    """A vehicle in the swarm frame as of its latest report: ``vel_ned_mps`` NaN while it has not said."""

    pos_ned_m: Vec3
    vel_ned_mps: Vec3

    @property
    def moving_known(self) -> bool:
        return all(map(math.isfinite, self.vel_ned_mps))


class SwarmPicture:
    """Every vehicle's place in the swarm frame as of its latest report: ``observe`` (after the fleet view has taken
    the same message in) marks it, the first reader after places it. ``attached``: the sysids of attached vehicles
    (they report where they are, not a local frame)."""

    def __init__(self, frame: SwarmFrame, fleet: Fleet, attached: Container[int]) -> None:
        self.frame = frame
        self._fleet = fleet
        self._attached = attached
        self._frames: dict[int, DroneFrame] = {}
        self._placed: dict[int, Placed] = {}
        self._stale: set[int] = set()  # vehicles that have reported since they were last placed

    # ---- as messages arrive ----------------------------------------------------------------------------------------
    def observe(self, msg: Any, _now_s: float = 0.0) -> None:
        """A message the swarm has taken in: a report of where a vehicle is, or of how it moves, makes its place
        stale; the next reader places it anew from the fleet view (a report nobody reads before the next is never
        converted: the supervisor pays per reading, not per report)."""
        if msg.get_type() in _MOVES and msg.get_srcComponent() == 1:
            self._stale.add(msg.get_srcSystem())

    def _place(self, sysid: int, view: DroneView) -> Placed | None:
        if sysid in self._attached:
            here = GeoPoint(lat_deg=view.lat_deg, lon_deg=view.lon_deg, alt_amsl_m=view.alt_amsl_m)
            if not all(map(math.isfinite, (here.lat_deg, here.lon_deg, here.alt_amsl_m))):
                return None
            return Placed(pos_ned_m=self.frame.ned_from_geo(here), vel_ned_mps=view.vel_ned_mps)
        frame = self.drone_frame(sysid)
        if frame is None or not all(map(math.isfinite, view.local_ned_m)):
            return None
        moving = all(map(math.isfinite, view.vel_ned_mps))
        return Placed(pos_ned_m=frame.to_swarm(view.local_ned_m),
                      vel_ned_mps=frame.vector_to_swarm(view.vel_ned_mps) if moving else NAN3)  # fmt: skip

    # ---- reading --------------------------------------------------------------------------------------------------
    def drone_frame(self, sysid: int) -> DroneFrame | None:
        """A simulated drone's local frame, once its HOME_POSITION has arrived (to command it in its own terms)."""
        frame = self._frames.get(sysid)
        if frame is None:
            view = self._fleet.drones.get(sysid)
            if view is None or view.home is None or view.home_local_ned_m is None:
                return None
            home = GeoPoint(lat_deg=view.home[0], lon_deg=view.home[1], alt_amsl_m=view.home[2])
            frame = self._frames[sysid] = self.frame.drone_frame(origin_from_home(home, view.home_local_ned_m))
        return frame

    def placed(self, sysid: int) -> Placed | None:
        """Where the vehicle is as of its latest report (None before it has said)."""
        if sysid in self._stale:
            self._stale.discard(sysid)
            view = self._fleet.drones.get(sysid)
            placed = self._place(sysid, view) if view is not None else None
            if placed is None:
                self._placed.pop(sysid, None)
            else:
                self._placed[sysid] = placed
        return self._placed.get(sysid)

    def positions(self, sysids: Iterable[int]) -> dict[int, Vec3]:
        """The positions of those of ``sysids`` in the picture."""
        out = {}
        for sysid in sysids:
            placed = self.placed(sysid)
            if placed is not None:
                out[sysid] = placed.pos_ned_m
        return out

    def state(self, sysids: Iterable[int]) -> SwarmState:
        """Position and velocity of those of ``sysids`` that are armed and have said both: what a flight law (a
        flock, a follow) starts from."""
        positions: dict[int, Vec3] = {}
        velocities: dict[int, Vec3] = {}
        for sysid in sysids:
            view, placed = self._fleet.drones.get(sysid), self.placed(sysid)
            if placed is not None and view is not None and view.armed and placed.moving_known:
                positions[sysid], velocities[sysid] = placed.pos_ned_m, placed.vel_ned_mps
        return SwarmState.from_mappings(positions, velocities)

    def home(self, sysid: int) -> Vec3 | None:
        """A simulated drone's current home (it moves when the drone arms) in the swarm frame."""
        view = self._fleet.drones.get(sysid)
        frame = self.drone_frame(sysid)
        if frame is None or view is None or view.home_local_ned_m is None:
            return None
        return frame.to_swarm(view.home_local_ned_m)

    def ned_from_geo(self, point: GeoPoint) -> Vec3:
        """A geodetic point (an obstacle, an attached vehicle's extrapolated body) in the swarm frame."""
        return self.frame.ned_from_geo(point)
