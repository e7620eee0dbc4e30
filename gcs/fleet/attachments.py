"""The swarm's attached vehicles (gcs/fleet/attach.py, docs/external.md), a part of the swarm as the router and
liveness are: attaching the vehicles a link carries, hearing them, moving their bodies in the world, and saying when
one goes quiet or is heard again.

It works through the swarm it belongs to: the plan (paced at speed 1, the ground station's sysid, the origin), the
pump (a wait keeps the swarm flying and its setpoints streamed), the fleet view and the listeners (a vehicle's
messages go where a drone's go), the router (its position reaches the drones as traffic) and the harness (its body).
"""

from __future__ import annotations

import math
import time
from typing import TYPE_CHECKING, Any

from gcs.fleet.attach import (
    OTHERS_SETTLE_S,
    AttachedVehicle,
    AttachError,
    AttachSpec,
    ExternalLink,
    is_vehicle_heartbeat,
    reported_geo,
    sysid_problem,
    traffic_report,
)
from gcs.fleet.clock import TICK_S, next_tick_s
from gcs.fleet.telemetry import LINK_LOST_S
from gcs.flight.frames import Vec3
from gcs.flight.geodesy import NedFrame
from gcs.mavlink.commands import AUTOPILOT_COMPID

if TYPE_CHECKING:
    from gcs.fleet.swarm import Swarm

WAIT_PUMP_S = 0.01  # simulated (= wall) seconds the swarm is pumped between two reads of a link being attached
# The simulated drones go to each attached vehicle as traffic (ADSB_VEHICLE), within SHARE_RADIUS_M of it, each at
# most SHARE_RATE_HZ, and within the link's budget (gcs/fleet/attach.py LINK_BUDGET_PER_S) whatever the swarm's size
SHARE_RADIUS_M = 100.0
SHARE_RATE_HZ = 2.0
# Roles whose vehicle is never commanded, so it does not avoid the drones in turn: the drones are told of it as
# traffic (ADSB_VEHICLE), which collision prevention avoids in full, not as a neighbour that takes half of each
# manoeuvre
NOT_COMMANDED = ("intruder", "leader")


class Attachments:
    def __init__(self, swarm: Swarm) -> None:
        self.swarm = swarm
        self.vehicles: dict[int, AttachedVehicle] = {}
        self._links: list[ExternalLink] = []
        self._frame = NedFrame(swarm.plan.origin)
        self._shared_s: dict[int, float] = {}  # each simulated drone's last report sent as traffic

    def attach(self, spec: AttachSpec, timeout_s: float) -> tuple[list[int], list[str]]:
        """Open ``spec``'s link, wait for an autopilot's HEARTBEAT (and OTHERS_SETTLE_S more for others on the same
        radio, and each one's first position), and take every vehicle that passes the checks. Returns the sysids
        attached and one line for each vehicle refused; AttachError (one line) when none can be attached, with the
        link closed again. Before the drones are up, the sysids the plan will give them are the ones refused."""
        plan = self.swarm.plan
        if plan.lockstep or plan.speed_factor != 1.0:
            raise AttachError(f"--attach {spec.describe()}: a swarm with an attached vehicle runs paced at speed 1 "
                              "(the real world keeps wall time), not in lockstep or at another --speed")  # fmt: skip
        link = ExternalLink(spec=spec, source_system=plan.gcs_sysid)
        link.open()
        try:
            heard = self._wait_for_vehicles(link, timeout_s)
        except BaseException:
            link.close()
            raise
        now = self.swarm.clock()
        simulated = dict.fromkeys(self.swarm.simulated_sysids())
        positions = {m.get_srcSystem(): m for m in heard if m.get_type() == "GLOBAL_POSITION_INT"}
        attached: list[int] = []
        refused: dict[int, str] = {}
        for msg in heard:
            sysid = msg.get_srcSystem()
            if not is_vehicle_heartbeat(msg) or sysid in link.sysids or sysid in refused:
                continue
            problem = sysid_problem(sysid, simulated, self.vehicles, plan.gcs_sysid) or self._too_far(
                sysid, positions.get(sysid), spec.max_distance_m
            )
            if problem is not None:
                refused[sysid] = f"--attach {spec.describe()}: {problem}: not attached"
                continue
            self.vehicles[sysid] = AttachedVehicle(sysid=sysid, spec=spec, link=link)
            link.sysids.add(sysid)
            attached.append(sysid)
        if not attached:
            link.close()
            raise AttachError(next(iter(refused.values()), f"--attach {spec.describe()}: no vehicle heard"))
        self._links.append(link)
        for msg in heard:
            self._handle(link, msg, now)
        return attached, list(refused.values())

    def _too_far(self, sysid: int, position: Any, max_distance_m: float) -> str | None:
        """Why a vehicle's first position keeps it out of the swarm (none yet, or farther from the origin than
        ``max_distance_m``), or None."""
        if position is None:
            return f"sysid {sysid} sent no GLOBAL_POSITION_INT (where is it?)"
        distance = math.dist((0.0, 0.0, 0.0), self._frame.ned_from_geo(reported_geo(position)))
        if distance > max_distance_m:
            return f"sysid {sysid} is {distance:.0f} m from the swarm's origin (at most {max_distance_m:g} m)"
        return None

    def _wait_for_vehicles(self, link: ExternalLink, timeout_s: float) -> list[Any]:
        """Read a new link until a vehicle's HEARTBEAT arrives, OTHERS_SETTLE_S more (other vehicles on the same
        radio), and until every vehicle heard has said where it is (or ``timeout_s`` wall seconds have passed),
        pumping the swarm and its setpoint stream meanwhile; AttachError when no HEARTBEAT comes in time."""
        swarm = self.swarm
        heard: list[Any] = []
        deadline = time.monotonic() + timeout_s
        settle_until = math.inf
        vehicles: set[int] = set()
        placed: set[int] = set()
        next_tick = swarm.clock()
        while (wall := time.monotonic()) < deadline and (wall < settle_until or not vehicles <= placed):
            batch = link.receive()
            heard.extend(batch)
            vehicles.update(m.get_srcSystem() for m in batch if is_vehicle_heartbeat(m))
            placed.update(m.get_srcSystem() for m in batch if m.get_type() == "GLOBAL_POSITION_INT")
            if math.isinf(settle_until) and vehicles:
                settle_until = time.monotonic() + OTHERS_SETTLE_S
            if swarm.stream_tick is not None and (clock := swarm.clock()) >= next_tick:
                swarm.stream_tick(clock)
                next_tick = next_tick_s(next_tick, clock, TICK_S)
            swarm.pump(WAIT_PUMP_S)
        if not vehicles:
            raise AttachError(f"--attach {link.spec.describe()}: no vehicle HEARTBEAT within {timeout_s:g} s")
        return heard

    def detach(self, sysid: int) -> None:
        """Let an attached vehicle go: its body leaves the world, nothing more is read from it (its link closes with
        its last vehicle); it is told nothing."""
        vehicle = self.vehicles.pop(sysid)
        self.swarm.harness.remove_external_body(sysid)
        vehicle.link.sysids.discard(sysid)
        if not vehicle.link.sysids:
            vehicle.link.close()
            self._links.remove(vehicle.link)

    def detect_changes(self, now_s: float) -> list[str]:
        """One line for each attached vehicle newly silent (its body stays where it was last known) or heard again."""
        lines = []
        for sysid, vehicle in self.vehicles.items():
            view = self.swarm.fleet.drones.get(sysid)
            silent = view is None or view.lost(now_s)
            if silent and not vehicle.lost:
                vehicle.lost = True
                lines.append(f"attached vehicle {sysid} lost at t={now_s:.1f} s: nothing heard for "
                             f"{LINK_LOST_S:g} s (its body stays where it was last known)")  # fmt: skip
            elif not silent and vehicle.lost:
                vehicle.lost = False
                lines.append(f"attached vehicle {sysid} heard again at t={now_s:.1f} s")
        return lines

    def pump(self, now: float) -> None:
        """What the attached vehicles' links have brought, handled; then every attached body moved in the world."""
        for link in list(self._links):
            for msg in link.receive():
                self._handle(link, msg, now)
        for sysid, vehicle in self.vehicles.items():
            geo = vehicle.body_at(now)
            if geo is not None:
                velocity = (0.0, 0.0, 0.0) if vehicle.lost else vehicle.vel_ned_mps
                self.swarm.harness.place_external_body(sysid, (geo.lat_deg, geo.lon_deg, geo.alt_amsl_m), velocity,
                                                       vehicle.spec.radius_m)  # fmt: skip

    def _handle(self, link: ExternalLink, msg: Any, now: float) -> None:
        """A message on an attached vehicle's link: into the fleet view, the relay and the listeners (the flight log,
        the report), as a simulated drone's. Only the vehicles attached are heard: one that shows up on the link later
        (or was refused) is not taken without an attach of its own."""
        if msg.get_srcComponent() != AUTOPILOT_COMPID:
            return
        vehicle = self.vehicles.get(msg.get_srcSystem())
        if vehicle is None or vehicle.link is not link:
            return
        swarm = self.swarm
        position = msg.get_type() == "GLOBAL_POSITION_INT"
        if position:
            vehicle.position = reported_geo(msg)
            vehicle.vel_ned_mps = (msg.vx * 0.01, msg.vy * 0.01, msg.vz * 0.01)
            vehicle.position_s = now
        swarm.fleet.handle(msg, now)
        traffic = vehicle.spec.role in NOT_COMMANDED
        swarm.router.carry(msg, now, swarm.fleet, relay=not traffic)
        if traffic and position:
            swarm.router.relay_traffic(vehicle.sysid, traffic_report(msg), now, swarm.fleet)
        for listener in swarm.listeners:
            listener(msg, now)

    def share(self, position: Any, now: float) -> None:
        """A simulated drone's GLOBAL_POSITION_INT, as traffic to every attached vehicle within SHARE_RADIUS_M of it,
        at most SHARE_RATE_HZ for each drone and within each link's budget (a radio's); what does not fit waits for
        the drone's next report."""
        source = position.get_srcSystem()
        if now - self._shared_s.get(source, -math.inf) < 1.0 / SHARE_RATE_HZ:
            return
        drone = self._frame.ned_from_geo(reported_geo(position))
        report = None
        for link in self._links:
            near = any(self._within(drone, v, now) for v in self.vehicles.values() if v.link is link)
            if not near or not link.budget.take(now):
                continue
            report = report or traffic_report(position)
            link.send(report)
            self._shared_s[source] = now

    def _within(self, drone_ned_m: Vec3, vehicle: AttachedVehicle, now: float) -> bool:
        """Whether the vehicle's body is within SHARE_RADIUS_M of a point (swarm frame)."""
        geo = vehicle.body_at(now)
        return geo is not None and math.dist(drone_ned_m, self._frame.ned_from_geo(geo)) <= SHARE_RADIUS_M

    def close(self) -> None:
        """Close every link (the vehicles are left as they are)."""
        for link in self._links:
            link.close()
        self._links.clear()
