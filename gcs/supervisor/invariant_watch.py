"""The invariants of a flight, checked at every tick of the session (gcs/invariants, docs/invariants.md).

The IO shell around the pure monitor: at each tick it builds the instant (``TickState``) from what the supervisor
knows (the picture's positions, the streamer's slots, the fleet view, the swarm's losses and waiting commands, the
flight recording's contacts, failsafes and faults), hands it to the monitor, and for each first violation says one
line and records it for the report.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

from gcs.fleet.swarm import Swarm
from gcs.flight.frames import Targets
from gcs.invariants.monitor import Monitor, Violation
from gcs.invariants.spec import Invariant
from gcs.invariants.state import FAULT, LOSS, START, STEP, TickState
from gcs.mavlink.statustext import COLLISION_PREFIX
from gcs.record.recording import FlightRecording


class InvariantWatch:
    def __init__(self, swarm: Swarm, targets: Targets, recording: FlightRecording,
                 say: Callable[[str], None], *, stop: bool) -> None:  # fmt: skip
        """The flight's parts it reads (never the session that holds it): the swarm (the picture's positions),
        ``targets`` (each drone's slot: the setpoint streamer's, never the streamer), the recording (contacts,
        failsafes, faults; where violations go) and ``say`` (the supervisor's output). ``stop``: the first violation
        ends the flight (``--stop-on-violation``)."""
        self.swarm = swarm
        self.targets = targets
        self.recording = recording
        self.say = say
        self.monitor = Monitor((), swarm.liveness.sysids)
        self.stop = stop
        self._started = False
        self._events_seen = len(recording.events)
        self._failsafes_seen = len(recording.failsafes)
        self._faults_seen = len(recording.faults)
        self._losses_seen = len(swarm.liveness.losses)
        self._step_began = False  # a step began since the last tick (``step_began``)

    def add(self, invariants: Sequence[Invariant], *, stop: bool) -> None:
        """More invariants, checked from the next tick (ValueError, one line, for a name already required)."""
        self.monitor.add(invariants)
        self.stop = self.stop or stop
        self.recording.invariants.extend(i.describe() for i in invariants)

    def step_began(self) -> None:
        """A mission step, or a verb that changes what the swarm flies, has begun: the next tick's ``step`` event."""
        self._step_began = True

    def check(self, now_s: float) -> list[Violation]:
        """One tick: the first violations new at it, said and recorded."""
        violations = self.monitor.check(self._state(now_s))
        for violation in violations:
            self.say(f"swarm: {violation.line()}")
            self.recording.violations.append(violation)
        return violations

    def _state(self, now_s: float) -> TickState:
        swarm, recording = self.swarm, self.recording
        positions = swarm.picture.positions(swarm.flown_sysids)
        drones = swarm.fleet.drones
        airborne = frozenset(s for s in positions if s in drones and drones[s].armed and drones[s].in_air())
        clock = swarm.clock.now()
        attached = {}
        for sysid, vehicle in swarm.attachments.vehicles.items():
            body = vehicle.body_at(clock)
            if body is not None and sysid not in positions:
                attached[sysid] = swarm.picture.ned_from_geo(body)
        slots = {s: p for s, p in self.targets(now_s).items() if s in positions}
        new_events = recording.events[self._events_seen :]
        contacts = tuple((e.sysid, e.text) for e in new_events if e.sysid is not None
                         and e.text.startswith(COLLISION_PREFIX))  # fmt: skip
        failsafes = tuple((e.sysid, e.text) for e in recording.failsafes[self._failsafes_seen :] if e.sysid is not None)
        events = set()
        if not self._started:
            events.add(START)
        losses = swarm.liveness.losses
        if len(losses) > self._losses_seen:
            events.add(LOSS)
        if len(recording.faults) > self._faults_seen:
            events.add(FAULT)
        if self._step_began:
            events.add(STEP)
        self._started = True
        self._events_seen, self._failsafes_seen = len(recording.events), len(recording.failsafes)
        self._faults_seen, self._losses_seen, self._step_began = len(recording.faults), len(losses), False
        return TickState(
            time_s=now_s,
            positions_ned_m=positions,
            airborne=airborne,
            attached_ned_m=attached,
            slots_ned_m=slots,
            contacts=contacts,
            failsafes=failsafes,
            faulted=frozenset(f.sysid for f in recording.faults),
            unanswered_s={s: clock - t for s, t in swarm.commands.client.waiting_since().items()},
            events=frozenset(events),
            lost=frozenset(losses),
        )
