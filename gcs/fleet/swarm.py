"""A running swarm as the ground station sees it, and what it can be told: the facade over its parts.

``Swarm`` brings drones up (launch, then wait for each one's first HEARTBEAT; never sleep-and-hope), attaches
vehicles the simulation does not run, and shuts everything down in order: land or disarm over MAVLink, then the
harness stops every drone. Everything else is the job of one of its parts, each owning its state and handed only the
parts it works with (never the swarm), which its users reach directly (``swarm.liveness.losses``,
``swarm.commands.land_all()``, ``swarm.pump.wait_until(...)``):

- ``clock`` (gcs/fleet/clock.py): simulated seconds, paced on the wall clock or moved on in lockstep frames;
- ``router`` (gcs/fleet/router.py): the socket's traffic both ways, batching, forwarding, the relay, the ground
  station's HEARTBEAT, and the listeners to what is received and sent;
- ``fleet`` (gcs/fleet/telemetry.py): every vehicle's view from its telemetry, in its own terms;
- ``picture`` (gcs/fleet/picture.py): every vehicle's place in the swarm frame, the one conversion, kept current as
  each report arrives: what every reader of positions reads;
- ``liveness`` (gcs/fleet/liveness.py): the drones launched, each loss recorded once, silent drones taken back;
- ``attachments`` (gcs/fleet/attachments.py): vehicles the simulation does not run, attached over links of their own;
- ``pump`` (gcs/fleet/pump.py): every message taken where it belongs, and the one loop every wait runs;
- ``commands`` (gcs/fleet/commanding.py): commands with their answers, modes, arming, takeoff, landing, Hold;
- ``params`` and ``missions`` (gcs/fleet/transfers.py): parameters and mission transfers on many drones at once.

The MAVLink protocol clients (gcs/mavlink/: state without IO) are made here and handed to the pump, which feeds them,
and to the part that drives each.

Times are simulated seconds on the supervisor's clock (``Swarm.clock``): paced, the wall clock times the speed
factor; in lockstep, the drones' common clock, which the supervisor itself moves on (through the harness) after
every pump, so formations, timeouts and mission steps run on exactly the drones' time.

The simulation is reached only through the ``SimulationHarness`` handed to the constructor (gcs/fleet/harness.py):
it starts the drones, says which ended and why, crashes one on request, and runs the lockstep clock.
"""

from __future__ import annotations

import functools
import time

from pymavlink.dialects.v20 import common as mavlink

from gcs.fleet.attach import HEARTBEAT_TIMEOUT_S, AttachedVehicle, AttachSpec
from gcs.fleet.attachments import Attachments
from gcs.fleet.clock import SwarmClock
from gcs.fleet.commanding import ARM_TIMEOUT_S, HOLD_MODE, Commands, check
from gcs.fleet.errors import SwarmError
from gcs.fleet.faults import BATTERY_LEVEL_PARAM, ENABLE_PARAM, FAULTS, FaultRequest
from gcs.fleet.harness import SimulationHarness, SpawnError, SpawnPlan
from gcs.fleet.liveness import Liveness
from gcs.fleet.picture import SwarmPicture
from gcs.fleet.pump import Protocols, Pump
from gcs.fleet.relay import DEFAULT_RELAY_SCOPE, NeighbourRelay, RelayScope
from gcs.fleet.router import BATCH_HOLD_S, Router
from gcs.fleet.telemetry import Fleet
from gcs.fleet.transfers import Missions, Params
from gcs.flight.frames import SwarmFrame
from gcs.mavlink.commands import Ack, CommandClient
from gcs.mavlink.mission_transfer import MissionClient, MissionProgress
from gcs.mavlink.modes import HOLD
from gcs.mavlink.params import ParamClient
from gcs.mavlink.signing import key_id, load_key
from gcs.mavlink.transport import GcsSocket

# What the swarm's users catch and check with, defined by the parts, reached through the facade they import
__all__ = ["ARM_TIMEOUT_S", "HOLD_MODE", "Swarm", "SwarmError", "check"]

READY_PUMP_S = 0.05  # wall seconds (paced: times the speed factor) a pump waits while the drones come up


class Swarm:
    def __init__(
        self,
        plan: SpawnPlan,
        harness: SimulationHarness,
        relay: RelayScope | None = DEFAULT_RELAY_SCOPE,  # None: no relay
        forward: tuple[str, int] | None = None,
        batch_hold_s: float = BATCH_HOLD_S,
    ) -> None:
        self.plan = plan
        self.harness = harness  # the simulation, made for this plan by the composition root (gcs/composition.py)
        self.clock = SwarmClock(plan, harness)
        key = load_key(plan.signing_key_file) if plan.signing_key_file is not None else None
        self.link = GcsSocket(signing_key=key, sysid=plan.gcs_sysid)  # signs what it sends when the plan has a key
        self.signing_key_id = key_id(key) if key is not None else None  # what the report names the key by
        self.router = Router(self.link, relay=NeighbourRelay(scope=relay) if relay is not None else None,
                             forward=forward, batch_hold_s=batch_hold_s, lockstep=plan.lockstep)  # fmt: skip
        self.fleet = Fleet()
        # the swarm-frame picture, kept current before any other listener reads the message that moved a vehicle,
        # and the one swarm frame the parts convert a geodetic point in; it places the attached vehicles (kept in
        # ``vehicles`` by the attachments) where they say they are
        vehicles: dict[int, AttachedVehicle] = {}
        self.picture = SwarmPicture(SwarmFrame(plan.origin), self.fleet, vehicles)
        self.router.listeners.append(self.picture.observe)
        self.liveness = Liveness(harness, self.fleet, self.clock, self.picture.ned_from_geo, lockstep=plan.lockstep)
        protocols = Protocols(commands=CommandClient(own_sysid=plan.gcs_sysid), params=ParamClient(),
                              missions=MissionClient(own_sysid=plan.gcs_sysid), progress=MissionProgress())  # fmt: skip
        self.attachments = Attachments(plan, self.clock, harness, self.fleet, self.router, protocols.commands,
                                       self.picture, vehicles)  # fmt: skip
        self.pump = Pump(self.clock, harness, self.router, self.fleet, self.liveness, self.attachments, protocols,
                         speed_factor=plan.speed_factor)  # fmt: skip
        self.commands = Commands(protocols.commands, self.pump, self.clock, self.fleet, self.liveness,
                                 self.attachments, self.picture)  # fmt: skip
        self.attachments.start_hold = functools.partial(self.commands.set_mode_start, purpose=HOLD)
        self.params = Params(protocols.params, self.pump, self.clock)
        self.missions = Missions(protocols.missions, protocols.progress, self.pump, self.clock)

    @property
    def flown_sysids(self) -> list[int]:
        """What the swarm's formations and behaviours fly: the drones it still has, then the attached members that
        fly now (``Attachments.members``)."""
        members = self.attachments.members(self.clock.now()) if self.attachments.vehicles else []
        return self.liveness.active_sysids + members

    def _simulated_sysids(self) -> list[int]:
        """The simulated drones' sysids: those launched, or before the launch those the plan will start."""
        first = self.plan.first_instance + 1
        return self.liveness.sysids or list(range(first, first + self.plan.n_drones))

    def attach(self, spec: AttachSpec, timeout_s: float = HEARTBEAT_TIMEOUT_S) -> tuple[list[int], list[str]]:
        """Attach the vehicles heard on ``spec``'s link (``Attachments.attach``): the sysids attached and one line
        for each vehicle refused; AttachError (one line) when none can be. The swarm flies on meanwhile, its
        setpoints streamed (``Pump.keep_flying``)."""
        return self.attachments.attach(spec, timeout_s, self._simulated_sysids(), self.pump.keep_flying)

    def inject_fault(self, sysid: int, fault: FaultRequest) -> Ack:
        """MAV_CMD_INJECT_FAILURE as PX4 takes it, after SYS_FAILURE_EN = 1 (and the battery level it needs)."""
        kind = FAULTS[fault.kind]
        self.params.set(sysid, ENABLE_PARAM, 1)
        if kind.battery_level is not None:
            self.params.set(sysid, BATTERY_LEVEL_PARAM, kind.battery_level)
        command = mavlink.MAV_CMD_INJECT_FAILURE
        acks = self.commands.command_all(command, kind.unit, kind.failure_type, fault.instance, fault.duration_param,
                                         sysids=[sysid])  # fmt: skip
        return acks[0]

    # ---- lifecycle -------------------------------------------------------------------------------------------------
    def up(self, ready_timeout_s: float = 30.0) -> None:
        """Spawn every drone and wait for its first HEARTBEAT; SpawnError names the first that does not come up."""
        try:
            sysids = self.harness.launch(self.link.port)
        except RuntimeError as exc:  # the harness's one line (gcs/fleet/harness.py)
            raise SpawnError(str(exc)) from None
        self.liveness.launched(sysids)
        self.clock.start(len(sysids))
        expected = set(sysids)
        end = time.monotonic() + ready_timeout_s  # start-up is wall-clock work (Python, JSBSim), whatever the mode
        while not expected <= set(self.fleet.drones):
            for sysid in self.harness.ended():
                raise SpawnError(self.harness.end_report(sysid))
            if time.monotonic() > end:
                missing = sorted(expected - set(self.fleet.drones))
                raise SpawnError(f"no HEARTBEAT within {ready_timeout_s:g} s from sysid {', '.join(map(str, missing))}")
            self.pump.once(self.plan.speed_factor * READY_PUMP_S)  # paced: 50 ms of wall time; in lockstep one frame

    def shutdown(self, land_timeout_s: float = 30.0) -> None:
        """Land what flies, disarm, then have the harness stop every drone and leave nothing behind (also after
        errors)."""
        try:
            self.commands.land_on_the_way_out(land_timeout_s)
        finally:
            try:
                self.harness.close()
            finally:
                self.attachments.close()  # an attached vehicle is left as it is: nothing is sent to it on the way out
                self.clock.close()
                self.router.close()
