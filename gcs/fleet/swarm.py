"""A running swarm as the ground station sees it: its simulation harness, the MAVLink socket and the fleet view.

``Swarm`` brings drones up (launch, then wait for each one's first HEARTBEAT; never sleep-and-hope), pumps
telemetry into the fleet view, sends commands with PX4-client retry rules, and shuts everything down in order:
land or disarm over MAVLink, then the harness stops every drone. The retry rules are not here: commands and
parameter writes are protocol objects without IO (gcs/mavlink/commands.py, gcs/mavlink/params.py) that the swarm feeds
with what it receives and whose effects it sends.

Times are simulated seconds on the supervisor's clock (``Swarm.clock``): paced, the wall clock times the speed
factor; in lockstep, the drones' common clock, which the supervisor itself moves on (through the harness) after
every pump, so formations, timeouts and mission steps run on exactly the drones' time.

The simulation is reached only through the ``SimulationHarness`` handed to the constructor (gcs/fleet/harness.py):
it starts the drones, says which ended and why, crashes one on request, and runs the lockstep clock.
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import math
import os
import selectors
import time
from collections.abc import Callable, Iterable, Mapping
from typing import Any

from pymavlink.dialects.v20 import common as mavlink

from gcs.fleet.faults import BATTERY_LEVEL_PARAM, ENABLE_PARAM, FAULTS, FaultRequest
from gcs.fleet.harness import SimulationHarness, SpawnError, SpawnPlan
from gcs.fleet.losses import MAV_STATE_FLIGHT_TERMINATION, DroneLoss, landing_clear_of
from gcs.fleet.relay import NeighbourRelay
from gcs.fleet.telemetry import LINK_LOST_S, Fleet
from gcs.flight.geodesy import GeoPoint, NedFrame
from gcs.mavlink.commands import FORCE_DISARM_MAGIC, Ack, CommandClient, Send
from gcs.mavlink.mission_transfer import MISSION_TYPE_MISSION, MissionClient, MissionProgress, TransferResult, WireItem
from gcs.mavlink.params import ParamClient, ParamResult
from gcs.mavlink.px4_modes import set_mode_params
from gcs.mavlink.signing import key_id, load_key
from gcs.mavlink.transport import GcsSocket

log = logging.getLogger(__name__)

INT32_MAX = 2**31 - 1  # COMMAND_INT x/y: no position given (MAVLink's convention)
ARM_TIMEOUT_S = 30.0  # simulated seconds for every drone to pass its pre-arm checks before it is armed
# How far the drones may run ahead of the supervisor's last look. Under load the drones sit at this limit, so it is
# the lag of setpoints and relayed positions in simulated time: 50 ms let an eight-drone swap touch on a busy machine.
LOCKSTEP_LEAD_S = 0.02
TICK_S = 0.05  # the period of a waiting loop's ``tick`` (the setpoint stream's 20 Hz)
LOCKSTEP_STALL_S = 10.0  # wall seconds without progress before the supervisor calls the simulation stalled
LOCKSTEP_MAX_WAIT_S = 0.005  # wall-clock cap on one wait for traffic in lockstep (simulated time has no wall rate)
LOCKSTEP_AWAIT_S = 1.0  # wall seconds the supervisor waits for a datagram a drone says it has sent
# Relayed positions (and copies for another ground station) are held up to this long, in simulated seconds, and
# leave with the next setpoint tick in one datagram per drone (gcs/mavlink/transport.py). A drone then wakes once per
# tick instead of once per neighbour report: with 8 neighbours reporting at 10 Hz that is 20 wake-ups a second instead
# of 100, and a wake-up costs a drone more CPU than the message it brings (docs/benchmarks.md). The receiving drone's
# neighbour table ages every report by its sender's timestamp in lockstep; paced, by its arrival.
BATCH_HOLD_S = 0.05
# DO_SET_MODE for PX4 Hold (AUTO.LOITER), as pymavlink encodes it for PX4
HOLD_MODE = set_mode_params("LOITER")
GCS_HEARTBEAT_PERIOD_S = 1.0  # QGroundControl sends its HEARTBEAT at 1 Hz; PX4's datalink-loss failsafe watches it
EXIT_CHECK_S = 0.5  # wall seconds between looks for ended drones while moving the lockstep clock


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
        self._lockstep_running = False
        # Lockstep: the common time once every drone stands at the gate. Nothing moves it until the next frame opens
        # the gate, and the supervisor reads its clock a dozen times between frames (a read scans the world table).
        self._gate_time_s: float | None = None
        self._wake_fd: int | None = None
        self._wall_t0 = time.monotonic()
        self._gate_progress = (0.0, time.monotonic())  # (common time, wall time it was first seen)
        self._next_exit_check = 0.0
        key = load_key(plan.signing_key_file) if plan.signing_key_file is not None else None
        self.link = GcsSocket(signing_key=key)  # signs what the supervisor sends when the plan has a key
        self.signing_key_id = key_id(key) if key is not None else None  # what the report names the key by
        self.fleet = Fleet()
        self.listeners: list[Callable[[Any, float], None]] = []  # e.g. the flight recorder, the relay
        # Commands and parameter writes the swarm sends, as packed MAVLink frames (the flight log keeps them)
        self.sent_listeners: list[Callable[[bytes, float], None]] = []
        self._selector = selectors.DefaultSelector()
        self._selector.register(self.link.sock, selectors.EVENT_READ)
        self._gate_selector = selectors.DefaultSelector()  # lockstep: woken by the drones reaching the gate
        # The MAVLink command and parameter protocols (no IO of their own: the swarm feeds them and sends for them)
        self.commands = CommandClient()
        self.params = ParamClient()
        self.missions = MissionClient()  # mission and fence transfers (gcs/mavlink/mission_transfer.py)
        self.mission_progress = MissionProgress()  # each drone's MISSION_CURRENT / MISSION_ITEM_REACHED
        self.relay: NeighbourRelay | None = NeighbourRelay(radius_m=relay_radius_m) if relay else None
        # Every drone's traffic also goes to this address (QGroundControl/MAVProxy listen on 14550), and what comes
        # back from there is routed to the drones by target system, as a MAVLink router does.
        self.forward = forward
        self.batch_hold_s = batch_hold_s
        self._flush_due_s = math.inf  # when the queued traffic must leave (-inf: at the next pump)
        self.losses: dict[int, DroneLoss] = {}  # sysid -> the loss, recorded once
        self.regained: list[DroneLoss] = []  # losses that ended: silent drones heard again (``detect_regains``)
        # Streaming that must go on while a command or a parameter waits for its answer (the setpoint stream: PX4
        # leaves OFFBOARD after COM_OF_LOSS_T without a setpoint, and on a lossy link an answer can take retries).
        self.stream_tick: Callable[[float], None] | None = None
        self._next_gcs_heartbeat_s = 0.0
        self._heard_wall_s: dict[int, float] = {}
        self._said_late_traffic = False  # sysid -> wall time of its last HEARTBEAT

    def clock(self) -> float:
        """Simulated seconds: the drones' common clock in lockstep, else wall time times the speed factor."""
        if self._lockstep_running:
            if self._gate_time_s is not None:
                return self._gate_time_s
            return self.harness.lockstep_time_s()
        return (time.monotonic() - self._wall_t0) * self.plan.speed_factor

    def _check_members(self, now: float) -> None:
        """Notice a drone that ended (it leaves the lockstep gate: it must hold nobody back) and a stalled
        simulation; both on the wall clock, at most every EXIT_CHECK_S."""
        wall = time.monotonic()
        if wall < self._next_exit_check:
            return
        self._next_exit_check = wall + EXIT_CHECK_S
        self.harness.ended()
        if now != self._gate_progress[0]:
            self._gate_progress = (now, wall)
        elif wall - self._gate_progress[1] > LOCKSTEP_STALL_S and len(self.harness.ended()) < len(self._sysids):
            raise SwarmError(f"simulation stalled at t={now:.3f} s: no drone advanced for {LOCKSTEP_STALL_S:g} s")

    def _lockstep_frame(self) -> None:
        """One frame of the lockstep clock: let the drones run LOCKSTEP_LEAD_S on and wait until every one of them
        stands at the gate; then read everything they sent, in sysid order, at that one simulated time.

        Every message then meets a fixed simulated time on both sides: what a drone sent up to the gate's step is
        read at the gate's time (it publishes a step only after sending what is due at it), and what the supervisor
        sends between frames reaches every drone while it waits at the gate, so it is handled there too (and
        delayed from there by the link model). Nothing depends on when a datagram happened to arrive, so the same
        mission with the same seeds flies the same, on an idle machine or a loaded one. The price is that the
        drones wait while the supervisor works, instead of running on into its lead."""
        now = self.clock()
        if self.plan.speed_factor > 0:  # paced lockstep: the frame starts when the wall clock has caught up with it
            ahead_s = (now + LOCKSTEP_LEAD_S) / self.plan.speed_factor - (time.monotonic() - self._wall_t0)
            if ahead_s > 0:
                time.sleep(ahead_s)
        addresses = self.link.addresses
        self.harness.note_sent_to_drones({s: self.link.sent_to.get(a, 0) for s, a in addresses.items()})
        self._gate_time_s = None
        if self.harness.advance_lockstep(LOCKSTEP_LEAD_S) is None:
            # Not every drone has joined yet (nobody starts before the rest): nothing runs, nothing to wait for.
            self._gate_selector.select(LOCKSTEP_MAX_WAIT_S)
            return
        target = now + LOCKSTEP_LEAD_S - 1e-9
        while (now := self.clock()) < target and len(self.harness.ended()) < len(self._sysids):
            self._check_members(now)
            if self._gate_selector.select(LOCKSTEP_MAX_WAIT_S) and self._wake_fd is not None:
                _consume(self._wake_fd)  # that wake-up is read: the next one is news
        if now >= target:
            self._gate_time_s = now  # every drone stands at the gate: the time holds until the next frame

    def _read_frame(self) -> list[tuple[Any, tuple[str, int]]]:
        """Lockstep: everything the drones sent up to the common time, in sysid order (each sender's own order kept).
        Loopback UDP may hand a datagram over a little after its ``sendto`` returned, so the supervisor reads until
        it has as many from each drone as the drone says it sent; one that never comes (a full buffer) is given up
        after LOCKSTEP_AWAIT_S, and said once."""
        messages: list[tuple[Any, tuple[str, int]]] = []
        sent = self.harness.sent_by_drones()
        deadline = time.monotonic() + LOCKSTEP_AWAIT_S
        while True:
            while batch := self.link.receive():
                messages.extend(batch)
            addresses, received = self.link.addresses, self.link.received_from
            missing = [s for s, n in sent.items() if n > received.get(addresses.get(s, ("", 0)), 0)]
            missing = [s for s in missing if s not in self.losses and s in addresses]
            if not missing:
                break
            if time.monotonic() > deadline:
                if not self._said_late_traffic:
                    self._said_late_traffic = True
                    log.warning("lockstep: datagrams from sysid %s never arrived; going on", missing)
                break
            self._selector.select(LOCKSTEP_MAX_WAIT_S)
        messages.sort(key=lambda item: int(item[0].get_srcSystem()))
        return messages

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

    # ---- losses ----------------------------------------------------------------------------------------------------
    def detect_losses(self, time_s: float) -> list[DroneLoss]:
        """Record every new loss once and return them: a drone the harness reports ended (any cause), one that reports
        MAV_STATE_FLIGHT_TERMINATION (crashed, terminated), or one silent for the link-loss time.

        ``time_s`` is the time to record (the caller's mission clock). The harness says which drones ended and how
        (and their bodies then fall in the simulated world from their last state).
        """
        new: list[DroneLoss] = []
        now = self.clock()
        for sysid, cause in self.harness.ended().items():
            if sysid not in self.losses:
                new.append(self._record_loss(sysid, time_s, cause))
        for sysid in self._sysids:
            view = self.fleet.drones.get(sysid)
            if view is None or sysid in self.losses:
                continue
            if view.system_status == MAV_STATE_FLIGHT_TERMINATION:
                new.append(self._record_loss(sysid, time_s, crash_cause(view.texts, now)))
            elif view.lost(now) and (self.plan.lockstep or self._silent_on_the_wall_clock(sysid)):
                cause = f"link lost (nothing heard for {view.link_age_s(now):.1f} s)"
                new.append(self._record_loss(sysid, time_s, cause, silent=True))
        self._settle_down_positions()
        return new

    def detect_regains(self, time_s: float) -> list[DroneLoss]:
        """Take back every drone lost for silence that has been heard again (QGroundControl's "communication
        regained"), once: it leaves ``losses`` and its ended loss, with ``regained_s``, goes to ``regained``. A drone
        lost any other way stays lost. What the swarm flies takes it in again (gcs/command/degrade.py
        ``apply_regain``)."""
        back: list[DroneLoss] = []
        now = self.clock()
        for sysid, loss in list(self.losses.items()):
            view = self.fleet.drones.get(sysid)
            if loss.silent and view is not None and not view.lost(now):
                del self.losses[sysid]
                ended = dataclasses.replace(loss, regained_s=time_s)
                self.regained.append(ended)
                back.append(ended)
        return back

    def _silent_on_the_wall_clock(self, sysid: int) -> bool:
        """Paced, a drone is lost when it is silent for the link-loss time on both clocks: a loaded machine that
        delays a paced drone's heartbeat by a fraction of a wall second (3 s at --speed 4 is 0.75 s) must not lose it
        for good. In lockstep the simulated clock alone decides: the drones cannot run more than the gate's lead
        ahead of the supervisor, so a heartbeat sent is read within that lead, however fast or slow the machine;
        counting wall seconds there kept a silent drone in the swarm when the simulation ran faster than real time."""
        return time.monotonic() - self._heard_wall_s.get(sysid, -math.inf) > LINK_LOST_S

    def _record_loss(self, sysid: int, time_s: float, cause: str, *, silent: bool = False) -> DroneLoss:
        loss = DroneLoss(sysid=sysid, time_s=time_s, cause=cause, silent=silent)
        self.losses[sysid] = loss
        return loss

    def _settle_down_positions(self) -> None:
        """Fill in where each lost drone came down, once its body is on the ground (north/east of the origin)."""
        if not self._sysids:
            return
        for sysid, loss in list(self.losses.items()):
            if loss.down_ne_m is None:
                geo = self.harness.grounded_body_geo(sysid, self.clock())
                if geo is not None:
                    point = GeoPoint(lat_deg=geo[0], lon_deg=geo[1], alt_amsl_m=geo[2])
                    north, east, _ = self._swarm_frame.ned_from_geo(point)
                    self.losses[sysid] = dataclasses.replace(loss, down_ne_m=(north, east))

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
        In lockstep, one frame of the common clock instead (``_lockstep_frame``), whatever ``wait_s``."""
        self._flush(self.clock())
        if self._lockstep_running:
            self._lockstep_frame()
            now = self.clock()
            messages = self._read_frame()
        else:
            if wait_s > 0:
                if self.link.queued:
                    wait_s = min(wait_s, max(0.0, self._flush_due_s - self.clock()))
                self._selector.select(wait_s / self.plan.speed_factor)
            now = self.clock()
            messages = self.link.receive()
        for msg, _sender in messages:
            if msg.get_srcComponent() != 1:
                self._route_from_ground_station(msg)
                continue
            if self.forward is not None:
                self._hold(bytes(msg.get_msgbuf()), self.forward, now)
            self.fleet.handle(msg, now)
            kind = msg.get_type()
            if kind == "GLOBAL_POSITION_INT" and self.relay is not None:
                data = bytes(msg.get_msgbuf())
                for target in self.relay.targets(msg.get_srcSystem(), now, self.fleet):
                    address = self.link.addresses.get(target)
                    if address is not None:
                        self._hold(data, address, now)
            if kind != "RADIO_STATUS":  # any other message is a sign of life (gcs/fleet/telemetry.py LINK_LOST_S)
                self._heard_wall_s[msg.get_srcSystem()] = time.monotonic()
            if kind == "COMMAND_ACK":
                self.commands.handle(msg, now)
            elif kind == "PARAM_VALUE":
                self._send_effects(self.params.handle(msg, now), now=False)
            elif kind.startswith("MISSION_"):  # the mission protocol (transfers) and its progress reports
                self._send_effects(self.missions.handle(msg, now), now=True)
                self.mission_progress.handle(msg, now)
            for listener in self.listeners:
                listener(msg, now)
        self._send_gcs_heartbeat(now)
        self._flush(now)

    def _send_gcs_heartbeat(self, now: float) -> None:
        """The ground station's own HEARTBEAT to every drone at 1 Hz (simulated time), as QGroundControl sends it:
        PX4's datalink-loss failsafe (COM_DL_LOSS_T) counts from the last one. Lost drones get none."""
        if now < self._next_gcs_heartbeat_s:
            return
        self._next_gcs_heartbeat_s = now + GCS_HEARTBEAT_PERIOD_S
        msg = mavlink.MAVLink_heartbeat_message(
            mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, mavlink.MAV_STATE_ACTIVE, 3
        )
        for sysid in list(self.link.addresses):  # every vehicle heard, as QGroundControl does, except the lost
            if sysid not in self.losses:
                self.link.queue(sysid, msg)
        self._flush_due_s = -math.inf

    def _hold(self, data: bytes, address: tuple[str, int], now: float) -> None:
        """Queue traffic that may wait for the next batch (at most ``batch_hold_s``)."""
        if not self.link.queued:
            self._flush_due_s = now + self.batch_hold_s
        self.link.queue_raw(data, address)

    def _flush(self, now: float) -> None:
        if self.link.queued and now >= self._flush_due_s:
            self.link.flush()
            self._flush_due_s = math.inf

    def _route_from_ground_station(self, msg: Any) -> None:
        """A message from another ground station (QGroundControl, MAVProxy on the forward port): to its target."""
        if self.forward is None:
            return
        target = getattr(msg, "target_system", 0)
        data = bytes(msg.get_msgbuf())
        for sysid in self.sysids if target == 0 else [target]:
            address = self.link.addresses.get(sysid)
            if address is not None:
                self.link.send_raw(data, address)

    def run_for(self, seconds: float, tick: Callable[[float], None] | None = None, tick_s: float = TICK_S) -> None:
        """Pump telemetry for a while, calling ``tick(now)`` every ``tick_s``."""
        end = self.clock() + seconds
        next_tick = self.clock()
        while (now := self.clock()) < end:
            if tick is not None and now >= next_tick:
                tick(now)
                next_tick = _next_tick_s(next_tick, now, tick_s)
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
                next_tick = _next_tick_s(next_tick, now, TICK_S)
            if condition():
                return True
            self.pump(min(0.05, max(0.0, end - self.clock())))
        return condition()

    # ---- lifecycle -------------------------------------------------------------------------------------------------
    def up(self, ready_timeout_s: float = 30.0) -> None:
        """Spawn every drone and wait for its first HEARTBEAT; SpawnError names the first that does not come up."""
        try:
            self._sysids = self.harness.launch(self.link.port)
        except RuntimeError as exc:  # the harness's one line (gcs/fleet/harness.py)
            raise SpawnError(str(exc)) from None
        self._wall_t0 = time.monotonic()
        self._wake_fd = self.harness.wake_fileno()
        if self._wake_fd is not None:
            self._gate_selector.register(self._wake_fd, selectors.EVENT_READ)
        self._lockstep_running = self.plan.lockstep
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
        self, timeout_s: float = ARM_TIMEOUT_S, tick: Callable[[float], None] | None = None, *, every: bool = False
    ) -> None:
        """Wait until the drones (the surviving ones; ``every``: all of them) pass their pre-arm checks;
        SwarmError names those that did not within ``timeout_s``."""
        drones = self.fleet.drones

        def waiting() -> list[int]:
            return [s for s in (self.sysids if every else self.active_sysids) if not drones[s].prearm_ok]

        if not self.wait_until(lambda: not waiting(), timeout_s, tick=tick):
            raise SwarmError(f"sysid {waiting()} did not pass pre-arm checks within {timeout_s:g} s")

    def arm_all(self, timeout_s: float = ARM_TIMEOUT_S, tick: Callable[[float], None] | None = None) -> None:
        """Wait until every drone passes its pre-arm checks, then arm them all; SwarmError names the laggards."""
        self.wait_prearm(timeout_s, tick)
        check(self.command_all(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1, sysids=self.active_sysids), "arm")

    def land_all(self, *, return_to_launch: bool = False) -> list[int]:
        """Land (or return to launch) every armed drone; returns those sysids (crashed or landed ones are left)."""
        flying = self.armed_sysids()
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
        """Every armed surviving drone into PX4 Hold (AUTO.LOITER), where it is; returns those sysids."""
        flying = self.armed_sysids()
        check(self.command_all(mavlink.MAV_CMD_DO_SET_MODE, *HOLD_MODE, sysids=flying), "hold")
        return flying

    def takeoff_all(self, alt_m: float) -> None:
        """NAV_TAKEOFF for every drone to ``alt_m`` above its own home (PX4 takes an AMSL altitude), all at once."""
        params: dict[int, tuple[float, ...]] = {}
        nan = math.nan
        for sysid in self.active_sysids:
            home = self.fleet.drones[sysid].home
            if home is None:
                raise SwarmError(f"sysid {sysid} has no home position yet")
            params[sysid] = (0, 0, 0, nan, nan, nan, home[2] + alt_m)
        check(self.command_each(mavlink.MAV_CMD_NAV_TAKEOFF, params), "takeoff")

    def shutdown(self, land_timeout_s: float = 30.0) -> None:
        """Land what flies, disarm, then have the harness stop every drone and leave nothing behind (also after
        errors)."""
        try:
            flying = [s for s in self.armed_sysids() if not self.fleet.drones[s].lost(self.clock())]
            if flying:
                self._land_clear_of_wrecks(flying)
                self.wait_until(lambda: not self.armed_sysids(flying), land_timeout_s)
                still = self.armed_sysids(flying)
                if still:  # a drone that cannot land in time is disarmed where it is
                    self.force_disarm(still)
        finally:
            if self._wake_fd is not None:
                self._gate_selector.unregister(self._wake_fd)
                self._wake_fd = None
            try:
                self.harness.close()
            finally:
                self._selector.close()
                self._gate_selector.close()
                self.link.close()

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
            waiting = [a.sysid for a in acks.values() if a.result is None and a.sysid in self.active_sysids
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
                if self.stream_tick is not None and (clock := self.clock()) >= next_tick:
                    self.stream_tick(clock)
                    next_tick = _next_tick_s(next_tick, clock, TICK_S)
                self.pump(min(0.02, max(0.0, client.next_due_s() - self.clock())))
        finally:
            for sysid in targets:
                client.cancel(sysid, key)
        return [results[s] for s in targets]

    def _send_effects(self, effects: list[Send], *, now: bool) -> None:
        for effect in effects:
            self._send_logged(effect.sysid, effect.message, now=now)

    def _send_logged(self, sysid: int, msg: Any, *, now: bool) -> None:
        """A command or parameter write, at once or with the next batch, also handed to ``sent_listeners``."""
        data = self.link.pack(msg)
        address = self.link.addresses.get(sysid)
        if address is None:
            return
        if now:
            if self.link.queued:
                self.link.flush()
            self.link.send_raw(data, address)
        else:
            self.link.queue_raw(data, address)
            self._flush_due_s = -math.inf
        for listener in self.sent_listeners:
            listener(data, self.clock())

    def send(self, sysid: int, msg: Any) -> None:
        """Streamed traffic (setpoints, parameter writes): leaves at the start of the next pump, batched with
        whatever else is queued for each drone. Commands that wait for an answer go out at once (``command_all``)."""
        if self.link.queue(sysid, msg):
            self._flush_due_s = -math.inf

    def send_now(self, sysid: int, msg: Any) -> None:
        """One message to one drone at once, outside any batch (a command whose answer is being timed)."""
        self.link.send(sysid, msg)


# Rounds of a command's retries (each MAVSDK's: the first try and 3 resends) for a drone that answers none: on a link
# losing 20 % each way one round goes unanswered 1.7 % of the time, three rounds once in 200,000.
NO_ANSWER_ROUNDS = 3
CRASH_TEXT_AGE_S = 5.0  # a warning this recent says why a drone crashed; an older one is about something else


def _consume(fd: int) -> None:
    """Read every datagram waiting on a non-blocking descriptor."""
    with contextlib.suppress(BlockingIOError, InterruptedError):
        while True:
            os.read(fd, 64)


def crash_cause(texts: list[tuple[float, int, str]], now_s: float) -> str:
    """``crashed``, with the first of the drone's recent warnings: the cause (``crashed: Collision with drone 2 at
    0.61 m``, an injected motor failure), not its consequences (``Motors stopped: crashed``) that follow it."""
    warnings = [
        text
        for t, severity, text in texts
        if severity <= mavlink.MAV_SEVERITY_WARNING and now_s - t <= CRASH_TEXT_AGE_S
    ]
    return f"crashed: {warnings[0]}" if warnings else "crashed"


def check(acks: list[Ack], what: str) -> None:
    """Raise one clear line naming every drone that refused or did not answer."""
    bad = [a for a in acks if not a.ok]
    if bad:
        names = ", ".join(f"sysid {a.sysid} ({'no answer' if a.result is None else f'result {a.result}'})" for a in bad)
        raise SwarmError(f"{what} failed for {names}")


def _next_tick_s(due_s: float, now_s: float, period_s: float) -> float:
    """When the next tick is due after one due at ``due_s`` ran at ``now_s``: a period after the one due, so that
    ticks keep their rate on average when the clock moves in steps that do not divide the period (lockstep frames
    of 0.02 s would otherwise tick every 0.06 s); a tick more than a period late starts the cadence afresh."""
    return due_s + period_s if now_s - due_s < period_s else now_s + period_s


class SwarmError(RuntimeError):
    """A swarm-level operation failed; the message is one line for the user."""
