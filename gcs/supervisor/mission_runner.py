"""``swarm fly``: run a mission file end to end: spawn, take off, formations, land, shut down, report.

The runner talks to the drones only over MAVLink, as it would to real PX4 drones: NAV_TAKEOFF and NAV_LAND
commands, and OFFBOARD with SET_POSITION_TARGET_LOCAL_NED streamed at 20 Hz for formations and behaviours
(leader-follower, flocking: gcs/flight/behaviours.py). Formation targets live in the swarm frame (gcs/flight/frames.py)
and are converted into each drone's own local frame, anchored where that drone booted (reported in its HOME_POSITION).
Mission time runs at the simulation's speed factor, so a step's ``hold_s`` is simulated seconds.

Everything received is written to ``flight.tlog`` and recorded for the flight report (gcs/view/report.py).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from pathlib import Path
from typing import Literal

from gcs.command.degrade import apply_loss_policy, apply_regain
from gcs.command.onboard_flight import FollowObserver, leader_arrived, start_onboard_flock, start_onboard_follow
from gcs.command.procedures import PaceWatch, start_onboard_behaviours, stop_onboard_behaviours, take_off_and_hold
from gcs.command.streamer import FormationStreamer
from gcs.fleet.faults import CRASH, result_text
from gcs.fleet.harness import Simulation, SpawnPlan
from gcs.fleet.links import LinkPlan, NeighbourPlan
from gcs.fleet.losses import LossPolicy, loss_line, regain_line
from gcs.fleet.swarm import Swarm, SwarmError
from gcs.flight.behaviours import FollowSpec, LeaderFollower
from gcs.flight.formation import SETPOINT_STREAM_HZ
from gcs.flight.frames import SwarmFrame
from gcs.flight.geodesy import GeoPoint
from gcs.missions.mission_file import (
    BehaviourStep,
    FaultStep,
    FlockStep,
    FollowStep,
    FormationStep,
    HoldStep,
    LandStep,
    MissionSpec,
    PlanStep,
    RtlStep,
    Step,
    SwapStep,
    TakeoffStep,
)
from gcs.missions.plan_flight import (
    copy_offsets,
    parse_drones,
    spawn_offsets,
    start_missions,
    unfinished,
    unreached,
    upload_plan,
)
from gcs.record.recorder import FlightRecorder
from gcs.record.recording import EventRecord, FaultRecord, FlightRecording, StepRecord
from gcs.view.feed import ViewFeed
from gcs.view.report import write_report
from gcs.view.scene import obstacle_shape
from gcs.view.server import ViewServer

Say = Callable[[str], None]
STATUS_EVERY_S = 2.0
FOLLOW_ARRIVAL_MARGIN_S = 30.0  # the leader must report itself at its last waypoint this long after its reference
FOLLOW_TIMEOUT_S = 3600.0  # the follow step's outer bound; it ends with the leader's arrival or its margin
HOLD_POLICY_S = 10.0  # a mission under loss policy hold hovers this long before it lands the survivors
POLICY_LANDING_S = 120.0  # survivors landed (land, hold) or back and landed (abort) within this time


class MissionRunner:
    def __init__(self, mission: MissionSpec, simulation: Simulation, *, speed_factor: float, origin: GeoPoint,
                 first_instance: int, report_dir: Path, say: Say, airframe: str | None = None, seed: int = 0,
                 forward: tuple[str, int] | None = None, lockstep: bool = False,
                 lockstep_quantum: int = 1, camera_drones: frozenset[int] = frozenset(),
                 drones_per_process: int | Literal["auto"] = 1, links: LinkPlan | None = None,
                 signing_key_file: Path | None = None, view: ViewServer | None = None) -> None:  # fmt: skip
        self.mission = mission
        self.speed = speed_factor
        self.say = say
        self.report_dir = report_dir
        self.swarm_frame = SwarmFrame(origin)
        plan = SpawnPlan(
            n_drones=mission.swarm.drones,
            spacing_m=mission.swarm.spacing_m,
            layout=mission.swarm.layout,
            origin=origin,
            speed_factor=speed_factor,
            first_instance=first_instance,
            airframe=airframe,
            seed=seed,
            log_dir=report_dir / "logs",
            lockstep=lockstep,
            lockstep_quantum=lockstep_quantum,
            camera_drones=camera_drones,
            camera_dir=report_dir / "camera",
            drones_per_process=drones_per_process,
            signing_key_file=signing_key_file,
            links=mission.swarm.links if links is None else links,  # None: the mission's own [swarm.links]
            mesh=mission.swarm.mesh,
            behaviour=mission.swarm.behaviour,
        )
        self.swarm = Swarm(plan, simulation.harness(plan), forward=forward, relay=mission.swarm.relay)
        self.streamer = FormationStreamer(self.swarm, self.swarm_frame)
        # Two bodies touch when their centres are closer than the sum of both collision radii.
        contact_distance = simulation.contact_distance_m(airframe)
        self.recording = FlightRecording(
            mission_name=mission.name, n_drones=mission.swarm.drones, collision_radius_m=contact_distance
        )
        # Paced, the supervisor's clock is the wall clock: watch that the drones keep up with it.
        self._pace = PaceWatch(self.swarm, say)
        self.recording.requested_speed = self._pace.requested_speed
        self._t0_s = 0.0
        self.recorder: FlightRecorder | None = None
        self._next_status_s = 0.0
        self._step_name = "spawn"
        self.recording.loss_policy = mission.loss_policy.value
        self.recording.signing_key_id = self.swarm.signing_key_id
        self.recording.neighbours = NeighbourPlan(relay=mission.swarm.relay, mesh=mission.swarm.mesh).describe()
        self._pending_faults: list[tuple[float, FaultStep]] = []  # (mission time due, step)
        self._policy_taken = False  # a loss policy other than continue has taken the survivors out of the mission
        self.view = view  # the live view, if one is served: fed once the drones are up
        self._view_feed: ViewFeed | None = None

    # ---- time and telemetry ----------------------------------------------------------------------------------------
    def now(self) -> float:
        """Mission time in simulated seconds (the supervisor's clock: paced wall time or the lockstep clock)."""
        return self.swarm.clock() - self._t0_s

    def _tick(self, _wall_s: float) -> None:
        now = self.now()
        self._watch_losses(now)
        self._inject_due_faults(now)
        self.streamer.tick(now)
        if self._view_feed is not None:
            self._view_feed.tick(now)
        rate = self._pace.tick()
        if now >= self._next_status_s:
            self._next_status_s = now + STATUS_EVERY_S
            pace = ""
            if rate is not None:  # the report keeps the reading of each status line
                self.recording.realtime_factors.append(rate)
                pace = f"  rtf {rate:.2f}"
            live = self.recorder.live.status().line() if self.recorder is not None else ""
            self.say(f"[{now:6.1f} s] {self._step_name:<10} {live}{pace}")

    def _watch_losses(self, now: float) -> None:
        """Each new loss: one line, one record, and the mission's loss policy; each silent drone heard again: one
        line, and it is taken back."""
        for loss in self.swarm.detect_losses(now):
            self.say(loss_line(loss))
            line = apply_loss_policy(self.mission.loss_policy, self.streamer, loss, now)
            if self.mission.loss_policy is not LossPolicy.CONTINUE:
                self._policy_taken = True
            if line is not None:
                self.say(f"  swarm: {line}")
                self.recording.policy_events.append(EventRecord(time_s=now, sysid=loss.sysid, text=line))
        for loss in self.swarm.detect_regains(now):
            self.say(regain_line(loss))
            line = apply_regain(self.mission.loss_policy, self.streamer, loss, now, policy_taken=self._policy_taken)
            if line is not None:
                self.say(f"  swarm: {line}")
                self.recording.policy_events.append(EventRecord(time_s=now, sysid=loss.sysid, text=line))

    def _inject_due_faults(self, now: float) -> None:
        due = [(t, step) for t, step in self._pending_faults if t <= now]
        if not due:
            return
        self._pending_faults = [(t, step) for t, step in self._pending_faults if t > now]
        for _t, step in due:
            sysid = self.swarm.sysids[step.drone - 1]
            what = step.fault.describe()
            if sysid in self.swarm.losses:
                result = "not injected: drone already lost"
            elif step.fault.kind == CRASH:
                result = self.swarm.kill(sysid)
            else:
                try:
                    result = result_text(self.swarm.inject_fault(sysid, step.fault).result)
                except SwarmError as exc:
                    result = f"not injected: {exc}"
            self.say(f"[{now:6.1f} s] fault {what} on drone {sysid}: {result}")
            self.recording.faults.append(FaultRecord(time_s=now, sysid=sysid, fault=what, result=result))

    def _wait(self, condition: Callable[[], bool], timeout_sim_s: float) -> bool:
        """Wait for ``condition``; True also as soon as a loss policy (hold, land, abort) takes over the flight,
        which ends the step."""
        return self.swarm.wait_until(lambda: self._policy_taken or condition(), timeout_sim_s, tick=self._tick)

    def _hold(self, duration_sim_s: float) -> None:
        """Fly on for ``duration_sim_s`` (the step's time), or until a loss policy takes over."""
        self._wait(lambda: False, duration_sim_s)

    def _behaviour(self, step: BehaviourStep) -> None:
        """Every drone runs its onboard behaviour (docs/onboard.md) for the step's time, then holds."""
        start_onboard_behaviours(self.swarm, self.streamer)
        self._hold(step.duration_s)
        stop_onboard_behaviours(self.swarm)

    def _set_params(self) -> None:
        """The mission's drone parameters on every drone, each confirmed by its PARAM_VALUE echo (as MAVSDK does)."""
        for name, value in self.mission.swarm.params:
            results = self.swarm.set_params(name, value, self.swarm.sysids)
            silent = [r.sysid for r in results if r.kept is None]
            if silent:
                raise SwarmError(f"parameter {name}: no answer from sysid {silent} (unknown parameter?)")
            refused = [r for r in results if r.refused]
            if refused:
                raise SwarmError(
                    f"parameter {name} = {value:g} refused by sysid {[r.sysid for r in refused]} "
                    f"(kept {refused[0].kept:g})"
                )
        if self.mission.swarm.params:
            listed = ", ".join(f"{n} = {v:g}" for n, v in self.mission.swarm.params)
            self.say(f"parameters set on every drone: {listed}")

    # ---- steps -----------------------------------------------------------------------------------------------------
    def _takeoff(self, step: TakeoffStep) -> None:
        take_off_and_hold(self.swarm, self.streamer, step.alt_m, step.timeout_s, wait=self._wait, tick=self._tick,
                          say=self.say)  # fmt: skip

    def _formation(self, step: FormationStep) -> None:
        self.streamer.command(step.formation, self.now())
        self._hold(step.hold_s)

    def _flock(self, step: FlockStep) -> None:
        if step.onboard:  # every drone flocks by itself (gcs/command/onboard_flight.py)
            start_onboard_flock(self.swarm, self.streamer, step.spec)
            self._hold(step.duration_s)
            stop_onboard_behaviours(self.swarm)
            return
        self.streamer.command_flock(step.spec, self.now())
        self._hold(step.duration_s)

    def _follow_onboard(self, step: FollowStep, spec: FollowSpec) -> None:
        """Every drone flies leader-follower by itself; the step ends when the leader reports itself at its last
        waypoint (or after ``duration_s``), the flight report's slots come from the ground law's observer."""
        follow = start_onboard_follow(self.swarm, self.streamer, spec, self.now())
        self.streamer.observer = FollowObserver(follow, self.streamer, spec, self.now())
        try:
            if step.duration_s is not None:
                self._hold(step.duration_s)
            elif not self._wait(lambda: follow.leader in self.swarm.losses
                                or leader_arrived(follow, self.streamer, self.now()),
                                follow.latest_end_s - self.now()):  # fmt: skip
                margin = follow.latest_end_s - follow.earliest_end_s
                raise SwarmError(f"leader sysid {follow.leader} did not reach its last waypoint within "
                                 f"{margin:.0f} s of the earliest it could")  # fmt: skip
            if follow.leader in self.swarm.losses:  # no hand-over onboard: the followers hold where they are
                self.say(f"[{self.now():6.1f} s] follow: leader sysid {follow.leader} lost, the step ends")
        finally:
            self.streamer.observer = None
        stop_onboard_behaviours(self.swarm)

    def _follow(self, step: FollowStep) -> None:
        spec = step.spec
        if step.leader_drone is not None:
            spec = dataclasses.replace(spec, leader_sysid=self.swarm.sysids[step.leader_drone - 1])
        if step.onboard:
            self._follow_onboard(step, spec)
            return
        behaviour = self.streamer.command_follow(spec, self.now())
        if step.duration_s is not None:
            self._hold(step.duration_s)
            return

        def current() -> LeaderFollower:
            # a lost leader hands over to a new flight (gcs/command/streamer.py handle_loss): wait for that one
            flown = self.streamer.behaviour
            return flown if isinstance(flown, LeaderFollower) else behaviour

        def over() -> bool:
            flown = current()
            return flown.done(self.now()) or self.now() > flown.finish_s + FOLLOW_ARRIVAL_MARGIN_S

        self._wait(over, FOLLOW_TIMEOUT_S)
        if not self._policy_taken and not current().done(self.now()):
            flown = current()
            raise SwarmError(
                f"leader sysid {flown.leader} did not reach its last waypoint within "
                f"{FOLLOW_ARRIVAL_MARGIN_S:g} s of its reference"
            )

    def _place_obstacles(self) -> None:
        """Declare the mission's static obstacles in the shared world (cameras see them, contact crashes)."""
        for ob in self.mission.obstacles:
            geo = self.swarm_frame.geo_from_ned((ob.north_m, ob.east_m, -ob.centre_alt_m))
            self.swarm.harness.add_obstacle(cylinder=ob.cylinder, centre_geo=(geo.lat_deg, geo.lon_deg, geo.alt_amsl_m),
                                            radius_m=ob.radius_m, height_m=ob.height_m)  # fmt: skip
        if self.mission.obstacles:
            self.say(f"{len(self.mission.obstacles)} static obstacle(s) placed")

    def _swap(self, step: SwapStep) -> None:
        move = self.streamer.command_swap(step.speed_mps, step.accel_mps2, self.now())

        def arrived() -> bool:
            positions = self.streamer.positions()
            return all(
                s in positions and math.dist(positions[s], goal) <= step.tolerance_m for s, goal in move.goals.items()
            )

        if not self._wait(arrived, step.timeout_s):
            raise SwarmError(f"not every drone reached the opposite point within {step.timeout_s:g} s")

    def _plan(self, step: PlanStep) -> None:
        """Upload the plan's copies to the step's drones and, with ``start``, fly it in AUTO.MISSION to its end."""
        numbers = parse_drones(step.drones, range(1, len(self.swarm.sysids) + 1))
        chosen = [self.swarm.sysids[n - 1] for n in numbers]
        offsets = {
            s: o
            for s, o in copy_offsets(spawn_offsets(self.swarm), chosen, step.offsets).items()
            if s not in self.swarm.losses
        }
        if step.start:
            # The setpoint stream cannot run while the transfer is served (a lossy link can stretch it over seconds):
            # every drone in the air waits in Hold rather than meet the offboard-loss failsafe.
            self.streamer.hand_over(self.swarm.hold_all)
        uploaded = upload_plan(self.swarm, step.plan, offsets)
        fence = (
            f" and a fence of {len(step.plan.polygons) + len(step.plan.circles)} zone(s)" if step.plan.has_fence else ""
        )
        self.say(f"[{self.now():6.1f} s] {step.file.name}: {len(step.plan.items)} items{fence} uploaded to sysid "
                 f"{', '.join(map(str, offsets))}")  # fmt: skip
        if not step.start:
            return
        start_missions(self.swarm, list(offsets))
        if not self._wait(lambda: not unfinished(self.swarm, uploaded), step.timeout_s):
            late = unfinished(self.swarm, uploaded)
            raise SwarmError(f"plan {step.file.name}: sysid {late} did not finish within {step.timeout_s:g} s")
        missing = unreached(self.swarm, uploaded)
        if missing:
            listed = "; ".join(f"sysid {s}: items {m}" for s, m in missing.items())
            self.say(f"[{self.now():6.1f} s] {step.file.name}: not reported reached: {listed}")
        else:
            self.say(f"[{self.now():6.1f} s] {step.file.name}: every drone reached every item")

    def _land(self, step: LandStep | RtlStep) -> None:
        """Land (or return) every drone still armed; a crashed or already landed drone has nothing to do."""
        flying = self.streamer.hand_over(lambda: self.swarm.land_all(return_to_launch=isinstance(step, RtlStep)))
        if not self._wait(lambda: not self.swarm.armed_sysids(flying), step.timeout_s):
            raise SwarmError(f"not every drone landed and disarmed within {step.timeout_s:g} s")

    def _finish_after_policy(self) -> None:
        """After a loss under hold, land or abort the remaining steps are dropped: the mission ends once the
        survivors are down (hold: they hold for HOLD_POLICY_S, then land where they are)."""
        self.say(f"[{self.now():6.1f} s] loss policy {self.mission.loss_policy.value}: remaining steps dropped")
        if self.mission.loss_policy is LossPolicy.HOLD:
            self.swarm.run_for(HOLD_POLICY_S, tick=self._tick, tick_s=1.0 / SETPOINT_STREAM_HZ)
            self.swarm.land_all()
        flying = self.swarm.armed_sysids()
        landed = self.swarm.wait_until(lambda: not self.swarm.armed_sysids(flying), POLICY_LANDING_S, tick=self._tick)
        if not landed:
            raise SwarmError(f"not every drone landed and disarmed within {POLICY_LANDING_S:g} s of the loss policy")

    def _run_step(self, index: int, step: Step) -> None:
        start = self.now()
        kind = type(step).__name__.removesuffix("Step").lower()
        name = step.name if isinstance(step, FormationStep | FlockStep | FollowStep) else kind
        self._step_name = name
        self.say(f"[{start:6.1f} s] step {index + 1}/{len(self.mission.steps)}: {name}")
        if isinstance(step, TakeoffStep):
            self._takeoff(step)
        elif isinstance(step, FormationStep):
            self._formation(step)
        elif isinstance(step, FlockStep):
            self._flock(step)
        elif isinstance(step, SwapStep):
            self._swap(step)
        elif isinstance(step, FollowStep):
            self._follow(step)
        elif isinstance(step, HoldStep):
            self._hold(step.duration_s)
        elif isinstance(step, BehaviourStep):
            self._behaviour(step)
        elif isinstance(step, PlanStep):
            self._plan(step)
        elif isinstance(step, FaultStep):
            self._pending_faults.append((start + step.after_s, step))
            self._inject_due_faults(self.now())
        else:
            self._land(step)
        if isinstance(step, FaultStep):
            return  # an instant, listed with the faults (a zero-length step would only clutter the steps table)
        self.recording.steps.append(
            StepRecord(
                index=index,
                name=name,
                kind=kind,
                start_s=start,
                end_s=self.now(),
                target_alt_m=step.alt_m if isinstance(step, TakeoffStep) else None,
            )
        )

    def run(self) -> Path:
        """Fly the mission; always shuts the swarm down and writes the report, also after a failure."""
        self.report_dir.mkdir(parents=True, exist_ok=True)
        self.recorder = FlightRecorder(
            self.streamer, self.recording, self.now, self.report_dir / "flight.tlog", self.say
        )
        failure: BaseException | None = None
        try:
            pace = ("lockstep, as fast as possible" if self.speed == 0 else f"lockstep at {self.speed:g}x") \
                if self.swarm.plan.lockstep else f"speed {self.speed:g}x"  # fmt: skip
            self.say(f"mission {self.mission.name}: spawning {self.mission.swarm.drones} drones ({pace})")
            self.swarm.up()
            self.recording.obstacles = [obstacle_shape(o) for o in self.mission.obstacles]
            if self.view is not None:
                self._view_feed = ViewFeed(self.view, self.streamer, self.recording.obstacles, live=self.recorder.live)
            self._place_obstacles()
            self._set_params()
            self._t0_s = self.swarm.clock()
            self.swarm.arm_all(tick=self._tick)  # before the takeoff step's clock starts
            for index, step in enumerate(self.mission.steps):
                if self._policy_taken:
                    self._finish_after_policy()
                    break
                self._run_step(index, step)
        except (SwarmError, KeyboardInterrupt) as exc:
            failure = exc
        finally:
            self.streamer.stop()
            self.recording.losses = list(self.swarm.losses.values())
            self.recording.regained = list(self.swarm.regained)
            # The link model's counts as the flight ends, published by the drones at steps the lockstep clock fixes;
            # what reaches them while they are stopped depends on the machine's timing and is not the flight's.
            self.recording.link_counters = self.swarm.harness.link_counters()
            self.swarm.shutdown()
            self.recorder.close()
        out = write_report(self.recording, self.report_dir)
        self.say((out / "summary.txt").read_text().rstrip())
        if failure is not None:
            raise failure
        return out
