"""The swarm's attached vehicles (gcs/fleet/attach.py, docs/external.md), a part of the swarm as the router and
liveness are: attaching the vehicles a link carries, hearing them, moving their bodies in the world, saying when
one goes quiet or is heard again, and commanding the members under the safety rules of hardware.

A member is commanded as any ground station commands a vehicle, and only so:

- it joins what the swarm flies only while it flies (armed, in the air): the swarm arms it and takes it off only
  when its attach says ``arm`` (``--arm-external``); otherwise its pilot flies it up and it joins at the next
  formation or behaviour;
- its setpoints go as SET_POSITION_TARGET_GLOBAL_INT (AMSL: no local frame of its own to know), at most
  MEMBER_SETPOINT_HZ, and none outside its keep-in (a cylinder around the origin, ``keep_in_m``): the first that
  would be is not sent, the member is put in Hold and released (the swarm no longer commands it);
- a member that leaves the mode it was asked for (a pilot's switch, its own failsafe) is released, never asked back;
- when the swarm lands, holds or stops, a member it commanded is put in its Hold mode (never landed, disarmed or
  terminated by the swarm).

It is handed what it works with, and never the swarm it belongs to: the plan (paced at speed 1, the ground station's
sysid, the origin), the clock, the fleet view (a vehicle's messages go where a drone's go), the command client (the
answers to what the swarm asks a member), the router (the listeners, and its position reaching the drones as
traffic), the harness (its body), the swarm-frame picture (gcs/fleet/picture.py: where a member is, and the one swarm
frame a geodetic point is converted in) and the store of its vehicles, which the picture reads to place them. An
attach waits while the swarm flies on: the swarm hands ``attach`` the wait (gcs/fleet/pump.py ``Pump.keep_flying``);
and a member released for a setpoint outside its keep-in is put in Hold through ``start_hold``, which the swarm wires
to its commands (gcs/fleet/commanding.py).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Collection
from typing import Any

from pymavlink.dialects.v20 import common as mavlink

from gcs.fleet.attach import (
    KEEP_IN_FLOOR_M,
    OTHERS_SETTLE_S,
    AttachedVehicle,
    AttachError,
    AttachSpec,
    ExternalLink,
    is_vehicle_heartbeat,
    last_known_traffic,
    reported_geo,
    sysid_problem,
    traffic_report,
)
from gcs.fleet.clock import SwarmClock
from gcs.fleet.errors import SwarmError
from gcs.fleet.harness import SimulationHarness, SpawnPlan
from gcs.fleet.picture import SwarmPicture
from gcs.fleet.router import GCS_HEARTBEAT_PERIOD_S, Router
from gcs.fleet.telemetry import LINK_LOST_S, DroneView, Fleet
from gcs.flight.frames import SwarmFrame, Vec3
from gcs.flight.geodesy import GeoPoint
from gcs.mavlink.commands import AUTOPILOT_COMPID, CommandClient
from gcs.mavlink.modes import OFFBOARD, purpose_mode_name

# Pump the swarm, its setpoints streamed, while ``going()``, each pump waiting up to the given simulated seconds
FlyOn = Callable[[Callable[[], bool], float], None]

WAIT_PUMP_S = 0.01  # simulated (= wall) seconds the swarm is pumped between two reads of a link being attached
# The simulated drones go to each attached vehicle as traffic (ADSB_VEHICLE), within SHARE_RADIUS_M of it, each at
# most SHARE_RATE_HZ, and within the link's budget (gcs/fleet/attach.py LINK_BUDGET_PER_S) whatever the swarm's size
SHARE_RADIUS_M = 100.0
SHARE_RATE_HZ = 2.0
# Roles whose vehicle is never commanded, so it does not avoid the drones in turn: the drones are told of it as
# traffic (ADSB_VEHICLE), which collision prevention avoids in full, not as a neighbour that takes half of each
# manoeuvre (a member the swarm released is told of so too)
NOT_COMMANDED = ("intruder", "leader")
# A member's setpoints go out at most this often: PX4 keeps OFFBOARD above 2 Hz (COM_OF_LOSS_T 1 s), and 10 frames of
# 53 bytes a second are about 650 B/s of a 57.6 kbit/s radio's 5.8 kB/s
MEMBER_SETPOINT_HZ = 10.0
# After asking a member for a mode, its HEARTBEATs (1 Hz) may show the old one this long before a different mode
# means that someone else (its pilot, its failsafe) has it
MODE_SETTLE_S = 2.5
# Where a velocity setpoint (flocking) would take a member, for its keep-in: where it is, carried this long at the
# setpoint's velocity
KEEP_IN_LOOKAHEAD_S = 1.0
# A vehicle gone silent is reported to the drones where it was last known this often, its age growing (``tslc``)
LAST_KNOWN_PERIOD_S = 1.0


class Attachments:
    def __init__(self, plan: SpawnPlan, clock: SwarmClock, harness: SimulationHarness, fleet: Fleet, router: Router,
                 acks: CommandClient, picture: SwarmPicture, vehicles: dict[int, AttachedVehicle]) -> None:  # fmt: skip
        """``acks``: the swarm's command client, fed the answers a member's link brings; ``vehicles``: where the
        vehicles attached are kept (empty), which ``picture`` places by their own reports."""
        self.plan = plan
        self.clock = clock
        self.harness = harness  # the members' bodies in the simulated world
        self.fleet = fleet
        self.router = router
        self.acks = acks
        # Ask a member for its Hold mode without waiting for the answer: the swarm's commands, wired by the swarm
        # (gcs/fleet/commanding.py ``Commands.set_mode_start``), which are made after this part and use it
        self.start_hold: Callable[[int], None] = _no_commands
        self.picture = picture
        self.vehicles = vehicles
        self._links: list[ExternalLink] = []
        self._shared_s: dict[int, float] = {}  # each simulated drone's last report sent as traffic
        self._notices: list[str] = []  # lines for the next ``detect_changes``
        self._released: list[int] = []  # members released since the last ``take_released``
        self._said_grounded: set[int] = set()  # members said once to be left out for not flying
        self._next_heartbeat_s = 0.0
        self._next_last_known_s = 0.0

    def attach(self, spec: AttachSpec, timeout_s: float, simulated: Collection[int],
               fly_on: FlyOn) -> tuple[list[int], list[str]]:  # fmt: skip
        """Open ``spec``'s link, wait for an autopilot's HEARTBEAT (and OTHERS_SETTLE_S more for others on the same
        radio, and each one's first position) while ``fly_on`` keeps the swarm flying, and take every vehicle that
        passes the checks. Returns the sysids attached and one line for each vehicle refused; AttachError (one line)
        when none can be attached, with the link closed again. ``simulated``: the simulated drones' sysids (before
        the drones are up, those the plan will give them), which are refused."""
        plan = self.plan
        if plan.lockstep or plan.speed_factor != 1.0:
            raise AttachError(f"--attach {spec.describe()}: a swarm with an attached vehicle runs paced at speed 1 "
                              "(the real world keeps wall time), not in lockstep or at another --speed")  # fmt: skip
        link = ExternalLink(spec=spec, source_system=plan.gcs_sysid)
        link.open()
        try:
            heard = self._wait_for_vehicles(link, timeout_s, fly_on)
        except BaseException:
            link.close()
            raise
        now = self.clock.now()
        simulated_ids = dict.fromkeys(simulated)
        positions = {m.get_srcSystem(): m for m in heard if m.get_type() == "GLOBAL_POSITION_INT"}
        attached: list[int] = []
        refused: dict[int, str] = {}
        for msg in heard:
            sysid = msg.get_srcSystem()
            if not is_vehicle_heartbeat(msg) or sysid in link.sysids or sysid in refused:
                continue
            problem = sysid_problem(sysid, simulated_ids, self.vehicles, plan.gcs_sysid) or self._too_far(
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
        distance = math.dist((0.0, 0.0, 0.0), self.picture.ned_from_geo(reported_geo(position)))
        if distance > max_distance_m:
            return f"sysid {sysid} is {distance:.0f} m from the swarm's origin (at most {max_distance_m:g} m)"
        return None

    def _wait_for_vehicles(self, link: ExternalLink, timeout_s: float, fly_on: FlyOn) -> list[Any]:
        """Read a new link until a vehicle's HEARTBEAT arrives, OTHERS_SETTLE_S more (other vehicles on the same
        radio), and until every vehicle heard has said where it is (or ``timeout_s`` wall seconds have passed),
        the swarm pumped and its setpoints streamed meanwhile (``fly_on``); AttachError when no HEARTBEAT comes in
        time."""
        heard: list[Any] = []
        deadline = time.monotonic() + timeout_s
        settle_until = math.inf
        vehicles: set[int] = set()
        placed: set[int] = set()

        def listening() -> bool:
            """Whether to go on listening; if so, what the link has brought since the last look, read."""
            nonlocal settle_until
            wall = time.monotonic()
            if not (wall < deadline and (wall < settle_until or not vehicles <= placed)):
                return False
            batch = link.receive()
            heard.extend(batch)
            vehicles.update(m.get_srcSystem() for m in batch if is_vehicle_heartbeat(m))
            placed.update(m.get_srcSystem() for m in batch if m.get_type() == "GLOBAL_POSITION_INT")
            if math.isinf(settle_until) and vehicles:
                settle_until = time.monotonic() + OTHERS_SETTLE_S
            return True

        fly_on(listening, WAIT_PUMP_S)
        if not vehicles:
            raise AttachError(f"--attach {link.spec.describe()}: no vehicle HEARTBEAT within {timeout_s:g} s")
        return heard

    def detach(self, sysid: int) -> None:
        """Let an attached vehicle go: its body leaves the world, nothing more is read from it (its link closes with
        its last vehicle); it is told nothing. SwarmError when none of that sysid is attached."""
        vehicle = self.vehicles.pop(sysid, None)
        if vehicle is None:
            raise SwarmError(f"no attached vehicle with sysid {sysid}")
        self.harness.remove_external_body(sysid)
        vehicle.link.sysids.discard(sysid)
        if not vehicle.link.sysids:
            vehicle.link.close()
            self._links.remove(vehicle.link)

    def detect_changes(self, now_s: float) -> list[str]:
        """One line for each attached vehicle newly silent (its body stays where it was last known) or heard again."""
        lines = []
        for sysid, vehicle in self.vehicles.items():
            view = self.fleet.drones.get(sysid)
            silent = view is None or view.lost(now_s)
            if silent and not vehicle.lost:
                vehicle.lost = True
                lines.append(f"attached vehicle {sysid} lost at t={now_s:.1f} s: nothing heard for "
                             f"{LINK_LOST_S:g} s (its body stays where it was last known)")  # fmt: skip
            elif not silent and vehicle.lost:
                vehicle.lost = False
                lines.append(f"attached vehicle {sysid} heard again at t={now_s:.1f} s")
            if view is not None and not silent:
                self._watch_mode(vehicle, view, now_s)
        lines.extend(self._notices)
        self._notices.clear()
        return lines

    # ---- members ---------------------------------------------------------------------------------------------------
    def members(self, now_s: float) -> list[int]:
        """The members the swarm flies now: attached as member, not released, heard, armed and in the air."""
        out = []
        for sysid, vehicle in self.vehicles.items():
            view = self.fleet.drones.get(sysid)
            if (vehicle.spec.role == "member" and vehicle.released is None and view is not None
                    and not view.lost(now_s) and view.armed and view.in_air()):  # fmt: skip
                out.append(sysid)
        return out

    def grounded_notice(self, flown: list[int]) -> None:
        """Say once of each member left out of what the swarm starts to fly because it does not fly."""
        for sysid, vehicle in self.vehicles.items():
            if vehicle.spec.role != "member" or vehicle.released is not None or sysid in flown:
                continue
            if sysid not in self._said_grounded:
                self._said_grounded.add(sysid)
                how = "" if vehicle.spec.arm else " (fly it up yourself, or attach it with --arm-external)"
                self._notices.append(f"member {sysid} is not flying: it joins the next formation or behaviour once it "
                                     f"is armed and in the air{how}")  # fmt: skip

    def to_arm(self) -> list[int]:
        """The members the swarm is allowed to arm (``arm``), heard and not armed yet."""
        now = self.clock.now()
        drones = self.fleet.drones
        return [
            s for s, v in self.vehicles.items()
            if v.spec.role == "member" and v.spec.arm and v.released is None and s in drones
            and not drones[s].lost(now) and not drones[s].armed
        ]  # fmt: skip

    def taken_off(self) -> list[int]:
        """The members the swarm takes off with its drones (``arm``), heard, not released and not flying already
        (armed just before: their HEARTBEAT may not say so yet)."""
        drones = self.fleet.drones
        return [s for s, v in self.vehicles.items() if v.spec.role == "member" and v.spec.arm
                and v.released is None and s in drones and not drones[s].in_air()]  # fmt: skip

    def commanded(self) -> list[int]:
        """The members last asked for OFFBOARD (GUIDED) and not released: those to put in Hold when the swarm stops."""
        return [s for s, v in self.vehicles.items() if v.asked == OFFBOARD and v.released is None]

    def asked(self, sysid: int, purpose: str, now_s: float) -> None:
        """The swarm has asked a member for a mode (gcs/fleet/commanding.py ``Commands.set_mode``)."""
        vehicle = self.vehicles[sysid]
        vehicle.asked, vehicle.asked_s = purpose, now_s

    def release(self, sysid: int, why: str, *, hold: bool) -> None:
        """The swarm stops commanding a member, for good (one line, said at the next ``detect_changes``); ``hold``:
        it is asked for its Hold mode first, without waiting for the answer."""
        vehicle = self.vehicles[sysid]
        if vehicle.released is not None:
            return
        vehicle.released = why
        if hold:
            self.start_hold(sysid)
        self._notices.append(f"member {sysid} released: {why}{'; asked to hold where it is' if hold else ''}")
        self._released.append(sysid)

    def take_released(self) -> list[int]:
        """The members released since the last call, once (what the swarm flies re-plans without them)."""
        out, self._released = self._released, []
        return out

    def _watch_mode(self, vehicle: AttachedVehicle, view: DroneView, now_s: float) -> None:
        """A member asked for OFFBOARD (GUIDED) that shows another mode, after MODE_SETTLE_S, has been taken by
        someone else: released, never asked back."""
        if vehicle.asked != OFFBOARD or vehicle.released is not None or now_s - vehicle.asked_s < MODE_SETTLE_S:
            return
        wanted = purpose_mode_name(OFFBOARD, view.autopilot)
        if view.mode != wanted:
            self.release(vehicle.sysid, f"it is in {view.mode}, not {wanted} as asked (its pilot or its own "
                                        "failsafe has it)", hold=False)  # fmt: skip

    def setpoint(self, sysid: int, pos_ned_m: Vec3, vel_ned_mps: Vec3, acc_ned_mps2: Vec3, yaw_rad: float,
                 mask: int, now_s: float) -> None:  # fmt: skip
        """A member's setpoint (swarm frame; ``mask`` the SET_POSITION_TARGET type_mask) as
        SET_POSITION_TARGET_GLOBAL_INT, at most MEMBER_SETPOINT_HZ; one outside its keep-in is not sent, and the
        member is put in Hold and released."""
        vehicle = self.vehicles.get(sysid)
        if vehicle is None or vehicle.released is not None or now_s - vehicle.setpoint_s < 1.0 / MEMBER_SETPOINT_HZ:
            return
        horizontal = not mask & mavlink.POSITION_TARGET_TYPEMASK_X_IGNORE
        vertical = not mask & mavlink.POSITION_TARGET_TYPEMASK_Z_IGNORE
        if not all(map(math.isfinite, pos_ned_m)):
            self.release(sysid, f"its setpoint {_ned_text(pos_ned_m)} is not a finite point", hold=True)
            return
        (lat_e7, lon_e7, alt_amsl_m), goes_to = on_the_wire(self.picture.frame, pos_ned_m)
        if not (horizontal and vertical):  # a velocity: where it takes the member, from where it says it is
            here = self.picture.placed(sysid)
            if here is None:
                return
            ahead = tuple(h + v * KEEP_IN_LOOKAHEAD_S for h, v in zip(here.pos_ned_m, vel_ned_mps, strict=True))
            goes_to = (goes_to[0] if horizontal else ahead[0], goes_to[1] if horizontal else ahead[1],
                       goes_to[2] if vertical else ahead[2])  # fmt: skip
        outside = keep_in_problem(goes_to, vehicle.spec.keep_in_m)
        if outside is not None:
            self.release(sysid, f"its setpoint {_ned_text(goes_to)} is {outside}", hold=True)
            return
        msg = mavlink.MAVLink_set_position_target_global_int_message(
            int(now_s * 1000) & 0xFFFFFFFF, sysid, AUTOPILOT_COMPID, mavlink.MAV_FRAME_GLOBAL_INT, mask,
            lat_e7, lon_e7, alt_amsl_m, *vel_ned_mps, *acc_ned_mps2,
            yaw_rad, 0.0,
        )  # fmt: skip
        vehicle.setpoint_s = now_s
        vehicle.link.send(msg)

    def send(self, sysid: int, msg: Any) -> bytes:
        """A command or parameter write for an attached vehicle, on its link; the frame as sent (for the tlog)."""
        vehicle = self.vehicles[sysid]
        vehicle.link.send(msg)
        return bytes(msg.get_msgbuf() or b"")

    def pump(self, now: float) -> None:
        """What the attached vehicles' links have brought, handled; then every attached body moved in the world."""
        for link in list(self._links):
            for msg in link.receive():
                self._handle(link, msg, now)
        if now >= self._next_heartbeat_s:  # as to the simulated drones: PX4's datalink-loss failsafe watches it
            self._next_heartbeat_s = now + GCS_HEARTBEAT_PERIOD_S
            beat = mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0,
                                                     mavlink.MAV_STATE_ACTIVE, 3)  # fmt: skip
            for link in self._links:
                link.send(beat)
        last_known_due = now >= self._next_last_known_s
        if last_known_due:
            self._next_last_known_s = now + LAST_KNOWN_PERIOD_S
        for sysid, vehicle in self.vehicles.items():
            geo = vehicle.body_at(now)
            if geo is not None:
                velocity = (0.0, 0.0, 0.0) if vehicle.lost else vehicle.vel_ned_mps
                self.harness.place_external_body(sysid, (geo.lat_deg, geo.lon_deg, geo.alt_amsl_m), velocity,
                                                 vehicle.spec.radius_m)  # fmt: skip
                if vehicle.lost and last_known_due:  # the drones keep a keep-out growing with its age around it
                    report = last_known_traffic(sysid, geo, now - vehicle.position_s)
                    self.router.relay_traffic(sysid, report, now, self.fleet)

    def _handle(self, link: ExternalLink, msg: Any, now: float) -> None:
        """A message on an attached vehicle's link: into the fleet view, the relay and the listeners (the flight log,
        the report), as a simulated drone's. Only the vehicles attached are heard: one that shows up on the link later
        (or was refused) is not taken without an attach of its own."""
        if msg.get_srcComponent() != AUTOPILOT_COMPID:
            return
        vehicle = self.vehicles.get(msg.get_srcSystem())
        if vehicle is None or vehicle.link is not link:
            return
        position = msg.get_type() == "GLOBAL_POSITION_INT"
        if position:
            vehicle.position = reported_geo(msg)
            vehicle.vel_ned_mps = (msg.vx * 0.01, msg.vy * 0.01, msg.vz * 0.01)
            vehicle.position_s = now
        self.fleet.handle(msg, now)
        if msg.get_type() == "COMMAND_ACK":
            self.acks.handle(msg, now)
        traffic = vehicle.spec.role in NOT_COMMANDED or vehicle.released is not None  # nobody says it avoids
        self.router.carry(msg, now, self.fleet, relay=not traffic)
        if traffic and position:
            self.router.relay_traffic(vehicle.sysid, traffic_report(msg), now, self.fleet)
        self.router.delivered(msg, now)

    def share(self, position: Any, now: float) -> None:
        """A simulated drone's GLOBAL_POSITION_INT, as traffic to every attached vehicle within SHARE_RADIUS_M of it,
        at most SHARE_RATE_HZ for each drone and within each link's budget (a radio's); what does not fit waits for
        the drone's next report."""
        source = position.get_srcSystem()
        if now - self._shared_s.get(source, -math.inf) < 1.0 / SHARE_RATE_HZ:
            return
        # the report shared, where it puts the drone: not the picture's place of the drone (from its
        # LOCAL_POSITION_NED, through its local frame), which differs in the last bits
        drone = self.picture.ned_from_geo(reported_geo(position))
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
        return geo is not None and math.dist(drone_ned_m, self.picture.ned_from_geo(geo)) <= SHARE_RADIUS_M

    def close(self) -> None:
        """Close every link (the vehicles are left as they are)."""
        for link in self._links:
            link.close()
        self._links.clear()


def _no_commands(sysid: int) -> None:
    raise SwarmError(f"member {sysid}: no commands to put it in Hold with (Attachments.start_hold is not wired)")


def on_the_wire(frame: SwarmFrame, pos_ned_m: Vec3) -> tuple[tuple[int, int, float], Vec3]:
    """A swarm-frame point as SET_POSITION_TARGET_GLOBAL_INT carries it (lat and lon in 1e-7 degrees, altitude AMSL)
    and the point a member reads back from that. The keep-in judges the second: a 1e-7 degree step is up to 11 mm,
    so a slot just inside the keep-in may reach the member just outside it."""
    geo = frame.geo_from_ned(pos_ned_m)
    lat_e7, lon_e7 = round(geo.lat_deg * 1e7), round(geo.lon_deg * 1e7)
    read = frame.ned_from_geo(GeoPoint(lat_deg=lat_e7 * 1e-7, lon_deg=lon_e7 * 1e-7, alt_amsl_m=geo.alt_amsl_m))
    return (lat_e7, lon_e7, geo.alt_amsl_m), read


def keep_in_problem(pos_ned_m: Vec3, keep_in_m: float) -> str | None:
    """Why a point (swarm frame) is outside a member's keep-in, a cylinder ``keep_in_m`` wide and high around the
    origin above KEEP_IN_FLOOR_M (one phrase), or None."""
    north, east, down = pos_ned_m
    if not all(math.isfinite(v) for v in pos_ned_m):
        return "not a finite point"
    if math.hypot(north, east) > keep_in_m:
        return f"{math.hypot(north, east):.1f} m from the origin, outside the keep-in of {keep_in_m:g} m"
    if -down > keep_in_m:
        return f"{-down:.1f} m above the origin, above the keep-in's {keep_in_m:g} m"
    if -down < KEEP_IN_FLOOR_M:
        return f"{-down:.1f} m above the origin, below the keep-in's floor of {KEEP_IN_FLOOR_M:g} m"
    return None


def _ned_text(pos_ned_m: Vec3) -> str:
    return "(" + ", ".join(f"{v:.1f}" for v in pos_ned_m) + ") m NED"
