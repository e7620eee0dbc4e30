"""The swarm's pump: every message taken where it belongs, and the one loop that keeps the swarm flying while
something waits.

``once`` is one pump: what is due leaves, and every message that has arrived goes, in order, to the fleet view, the
router (the forward address, the relay), the attached vehicles (a simulated drone's position, as traffic), liveness
(a sign of life), the protocol clients (command answers, parameter echoes, mission transfers and progress) and the
listeners; then the attached vehicles' links are read and their bodies moved, the ground station's HEARTBEAT goes
out, and the batch leaves when due. In lockstep one pump is one frame of the common clock, whatever the wait, and
frames are pipelined: once every drone stands at gate k the supervisor sends what it has queued, opens gate k + 1,
and only then reads and handles what the drones sent up to gate k (and ticks: setpoints, verbs, checks) while they
fly on to k + 1. Everything it sends is held until the next gate, so every message meets a fixed simulated time on
both sides: what a drone sent up to gate k is handled at gate k's time, and the supervisor's answer reaches every
drone while it stands at gate k + 1, one frame (LOCKSTEP_LEAD_S) later, read before its next step. Nothing depends
on when a datagram happened to arrive, and the same mission with the same seeds flies the same on an idle machine or
a loaded one. The drones no longer wait while the supervisor works: each frame costs the longer of the two, not
their sum.

Waiting is pumping: ``pump_while`` is the one loop every wait runs (``run_for``, ``wait_until``, a command, parameter
or mission transfer being served, an attach listening to its link). It pumps, and calls a tick at its period in
between: the caller's, or the setpoint stream given once by whoever assembles the flight (``keep_streaming``), which
must go on while a command waits for its answer (PX4 leaves OFFBOARD after COM_OF_LOSS_T without a setpoint, and on
a lossy link an answer can take retries).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from gcs.fleet.attachments import Attachments
from gcs.fleet.clock import TICK_S, ClockStalled, SwarmClock, next_tick_s
from gcs.fleet.errors import SwarmError
from gcs.fleet.harness import SimulationHarness
from gcs.fleet.liveness import Liveness
from gcs.fleet.router import Router
from gcs.fleet.telemetry import Fleet
from gcs.mavlink.commands import CommandClient, Send
from gcs.mavlink.mission_transfer import MissionClient, MissionProgress
from gcs.mavlink.params import ParamClient

Tick = Callable[[float], None]
SERVE_PUMP_S = 0.02  # simulated seconds a pump waits at most while a protocol client's work is served
WAIT_UNTIL_PUMP_S = 0.05  # simulated seconds a pump waits at most between two looks at a condition waited for


@dataclass(frozen=True, slots=True)
class Protocols:
    """The MAVLink protocol clients (gcs/mavlink/: state without IO): the pump feeds them what arrives and sends
    what they answer; the part that drives each (gcs/fleet/commanding.py ``Commands``, gcs/fleet/transfers.py
    ``Params`` and ``Missions``) starts their work and takes its outcomes."""

    commands: CommandClient
    params: ParamClient
    missions: MissionClient
    progress: MissionProgress  # each drone's MISSION_CURRENT / MISSION_ITEM_REACHED


class Pump:
    def __init__(self, clock: SwarmClock, harness: SimulationHarness, router: Router, fleet: Fleet,
                 liveness: Liveness, attachments: Attachments, protocols: Protocols, *,
                 speed_factor: float) -> None:  # fmt: skip
        self.clock = clock
        self.harness = harness  # what the drones say they sent (lockstep)
        self.router = router
        self.fleet = fleet
        self.liveness = liveness
        self.attachments = attachments
        self.protocols = protocols
        self.speed_factor = speed_factor
        self._stream_tick: Tick | None = None

    def keep_streaming(self, tick: Tick) -> None:
        """While a command waits for its answer, call ``tick(now)`` at the stream's rate: the setpoint stream of the
        flight this swarm flies, given once by whoever assembles it (gcs/supervisor/session.py, the bench)."""
        self._stream_tick = tick

    def once(self, wait_s: float = 0.0, *, gather: bool = True) -> None:
        """Send what is due, then handle every waiting message, waiting up to ``wait_s`` (simulated) for the first;
        paced and with ``gather``, reading at most every GATHER_S of wall time (gcs/fleet/router.py): work that
        waits for an answer pumps without. In lockstep, one frame of the common clock instead, whatever ``wait_s``
        (the module docstring says why)."""
        router, clock, liveness, protocols = self.router, self.clock, self.liveness, self.protocols
        lockstep = clock.lockstep_running
        if lockstep:
            handled_s = clock.now()  # the frame handled last: what it queued leaves at this gate
            try:
                clock.reach_gate()
            except ClockStalled as exc:
                raise SwarmError(str(exc)) from None
            router.flush(handled_s)
            sent_by_drones = self.harness.sent_by_drones()  # up to this gate: read before any drone flies on
            clock.open_gate(router.sent_to_drones())
            now = clock.now()
            messages = router.receive_frame(sent_by_drones, liveness.losses)
        else:
            router.flush(clock.now())
            router.wait(wait_s, self.speed_factor, clock.now(), gather=gather)
            now = clock.now()
            messages = router.receive()
        attachments = self.attachments
        for msg, _sender in messages:
            if msg.get_srcComponent() != 1:
                router.from_ground_station(msg, liveness.sysids)
                continue
            self.fleet.handle(msg, now)
            router.carry(msg, now, self.fleet)
            kind = msg.get_type()
            if kind == "GLOBAL_POSITION_INT" and attachments.vehicles:
                attachments.share(msg, now)  # the simulated drones, as traffic, to the attached vehicles
            if kind != "RADIO_STATUS":  # any other message is a sign of life (gcs/fleet/telemetry.py LINK_LOST_S)
                liveness.heard(msg.get_srcSystem())
            if kind == "COMMAND_ACK":
                protocols.commands.handle(msg, now)
            elif kind == "PARAM_VALUE":
                self.send(protocols.params.handle(msg, now), now=False)
            elif kind.startswith("MISSION_"):  # the mission protocol (transfers) and its progress reports
                self.send(protocols.missions.handle(msg, now), now=True)
                protocols.progress.handle(msg, now)
            router.delivered(msg, now)
        if attachments.vehicles:
            attachments.pump(now)
        router.heartbeat(now, liveness.losses)
        if not lockstep:  # in lockstep everything leaves at the next gate
            router.flush(now)

    # ---- waiting: the one loop --------------------------------------------------------------------------------------
    def pump_while(self, going: Callable[[], bool], wait_s: Callable[[float], float], *, tick: Tick | None,
                   tick_s: float = TICK_S, until: Callable[[], bool] | None = None,
                   gather: bool = True) -> bool:  # fmt: skip
        """Pump while ``going()``: each round calls ``tick(now)`` when its period ``tick_s`` is due, ends (True) if
        ``until()`` holds after it, and pumps waiting up to ``wait_s(next tick's time)`` (``gather``: as ``once``).
        False when ``going`` ended it."""
        clock = self.clock
        next_tick = clock.now()
        while going():
            now = clock.now()
            if tick is not None and now >= next_tick:
                tick(now)
                next_tick = next_tick_s(next_tick, now, tick_s)
            if until is not None and until():
                return True
            self.once(wait_s(next_tick), gather=gather)
        return False

    def run_for(self, seconds: float, tick: Tick | None = None, tick_s: float = TICK_S) -> None:
        """Pump telemetry for a while, calling ``tick(now)`` every ``tick_s``."""
        clock = self.clock
        end = clock.now() + seconds
        self.pump_while(lambda: clock.now() < end, lambda due: max(0.0, min(due, end) - clock.now()), tick=tick,
                        tick_s=tick_s)  # fmt: skip

    def wait_until(self, condition: Callable[[], bool], timeout_s: float, tick: Tick | None = None) -> bool:
        """Pump until ``condition()`` (looked at after each tick), at most ``timeout_s``; whether it holds."""
        clock = self.clock
        end = clock.now() + timeout_s
        if self.pump_while(lambda: clock.now() < end, lambda _due: min(WAIT_UNTIL_PUMP_S, max(0.0, end - clock.now())),
                           tick=tick, until=condition):  # fmt: skip
            return True
        return condition()

    def keep_flying(self, going: Callable[[], bool], wait_s: float) -> None:
        """Pump, the setpoint stream kept going (``keep_streaming``), while ``going()``; each pump waits up to
        ``wait_s`` (an attach listening to its link: gcs/fleet/attachments.py)."""
        self.pump_while(going, lambda _due: wait_s, tick=self._stream_tick)

    # ---- the protocol clients' work --------------------------------------------------------------------------------
    def serve(
        self, client: CommandClient | ParamClient | MissionClient, key: Any, targets: list[int], *, now: bool
    ) -> list[Any]:
        """Pump until the work ``key`` (a command, a parameter name, a mission type) has ended on every target, the
        setpoint stream kept going, sending what the client's ``poll`` asks for when its timers come due (``now``:
        at once, else with the next batch); the outcomes in the order of ``targets``. Interrupted or failed, nothing
        is left in flight to block the next use of the same command or parameter (the shutdown's)."""
        clock = self.clock
        results: dict[int, Any] = {}

        def collect() -> bool:
            for sysid in targets:
                if sysid not in results and (outcome := client.take(sysid, key)) is not None:
                    results[sysid] = outcome
            return len(results) == len(targets)

        def unfinished() -> bool:
            if collect():
                return False
            self.send(client.poll(clock.now()), now=now)
            return not collect()

        try:
            self.pump_while(unfinished, lambda _due: min(SERVE_PUMP_S, max(0.0, client.next_due_s() - clock.now())),
                            tick=self._stream_tick, gather=False)  # fmt: skip
        finally:
            for sysid in targets:
                client.cancel(sysid, key)
        return [results[s] for s in targets]

    def send(self, effects: list[Send], *, now: bool) -> None:
        """What a protocol client asks to send: to an attached vehicle on its own link, at once; to a drone at once
        (``now``) or with the next batch; each handed to the router's ``sent_listeners`` (the flight log)."""
        for effect in effects:
            if effect.sysid in self.attachments.vehicles:
                data = self.attachments.send(effect.sysid, effect.message)
                for listener in self.router.sent_listeners:
                    listener(data, self.clock.now())
            else:
                self.router.send_logged(effect.sysid, effect.message, now=now, clock_s=self.clock.now())
