"""The swarm's verbs, each written once: what it checks, how it starts, and how to know it is done.

Every front-end decodes what its user said into a request (gcs/supervisor/requests.py) and hands it to ``start``, on
a ``FlightSession`` (gcs/supervisor/session.py): the control channel of ``swarm up`` (gcs/supervisor/station.py, with
the CLI's commands decoded by gcs/supervisor/commands.py), which must not block and so only starts a verb and
answers; a mission file's steps (gcs/supervisor/mission_runner.py) and the Python API (gcs/api/engine.py), which start
a verb and wait until it is done (``carry_out``). A verb returns a ``Started``: what to answer at once, and the
condition, time limit and complaint a front-end that waits uses. Each front-end waits in its own way (a mission's
wait also ends when a loss policy takes the flight over; the API's ends on Ctrl-C), which is why waiting is not a
verb's.

``VERBS`` is the table from request type to verb; tests/unit/test_requests.py drives every front-end's decoder to its
requests. A verb need not exist in every front-end (a swap is a mission step, a controller an API call), but where it
exists it is this code.

Checks: a request checks its own fields when it is made (``FieldError``); a verb raises ``ValueError`` for a mistake
only the swarm reveals (no such sysid: one line, the user's to fix, which the control channel answers as a usage
error, exit code 2) and ``SwarmError`` when the swarm cannot do it.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Final

from gcs.command.onboard_flight import FollowObserver, leader_arrived, start_onboard_flock, start_onboard_follow
from gcs.command.procedures import (
    start_onboard_behaviours,
    start_takeoff,
    stop_onboard_behaviours,
)
from gcs.fleet.attach import AttachError, AttachSpec
from gcs.fleet.faults import CRASH, result_text
from gcs.fleet.swarm import SwarmError
from gcs.flight.behaviours import FollowAttached, LeaderFollower, LeaderReport
from gcs.invariants.spec import Invariant, build_invariant, unique_names
from gcs.missions.mission_file import build_formation
from gcs.missions.plan_flight import download_plan, start_missions, unfinished, upload_plan
from gcs.supervisor import requests as rq
from gcs.supervisor.session import FlightSession

FOLLOW_ARRIVAL_MARGIN_S: Final = 30.0  # the leader must report itself at its last waypoint this long after its path
FOLLOW_TIMEOUT_S: Final = 3600.0  # a followed path's outer bound; it ends with the leader's arrival or its margin


def _never() -> bool:
    return False


@dataclass(frozen=True, slots=True)
class Started:
    """A verb under way. ``result``: what the control channel answers; ``value``: what an API call returns.

    A front-end that waits waits for ``done`` up to ``timeout_s`` (simulated seconds) and then raises SwarmError
    with ``late()``, unless ``ends_by_time`` (a hold: its time is its end); ``finish`` runs after a wait that did
    not fail, and may still raise. ``done`` None: the verb is done once started (a formation is then flown until
    the next verb). ``new_step``: the verb changes what the swarm flies, so a report that records verbs as they come
    (``swarm up``, the API; a mission's steps are its own) begins a step with it."""

    result: str = ""
    value: Any = None
    done: Callable[[], bool] | None = None
    timeout_s: float = math.inf
    late: Callable[[], str] = lambda: "not done in time"
    ends_by_time: bool = False
    finish: Callable[[], None] | None = None
    new_step: bool = False
    target_alt_m: float | None = None  # a takeoff: the altitude the drones climb to (MIS_TAKEOFF_ALT at least)
    arrival_s: float | None = None  # a formation: when its planned transition puts every setpoint on its slot


Wait = Callable[[Callable[[], bool], float], bool]  # (condition, timeout in simulated seconds) -> ended with it


def carry_out(started: Started, wait: Wait) -> Any:
    """Wait until a started verb is done, as a mission step or an API call does; its value."""
    if started.done is not None and not wait(started.done, started.timeout_s) and not started.ends_by_time:
        raise SwarmError(started.late())
    if started.finish is not None:
        started.finish()
    return started.value


def start(session: FlightSession, request: rq.Request) -> Started:
    """Start what a request asks, whichever front-end decoded it. In a session flown verb by verb (``swarm up``, the
    API) a verb that changes what the swarm flies begins the report's next step: a goto is a formation step, a plan's
    start a plan step (a mission's steps are its own)."""
    started = VERBS[type(request)](session, request)
    if started.new_step and session.records_verbs:
        step = request.verb.removesuffix("_start")
        shape = request.shape if isinstance(request, rq.FlyFormation) else step
        session.begin_step("formation" if step == "goto" else step, shape, started.target_alt_m, started.arrival_s)
    return started


def take_over(session: FlightSession) -> None:
    """Before the ground station flies the drones itself: a user's controller ends, and drones flying their onboard
    behaviour stop it and hold (BHV_EN = 0), so that only one source feeds their offboard input."""
    session.controller = None
    if session.onboard:
        behaviour(session, rq.Behaviours(run=False))


# ---- the verbs ------------------------------------------------------------------------------------------------------
def arm(session: FlightSession, request: rq.Arm) -> Started:
    """Arm every surviving drone on the ground, after its pre-arm checks (the swarm flies on meanwhile)."""
    session.swarm.commands.arm_all(request.timeout_s, tick=session.waiting_tick)
    return Started()


def takeoff(session: FlightSession, request: rq.Takeoff) -> Started:
    """Arm (unless armed) and take every surviving drone off to ``alt_m`` above its home; done when they hold it."""
    timeout_s = request.timeout_s
    target_m, holding = start_takeoff(session.swarm, session.streamer, request.alt_m, tick=session.waiting_tick,
                                      say=session.say)  # fmt: skip
    return Started(done=holding, timeout_s=timeout_s, new_step=True, target_alt_m=target_m,
                   late=lambda: f"takeoff to {target_m:g} m not reached within {timeout_s:g} s")  # fmt: skip


def formation(session: FlightSession, request: rq.FlyFormation) -> Started:
    """Fly a formation, from wherever the drones are (a synchronised, collision-aware transition); its value is the
    time the transition needs, in seconds. A square grid is counted over the surviving drones."""
    spec = request.formation
    if isinstance(spec, rq.SquareGrid):
        spec = build_formation("grid", spec.fields(len(session.swarm.liveness.active_sysids)))
    take_over(session)
    now = session.mission_time()
    session.streamer.command(spec, now)
    transition = session.streamer.engine.transition
    arrival_s = transition.arrival_s if transition is not None else now
    return Started(value=arrival_s - now, new_step=True, arrival_s=arrival_s)


def goto(session: FlightSession, request: rq.Goto) -> Started:
    """Move the formation being flown so that its centre is at north/east (and altitude), keeping its shape."""
    flown = session.streamer.formation
    if flown is None or not session.streamer.active:
        raise SwarmError("no formation is being flown: use 'swarm formation' first")
    changes: dict[str, Any] = {"centre_ne_m": (request.north_m, request.east_m)}
    if request.alt_m is not None:
        changes["alt_m"] = request.alt_m
    moved = dataclasses.replace(flown, **changes)  # type: ignore[type-var]
    return formation(session, rq.FlyFormation(formation=moved))


def flock(session: FlightSession, request: rq.Flock) -> Started:
    """Reynolds flocking, computed by the ground station or (``onboard``) by every drone itself."""
    spec = request.spec
    take_over(session)
    if request.onboard:  # every drone flocks by itself (gcs/command/onboard_flight.py)
        start_onboard_flock(session.swarm, session.streamer, spec)
        session.onboard = True
    else:
        session.streamer.command_flock(spec, session.mission_time())
    return Started(new_step=True)


def follow(session: FlightSession, request: rq.Follow) -> Started:
    """Leader-follower along the leader's path; done when the leader has flown it (reported at its last waypoint)."""
    spec = request.spec
    take_over(session)
    swarm, streamer = session.swarm, session.streamer
    if request.onboard:
        flown = start_onboard_follow(swarm, streamer, spec, session.mission_time())
        session.onboard = True
        # the followers' slots for the report, from the ground law's observer (the drones fly themselves)
        streamer.observer = FollowObserver(flown, streamer, spec, session.mission_time())
        margin = flown.latest_end_s - flown.earliest_end_s

        def said_if_lost() -> None:
            if flown.leader in swarm.liveness.losses:  # no hand-over onboard: the followers hold where they are
                session.note(f"follow: leader sysid {flown.leader} lost, the step ends")

        return Started(
            done=lambda: flown.leader in swarm.liveness.losses
            or leader_arrived(flown, streamer, session.mission_time()),
            timeout_s=flown.latest_end_s - session.mission_time(),
            late=lambda: f"leader sysid {flown.leader} did not reach its last waypoint within {margin:.0f} s of the "
                         "earliest it could",
            finish=said_if_lost,
            new_step=True,
        )  # fmt: skip
    ground = streamer.command_follow(spec, session.mission_time())

    def current() -> LeaderFollower:
        # a lost leader hands over to a new flight (gcs/command/streamer.py handle_loss): wait for that one
        flown = streamer.behaviour
        return flown if isinstance(flown, LeaderFollower) else ground

    def over() -> bool:
        flown = current()
        return flown.done(session.mission_time()) or session.mission_time() > flown.finish_s + FOLLOW_ARRIVAL_MARGIN_S

    def late() -> str:
        return (f"leader sysid {current().leader} did not reach its last waypoint within "
                f"{FOLLOW_ARRIVAL_MARGIN_S:g} s of its reference")  # fmt: skip

    def arrived() -> None:
        if not session.policy_taken and not current().done(session.mission_time()):
            raise SwarmError(late())

    return Started(done=over, timeout_s=FOLLOW_TIMEOUT_S, late=late, finish=arrived, new_step=True)


def follow_attached(session: FlightSession, request: rq.FollowAttached) -> Started:
    """Every drone holds its offset from a leader that flies itself (a vehicle attached as ``leader``,
    docs/external.md), from the leader's reports; the ground station never commands the leader. A wait holds it for
    the spec's ``duration_s``."""
    swarm, streamer, spec = session.swarm, session.streamer, request.spec
    leaders = [s for s, v in swarm.attachments.vehicles.items() if v.spec.role == "leader"]
    sysid = spec.leader_sysid if spec.leader_sysid is not None else (leaders[0] if len(leaders) == 1 else None)
    if sysid is None or sysid not in leaders:
        which = "" if spec.leader_sysid is None else f" with sysid {spec.leader_sysid}"
        raise ValueError(f"follow an attached leader: no attached leader{which} to follow (attached leaders: "
                         f"{leaders or 'none'}; attach one with --attach leader=URL)")  # fmt: skip
    vehicle = swarm.attachments.vehicles[sysid]

    def report() -> LeaderReport | None:
        if vehicle.lost:
            return None
        geo = vehicle.body_at(swarm.clock.now())
        if geo is None:
            return None
        return LeaderReport(pos_ned_m=swarm.picture.ned_from_geo(geo), vel_ned_mps=vehicle.vel_ned_mps)

    take_over(session)
    law = FollowAttached(spec, report, session.mission_time(), swarm.picture.state(swarm.flown_sysids))
    streamer.command_behaviour(law, session.mission_time(), "following an attached leader")
    return Started(result=f"following attached leader sysid {sysid}", done=_never, timeout_s=spec.duration_s,
                   ends_by_time=True, new_step=True)  # fmt: skip


def swap(session: FlightSession, request: rq.Swap) -> Started:
    """Every drone straight through the centre to the opposite point (the avoidance stress test); done when each is
    within ``tolerance_m`` of its goal."""
    take_over(session)
    move = session.streamer.command_swap(request.speed_mps, request.accel_mps2, session.mission_time())
    tolerance_m, timeout_s = request.tolerance_m, request.timeout_s

    def arrived() -> bool:
        positions = session.swarm.picture.positions(move.goals)
        return all(s in positions and math.dist(positions[s], goal) <= tolerance_m for s, goal in move.goals.items())

    return Started(done=arrived, timeout_s=timeout_s, new_step=True,
                   late=lambda: f"not every drone reached the opposite point within {timeout_s:g} s")  # fmt: skip


def hold(session: FlightSession, request: rq.Hold) -> Started:
    """Fly on as now for ``duration_s`` simulated seconds."""
    return Started(done=_never, timeout_s=request.duration_s, ends_by_time=True)


def pause(session: FlightSession, _request: rq.Pause) -> Started:
    """Every drone into PX4 Hold where it is (members into their Hold mode); the controller, the drones' own
    behaviours and the stream stop. Its value is the sysids put in Hold."""
    take_over(session)
    held = session.streamer.hand_over(session.swarm.commands.hold_all)
    return Started(result=f"sysid {held}: Hold", value=held, new_step=True)


def land(session: FlightSession, request: rq.Land | rq.ReturnToLaunch) -> Started:
    """Land (or return and land) every drone still armed; done when they have landed and disarmed. A crashed or
    landed drone has nothing to do."""
    return_to_launch, timeout_s = isinstance(request, rq.ReturnToLaunch), request.timeout_s
    session.controller = None
    session.onboard = False  # landing takes the drones out of OFFBOARD: their behaviours stop by themselves
    swarm = session.swarm
    flying = session.streamer.hand_over(lambda: swarm.commands.land_all(return_to_launch=return_to_launch))
    return Started(done=lambda: not swarm.liveness.armed_sysids(flying), timeout_s=timeout_s, new_step=True,
                   late=lambda: f"not every drone landed and disarmed within {timeout_s:g} s")  # fmt: skip


def behaviour(session: FlightSession, request: rq.Behaviours) -> Started:
    """Every drone's onboard behaviour on (BHV_EN = 1; the ground station's stream stops) or off (BHV_EN = 0, then
    Hold where they are); its value is the sysids."""
    run = request.run
    session.controller = None
    session.streamer.observer = None
    if run:
        sysids = start_onboard_behaviours(session.swarm, session.streamer)
    else:
        sysids = stop_onboard_behaviours(session.swarm)
    session.onboard = run
    return Started(result=f"sysid {sysids}: behaviour {'start' if run else 'stop'}", value=sysids, new_step=run)


class FaultRefused(SwarmError):
    """The drone answered a fault injection with a refusal: noted and recorded as its answer, unlike a fault that
    was never sent (a drone already lost, or silent)."""


def fault(session: FlightSession, asked: rq.InjectFault | rq.Kill) -> Started:
    """Inject a fault into one drone: PX4's MAV_CMD_INJECT_FAILURE, or (``crash``, a kill) the harness ends its flight
    software. Noted and recorded for the report, refused or not; ``FaultRefused`` when the drone refuses it."""
    swarm, sysid, request = session.swarm, asked.sysid, asked.fault
    ordered_s = session.mission_time()  # the report's time: the answer comes frames later
    sysids, losses = swarm.liveness.sysids, swarm.liveness.losses
    if sysid not in sysids:  # a sysid by the request's own check (gcs/supervisor/requests.py)
        known = f"{sysids[0]}..{sysids[-1]}" if sysids else "none"
        raise ValueError(f"no drone with sysid {sysid!r} (sysids {known})")
    if sysid in losses:
        raise SwarmError(f"drone {sysid} is already lost ({losses[sysid].cause})")
    if request.kind == CRASH:
        result, accepted = swarm.liveness.kill(sysid), True
    else:
        ack = swarm.inject_fault(sysid, request)
        result, accepted = result_text(ack.result), ack.ok
    session.note(f"fault {request.describe()} on drone {sysid}: {result}")
    session.record_fault(sysid, request.describe(), result, ordered_s)
    if not accepted:
        raise FaultRefused(f"drone {sysid} refused fault {request.describe()}: {result}")
    return Started(result=result, value=result)


def plan_upload(session: FlightSession, request: rq.PlanUpload) -> Started:
    """Upload a QGroundControl plan's copy to each drone named (moved by its offset); its value says what was
    uploaded, for ``plan_start`` to watch. ``hold_first``: every drone in the air first waits in Hold, the stream
    stopped (it cannot run while the transfer is served, and a lossy link can stretch that over seconds: Hold is
    better than the offboard-loss failsafe)."""
    plan, offsets = request.plan, request.offsets
    if request.hold_first:
        session.controller = None
        session.streamer.hand_over(session.swarm.commands.hold_all)
    uploaded = upload_plan(session.swarm, plan, dict(offsets))
    fence = f" and {len(plan.polygons) + len(plan.circles)} fence zone(s)" if plan.has_fence else ""
    rally = f"; {len(plan.rally_points)} rally point(s) not uploaded (not stored)" if plan.rally_points else ""
    result = f"{len(plan.items)} items{fence} uploaded to sysid {', '.join(map(str, offsets))}{rally}"
    return Started(result=result, value=uploaded)


def plan_start(session: FlightSession, request: rq.PlanStart) -> Started:
    """AUTO.MISSION on the drones named (out of OFFBOARD: the stream stops); with what was ``uploaded``, done when
    every one has finished its mission."""
    sysids, uploaded, timeout_s = request.sysids, request.uploaded, request.timeout_s
    session.controller = None
    session.streamer.hand_over(lambda: start_missions(session.swarm, list(sysids)))
    result = f"AUTO.MISSION on sysid {', '.join(map(str, sysids))}"
    if uploaded is None:
        return Started(result=result, new_step=True)
    return Started(
        result=result,
        new_step=True,
        done=lambda: not unfinished(session.swarm, uploaded),
        timeout_s=timeout_s,
        late=lambda: f"sysid {unfinished(session.swarm, uploaded)} did not finish within {timeout_s:g} s",
    )


def plan_download(session: FlightSession, request: rq.PlanDownload) -> Started:
    """One drone's mission and fence, as a QGroundControl plan (its value)."""
    sysid = request.sysid
    if sysid not in session.swarm.liveness.sysids:
        raise ValueError(f"no drone with sysid {sysid!r} (sysids {session.swarm.liveness.sysids})")
    return Started(value=download_plan(session.swarm, sysid))


def param(session: FlightSession, request: rq.SetParam) -> Started:
    """Set a parameter on the drones named (all, when None), each confirmed by its PARAM_VALUE echo (as MAVSDK)."""
    swarm, name, value, sysids = session.swarm, request.name, request.value, request.sysids
    results = swarm.params.set_all(name, value, list(swarm.liveness.sysids if sysids is None else sysids))
    silent = [r.sysid for r in results if r.kept is None]
    if silent:
        raise SwarmError(f"parameter {name}: no answer from sysid {silent} (unknown parameter?)")
    refused = [r for r in results if r.refused]
    if refused:
        raise SwarmError(f"parameter {name} = {value:g} refused by sysid {[r.sysid for r in refused]} "
                         f"(kept {refused[0].kept:g})")  # fmt: skip
    return Started(result=f"{name} = {value:g}")


def attach(session: FlightSession, request: rq.Attach) -> Started:
    """Attach the vehicles heard on a link the simulation does not run (gcs/fleet/attach.py): its HEARTBEAT and first
    position waited for (the swarm flies on meanwhile), its sysid and distance checked; AttachError (a ValueError:
    the user's to fix) when none can be. Each vehicle refused on the link is said; the value is the sysids."""
    spec = request.spec
    sysids, refused = session.swarm.attach(spec)
    for line in refused:
        session.say(f"swarm: {line}")
    result = f"attached {spec.role} sysid {', '.join(map(str, sysids))} on {spec.url.describe()}"
    session.say(f"swarm: {result}")
    return Started(result=result, value=sysids)


def detach(session: FlightSession, request: rq.Detach) -> Started:
    """Let an attached vehicle go: its body leaves the world and nothing more is read from it; it is told nothing."""
    sysid = request.sysid
    attached = session.swarm.attachments.vehicles
    if sysid not in attached:
        raise ValueError(f"no attached vehicle with sysid {sysid!r} (attached: {sorted(attached)})")
    session.swarm.attachments.detach(sysid)
    result = f"detached sysid {sysid}"
    session.say(f"swarm: {result}")
    return Started(result=result)


def require(session: FlightSession, request: rq.Require) -> Started:
    """Check invariants (each as plain fields, as a mission's ``[[invariants]]`` table: gcs/invariants/spec.py, or
    built already) at every tick from now on; ``base``: where a predicate's file is read from; ``stop``: the first
    violation ends the flight. A bad one is a ValueError of one line, and none of them is taken."""
    count = len(session.swarm.liveness.sysids)
    invariants = [f if isinstance(f, Invariant) else build_invariant(f, base=request.base, drone_count=count)
                  for f in request.invariants]  # fmt: skip
    unique_names(invariants)
    session.require(invariants, stop=request.stop)
    return Started(result=f"checking {'; '.join(i.describe() for i in invariants)}", value=[i.name for i in invariants])


def attach_all(session: FlightSession, specs: Sequence[AttachSpec]) -> None:
    """``attach`` every spec (before the drones start, so that a bad one stops nothing that flies); on a failure the
    swarm is shut down (every link opened is closed) and the AttachError goes on with its one line."""
    try:
        for spec in specs:
            start(session, rq.Attach(spec=spec))
    except AttachError:
        session.swarm.shutdown()
        raise


def control(session: FlightSession, request: rq.Control) -> Started:
    """A user's controller flies the swarm: the streamer asks it for setpoints every tick."""
    take_over(session)
    session.controller = request.controller
    session.streamer.command_behaviour(request.controller, session.mission_time())
    return Started(new_step=True)


VERBS: Final[Mapping[type, Callable[[FlightSession, Any], Started]]] = {
    rq.Arm: arm,
    rq.Takeoff: takeoff,
    rq.Goto: goto,
    rq.FlyFormation: formation,
    rq.Flock: flock,
    rq.Follow: follow,
    rq.FollowAttached: follow_attached,
    rq.Swap: swap,
    rq.Hold: hold,
    rq.Pause: pause,
    rq.Land: land,
    rq.ReturnToLaunch: land,
    rq.Behaviours: behaviour,
    rq.InjectFault: fault,
    rq.Kill: fault,
    rq.PlanUpload: plan_upload,
    rq.PlanStart: plan_start,
    rq.PlanDownload: plan_download,
    rq.SetParam: param,
    rq.Control: control,
    rq.Attach: attach,
    rq.Require: require,
    rq.Detach: detach,
}
