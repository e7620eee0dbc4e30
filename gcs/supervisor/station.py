"""The supervisor's main loop behind ``swarm up``: telemetry, liveness, control requests, and the swarm commands.

Commands arrive from the control channel (gcs/supervisor/control.py) as JSON requests; each is carried out over MAVLink
with the same messages a PX4 ground station would send, and answered with one JSON response.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

from pymavlink.dialects.v20 import common as mavlink

from gcs.command.degrade import apply_loss_policy, apply_regain
from gcs.command.procedures import PaceWatch, start_onboard_behaviours, stop_onboard_behaviours
from gcs.command.streamer import FormationStreamer
from gcs.fleet.faults import CRASH, FaultError, fault_request, result_text
from gcs.fleet.links import NeighbourPlan
from gcs.fleet.losses import MAV_STATE_CRITICAL, LossPolicy, loss_line, regain_line
from gcs.fleet.swarm import Swarm, SwarmError
from gcs.flight.frames import SwarmFrame
from gcs.mavlink.mission_transfer import MISSION_STATE_NAMES
from gcs.missions.mission_file import build_flock, build_follow, build_formation
from gcs.missions.plan_flight import (
    PlanUsageError,
    copy_offsets,
    download_plan,
    parse_drones,
    parse_offsets,
    spawn_offsets,
    start_missions,
    upload_plan,
)
from gcs.missions.qgc_plan import PlanFileError, load_plan, plan_text
from gcs.record.recorder import FlightRecorder
from gcs.record.recording import EventRecord, FaultRecord, FlightRecording, StepRecord
from gcs.view.feed import ViewFeed
from gcs.view.report import write_report
from gcs.view.server import ViewServer

Say = Callable[[str], None]


# Commands that start what the report calls a step (name and kind taken from the request)
STEP_COMMANDS = ("takeoff", "formation", "flock", "follow", "goto", "land", "rtl", "plan_start", "behaviour")


class Station:
    def __init__(self, swarm: Swarm, say: Say, loss_policy: LossPolicy = LossPolicy.CONTINUE,
                 report_dir: Path | None = None, contact_distance_m: float = 0.0) -> None:  # fmt: skip
        """``report_dir``: record the session and write a flight report there at the end (``swarm up --report``)."""
        self.swarm = swarm
        self.say = say
        self.loss_policy = loss_policy
        self._policy_taken = False  # a loss policy other than continue has taken the survivors out of the flight
        self.streamer = FormationStreamer(swarm, SwarmFrame(swarm.plan.origin))
        self._t0 = swarm.clock()
        self.stop_requested = False
        self._pace = PaceWatch(swarm, say)
        swarm.listeners.append(self._on_message)
        self.report_dir = report_dir
        self.recording = FlightRecording(
            mission_name="swarm-up", n_drones=swarm.plan.n_drones, collision_radius_m=contact_distance_m
        )
        self.recording.loss_policy = loss_policy.value
        self.recording.signing_key_id = swarm.signing_key_id
        self.recording.neighbours = NeighbourPlan(relay=swarm.relay is not None, mesh=swarm.plan.mesh).describe()
        self.recorder: FlightRecorder | None = None
        self.view: ViewFeed | None = None  # the live view, if one is served (gcs/view)
        if report_dir is not None:
            report_dir.mkdir(parents=True, exist_ok=True)
            self.recorder = FlightRecorder(self.streamer, self.recording, self.mission_time,
                                           report_dir / "flight.tlog", say=None)  # fmt: skip
        self._step: StepRecord | None = None  # the command being flown, for the report

    def serve(self, server: ViewServer) -> None:
        """Feed the live view served by ``server`` from now on (gcs/view): the streamer's slots, the drones'
        telemetry, and the live recording's events when there is one."""
        self.view = ViewFeed(server, self.streamer, live=self.recorder.live if self.recorder is not None else None)

    def begin_step(self, request: dict[str, Any]) -> None:
        """A command that changes what the swarm flies ends the report's current step and starts the next."""
        now = self.mission_time()
        self._end_step(now)
        cmd = request["cmd"].removesuffix("_start")  # plan_start: a plan step
        name = str(request.get("shape", cmd)) if cmd == "formation" else cmd
        kind = "formation" if cmd == "goto" else cmd
        alt = float(request.get("alt", 3.0)) if cmd == "takeoff" else None
        index = len(self.recording.steps)
        self._step = StepRecord(index=index, name=name, kind=kind, start_s=now, end_s=now, target_alt_m=alt)

    def _end_step(self, now: float) -> None:
        if self._step is not None:
            self.recording.steps.append(dataclasses.replace(self._step, end_s=now))
            self._step = None

    def end_session(self) -> None:
        """Before the swarm shuts down (its clock goes with it): the last step ends now. The shutdown's landing
        traffic is still recorded."""
        self._end_step(self.mission_time())

    def write_report(self) -> Path | None:
        """After the swarm is shut down: the flight report of the session (None without ``report_dir``)."""
        if self.report_dir is None or self.recorder is None:
            return None
        self._end_step(self.recording.steps[-1].end_s if self.recording.steps else 0.0)
        self.recording.losses = list(self.swarm.losses.values())
        self.recording.regained = list(self.swarm.regained)
        self.recording.link_counters = self.swarm.harness.link_counters()
        self.recorder.close()
        return write_report(self.recording, self.report_dir)

    def _on_message(self, msg: Any, _now_s: float) -> None:
        """A drone's warnings (collisions, failsafes, fault injections) on the supervisor's output, as a ground
        station shows them."""
        if msg.get_type() == "STATUSTEXT" and msg.severity <= mavlink.MAV_SEVERITY_WARNING:
            self.say(f"  sysid {msg.get_srcSystem()}: {msg.text}")

    # ---- periodic work ---------------------------------------------------------------------------------------------
    def mission_time(self) -> float:
        """Simulated seconds since the supervisor started (formations run on the drones' clock)."""
        return self.swarm.clock() - self._t0

    def tick(self) -> None:
        now = self.mission_time()
        self.streamer.tick(now)
        if self.view is not None:
            self.view.tick(now)

    def watch(self, now_s: float) -> None:
        """Record and report each lost drone once (one line), apply the loss policy, and report a swarm that cannot
        keep the requested pace (once)."""
        self._pace.tick()
        for loss in self.swarm.detect_losses(self.mission_time()):
            self.say(loss_line(loss))
            line = apply_loss_policy(self.loss_policy, self.streamer, loss, self.mission_time())
            self._policy_taken = self._policy_taken or self.loss_policy is not LossPolicy.CONTINUE
            if line is not None:
                self.say(f"swarm: {line}")
                self.recording.policy_events.append(EventRecord(time_s=loss.time_s, sysid=loss.sysid, text=line))
        now = self.mission_time()
        for loss in self.swarm.detect_regains(now):
            self.say(regain_line(loss))
            line = apply_regain(self.loss_policy, self.streamer, loss, now, policy_taken=self._policy_taken)
            if line is not None:
                self.say(f"swarm: {line}")
                self.recording.policy_events.append(EventRecord(time_s=now, sysid=loss.sysid, text=line))

    # ---- requests --------------------------------------------------------------------------------------------------
    def handle(self, request: dict[str, Any]) -> dict[str, Any]:
        response = self._handle(request)
        if response.get("ok") and request["cmd"] in STEP_COMMANDS:
            self.begin_step(request)
        return response

    def _handle(self, request: dict[str, Any]) -> dict[str, Any]:
        cmd = request["cmd"]
        try:
            if cmd == "ping":
                return {"ok": True}
            if cmd == "status":
                return {"ok": True, "drones": self.status_rows()}
            if cmd == "takeoff":
                return self.takeoff(float(request.get("alt", 3.0)))
            if cmd == "formation":
                fields = dict(request.get("fields", {}))
                if request.get("shape") == "grid" and not fields.get("rows"):
                    n = len(self.swarm.active_sysids)
                    fields["cols"] = max(1, math.ceil(math.sqrt(n)))
                    fields["rows"] = math.ceil(n / fields["cols"])
                formation = build_formation(str(request.get("shape")), fields)
                self.streamer.command(formation, self.mission_time())
                return {"ok": True}
            if cmd == "flock":
                self.streamer.command_flock(build_flock(dict(request.get("fields", {}))), self.mission_time())
                return {"ok": True}
            if cmd == "follow":
                self.streamer.command_follow(build_follow(dict(request.get("fields", {}))), self.mission_time())
                return {"ok": True}
            if cmd == "goto":
                return self.goto(request)
            if cmd == "land":
                self.streamer.hand_over(self.swarm.land_all)
                return {"ok": True}
            if cmd == "rtl":
                self.streamer.hand_over(lambda: self.swarm.land_all(return_to_launch=True))
                return {"ok": True}
            if cmd == "behaviour":
                return self.behaviour(request.get("action"))
            if cmd == "down":
                self.stop_requested = True
                return {"ok": True}
            if cmd == "fault":
                return self.fault(request)
            if cmd in ("plan_upload", "plan_start", "plan_download"):
                return self.plan(request)
        except (PlanUsageError, PlanFileError) as exc:
            return {"ok": False, "usage": True, "error": str(exc)}
        except (SwarmError, FaultError, ValueError) as exc:
            return {"ok": False, "error": str(exc)}
        return {"ok": False, "error": f"unknown command {cmd!r}"}

    def behaviour(self, action: object) -> dict[str, Any]:
        """``swarm behaviour start|stop``: every drone's onboard behaviour on (BHV_EN = 1) or off (0, then Hold)."""
        if action == "start":
            sysids = start_onboard_behaviours(self.swarm, self.streamer)
        elif action == "stop":
            sysids = stop_onboard_behaviours(self.swarm)
        else:
            return {"ok": False, "usage": True, "error": f"behaviour must be start or stop, got {action!r}"}
        return {"ok": True, "result": f"sysid {sysids}: behaviour {action}"}

    def fault(self, request: dict[str, Any]) -> dict[str, Any]:
        """Inject a fault into one drone (``swarm fault``, ``swarm kill``): a MAVLink fault or a killed process."""
        sysid = request.get("sysid")
        if isinstance(sysid, bool) or not isinstance(sysid, int) or sysid not in self.swarm.sysids:
            sysids = self.swarm.sysids
            known = f"{sysids[0]}..{sysids[-1]}" if sysids else "none"
            return {"ok": False, "usage": True, "error": f"no drone with sysid {sysid!r} (sysids {known})"}
        if sysid in self.swarm.losses:
            return {"ok": False, "error": f"drone {sysid} is already lost ({self.swarm.losses[sysid].cause})"}
        try:
            fault = fault_request(request.get("kind"), request.get("motor"), request.get("for_s"))
        except FaultError as exc:
            return {"ok": False, "usage": True, "error": str(exc)}
        if fault.kind == CRASH:
            done = self.swarm.kill(sysid)
            self.say(f"swarm: fault: drone {sysid}: {done}")
            self._record_fault(sysid, fault.describe(), done)
            return {"ok": True, "result": done}
        ack = self.swarm.inject_fault(sysid, fault)
        self.say(f"swarm: fault {fault.describe()} on drone {sysid}: {result_text(ack.result)}")
        self._record_fault(sysid, fault.describe(), result_text(ack.result))
        if not ack.ok:
            return {"ok": False, "error": f"drone {sysid} refused fault {fault.describe()}: {result_text(ack.result)}"}
        return {"ok": True, "result": result_text(ack.result)}

    def plan(self, request: dict[str, Any]) -> dict[str, Any]:
        """``swarm plan upload/start/download``: a QGroundControl plan to some drones (each its own copy, moved by
        an offset), AUTO.MISSION on them, or one drone's mission and fence back as a plan
        (gcs/missions/plan_flight.py)."""
        cmd = request["cmd"]
        if cmd == "plan_download":
            sysid = request.get("sysid")
            if isinstance(sysid, bool) or not isinstance(sysid, int) or sysid not in self.swarm.sysids:
                raise PlanUsageError(f"no drone with sysid {sysid!r} (sysids {self.swarm.sysids})")
            return {"ok": True, "plan": plan_text(download_plan(self.swarm, sysid))}
        chosen = parse_drones(str(request.get("drones", "all")), self.swarm.sysids)
        chosen = [s for s in chosen if s not in self.swarm.losses]
        if not chosen:
            return {"ok": False, "error": "every chosen drone is lost"}
        if cmd == "plan_start":
            self.streamer.hand_over(lambda: start_missions(self.swarm, chosen))  # OFFBOARD -> AUTO.MISSION
            return {"ok": True, "result": f"AUTO.MISSION on sysid {', '.join(map(str, chosen))}"}
        plan = load_plan(Path(str(request.get("path"))))
        offsets = copy_offsets(spawn_offsets(self.swarm), chosen, parse_offsets(str(request.get("offsets", "spawn"))))
        upload_plan(self.swarm, plan, offsets)
        fence = f" and {len(plan.polygons) + len(plan.circles)} fence zone(s)" if plan.has_fence else ""
        rally = f"; {len(plan.rally_points)} rally point(s) not uploaded (not stored)" if plan.rally_points else ""
        text = f"{len(plan.items)} items{fence} uploaded to sysid {', '.join(map(str, chosen))}{rally}"
        self.say(f"swarm: plan {Path(str(request.get('path'))).name}: {text}")
        return {"ok": True, "result": text}

    def _record_fault(self, sysid: int, what: str, result: str) -> None:
        record = FaultRecord(time_s=self.mission_time(), sysid=sysid, fault=what, result=result)
        self.recording.faults.append(record)

    def takeoff(self, alt_m: float) -> dict[str, Any]:
        if not (math.isfinite(alt_m) and 0.5 <= alt_m <= 100.0):
            return {"ok": False, "error": f"--alt must be between 0.5 and 100 m, got {alt_m:g}"}
        self.swarm.arm_all()
        self.swarm.takeoff_all(alt_m)
        return {"ok": True}

    def goto(self, request: dict[str, Any]) -> dict[str, Any]:
        """Move the current formation's centre to north/east (and altitude), keeping its shape."""
        formation = self.streamer.formation
        if formation is None or not self.streamer.active:
            return {"ok": False, "error": "no formation is being flown: use 'swarm formation' first"}
        north, east = float(request["north_m"]), float(request["east_m"])
        if not (math.isfinite(north) and math.isfinite(east)):
            return {"ok": False, "error": "north and east must be finite numbers"}
        changes: dict[str, Any] = {"centre_ne_m": (north, east)}
        if request.get("alt_m") is not None:
            changes["alt_m"] = float(request["alt_m"])
        moved = dataclasses.replace(formation, **changes)  # type: ignore[type-var]
        self.streamer.command(moved, self.mission_time())
        return {"ok": True}

    def _mission_progress(self, sysid: int, mode: str) -> str | None:
        """``item 3/5 active`` while a drone flies a mission or has finished one (its MISSION_CURRENT), else None."""
        progress = self.swarm.mission_progress.drones.get(sysid)
        if progress is None or progress.total == 0:
            return None
        state = MISSION_STATE_NAMES.get(progress.state, "")
        if mode != "AUTO.MISSION" and state != "complete":
            return None
        return f"item {progress.current_seq + 1}/{progress.total} {state}".rstrip()

    def status_rows(self) -> list[dict[str, Any]]:
        now = self.swarm.clock()
        rows = []
        for sysid in self.swarm.sysids:
            d = self.swarm.fleet.drones.get(sysid)
            loss = self.swarm.losses.get(sysid)
            if loss is not None:
                down = loss.down_ne_m
                where = "" if down is None else f", down at {down[0]:.1f} m N {down[1]:.1f} m E"
                rows.append({"sysid": sysid, "mode": "LOST", "detail": f"t={loss.time_s:.1f} s: {loss.cause}{where}"})
                continue
            if d is None:
                rows.append({"sysid": sysid, "mode": "NO LINK"})
                continue
            rows.append(
                {
                    "sysid": sysid,
                    "mode": d.mode,
                    "armed": d.armed,
                    "lat_deg": d.lat_deg,
                    "lon_deg": d.lon_deg,
                    "alt_m": d.relative_alt_m,
                    "battery": d.battery_remaining,
                    "link_age_s": d.link_age_s(now),
                    "failsafe": failsafe_text(d.system_status, d.texts),
                    "mission": self._mission_progress(sysid, d.mode),
                }
            )
        return rows


def format_status(rows: list[dict[str, Any]]) -> str:
    lines = [f"{'sysid':>5}  {'mode':<14} {'armed':<5} {'lat':>11} {'lon':>11} {'alt m':>6} {'batt':>5} {'link s':>6}"]
    for r in rows:
        if "armed" not in r:
            detail = f"  {r['detail']}" if r.get("detail") else ""
            lines.append(f"{r['sysid']:>5}  {r['mode']}{detail}")
            continue
        batt = f"{r['battery']:.0%}" if r["battery"] == r["battery"] else "?"
        lines.append(
            f"{r['sysid']:>5}  {r['mode']:<14} {'yes' if r['armed'] else 'no':<5} {r['lat_deg']:>11.7f} "
            f"{r['lon_deg']:>11.7f} {r['alt_m']:>6.2f} {batt:>5} {r['link_age_s']:>6.1f}"
            + (f"  FAILSAFE: {r['failsafe']}" if r.get("failsafe") else "")
            + (f"  mission: {r['mission']}" if r.get("mission") else "")
        )
    return "\n".join(lines)


def failsafe_text(system_status: int, texts: list[tuple[float, int, str]]) -> str | None:
    """While a drone reports MAV_STATE_CRITICAL (PX4: a failsafe acts), its last warning says which one."""
    if system_status != MAV_STATE_CRITICAL:
        return None
    warnings = [text for _t, severity, text in texts if severity <= mavlink.MAV_SEVERITY_WARNING]
    return warnings[-1] if warnings else "active"
