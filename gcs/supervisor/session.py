"""One swarm being flown, with the parts every front-end needs assembled once: the swarm link, the setpoint
streamer, the pace watch, the recording and its recorder, the live view's feed, and the loss policy.

``swarm up``'s station (gcs/supervisor/station.py), ``swarm fly``'s mission runner (gcs/supervisor/mission_runner.py)
and the Python API's engine (gcs/api/engine.py) each hold one ``FlightSession`` and carry out the swarm's verbs
(gcs/supervisor/verbs.py) on it. What differs between them is only how they are driven: the station answers its
control channel and never waits, the runner walks a mission's steps, the engine serves a user's calls.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path

from gcs.command.degrade import apply_loss_policy, apply_regain
from gcs.command.procedures import PaceWatch
from gcs.command.streamer import DEFAULT_LIMITS, FormationStreamer
from gcs.fleet.links import NeighbourPlan
from gcs.fleet.losses import LossPolicy, loss_line, regain_line
from gcs.fleet.relay import DEFAULT_RELAY_SCOPE
from gcs.fleet.swarm import Swarm, SwarmError
from gcs.flight.behaviours import Behaviour
from gcs.flight.formation import TransitionLimits
from gcs.invariants.spec import Invariant
from gcs.record.recorder import FlightRecorder
from gcs.record.recording import EventRecord, FaultRecord, FlightRecording, ObstacleShape, StepRecord
from gcs.supervisor.invariant_watch import InvariantWatch
from gcs.view.feed import ViewFeed
from gcs.view.report import write_report
from gcs.view.server import ViewServer

Say = Callable[[str], None]
Tick = Callable[[float], None]


class FlightSession:
    """The parts of one flight and the state the verbs share: who flies the drones now (the ground station's
    stream, their onboard behaviours, a user's controller) and whether a loss policy has taken the flight over."""

    def __init__(self, swarm: Swarm, say: Say, recording: FlightRecording, loss_policy: LossPolicy, *,
                 note: Say | None = None, t0_s: float | None = None,
                 limits: TransitionLimits = DEFAULT_LIMITS) -> None:  # fmt: skip
        """``say``: the supervisor's output; ``note``: a line about what a verb did, as the front-end shows it (a
        mission prefixes its time); ``t0_s``: the swarm clock's reading at mission time zero (now, when not given);
        ``limits``: the formations' transition limits (``swarm bench`` raises them for its rotating circle)."""
        self.swarm = swarm
        self.say = say
        self.note = note or say
        self.recording = recording
        self.loss_policy = loss_policy
        self.streamer = FormationStreamer(swarm, limits)
        swarm.pump.keep_streaming(self.streamer.tick)  # setpoints go on while a command waits for its answer
        self.pace = PaceWatch(swarm, say)
        recording.requested_speed = self.pace.requested_speed
        recording.loss_policy = loss_policy.value
        recording.signing_key_id = swarm.signing_key_id
        relay = swarm.router.relay
        scope = relay.scope if relay else DEFAULT_RELAY_SCOPE
        plan = NeighbourPlan(relay=relay is not None, mesh=swarm.plan.mesh, relay_scope=scope)
        recording.neighbours = plan.describe()
        self.recorder: FlightRecorder | None = None
        self.view: ViewFeed | None = None
        self.policy_taken = False  # a loss policy other than continue has taken the survivors out of the flight
        self.onboard = False  # the drones' onboard behaviours fly them (BHV_EN = 1)
        self.controller: Behaviour | None = None  # a user's controller the streamer runs (the Python API)
        self.waiting_tick: Tick | None = None  # the front-end's tick, run while a verb waits on the drones (arming)
        self._t0_s = swarm.clock.now() if t0_s is None else t0_s
        self._step: StepRecord | None = None  # the report's step under way (begin_step)
        self.report_dir: Path | None = None  # where a session flown verb by verb writes its report
        self.records_verbs = False  # flown verb by verb: a verb that changes what the swarm flies begins a step
        self.watch: InvariantWatch | None = None  # the flight's invariants (``require``)

    @classmethod
    def verb_by_verb(cls, swarm: Swarm, say: Say, loss_policy: LossPolicy, *, report_dir: Path | None,
                     contact_distance_m: float, note: Say | None = None) -> FlightSession:  # fmt: skip
        """A session flown one verb at a time as a user asks (``swarm up``, the Python API): its report, when there is
        a ``report_dir``, records each verb that changes what the swarm flies as a step (``begin_step``)."""
        recording = FlightRecording(mission_name="swarm-up", n_drones=swarm.plan.n_drones,
                                    collision_radius_m=contact_distance_m)  # fmt: skip
        session = cls(swarm, say, recording, loss_policy, note=note)
        session.report_dir = report_dir
        session.records_verbs = True
        if report_dir is not None:
            report_dir.mkdir(parents=True, exist_ok=True)
            session.record(report_dir / "flight.tlog", say=None)
        return session

    # ---- time ------------------------------------------------------------------------------------------------------
    def mission_time(self) -> float:
        """Simulated seconds since mission time zero (formations run on the drones' clock)."""
        return self.swarm.clock.now() - self._t0_s

    def restart_clock(self) -> None:
        """Mission time zero is now (``swarm fly``: once the drones are up, armed and set)."""
        self._t0_s = self.swarm.clock.now()

    # ---- parts -----------------------------------------------------------------------------------------------------
    def record(self, tlog: Path, say: Say | None) -> FlightRecorder:
        """Record the flight from now on: samples, events and both directions of the traffic into ``tlog``."""
        self.recorder = FlightRecorder(self.swarm, self.streamer.targets, self.recording, self.mission_time, tlog,
                                       say=say)  # fmt: skip
        return self.recorder

    def serve(self, server: ViewServer, obstacles: Iterable[ObstacleShape] = ()) -> None:
        """Feed the live view served by ``server`` from now on (gcs/view): the streamer's slots, the drones'
        telemetry, the obstacles, and the recording's running metrics when there is a recorder."""
        live = self.recorder.live if self.recorder is not None else None
        self.view = ViewFeed(server, self.swarm, self.streamer.targets, obstacles, live=live)

    def tick(self, now_s: float) -> None:
        """The setpoints of whatever the ground station flies, the live view's frame, and the invariants' check;
        InvariantViolated when one is first violated and the flight stops on a violation."""
        self.streamer.tick(now_s)
        if self.view is not None:
            self.view.tick(now_s)
        if self.watch is not None:
            violations = self.watch.check(now_s)
            if violations and self.watch.stop:
                raise InvariantViolated(f"stopped on a violation: {violations[0].line()}")

    def require(self, invariants: Sequence[Invariant], *, stop: bool = False) -> None:
        """Check these invariants at every tick from now on (with those already required); ``stop``: the first
        violation ends the flight. Needs the drones up (their numbers name them)."""
        if not invariants:
            return
        if self.watch is None:
            self.watch = InvariantWatch(self.swarm, self.streamer.targets, self.recording, self.say, stop=stop)
        self.watch.add(invariants, stop=stop)

    def step_began(self) -> None:
        """A mission step, or a verb that changes what the swarm flies, begins (an invariant's ``step`` event)."""
        if self.watch is not None:
            self.watch.step_began()

    def watch_losses(self, now_s: float, indent: str = "") -> None:
        """Each new loss: one line, and the loss policy applied (with its line and record); each drone heard again:
        one line, and it is taken back as the policy says."""
        for loss in self.swarm.liveness.detect_losses(now_s):
            self.say(loss_line(loss))
            line = apply_loss_policy(self.loss_policy, self.streamer, loss, now_s)
            self.policy_taken = self.policy_taken or self.loss_policy is not LossPolicy.CONTINUE
            self._policy_line(line, now_s, loss.sysid, indent)
        for loss in self.swarm.liveness.detect_regains(now_s):
            self.say(regain_line(loss))
            line = apply_regain(self.loss_policy, self.streamer, loss, now_s, policy_taken=self.policy_taken)
            self._policy_line(line, now_s, loss.sysid, indent)
        for line in self.swarm.attachments.detect_changes(now_s):
            self.say(f"swarm: {line}")
        for sysid in self.swarm.attachments.take_released():  # a member no longer commanded: flown on without it
            self._policy_line(self.streamer.handle_loss(sysid, now_s), now_s, sysid, indent)

    def _policy_line(self, line: str | None, now_s: float, sysid: int, indent: str) -> None:
        if line is not None:
            self.say(f"{indent}swarm: {line}")
            self.recording.policy_events.append(EventRecord(time_s=now_s, sysid=sysid, text=line))

    def record_fault(self, sysid: int, what: str, result: str, ordered_s: float | None = None) -> None:
        """A fault for the report, at the mission time it was ordered (``ordered_s``; now when not given), whenever
        the drone's answer came."""
        time_s = self.mission_time() if ordered_s is None else ordered_s
        self.recording.faults.append(FaultRecord(time_s=time_s, sysid=sysid, fault=what, result=result))

    # ---- the report's steps (``swarm up`` and the API: a verb that changes what the swarm flies starts one) ------
    def begin_step(self, kind: str, name: str | None = None, alt_m: float | None = None,
                   arrival_s: float | None = None) -> None:  # fmt: skip
        """The report's current step ends now and the next begins (``name``: the kind, when not given; ``alt_m`` a
        takeoff's target, ``arrival_s`` a formation's planned arrival)."""
        now = self.mission_time()
        self.end_step(now)
        self.step_began()
        index = len(self.recording.steps)
        self._step = StepRecord(index=index, name=name or kind, kind=kind, start_s=now, end_s=now, target_alt_m=alt_m,
                                arrival_s=arrival_s)  # fmt: skip

    def end_step(self, now_s: float) -> None:
        if self._step is not None:
            self.recording.steps.append(dataclasses.replace(self._step, end_s=now_s))
            self._step = None

    def write_report(self) -> Path | None:
        """After the swarm of a session flown verb by verb is shut down: what the swarm knows taken in, the tlog
        closed, and the flight report written (gcs/view/report.py); None without a ``report_dir``."""
        if self.report_dir is None or self.recorder is None:
            return None
        self.end_step(self.recording.steps[-1].end_s if self.recording.steps else 0.0)
        self.take_stock()
        self.recorder.close()
        return write_report(self.recording, self.report_dir)

    def discard(self) -> None:
        """A session that never flew (an attach failed before the drones started): its flight log is closed, no
        report is written."""
        if self.recorder is not None:
            self.recorder.close()

    def take_stock(self) -> None:
        """What the swarm knows of its drones into the recording, as the flight ends: losses, returns, and the link
        model's counts (``swarm fly`` takes them before the shutdown: what reaches a stopped drone depends on the
        machine's timing and is not the flight's)."""
        self.recording.losses = list(self.swarm.liveness.losses.values())
        self.recording.regained = list(self.swarm.liveness.regained)
        self.recording.link_counters = self.swarm.harness.link_counters()


class InvariantViolated(SwarmError):
    """A flight that stops on a violation (``--stop-on-violation``) stops here; the message is one line."""
