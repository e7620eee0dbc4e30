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
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

from gcs.fleet.attach import AttachSpec
from gcs.fleet.harness import Simulation, SpawnPlan
from gcs.fleet.links import LinkPlan
from gcs.fleet.losses import LossPolicy
from gcs.fleet.swarm import Swarm, SwarmError
from gcs.flight.formation import SETPOINT_STREAM_HZ
from gcs.flight.geodesy import GeoPoint
from gcs.mavlink.transport import GCS_SYSID
from gcs.missions.mission_file import (
    BehaviourStep,
    FaultStep,
    FlockStep,
    FollowAttachedStep,
    FollowStep,
    FormationStep,
    HoldStep,
    LandStep,
    MissionSpec,
    PauseStep,
    PlanStep,
    RtlStep,
    Step,
    SwapStep,
    TakeoffStep,
)
from gcs.missions.plan_flight import copy_offsets, parse_drones, spawn_offsets, unreached
from gcs.record.recording import FlightRecording, StepRecord
from gcs.supervisor import requests as rq
from gcs.supervisor.session import FlightSession
from gcs.supervisor.verbs import FaultRefused, Started, attach_all, carry_out, start
from gcs.view.report import PlotPolicy, write_report
from gcs.view.scene import obstacle_shape
from gcs.view.server import ViewServer

Say = Callable[[str], None]
STATUS_EVERY_S = 2.0
HOLD_POLICY_S = 10.0  # a mission under loss policy hold hovers this long before it lands the survivors
POLICY_LANDING_S = 120.0  # survivors landed (land, hold) or back and landed (abort) within this time


@dataclass(frozen=True, slots=True)
class Planned:
    """One request of a step: started, then (``wait``) flown until it is done, its failure the step's."""

    request: rq.Request
    wait: bool = True


def step_requests(step: Step, sysids: Sequence[int]) -> tuple[Planned, ...]:
    """A mission step as the requests it makes, in order (``sysids``: the swarm's, for a step that names a drone by
    its number). A plan step and a fault step are decoded as they are reached: they depend on the swarm then (where
    each drone spawned, which are lost, the mission time)."""
    if isinstance(step, TakeoffStep):
        return (Planned(rq.Takeoff(alt_m=step.alt_m, timeout_s=step.timeout_s)),)
    if isinstance(step, FormationStep):  # the hold runs from the transition's start
        return Planned(rq.FlyFormation(formation=step.formation)), Planned(rq.Hold(duration_s=step.hold_s))
    if isinstance(step, FlockStep):
        stop = (Planned(rq.Behaviours(run=False)),) if step.onboard else ()
        return Planned(rq.Flock(spec=step.spec, onboard=step.onboard)), Planned(rq.Hold(duration_s=step.duration_s)), \
            *stop  # fmt: skip
    if isinstance(step, FollowStep):
        spec = step.spec
        if step.leader_drone is not None:
            spec = dataclasses.replace(spec, leader_sysid=sysids[step.leader_drone - 1])
        # without a time of its own, the step lasts until the leader has flown its path
        follow = (Planned(rq.Follow(spec=spec, onboard=step.onboard), wait=step.duration_s is None),)
        held = () if step.duration_s is None else (Planned(rq.Hold(duration_s=step.duration_s)),)
        return follow + held + ((Planned(rq.Behaviours(run=False)),) if step.onboard else ())
    if isinstance(step, FollowAttachedStep):
        return Planned(rq.FollowAttached(spec=step.spec)), Planned(rq.Hold(duration_s=step.spec.duration_s))
    if isinstance(step, SwapStep):
        return (Planned(rq.Swap(speed_mps=step.speed_mps, accel_mps2=step.accel_mps2, tolerance_m=step.tolerance_m,
                                timeout_s=step.timeout_s)),)  # fmt: skip
    if isinstance(step, HoldStep):
        return (Planned(rq.Hold(duration_s=step.duration_s)),)
    if isinstance(step, BehaviourStep):  # the drones' own behaviour for the step's time, then Hold
        return tuple(Planned(r) for r in (rq.Behaviours(run=True), rq.Hold(duration_s=step.duration_s),
                                          rq.Behaviours(run=False)))  # fmt: skip
    if isinstance(step, PauseStep):  # PX4 Hold for the step's time
        return Planned(rq.Pause()), Planned(rq.Hold(duration_s=step.duration_s))
    if isinstance(step, LandStep):
        return (Planned(rq.Land(timeout_s=step.timeout_s)),)
    if isinstance(step, RtlStep):
        return (Planned(rq.ReturnToLaunch(timeout_s=step.timeout_s)),)
    raise TypeError(f"{type(step).__name__} is decoded when it is reached")


class MissionRunner:
    def __init__(self, mission: MissionSpec, simulation: Simulation, *, speed_factor: float, origin: GeoPoint,
                 first_instance: int, report_dir: Path, say: Say, airframe: str | None = None, seed: int = 0,
                 forward: tuple[str, int] | None = None, lockstep: bool = False,
                 lockstep_quantum: int = 1, camera_drones: frozenset[int] = frozenset(),
                 drones_per_process: int | Literal["auto"] = 1, links: LinkPlan | None = None,
                 signing_key_file: Path | None = None, view: ViewServer | None = None,
                 attach: tuple[AttachSpec, ...] = (), gcs_sysid: int = GCS_SYSID,
                 stop_on_violation: bool = False, plots: PlotPolicy = "always") -> None:  # fmt: skip
        """``attach``: vehicles the simulation does not run, attached before the drones start (gcs/fleet/attach.py);
        ``run`` raises AttachError (one line, nothing flown) when one cannot be. ``stop_on_violation``: the first
        violation of one of the mission's invariants ends the flight there (a SwarmError). ``plots``: when the report
        draws its plots (gcs/view/report.py)."""
        self.mission = mission
        self.plots = plots
        self.stop_on_violation = stop_on_violation
        self.attach = attach
        self.speed = speed_factor
        self.say = say
        self.report_dir = report_dir
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
            gcs_sysid=gcs_sysid,
            wind_ned_mps=mission.swarm.wind_ned_mps,
            gust_mps=mission.swarm.gust_mps,
            spawn_jitter_m=mission.swarm.spawn_jitter_m,
        )
        self.swarm = Swarm(plan, simulation.harness(plan), forward=forward, relay=mission.swarm.relayed)
        # Two bodies touch when their centres are closer than the sum of both collision radii.
        contact_distance = simulation.contact_distance_m(airframe)
        recording = FlightRecording(
            mission_name=mission.name, n_drones=mission.swarm.drones, collision_radius_m=contact_distance
        )
        self.session = FlightSession(self.swarm, say, recording, mission.loss_policy, note=self._note, t0_s=0.0)
        self.session.waiting_tick = self._tick
        self._next_status_s = 0.0
        self._step_name = "spawn"
        self._pending_faults: list[tuple[float, FaultStep]] = []  # (mission time due, step)
        self.view = view  # the live view, if one is served: fed once the drones are up

    # ---- time and telemetry ----------------------------------------------------------------------------------------
    def now(self) -> float:
        """Mission time in simulated seconds (the supervisor's clock: paced wall time or the lockstep clock)."""
        return self.session.mission_time()

    def _note(self, text: str) -> None:
        self.say(f"[{self.now():6.1f} s] {text}")

    def _tick(self, _wall_s: float) -> None:
        now = self.now()
        self.session.watch_losses(now, indent="  ")
        self._inject_due_faults(now)
        self.session.tick(now)
        rate = self.session.pace.tick()
        if now >= self._next_status_s:
            self._next_status_s = now + STATUS_EVERY_S
            pace = ""
            if rate is not None:  # the report keeps the reading of each status line
                self.session.recording.realtime_factors.append(rate)
                pace = f"  rtf {rate:.2f}"
            recorder = self.session.recorder
            live = recorder.live.status().line() if recorder is not None else ""
            self.say(f"[{now:6.1f} s] {self._step_name:<10} {live}{pace}")

    def _inject_due_faults(self, now: float) -> None:
        due = [(t, step) for t, step in self._pending_faults if t <= now]
        if not due:
            return
        self._pending_faults = [(t, step) for t, step in self._pending_faults if t > now]
        for _t, step in due:
            sysid = self.swarm.liveness.sysids[step.drone - 1]
            try:
                start(self.session, rq.InjectFault(sysid=sysid, fault=step.fault))
            except FaultRefused:
                pass  # the drone's answer, noted and recorded with it: the mission flies on
            except SwarmError as exc:  # not sent: the drone is lost, or did not answer
                self._note(f"fault {step.fault.describe()} on drone {sysid}: not injected: {exc}")
                self.session.record_fault(sysid, step.fault.describe(), f"not injected: {exc}")

    def _wait(self, condition: Callable[[], bool], timeout_sim_s: float) -> bool:
        """Wait for ``condition``; True also as soon as a loss policy (hold, land, abort) takes over the flight,
        which ends the step."""
        return self.swarm.pump.wait_until(
            lambda: self.session.policy_taken or condition(), timeout_sim_s, tick=self._tick
        )

    def _set_params(self) -> None:
        """The mission's drone parameters on every drone, each confirmed by its PARAM_VALUE echo (as MAVSDK does)."""
        for name, value in self.mission.swarm.params:
            start(self.session, rq.SetParam(name=name, value=value))
        if self.mission.swarm.params:
            listed = ", ".join(f"{n} = {v:g}" for n, v in self.mission.swarm.params)
            self.say(f"parameters set on every drone: {listed}")
        for drone, params in self.mission.swarm.drone_params:  # [swarm.drone.N]: over the swarm's own
            sysid = self.swarm.liveness.sysids[drone - 1]
            for name, value in params:
                start(self.session, rq.SetParam(name=name, value=value, sysids=(sysid,)))
            self.say(f"parameters set on drone {drone} (sysid {sysid}): "
                     + ", ".join(f"{n} = {v:g}" for n, v in params))  # fmt: skip

    # ---- steps -----------------------------------------------------------------------------------------------------
    def _carry(self, planned: Sequence[Planned]) -> Started:
        """A step's requests, each started and (unless it only starts) waited for; the first one's ``Started`` (it
        sets what the step flies: a takeoff's target altitude, a formation's planned arrival)."""
        first: Started | None = None
        for p in planned:
            started = start(self.session, p.request)
            first = first or started
            if p.wait:
                carry_out(started, self._wait)
        assert first is not None
        return first

    def _fault(self, step: FaultStep) -> None:
        """Due ``after_s`` from now, injected at the first tick it is due (this one, when it is due at once)."""
        self._pending_faults.append((self.now() + step.after_s, step))
        self._inject_due_faults(self.now())

    def _place_obstacles(self) -> None:
        """Declare the mission's static obstacles in the shared world (cameras see them, contact crashes)."""
        for ob in self.mission.obstacles:
            geo = self.swarm.picture.frame.geo_from_ned((ob.north_m, ob.east_m, -ob.centre_alt_m))
            self.swarm.harness.add_obstacle(cylinder=ob.cylinder, centre_geo=(geo.lat_deg, geo.lon_deg, geo.alt_amsl_m),
                                            radius_m=ob.radius_m, height_m=ob.height_m)  # fmt: skip
        if self.mission.obstacles:
            self.say(f"{len(self.mission.obstacles)} static obstacle(s) placed")

    def _plan(self, step: PlanStep) -> None:
        """Upload the plan's copies to the step's drones and, with ``start``, fly it in AUTO.MISSION to its end."""
        sysids = self.swarm.liveness.sysids
        numbers = parse_drones(step.drones, range(1, len(sysids) + 1))
        chosen = [sysids[n - 1] for n in numbers]
        offsets = {
            s: o
            for s, o in copy_offsets(spawn_offsets(self.swarm), chosen, step.offsets).items()
            if s not in self.swarm.liveness.losses
        }
        upload = start(self.session, rq.PlanUpload(plan=step.plan, offsets=offsets, hold_first=step.start))
        self._note(f"{step.file.name}: {upload.result}")
        if not step.start:
            return
        self._carry([Planned(rq.PlanStart(sysids=tuple(offsets), uploaded=upload.value, timeout_s=step.timeout_s))])
        missing = unreached(self.swarm, upload.value)
        if missing:
            listed = "; ".join(f"sysid {s}: items {m}" for s, m in missing.items())
            self._note(f"{step.file.name}: not reported reached: {listed}")
        else:
            self._note(f"{step.file.name}: every drone reached every item")

    def _finish_after_policy(self) -> None:
        """After a loss under hold, land or abort the remaining steps are dropped: the mission ends once the
        survivors are down (hold: they hold for HOLD_POLICY_S, then land where they are)."""
        self._note(f"loss policy {self.mission.loss_policy.value}: remaining steps dropped")
        if self.mission.loss_policy is LossPolicy.HOLD:
            self.swarm.pump.run_for(HOLD_POLICY_S, tick=self._tick, tick_s=1.0 / SETPOINT_STREAM_HZ)
            self.swarm.commands.land_all()
        armed_sysids = self.swarm.liveness.armed_sysids
        flying = armed_sysids()
        landed = self.swarm.pump.wait_until(lambda: not armed_sysids(flying), POLICY_LANDING_S, tick=self._tick)
        if not landed:
            raise SwarmError(f"not every drone landed and disarmed within {POLICY_LANDING_S:g} s of the loss policy")

    def _run_step(self, index: int, step: Step) -> None:
        began = self.now()
        kind = type(step).__name__.removesuffix("Step").lower()
        name = step.name if isinstance(step, FormationStep | FlockStep | FollowStep | FollowAttachedStep) else kind
        self._step_name = name
        self.session.step_began()
        self.say(f"[{began:6.1f} s] step {index + 1}/{len(self.mission.steps)}: {name}")
        flown: Started | None = None
        if isinstance(step, PlanStep):
            self._plan(step)
        elif isinstance(step, FaultStep):
            self._fault(step)
        else:
            flown = self._carry(step_requests(step, self.swarm.liveness.sysids))
        if isinstance(step, FaultStep):
            return  # an instant, listed with the faults (a zero-length step would only clutter the steps table)
        self.session.recording.steps.append(
            StepRecord(
                index=index,
                name=name,
                kind=kind,
                start_s=began,
                end_s=self.now(),
                target_alt_m=flown.target_alt_m if flown is not None else None,  # a takeoff's: MIS_TAKEOFF_ALT at least
                arrival_s=flown.arrival_s if flown is not None else None,
            )
        )

    def run(self) -> Path:
        """Fly the mission; always shuts the swarm down and writes the report, also after a failure (but an attach
        that fails is an AttachError before anything starts, and leaves no report)."""
        attach_all(self.session, self.attach)
        self.report_dir.mkdir(parents=True, exist_ok=True)
        recorder = self.session.record(self.report_dir / "flight.tlog", self.say)
        failure: BaseException | None = None
        try:
            pace = ("lockstep, as fast as possible" if self.speed == 0 else f"lockstep at {self.speed:g}x") \
                if self.swarm.plan.lockstep else f"speed {self.speed:g}x"  # fmt: skip
            self.say(f"mission {self.mission.name}: spawning {self.mission.swarm.drones} drones ({pace})")
            self.swarm.up()
            # the mission's [[invariants]], built and checked when the file was read, from the first tick on
            start(self.session, rq.Require(invariants=self.mission.invariants, stop=self.stop_on_violation))
            self.session.recording.obstacles = [obstacle_shape(o) for o in self.mission.obstacles]
            if self.view is not None:
                self.session.serve(self.view, self.session.recording.obstacles)
            self._place_obstacles()
            self._set_params()
            self.session.restart_clock()
            self._pending_faults += [(f.after_s, f) for f in self.mission.faults]  # [[faults]]: at mission times
            start(self.session, rq.Arm())  # before the takeoff step's clock starts
            for index, step in enumerate(self.mission.steps):
                if self.session.policy_taken:
                    self._finish_after_policy()
                    break
                self._run_step(index, step)
        except (SwarmError, KeyboardInterrupt) as exc:
            failure = exc
        finally:
            self.session.streamer.stop()
            self.session.take_stock()
            self.swarm.shutdown()
            recorder.close()
        out = write_report(self.session.recording, self.report_dir, plots=self.plots, failed=failure is not None)
        self.say((out / "summary.txt").read_text().rstrip())
        if failure is not None:
            raise failure
        return out
