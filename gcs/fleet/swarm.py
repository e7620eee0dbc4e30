"""A running swarm as the ground station sees it, and what it can be told: the facade over its parts.

``Swarm`` brings drones up (launch, then wait for each one's first HEARTBEAT; never sleep-and-hope), pumps
telemetry into the fleet view, sends commands with PX4-client retry rules, and shuts everything down in order:
land or disarm over MAVLink, then the harness stops every drone. It is assembled from parts with one job each:

- the clock (gcs/fleet/clock.py): simulated seconds, paced on the wall clock or moved on in lockstep frames;
- the router (gcs/fleet/router.py): the socket's traffic both ways, batching, forwarding, the relay, the ground
  station's HEARTBEAT;
- liveness (gcs/fleet/liveness.py): each loss recorded once, silent drones taken back;
- attachments (gcs/fleet/attachments.py): vehicles the simulation does not run, attached over links of their own;
- the fleet view (gcs/fleet/telemetry.py) and the MAVLink clients for commands, parameters and missions
  (gcs/mavlink/: protocol objects without IO that the swarm feeds with what it receives and whose effects it sends).

Times are simulated seconds on the supervisor's clock (``Swarm.clock``): paced, the wall clock times the speed
factor; in lockstep, the drones' common clock, which the supervisor itself moves on (through the harness) after
every pump, so formations, timeouts and mission steps run on exactly the drones' time.

The simulation is reached only through the ``SimulationHarness`` handed to the constructor (gcs/fleet/harness.py):
it starts the drones, says which ended and why, crashes one on request, and runs the lockstep clock.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable, Iterable, Mapping
from typing import Any

from pymavlink.dialects.v20 import common as mavlink

from gcs.fleet.attach import HEARTBEAT_TIMEOUT_S, AttachedVehicle, AttachSpec
from gcs.fleet.attachments import Attachments
from gcs.fleet.clock import TICK_S, ClockStalled, SwarmClock, next_tick_s
from gcs.fleet.faults import BATTERY_LEVEL_PARAM, ENABLE_PARAM, FAULTS, FaultRequest
from gcs.fleet.harness import SimulationHarness, SpawnError, SpawnPlan
from gcs.fleet.liveness import Liveness
from gcs.fleet.losses import DroneLoss, landing_clear_of
from gcs.fleet.relay import NeighbourRelay
from gcs.fleet.router import BATCH_HOLD_S, Router
from gcs.fleet.telemetry import Fleet
from gcs.flight.geodesy import GeoPoint, NedFrame
from gcs.mavlink.commands import FORCE_DISARM_MAGIC, Ack, CommandClient, Send
from gcs.mavlink.mission_transfer import MISSION_TYPE_MISSION, MissionClient, MissionProgress, TransferResult, WireItem
from gcs.mavlink.modes import ARDUPILOT, HOLD, OFFBOARD, purpose_params
from gcs.mavlink.params import ParamClient, ParamResult
from gcs.mavlink.signing import key_id, load_key
from gcs.mavlink.transport import GcsSocket

log = logging.getLogger(__name__)

INT32_MAX = 2**31 - 1  # COMMAND_INT x/y: no position given (MAVLink's convention)
ARM_TIMEOUT_S = 30.0  # simulated seconds for every drone to pass its pre-arm checks before it is armed
# DO_SET_MODE for PX4 Hold (AUTO.LOITER), as pymavlink encodes it for PX4
HOLD_MODE = purpose_params(HOLD)


class Swarm:
    def __init__(
        self,
        plan: SpawnPlan,
        harness: SimulationHarness,
        relay_radius_m: float | None = None,
        relay: bool = True,
        forward: tuple[str, int] | None = None,
        batch_hold_s: float = BATCH_HOLD_S,
    ) -> None:
        self.plan = plan
        self.harness = harness  # the simulation, made for this plan by the composition root (gcs/composition.py)
        self._swarm_frame = NedFrame(plan.origin)
        self._sysids: list[int] = []  # spawn order, once launched
        self._clock = SwarmClock(plan, harness)
        key = load_key(plan.signing_key_file) if plan.signing_key_file is not None else None
        self.link = GcsSocket(signing_key=key, sysid=plan.gcs_sysid)  # signs what it sends when the plan has a key
        self.signing_key_id = key_id(key) if key is not None else None  # what the report names the key by
        self.router = Router(self.link, relay=NeighbourRelay(radius_m=relay_radius_m) if relay else None,
                             forward=forward, batch_hold_s=batch_hold_s)  # fmt: skip
        self.fleet = Fleet()
        self.liveness = Liveness(harness, self.fleet, self._swarm_frame, lockstep=plan.lockstep)
        self.listeners: list[Callable[[Any, float], None]] = []  # e.g. the flight recorder, the relay
        # The MAVLink command and parameter protocols (no IO of their own: the swarm feeds them and sends for them)
        self.commands = CommandClient(own_sysid=plan.gcs_sysid)
        self.params = ParamClient()
        # mission and fence transfers (gcs/mavlink/mission_transfer.py)
        self.missions = MissionClient(own_sysid=plan.gcs_sysid)
        self.mission_progress = MissionProgress()  # each drone's MISSION_CURRENT / MISSION_ITEM_REACHED
        # The setpoint stream that goes on while a command or a parameter waits for its answer (PX4 leaves OFFBOARD
        # after COM_OF_LOSS_T without a setpoint, and on a lossy link an answer can take retries): ``keep_streaming``.
        self._stream_tick: Callable[[float], None] | None = None
        # Vehicles the simulation does not run, attached over links of their own (gcs/fleet/attachments.py)
        self.attachments = Attachments(self)

    def keep_streaming(self, tick: Callable[[float], None]) -> None:
        """While a command waits for its answer, call ``tick(now)`` at the stream's rate: the setpoint stream of the
        flight this swarm flies, given once by whoever assembles it (gcs/supervisor/session.py, the bench)."""
        self._stream_tick = tick

    # ---- the parts' state, as the swarm's users read it ------------------------------------------------------------
    def clock(self) -> float:
        """Simulated seconds: the drones' common clock in lockstep, else wall time times the speed factor."""
        return self._clock.now()

    @property
    def relay(self) -> NeighbourRelay | None:
        return self.router.relay

    @property
    def forward(self) -> tuple[str, int] | None:
        return self.router.forward

    @property
    def sent_listeners(self) -> list[Callable[[bytes, float], None]]:
        """Called with every command and parameter write sent, packed (the flight log keeps them)."""
        return self.router.sent_listeners

    @property
    def losses(self) -> dict[int, DroneLoss]:
        return self.liveness.losses

    @property
    def regained(self) -> list[DroneLoss]:
        return self.liveness.regained

    def drone_time_s(self) -> float | None:
        """The slowest running drone's own simulated time; None before every drone has one."""
        return self.harness.drone_time_s()

    @property
    def sysids(self) -> list[int]:
        return list(self._sysids)

    @property
    def active_sysids(self) -> list[int]:
        """The drones the swarm still has: every one not in ``losses``."""
        return [s for s in self._sysids if s not in self.losses]

    @property
    def flown_sysids(self) -> list[int]:
        """What the swarm's formations and behaviours fly: the drones it still has, then the attached members that
        fly now (``Attachments.members``)."""
        members = self.attachments.members(self.clock()) if self.attachments.vehicles else []
        return self.active_sysids + members

    # ---- losses ----------------------------------------------------------------------------------------------------
    def detect_losses(self, time_s: float) -> list[DroneLoss]:
        """Record every new loss once and return them (gcs/fleet/liveness.py); ``time_s`` is the time to record (the
        caller's mission clock)."""
        return self.liveness.detect_losses(self._sysids, time_s, self.clock())

    def detect_regains(self, time_s: float) -> list[DroneLoss]:
        """Take back every drone lost for silence that has been heard again, once (gcs/fleet/liveness.py)."""
        return self.liveness.detect_regains(time_s, self.clock())

    def kill(self, sysid: int) -> str:
        """Crash drone ``sysid``'s flight software (the harness kills what runs it); returns what was done, in one
        line. The loss is recorded by ``detect_losses`` when the harness reports the end, as for any other end."""
        done = self.harness.kill(sysid)
        if done is None:
            raise SwarmError(f"drone {sysid}: its flight software has already ended")
        return done

    def set_param(self, sysid: int, name: str, value: int | float) -> None:
        """PARAM_SET, confirmed by the drone's PARAM_VALUE echo (as MAVSDK does); SwarmError if refused or silent."""
        result = self.set_params(name, value, [sysid])[0]
        if result.refused:
            raise SwarmError(f"drone {sysid}: parameter {name} = {value:g} refused (kept {result.kept:g})")
        if not result.ok:
            raise SwarmError(f"drone {sysid}: no answer to setting parameter {name}")

    def set_params(self, name: str, value: int | float, sysids: Iterable[int]) -> list[ParamResult]:
        """One parameter on several drones at once, each confirmed by its echo or retried (gcs/mavlink/params.py)."""
        return self.set_param_each(name, dict.fromkeys(sysids, value))

    def read_params(self, name: str, sysids: Iterable[int]) -> list[ParamResult]:
        """One parameter read from several drones at once (PARAM_REQUEST_READ, retried as a set); ``kept`` is the
        value, None for a drone that never answered."""
        return self.set_param_each(name, dict.fromkeys(sysids, None))

    def set_param_each(self, name: str, values: Mapping[int, int | float | None]) -> list[ParamResult]:
        """One parameter, a value of its own on each drone (sysid -> value; None reads it), all at once as
        ``set_params``."""
        for sysid, value in values.items():
            self._send_effects(self.params.start(sysid, name, value, self.clock()), now=False)
        return self._serve(self.params, name, list(values), now=False)

    def upload_mission(
        self, items: dict[int, list[WireItem]], mission_type: int = MISSION_TYPE_MISSION
    ) -> list[TransferResult]:
        """A mission (or fence: ``mission_type`` 1) to several drones at once, each its own list (sysid -> items),
        with MAVSDK's timeouts and retries (gcs/mavlink/mission_transfer.py); the outcomes in the order of ``items``."""
        for sysid, own in items.items():
            self._send_effects(self.missions.start_upload(sysid, own, mission_type, self.clock()), now=True)
        return self._serve(self.missions, mission_type, list(items), now=True)

    def download_mission(self, sysids: Iterable[int], mission_type: int = MISSION_TYPE_MISSION) -> list[TransferResult]:
        """Several drones' missions (or fences) at once; each outcome carries the items downloaded."""
        targets = list(sysids)
        for sysid in targets:
            self._send_effects(self.missions.start_download(sysid, mission_type, self.clock()), now=True)
        return self._serve(self.missions, mission_type, targets, now=True)

    def inject_fault(self, sysid: int, fault: FaultRequest) -> Ack:
        """MAV_CMD_INJECT_FAILURE as PX4 takes it, after SYS_FAILURE_EN = 1 (and the battery level it needs)."""
        kind = FAULTS[fault.kind]
        self.set_param(sysid, ENABLE_PARAM, 1)
        if kind.battery_level is not None:
            self.set_param(sysid, BATTERY_LEVEL_PARAM, kind.battery_level)
        command = mavlink.MAV_CMD_INJECT_FAILURE
        acks = self.command_all(command, kind.unit, kind.failure_type, fault.instance, fault.duration_param,
                                sysids=[sysid])  # fmt: skip
        return acks[0]

    # ---- IO --------------------------------------------------------------------------------------------------------
    def pump(self, wait_s: float = 0.0) -> None:
        """Send what is due, then handle every waiting message, waiting up to ``wait_s`` (simulated) for the first.
        In lockstep, one frame of the common clock instead, whatever ``wait_s``: every message then meets a fixed
        simulated time on both sides (what a drone sent up to the gate's step is read at the gate's time, and what
        the supervisor sends between frames reaches every drone while it waits at the gate), so nothing depends on
        when a datagram happened to arrive, and the same mission with the same seeds flies the same on an idle
        machine or a loaded one."""
        router = self.router
        router.flush(self.clock())
        if self._clock.lockstep_running:
            try:
                self._clock.frame(router.sent_to_drones())
            except ClockStalled as exc:
                raise SwarmError(str(exc)) from None
            now = self.clock()
            messages = router.receive_frame(self.harness.sent_by_drones(), self.losses)
        else:
            router.wait(wait_s, self.plan.speed_factor, self.clock())
            now = self.clock()
            messages = router.receive()
        for msg, _sender in messages:
            if msg.get_srcComponent() != 1:
                router.from_ground_station(msg, self.sysids)
                continue
            self.fleet.handle(msg, now)
            router.carry(msg, now, self.fleet)
            kind = msg.get_type()
            if kind == "GLOBAL_POSITION_INT" and self.attachments.vehicles:
                self.attachments.share(msg, now)  # the simulated drones, as traffic, to the attached vehicles
            if kind != "RADIO_STATUS":  # any other message is a sign of life (gcs/fleet/telemetry.py LINK_LOST_S)
                self.liveness.heard(msg.get_srcSystem())
            if kind == "COMMAND_ACK":
                self.commands.handle(msg, now)
            elif kind == "PARAM_VALUE":
                self._send_effects(self.params.handle(msg, now), now=False)
            elif kind.startswith("MISSION_"):  # the mission protocol (transfers) and its progress reports
                self._send_effects(self.missions.handle(msg, now), now=True)
                self.mission_progress.handle(msg, now)
            for listener in self.listeners:
                listener(msg, now)
        if self.attachments.vehicles:
            self.attachments.pump(now)
        router.heartbeat(now, self.losses)
        router.flush(now)

    def run_for(self, seconds: float, tick: Callable[[float], None] | None = None, tick_s: float = TICK_S) -> None:
        """Pump telemetry for a while, calling ``tick(now)`` every ``tick_s``."""
        end = self.clock() + seconds
        next_tick = self.clock()
        while (now := self.clock()) < end:
            if tick is not None and now >= next_tick:
                tick(now)
                next_tick = next_tick_s(next_tick, now, tick_s)
            self.pump(max(0.0, min(next_tick, end) - self.clock()))

    def wait_until(
        self,
        condition: Callable[[], bool],
        timeout_s: float,
        tick: Callable[[float], None] | None = None,
    ) -> bool:
        end = self.clock() + timeout_s
        next_tick = self.clock()
        while self.clock() < end:
            now = self.clock()
            if tick is not None and now >= next_tick:
                tick(now)
                next_tick = next_tick_s(next_tick, now, TICK_S)
            if condition():
                return True
            self.pump(min(0.05, max(0.0, end - self.clock())))
        return condition()

    # ---- attached vehicles (gcs/fleet/attachments.py) -------------------------------------------------------------
    @property
    def attached(self) -> dict[int, AttachedVehicle]:
        """The vehicles the simulation does not run, attached to the swarm, by sysid."""
        return self.attachments.vehicles

    def attach(self, spec: AttachSpec, timeout_s: float = HEARTBEAT_TIMEOUT_S) -> tuple[list[int], list[str]]:
        """Attach the vehicles heard on ``spec``'s link (``Attachments.attach``): the sysids attached and one line
        for each vehicle refused; AttachError (one line) when none can be. The swarm flies on meanwhile."""
        return self.attachments.attach(spec, timeout_s)

    def detach(self, sysid: int) -> None:
        """Let an attached vehicle go (``Attachments.detach``); SwarmError when none of that sysid is attached."""
        if sysid not in self.attachments.vehicles:
            raise SwarmError(f"no attached vehicle with sysid {sysid}")
        self.attachments.detach(sysid)

    def detect_external_changes(self, now_s: float) -> list[str]:
        """One line for each attached vehicle newly silent or heard again (``Attachments.detect_changes``)."""
        return self.attachments.detect_changes(now_s)

    @property
    def stream_tick(self) -> Callable[[float], None] | None:
        """The setpoint stream kept going while the swarm waits (``keep_streaming``), if any."""
        return self._stream_tick

    def simulated_sysids(self) -> list[int]:
        """The simulated drones' sysids: those launched, or before the launch those the plan will start."""
        first = self.plan.first_instance + 1
        return self._sysids or list(range(first, first + self.plan.n_drones))

    # ---- lifecycle -------------------------------------------------------------------------------------------------
    def up(self, ready_timeout_s: float = 30.0) -> None:
        """Spawn every drone and wait for its first HEARTBEAT; SpawnError names the first that does not come up."""
        try:
            self._sysids = self.harness.launch(self.link.port)
        except RuntimeError as exc:  # the harness's one line (gcs/fleet/harness.py)
            raise SpawnError(str(exc)) from None
        self._clock.start(len(self._sysids))
        expected = set(self.sysids)
        end = time.monotonic() + ready_timeout_s  # start-up is wall-clock work (Python, JSBSim), whatever the mode
        while not expected <= set(self.fleet.drones):
            for sysid in self.harness.ended():
                raise SpawnError(self.harness.end_report(sysid))
            if time.monotonic() > end:
                missing = sorted(expected - set(self.fleet.drones))
                raise SpawnError(f"no HEARTBEAT within {ready_timeout_s:g} s from sysid {', '.join(map(str, missing))}")
            self.pump(self.plan.speed_factor * 0.05)  # paced: 50 ms of wall time; in lockstep one frame

    def armed_sysids(self, sysids: Iterable[int] | None = None) -> list[int]:
        """Of ``sysids`` (default: every drone), those not lost whose last HEARTBEAT said armed (a lost drone's last
        report may say armed for ever)."""
        drones = self.fleet.drones
        return [
            s
            for s in (self.sysids if sysids is None else sysids)
            if s not in self.losses and s in drones and drones[s].armed
        ]

    def wait_prearm(
        self, timeout_s: float = ARM_TIMEOUT_S, tick: Callable[[float], None] | None = None, *, every: bool = False,
        also: Iterable[int] = (),
    ) -> None:  # fmt: skip
        """Wait until the drones (the surviving ones; ``every``: all of them; and the attached vehicles ``also``)
        pass their pre-arm checks; SwarmError names those that did not within ``timeout_s``."""
        drones = self.fleet.drones
        extra = list(also)

        def waiting() -> list[int]:
            return [s for s in [*(self.sysids if every else self.active_sysids), *extra] if not drones[s].prearm_ok]

        if not self.wait_until(lambda: not waiting(), timeout_s, tick=tick):
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
        check(self.command_all(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1, sysids=self.active_sysids + members), "arm")

    def land_all(self, *, return_to_launch: bool = False) -> list[int]:
        """Land (or return to launch) every armed drone; returns those sysids (crashed or landed ones are left)."""
        flying = self.armed_sysids()
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
        wrecks = [loss.down_ne_m for loss in self.losses.values() if loss.down_ne_m is not None]
        params: dict[int, tuple[float, ...]] = {}
        for sysid in sysids:
            x, y = INT32_MAX, INT32_MAX  # no point: land where it is
            view = self.fleet.drones.get(sysid)
            if wrecks and view is not None and math.isfinite(view.lat_deg):
                here = GeoPoint(lat_deg=view.lat_deg, lon_deg=view.lon_deg, alt_amsl_m=0.0)
                north, east, _ = self._swarm_frame.ned_from_geo(here)
                spot = landing_clear_of((north, east), wrecks)
                if spot is not None:
                    point = self._swarm_frame.geo_from_ned((spot[0], spot[1], 0.0))
                    x, y = round(point.lat_deg * 1e7), round(point.lon_deg * 1e7)
            params[sysid] = (0.0, 0.0, 0.0, math.nan, float(x), float(y), math.nan)
        return self.command_each(mavlink.MAV_CMD_NAV_LAND, params, frame=mavlink.MAV_FRAME_GLOBAL)

    def hold_all(self) -> list[int]:
        """Every armed surviving drone into PX4 Hold (AUTO.LOITER), where it is, and every member the swarm commands
        into its Hold mode; returns the drones' sysids."""
        flying = self.armed_sysids()
        self.hold_members()
        check(self.command_all(mavlink.MAV_CMD_DO_SET_MODE, *HOLD_MODE, sysids=flying), "hold")
        return flying

    def hold_members(self) -> list[Ack]:
        """Every attached member the swarm commands (asked for OFFBOARD or GUIDED) into its Hold mode: what the swarm
        does with a member when it lands, holds or stops (never land, disarm or terminate a vehicle it did not start).
        Not checked: a member that refuses or does not answer is its pilot's."""
        members = self.attachments.commanded() if self.attachments.vehicles else []
        return self.set_mode(HOLD, members) if members else []

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
        now = self.clock()
        for sysid in sysids:
            if sysid in self.attachments.vehicles:
                self.attachments.asked(sysid, purpose, now)

    def takeoff_all(self, alt_m: float) -> None:
        """NAV_TAKEOFF for every drone to ``alt_m`` above its own home (PX4 takes an AMSL altitude), all at once."""
        params: dict[int, tuple[float, ...]] = {}
        nan = math.nan
        for sysid in self.active_sysids:
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
        target_amsl = self.plan.origin.alt_amsl_m + alt_m
        view = self.fleet.drones[sysid]
        if view.autopilot != ARDUPILOT:
            return target_amsl
        home_amsl = view.home[2] if view.home is not None else view.alt_amsl_m - view.relative_alt_m
        if not math.isfinite(home_amsl):
            raise SwarmError(f"member {sysid} has no home position yet")
        return target_amsl - home_amsl

    def shutdown(self, land_timeout_s: float = 30.0) -> None:
        """Land what flies, disarm, then have the harness stop every drone and leave nothing behind (also after
        errors)."""
        try:
            try:
                self.hold_members()
            except SwarmError:  # the swarm's own drones land all the same
                log.warning("attached members not put in Hold on the way out", exc_info=True)
            flying = [s for s in self.armed_sysids() if not self.fleet.drones[s].lost(self.clock())]
            if flying:
                self._land_clear_of_wrecks(flying)
                self.wait_until(lambda: not self.armed_sysids(flying), land_timeout_s)
                still = self.armed_sysids(flying)
                if still:  # a drone that cannot land in time is disarmed where it is
                    self.force_disarm(still)
        finally:
            try:
                self.harness.close()
            finally:
                self.attachments.close()  # an attached vehicle is left as it is: nothing is sent to it on the way out
                self._clock.close()
                self.router.close()

    # ---- commands --------------------------------------------------------------------------------------------------
    def command_all(self, command: int, *params: float, sysids: Iterable[int] | None = None) -> list[Ack]:
        """COMMAND_LONG to several drones at once, each retried until answered (MAVSDK's rules:
        gcs/mavlink/commands.py)."""
        targets = self.sysids if sysids is None else sysids
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
                self.commands.cancel(sysid, command)  # superseded: one begun with ``command_start`` still waiting
                effects = self.commands.start(sysid, command, params[sysid], self.clock(), frame=frame)
                self._send_effects(effects, now=True)
            acks.update((a.sysid, a) for a in self._serve(self.commands, command, waiting, now=True))
            # A drone that never answered, on a lossy link, is asked again (commands are idempotent, as PX4's); one
            # that is lost or gone is not
            waiting = [a.sysid for a in acks.values() if a.result is None
                       and (a.sysid in self.active_sysids or a.sysid in self.attachments.vehicles)
                       and not self.fleet.drones[a.sysid].lost(self.clock())]  # fmt: skip
            if not waiting:
                break
        return [acks[sysid] for sysid in params]

    def command_start(self, sysid: int, command: int, *params: float) -> None:
        """Begin a COMMAND_LONG without waiting for its answer (the streamer's, from inside a tick); its outcome
        comes from ``command_outcome``. A later ``command_all`` of the same command to the drone supersedes it."""
        self.commands.cancel(sysid, command)
        self._send_effects(self.commands.start(sysid, command, params, self.clock()), now=True)

    def command_outcome(self, sysid: int, command: int) -> Ack | None:
        """How a command begun with ``command_start`` ended, once; None while it waits (resending what timed out)
        or when it was superseded (``commands.in_flight`` tells the two apart)."""
        self._send_effects(self.commands.poll(self.clock()), now=True)
        return self.commands.take(sysid, command)

    def force_disarm(self, sysids: Iterable[int]) -> list[Ack]:
        """Disarm where they are, in the air too (the motors stop: the drones fall)."""
        return self.command_all(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0, FORCE_DISARM_MAGIC, sysids=sysids)

    def _serve(
        self, client: CommandClient | ParamClient | MissionClient, key: Any, targets: list[int], *, now: bool
    ) -> list[Any]:
        """Pump until the work ``key`` (a command, a parameter name) has ended on every target, sending what the
        client's ``poll`` asks for when its timers come due; the outcomes in the order of ``targets``. Interrupted or
        failed, nothing is left in flight to block the next use of the same command or parameter (the shutdown's)."""
        results: dict[int, Any] = {}

        def collect() -> bool:
            for sysid in targets:
                if sysid not in results and (outcome := client.take(sysid, key)) is not None:
                    results[sysid] = outcome
            return len(results) == len(targets)

        next_tick = self.clock()
        try:
            while not collect():
                self._send_effects(client.poll(self.clock()), now=now)
                if collect():
                    break
                if self._stream_tick is not None and (clock := self.clock()) >= next_tick:
                    self._stream_tick(clock)
                    next_tick = next_tick_s(next_tick, clock, TICK_S)
                self.pump(min(0.02, max(0.0, client.next_due_s() - self.clock())))
        finally:
            for sysid in targets:
                client.cancel(sysid, key)
        return [results[s] for s in targets]

    def _send_effects(self, effects: list[Send], *, now: bool) -> None:
        for effect in effects:
            self._send_logged(effect.sysid, effect.message, now=now)

    def _send_logged(self, sysid: int, msg: Any, *, now: bool) -> None:
        if sysid in self.attachments.vehicles:  # on the attached vehicle's own link, at once
            data = self.attachments.send(sysid, msg)
            for listener in self.router.sent_listeners:
                listener(data, self.clock())
            return
        self.router.send_logged(sysid, msg, now=now, clock_s=self.clock())

    def send(self, sysid: int, msg: Any) -> None:
        """Streamed traffic (setpoints, parameter writes): leaves at the start of the next pump, batched with
        whatever else is queued for each drone. Commands that wait for an answer go out at once (``command_all``).
        An attached member's setpoints go through ``Attachments.setpoint`` (its safety rules), not here."""
        self.router.send(sysid, msg)

    def send_now(self, sysid: int, msg: Any) -> None:
        """One message to one drone at once, outside any batch (a command whose answer is being timed)."""
        self.router.send_now(sysid, msg)


# Rounds of a command's retries (each MAVSDK's: the first try and 3 resends) for a drone that answers none: on a link
# losing 20 % each way one round goes unanswered 1.7 % of the time, three rounds once in 200,000.
NO_ANSWER_ROUNDS = 3


def check(acks: list[Ack], what: str) -> None:
    """Raise one clear line naming every drone that refused or did not answer."""
    bad = [a for a in acks if not a.ok]
    if bad:
        names = ", ".join(f"sysid {a.sysid} ({'no answer' if a.result is None else f'result {a.result}'})" for a in bad)
        raise SwarmError(f"{what} failed for {names}")


class SwarmError(RuntimeError):
    """A swarm-level operation failed; the message is one line for the user."""
