"""The invariants of a flight, checked at every tick of the session (gcs/invariants, docs/invariants.md).

The IO shell around the pure monitor: at each tick it builds the instant (``TickState``) from what the supervisor
knows (the streamer's positions and slots, the fleet view, the swarm's losses and waiting commands, the flight
recording's contacts, failsafes and faults), hands it to the monitor, and for each first violation says one line
and records it for the report.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

from gcs.invariants.monitor import Monitor, Violation
from gcs.invariants.spec import Invariant
from gcs.invariants.state import FAULT, LOSS, START, STEP, TickState
from gcs.mavlink.statustext import COLLISION_PREFIX

if TYPE_CHECKING:
    from gcs.supervisor.session import FlightSession


class InvariantWatch:
    def __init__(self, session: FlightSession, *, stop: bool) -> None:
        """``stop``: the first violation ends the flight (``--stop-on-violation``)."""
        self.session = session
        self.monitor = Monitor((), session.swarm.sysids)
        self.stop = stop
        self._started = False
        self._events_seen = len(session.recording.events)
        self._failsafes_seen = len(session.recording.failsafes)
        self._faults_seen = len(session.recording.faults)
        self._losses_seen = len(session.swarm.losses)
        self._steps_seen = session.steps_begun

    def add(self, invariants: Sequence[Invariant], *, stop: bool) -> None:
        """More invariants, checked from the next tick (ValueError, one line, for a name already required)."""
        self.monitor.add(invariants)
        self.stop = self.stop or stop
        self.session.recording.invariants.extend(i.describe() for i in invariants)

    def check(self, now_s: float) -> list[Violation]:
        """One tick: the first violations new at it, said and recorded."""
        violations = self.monitor.check(self._state(now_s))
        for violation in violations:
            self.session.say(f"swarm: {violation.line()}")
            self.session.recording.violations.append(violation)
        return violations

    def _state(self, now_s: float) -> TickState:
        session, swarm = self.session, self.session.swarm
        recording = session.recording
        positions = session.streamer.positions()
        drones = swarm.fleet.drones
        airborne = frozenset(s for s in positions if s in drones and drones[s].armed and drones[s].in_air())
        clock = swarm.clock()
        attached = {}
        for sysid, vehicle in swarm.attached.items():
            body = vehicle.body_at(clock)
            if body is not None and sysid not in positions:
                attached[sysid] = session.streamer.swarm_frame.ned_from_geo(body)
        slots = {s: p for s, p in session.streamer.targets(now_s).items() if s in positions}
        new_events = recording.events[self._events_seen :]
        contacts = tuple((e.sysid, e.text) for e in new_events if e.sysid is not None
                         and e.text.startswith(COLLISION_PREFIX))  # fmt: skip
        failsafes = tuple((e.sysid, e.text) for e in recording.failsafes[self._failsafes_seen :] if e.sysid is not None)
        events = set()
        if not self._started:
            events.add(START)
        if len(swarm.losses) > self._losses_seen:
            events.add(LOSS)
        if len(recording.faults) > self._faults_seen:
            events.add(FAULT)
        if session.steps_begun > self._steps_seen:
            events.add(STEP)
        self._started = True
        self._events_seen, self._failsafes_seen = len(recording.events), len(recording.failsafes)
        self._faults_seen, self._losses_seen, self._steps_seen = (len(recording.faults), len(swarm.losses),
                                                                  session.steps_begun)  # fmt: skip
        return TickState(
            time_s=now_s,
            positions_ned_m=positions,
            airborne=airborne,
            attached_ned_m=attached,
            slots_ned_m=slots,
            contacts=contacts,
            failsafes=failsafes,
            faulted=frozenset(f.sysid for f in recording.faults),
            unanswered_s={s: clock - t for s, t in swarm.commands.waiting_since().items()},
            events=frozenset(events),
            lost=frozenset(swarm.losses),
        )
