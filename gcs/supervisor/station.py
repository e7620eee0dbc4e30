"""The supervisor behind ``swarm up``: telemetry, liveness, control requests, and the swarm's verbs.

Commands arrive from the control channel (gcs/supervisor/control.py) as JSON requests; each is one of the swarm's verbs
(gcs/supervisor/verbs.py), started over MAVLink with the messages a PX4 ground station would send and answered at
once with one JSON response (the channel must not block: a takeoff is started here, not waited for).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

from pymavlink.dialects.v20 import common as mavlink

from gcs.fleet.attach import DEFAULT_KEEP_IN_M, DEFAULT_MAX_DISTANCE_M, AttachSpec, parse_attach
from gcs.fleet.faults import fault_request
from gcs.fleet.losses import MAV_STATE_CRITICAL, LossPolicy
from gcs.fleet.swarm import Swarm, SwarmError
from gcs.fleet.telemetry import DroneView
from gcs.flight.formation import Formation
from gcs.mavlink.mission_transfer import MISSION_STATE_NAMES
from gcs.missions.mission_file import (
    TAKEOFF_ALT_M,
    build_flock,
    build_follow,
    build_follow_attached,
    build_formation,
)
from gcs.missions.plan_flight import PlanUsageError, copy_offsets, parse_drones, parse_offsets, spawn_offsets
from gcs.missions.qgc_plan import PlanFileError, load_plan, plan_text
from gcs.supervisor.session import FlightSession
from gcs.supervisor.verbs import VERBS, begin_report_step
from gcs.view.server import ViewServer

Say = Callable[[str], None]


class Station:
    """``swarm up``'s front-end: control requests carried out as the swarm's verbs (gcs/supervisor/verbs.py), each
    started and answered at once (the control channel must not block), plus status and the session's report."""

    def __init__(self, swarm: Swarm, say: Say, loss_policy: LossPolicy = LossPolicy.CONTINUE,
                 report_dir: Path | None = None, contact_distance_m: float = 0.0) -> None:  # fmt: skip
        """``report_dir``: record the session and write a flight report there at the end (``swarm up --report``)."""
        self.swarm = swarm
        self.say = say
        self.session = FlightSession.verb_by_verb(
            swarm, say, loss_policy, report_dir=report_dir, contact_distance_m=contact_distance_m, note=swarm_note(say)
        )
        self.stop_requested = False
        swarm.listeners.append(self._on_message)
        self.commands: dict[str, Callable[[dict[str, Any]], dict[str, Any]]] = {
            "ping": lambda _r: {"ok": True},
            "status": lambda _r: {"ok": True, "drones": self.status_rows()},
            "down": self._down,
            "takeoff": lambda r: self._verb(r, "takeoff", float(r.get("alt", TAKEOFF_ALT_M))),
            "formation": lambda r: self._verb(r, "formation", self._formation(r)),
            "flock": lambda r: self._verb(r, "flock", build_flock(dict(r.get("fields", {})))),
            "follow": lambda r: self._verb(r, "follow", build_follow(dict(r.get("fields", {})))),
            "follow_attached": lambda r: self._verb(r, "follow_attached",
                                                    build_follow_attached(dict(r.get("fields", {})))),
            "goto": lambda r: self._verb(r, "goto", float(r["north_m"]), float(r["east_m"]),
                                         None if r.get("alt_m") is None else float(r["alt_m"])),
            "land": lambda r: self._verb(r, "land"),
            "rtl": lambda r: self._verb(r, "rtl"),
            "behaviour": lambda r: self._verb(r, "behaviour", run=_start_or_stop(r.get("action"))),
            "fault": self._fault,
            "plan_upload": self._plan_upload,
            "plan_start": self._plan_start,
            "plan_download": lambda r: {"ok": True, "plan": plan_text(VERBS["plan_download"](
                self.session, r.get("sysid")).value)},
            "attach": lambda r: self._verb(r, "attach", _attach_spec(r)),
            "detach": lambda r: self._verb(r, "detach", r.get("sysid")),
            "require": lambda r: self._verb(r, "require", [dict(r.get("fields", {}))], base=Path(str(r.get("cwd",
                                                                                                          ".")))),
        }  # fmt: skip

    def serve(self, server: ViewServer) -> None:
        """Feed the live view served by ``server`` from now on (gcs/view)."""
        self.session.serve(server)

    def end_session(self) -> None:
        """Before the swarm shuts down (its clock goes with it): the last step ends now. The shutdown's landing
        traffic is still recorded."""
        self.session.end_step(self.mission_time())

    def write_report(self) -> Path | None:
        """After the swarm is shut down: the flight report of the session (None without ``report_dir``)."""
        return self.session.write_report()

    def _on_message(self, msg: Any, _now_s: float) -> None:
        """A drone's warnings (collisions, failsafes, fault injections) on the supervisor's output, as a ground
        station shows them."""
        if msg.get_type() == "STATUSTEXT" and msg.severity <= mavlink.MAV_SEVERITY_WARNING:
            self.say(f"  sysid {msg.get_srcSystem()}: {msg.text}")

    # ---- periodic work ---------------------------------------------------------------------------------------------
    def mission_time(self) -> float:
        """Simulated seconds since the supervisor started (formations run on the drones' clock)."""
        return self.session.mission_time()

    def tick(self) -> None:
        self.session.tick(self.mission_time())

    def watch(self) -> None:
        """Report a swarm that cannot keep the requested pace (once), and each lost drone once, with the loss
        policy applied."""
        self.session.pace.tick()
        self.session.watch_losses(self.mission_time())

    # ---- requests --------------------------------------------------------------------------------------------------
    def handle(self, request: dict[str, Any]) -> dict[str, Any]:
        handler = self.commands.get(request["cmd"])
        if handler is None:
            return {"ok": False, "error": f"unknown command {request['cmd']!r}"}
        try:
            return handler(request)
        except (PlanUsageError, PlanFileError) as exc:
            return {"ok": False, "usage": True, "error": str(exc)}
        except SwarmError as exc:
            return {"ok": False, "error": str(exc)}
        except ValueError as exc:  # a verb's check: the user's mistake
            return {"ok": False, "usage": True, "error": str(exc)}

    def _verb(self, request: dict[str, Any], name: str, *args: Any, **kwargs: Any) -> dict[str, Any]:
        """Start a verb and answer; one that changes what the swarm flies begins the report's next step."""
        started = VERBS[name](self.session, *args, **kwargs)
        begin_report_step(self.session, name, started, shape=str(request["shape"]) if "shape" in request else None)
        return {"ok": True, "result": started.result} if started.result else {"ok": True}

    def _down(self, _request: dict[str, Any]) -> dict[str, Any]:
        self.stop_requested = True
        return {"ok": True}

    def _formation(self, request: dict[str, Any]) -> Formation:
        """The formation a request names; a grid without rows is made as square as the surviving drones allow."""
        fields = dict(request.get("fields", {}))
        if request.get("shape") == "grid" and not fields.get("rows"):
            n = len(self.swarm.active_sysids)
            fields["cols"] = max(1, math.ceil(math.sqrt(n)))
            fields["rows"] = math.ceil(n / fields["cols"])
        return build_formation(str(request.get("shape")), fields)

    def _fault(self, request: dict[str, Any]) -> dict[str, Any]:
        """``swarm fault``, ``swarm kill``: a MAVLink fault or a killed process."""
        fault = fault_request(request.get("kind"), request.get("motor"), request.get("for_s"))
        return self._verb(request, "fault", request.get("sysid"), fault)

    def _chosen(self, request: dict[str, Any]) -> list[int]:
        chosen = parse_drones(str(request.get("drones", "all")), self.swarm.sysids)
        chosen = [s for s in chosen if s not in self.swarm.losses]
        if not chosen:
            raise SwarmError("every chosen drone is lost")
        return chosen

    def _plan_upload(self, request: dict[str, Any]) -> dict[str, Any]:
        """``swarm plan upload``: each chosen drone its copy of a QGroundControl plan, moved by an offset
        (gcs/missions/plan_flight.py)."""
        chosen = self._chosen(request)
        path = Path(str(request.get("path")))
        plan = load_plan(path)
        offsets = copy_offsets(spawn_offsets(self.swarm), chosen, parse_offsets(str(request.get("offsets", "spawn"))))
        started = VERBS["plan_upload"](self.session, plan, offsets)
        self.session.note(f"plan {path.name}: {started.result}")
        return {"ok": True, "result": started.result}

    def _plan_start(self, request: dict[str, Any]) -> dict[str, Any]:
        return self._verb(request, "plan_start", self._chosen(request))

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
            rows.append({**_telemetry_row(d, now), "mission": self._mission_progress(sysid, d.mode)})
        for sysid, vehicle in self.swarm.attached.items():
            d = self.swarm.fleet.drones.get(sysid)
            if d is not None:
                lost = ", lost" if vehicle.lost else ""
                rows.append({**_telemetry_row(d, now),
                             "external": f"{vehicle.spec.role} on {vehicle.spec.url.describe()}{lost}"})  # fmt: skip
        return rows


def _telemetry_row(d: DroneView, now_s: float) -> dict[str, Any]:
    """A vehicle's status row from its telemetry (a simulated drone's or an attached one's)."""
    return {"sysid": d.sysid, "mode": d.mode, "armed": d.armed, "lat_deg": d.lat_deg, "lon_deg": d.lon_deg,
            "alt_m": d.relative_alt_m, "battery": d.battery_remaining, "link_age_s": d.link_age_s(now_s),
            "failsafe": failsafe_text(d.system_status, d.texts)}  # fmt: skip


def swarm_note(say: Say) -> Say:
    """What a verb did, as the supervisor says it: ``swarm: ...``."""
    return lambda text: say(f"swarm: {text}")


def _attach_spec(request: dict[str, Any]) -> AttachSpec:
    """``swarm attach``'s request as the attach verb takes it (AttachError, a ValueError of one line)."""
    key = request.get("signing_key")
    return parse_attach(str(request.get("url")), max_distance_m=float(request.get("max_distance_m",
                        DEFAULT_MAX_DISTANCE_M)), keep_in_m=float(request.get("keep_in_m", DEFAULT_KEEP_IN_M)),
                        signing_key_file=None if key is None else Path(str(key)))  # fmt: skip


def _start_or_stop(action: object) -> bool:
    if action not in ("start", "stop"):
        raise ValueError(f"behaviour must be start or stop, got {action!r}")
    return action == "start"


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
            + (f"  external: {r['external']}" if r.get("external") else "")
        )
    return "\n".join(lines)


def failsafe_text(system_status: int, texts: list[tuple[float, int, str]]) -> str | None:
    """While a drone reports MAV_STATE_CRITICAL (PX4: a failsafe acts), its last warning says which one."""
    if system_status != MAV_STATE_CRITICAL:
        return None
    warnings = [text for _t, severity, text in texts if severity <= mavlink.MAV_SEVERITY_WARNING]
    return warnings[-1] if warnings else "active"
