"""The swarm's commands: COMMAND_LONG (and COMMAND_INT) to any number of vehicles at once, with MAVSDK's retry
rules (gcs/mavlink/commands.py, whose client this part drives and whose answers the pump feeds it), and what the
swarm is told through them: modes, arming, takeoff, landing, Hold, the forced disarm.

A command waits for every answer while the swarm flies on (gcs/fleet/pump.py ``Pump.serve``: pumped, its setpoints
streamed); one begun from inside a tick (``command_start``) does not wait, and its outcome is picked up later
(``command_outcome``). Attached members (gcs/fleet/attachments.py) are commanded as the swarm's own drones are, with
their own rules: armed and taken off only when their attach says so, put in Hold (never landed or disarmed) when the
swarm lands, holds or stops.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Iterable
from typing import Final

from pymavlink.dialects.v20 import common as mavlink

from gcs.fleet.attachments import Attachments
from gcs.fleet.clock import SwarmClock
from gcs.fleet.errors import SwarmError
from gcs.fleet.liveness import Liveness
from gcs.fleet.losses import landing_clear_of
from gcs.fleet.picture import SwarmPicture
from gcs.fleet.pump import Pump
from gcs.fleet.telemetry import Fleet
from gcs.flight.geodesy import GeoPoint
from gcs.mavlink.commands import FORCE_DISARM_MAGIC, Ack, CommandClient
from gcs.mavlink.modes import ARDUPILOT, HOLD, OFFBOARD, purpose_params

log = logging.getLogger(__name__)

INT32_MAX: Final = 2**31 - 1  # COMMAND_INT x/y: no position given (MAVLink's convention)
ARM_TIMEOUT_S: Final = 30.0  # simulated seconds for every drone to pass its pre-arm checks before it is armed
# DO_SET_MODE for PX4 Hold (AUTO.LOITER), as pymavlink encodes it for PX4
HOLD_MODE: Final = purpose_params(HOLD)
# Rounds of a command's retries (each MAVSDK's: the first try and 3 resends) for a drone that answers none: on a link
# losing 20 % each way one round goes unanswered 1.7 % of the time, three rounds once in 200,000.
NO_ANSWER_ROUNDS: Final = 3


class Commands:
    def __init__(self, client: CommandClient, pump: Pump, clock: SwarmClock, fleet: Fleet, liveness: Liveness,
                 attachments: Attachments, picture: SwarmPicture) -> None:  # fmt: skip
        """``picture``: the swarm-frame picture, whose frame (NED around the swarm's origin) says where wrecks lie and
        the height members take off to."""
        self.client = client
        self.pump = pump
        self.clock = clock
        self.fleet = fleet
        self.liveness = liveness
        self.attachments = attachments
        self.picture = picture

    # ---- commands --------------------------------------------------------------------------------------------------
    def command_all(self, command: int, *params: float, sysids: Iterable[int] | None = None) -> list[Ack]:
        """COMMAND_LONG to several drones at once (default: every drone launched), each retried until answered
        (MAVSDK's rules: gcs/mavlink/commands.py)."""
        targets = self.liveness.sysids if sysids is None else sysids
        return self.command_each(command, {sysid: params for sysid in targets})

    def command_each(
        self, command: int, params: dict[int, tuple[float, ...]], *, frame: int | None = None
    ) -> list[Ack]:
        """One command to several drones at once, each with its own params (sysid -> params 1-7), each retried
        until answered; the answers in the order of ``params``. With ``frame``, as COMMAND_INT in that frame."""
        acks: dict[int, Ack] = {}
        waiting = list(params)
        for _round in range(NO_ANSWER_ROUNDS):
            for sysid in waiting:
                self.client.cancel(sysid, command)  # superseded: one begun with ``command_start`` still waiting
                effects = self.client.start(sysid, command, params[sysid], self.clock.now(), frame=frame)
                self.pump.send(effects, now=True)
            acks.update((a.sysid, a) for a in self.pump.serve(self.client, command, waiting, now=True))
            # A drone that never answered, on a lossy link, is asked again (commands are idempotent, as PX4's); one
            # that is lost or gone is not
            waiting = [a.sysid for a in acks.values() if a.result is None
                       and (a.sysid in self.liveness.active_sysids or a.sysid in self.attachments.vehicles)
                       and not self.fleet.drones[a.sysid].lost(self.clock.now())]  # fmt: skip
            if not waiting:
                break
        return [acks[sysid] for sysid in params]

    def command_start(self, sysid: int, command: int, *params: float) -> None:
        """Begin a COMMAND_LONG without waiting for its answer (the streamer's, from inside a tick); its outcome
        comes from ``command_outcome``. A later ``command_all`` of the same command to the drone supersedes it."""
        self.client.cancel(sysid, command)
        self.pump.send(self.client.start(sysid, command, params, self.clock.now()), now=True)

    def command_outcome(self, sysid: int, command: int) -> Ack | None:
        """How a command begun with ``command_start`` ended, once; None while it waits (resending what timed out)
        or when it was superseded (``client.in_flight`` tells the two apart)."""
        self.pump.send(self.client.poll(self.clock.now()), now=True)
        return self.client.take(sysid, command)

    def force_disarm(self, sysids: Iterable[int]) -> list[Ack]:
        """Disarm where they are, in the air too (the motors stop: the drones fall)."""
        return self.command_all(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0, FORCE_DISARM_MAGIC, sysids=sysids)

    # ---- modes -----------------------------------------------------------------------------------------------------
    def mode_params(self, sysid: int, purpose: str) -> tuple[float, float, float]:
        """DO_SET_MODE params 1-3 of a purpose (gcs/mavlink/modes.py OFFBOARD, HOLD) for a vehicle's autopilot, as
        its HEARTBEAT says it is (the simulated drones are PX4)."""
        view = self.fleet.drones.get(sysid)
        return purpose_params(purpose) if view is None else purpose_params(purpose, view.autopilot, view.vehicle_type)

    def set_mode(self, purpose: str, sysids: Iterable[int]) -> list[Ack]:
        """Each vehicle into its autopilot's mode for ``purpose``, all at once, each retried until answered."""
        params: dict[int, tuple[float, ...]] = {s: self.mode_params(s, purpose) for s in sysids}
        self._asked(purpose, params)
        return self.command_each(mavlink.MAV_CMD_DO_SET_MODE, params)

    def set_mode_start(self, sysid: int, purpose: str) -> None:
        """``set_mode`` of one vehicle, without waiting for its answer (``command_start``)."""
        self._asked(purpose, [sysid])
        self.command_start(sysid, mavlink.MAV_CMD_DO_SET_MODE, *self.mode_params(sysid, purpose))

    def _asked(self, purpose: str, sysids: Iterable[int]) -> None:
        now = self.clock.now()
        for sysid in sysids:
            if sysid in self.attachments.vehicles:
                self.attachments.asked(sysid, purpose, now)

    # ---- what the swarm is told ------------------------------------------------------------------------------------
    def wait_prearm(
        self, timeout_s: float = ARM_TIMEOUT_S, tick: Callable[[float], None] | None = None, *, every: bool = False,
        also: Iterable[int] = (),
    ) -> None:  # fmt: skip
        """Wait until the drones (the surviving ones; ``every``: all of them; and the attached vehicles ``also``)
        pass their pre-arm checks; SwarmError names those that did not within ``timeout_s``."""
        drones = self.fleet.drones
        extra = list(also)

        def waiting() -> list[int]:
            drones_now = self.liveness.sysids if every else self.liveness.active_sysids
            return [s for s in [*drones_now, *extra] if not drones[s].prearm_ok]

        if not self.pump.wait_until(lambda: not waiting(), timeout_s, tick=tick):
            raise SwarmError(f"sysid {waiting()} did not pass pre-arm checks within {timeout_s:g} s")

    def arm_all(self, timeout_s: float = ARM_TIMEOUT_S, tick: Callable[[float], None] | None = None) -> None:
        """Wait until every drone passes its pre-arm checks, then arm them all; SwarmError names the laggards. The
        attached members the swarm may arm (``Attachments.to_arm``) are armed with them, an ArduPilot one in GUIDED
        first (where ArduCopter takes off on command)."""
        members = self.attachments.to_arm() if self.attachments.vehicles else []
        self.wait_prearm(timeout_s, tick, also=members)
        ardupilot = [s for s in members if self.fleet.drones[s].autopilot == ARDUPILOT]
        if ardupilot:
            check(self.set_mode(OFFBOARD, ardupilot), "GUIDED")
        arming = self.liveness.active_sysids + members
        check(self.command_all(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1, sysids=arming), "arm")

    def takeoff_all(self, alt_m: float) -> None:
        """NAV_TAKEOFF for every drone to ``alt_m`` above its own home (PX4 takes an AMSL altitude), all at once."""
        params: dict[int, tuple[float, ...]] = {}
        nan = math.nan
        for sysid in self.liveness.active_sysids:
            home = self.fleet.drones[sysid].home
            if home is None:
                raise SwarmError(f"sysid {sysid} has no home position yet")
            params[sysid] = (0, 0, 0, nan, nan, nan, home[2] + alt_m)
        for sysid in self.attachments.taken_off() if self.attachments.vehicles else []:
            params[sysid] = (0, 0, 0, nan, nan, nan, self._member_takeoff_alt(sysid, alt_m))
        check(self.command_each(mavlink.MAV_CMD_NAV_TAKEOFF, params), "takeoff")

    def _member_takeoff_alt(self, sysid: int, alt_m: float) -> float:
        """NAV_TAKEOFF's altitude for an attached member to climb ``alt_m`` above the swarm's origin (heights are
        compared above the origin, not above each vehicle's home): AMSL for PX4, above its home for ArduPilot."""
        target_amsl = self.picture.frame.origin.alt_amsl_m + alt_m
        view = self.fleet.drones[sysid]
        if view.autopilot != ARDUPILOT:
            return target_amsl
        home_amsl = view.home[2] if view.home is not None else view.alt_amsl_m - view.relative_alt_m
        if not math.isfinite(home_amsl):
            raise SwarmError(f"member {sysid} has no home position yet")
        return target_amsl - home_amsl

    def land_all(self, *, return_to_launch: bool = False) -> list[int]:
        """Land (or return to launch) every armed drone; returns those sysids (crashed or landed ones are left)."""
        flying = self.liveness.armed_sysids()
        self.hold_members()
        if return_to_launch:
            check(self.command_all(mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH, sysids=flying), "return to launch")
        else:
            check(self._land_clear_of_wrecks(flying), "land")
        return flying

    def _land_clear_of_wrecks(self, sysids: list[int]) -> list[Ack]:
        """NAV_LAND for ``sysids``, each where it is, except a drone above or beside a lost drone's wreck, which is
        sent to land WRECK_CLEARANCE_M from it (NAV_LAND at a point: it flies there at its altitude, then descends).
        The point goes as COMMAND_INT, whose degE7 integers keep centimetres that COMMAND_LONG's floats would round
        to decimetres."""
        wrecks = [loss.down_ne_m for loss in self.liveness.losses.values() if loss.down_ne_m is not None]
        params: dict[int, tuple[float, ...]] = {}
        for sysid in sysids:
            x, y = INT32_MAX, INT32_MAX  # no point: land where it is
            view = self.fleet.drones.get(sysid)
            if wrecks and view is not None and math.isfinite(view.lat_deg):
                # where its GLOBAL_POSITION_INT puts it, as NAV_LAND's point is geodetic: not the picture's place of
                # it (from its LOCAL_POSITION_NED, through its local frame), which differs in the last bits
                here = GeoPoint(lat_deg=view.lat_deg, lon_deg=view.lon_deg, alt_amsl_m=0.0)
                north, east, _ = self.picture.ned_from_geo(here)
                spot = landing_clear_of((north, east), wrecks)
                if spot is not None:
                    point = self.picture.frame.geo_from_ned((spot[0], spot[1], 0.0))
                    x, y = round(point.lat_deg * 1e7), round(point.lon_deg * 1e7)
            params[sysid] = (0.0, 0.0, 0.0, math.nan, float(x), float(y), math.nan)
        return self.command_each(mavlink.MAV_CMD_NAV_LAND, params, frame=mavlink.MAV_FRAME_GLOBAL)

    def hold_all(self) -> list[int]:
        """Every armed surviving drone into PX4 Hold (AUTO.LOITER), where it is, and every member the swarm commands
        into its Hold mode; returns the drones' sysids."""
        flying = self.liveness.armed_sysids()
        self.hold_members()
        check(self.command_all(mavlink.MAV_CMD_DO_SET_MODE, *HOLD_MODE, sysids=flying), "hold")
        return flying

    def hold_members(self) -> list[Ack]:
        """Every attached member the swarm commands (asked for OFFBOARD or GUIDED) into its Hold mode: what the swarm
        does with a member when it lands, holds or stops (never land, disarm or terminate a vehicle it did not start).
        Not checked: a member that refuses or does not answer is its pilot's."""
        members = self.attachments.commanded() if self.attachments.vehicles else []
        return self.set_mode(HOLD, members) if members else []

    def land_on_the_way_out(self, timeout_s: float) -> None:
        """The shutdown's landing: members put in Hold, every drone that flies and is heard landed (clear of the
        wrecks), and one that cannot land within ``timeout_s`` disarmed where it is."""
        try:
            self.hold_members()
        except SwarmError:  # the swarm's own drones land all the same
            log.warning("attached members not put in Hold on the way out", exc_info=True)
        flying = [s for s in self.liveness.armed_sysids() if not self.fleet.drones[s].lost(self.clock.now())]
        if flying:
            self._land_clear_of_wrecks(flying)
            self.pump.wait_until(lambda: not self.liveness.armed_sysids(flying), timeout_s)
            still = self.liveness.armed_sysids(flying)
            if still:  # a drone that cannot land in time is disarmed where it is
                self.force_disarm(still)


def check(acks: list[Ack], what: str) -> None:
    """Raise one clear line naming every drone that refused or did not answer."""
    bad = [a for a in acks if not a.ok]
    if bad:
        names = ", ".join(f"sysid {a.sysid} ({'no answer' if a.result is None else f'result {a.result}'})" for a in bad)
        raise SwarmError(f"{what} failed for {names}")
