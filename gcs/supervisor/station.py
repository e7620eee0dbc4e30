"""The supervisor behind ``swarm up``: telemetry, liveness, control requests, and the swarm's verbs.

Commands arrive from the control channel (gcs/supervisor/control.py) as JSON; each is decoded into a request
(gcs/supervisor/commands.py) and started as the swarm's verb (gcs/supervisor/verbs.py), over MAVLink with the messages
a PX4 ground station would send, and answered at once with one JSON response (the channel must not block: a takeoff
is started here, not waited for).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

from pymavlink.dialects.v20 import common as mavlink

from gcs.fleet.losses import MAV_STATE_CRITICAL, LossPolicy
from gcs.fleet.picture import Placed
from gcs.fleet.swarm import Swarm, SwarmError
from gcs.fleet.telemetry import DroneView
from gcs.mavlink.mission_transfer import MISSION_STATE_NAMES
from gcs.missions.plan_flight import PlanUsageError
from gcs.missions.qgc_plan import PlanFileError, plan_text
from gcs.supervisor import requests as rq
from gcs.supervisor.commands import DECODERS, decode
from gcs.supervisor.session import FlightSession
from gcs.supervisor.verbs import start
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
        swarm.router.listeners.append(self._on_message)
        # the session's own commands; every other ``cmd`` is a verb's (gcs/supervisor/commands.py DECODERS)
        self.commands: dict[str, Callable[[dict[str, Any]], dict[str, Any]]] = {
            "ping": lambda _r: {"ok": True},
            "status": lambda _r: {"ok": True, "drones": self.status_rows()},
            "down": self._down,
        }

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
        if handler is None and request["cmd"] not in DECODERS:
            return {"ok": False, "error": f"unknown command {request['cmd']!r}"}
        try:
            return handler(request) if handler is not None else self._verb(request)
        except (PlanUsageError, PlanFileError) as exc:
            return {"ok": False, "usage": True, "error": str(exc)}
        except SwarmError as exc:
            return {"ok": False, "error": str(exc)}
        except ValueError as exc:  # a verb's check: the user's mistake
            return {"ok": False, "usage": True, "error": str(exc)}

    def _verb(self, command: dict[str, Any]) -> dict[str, Any]:
        """Decode a command, start its verb and answer; one that changes what the swarm flies begins the report's
        next step."""
        request = decode(command, self.swarm)
        started = start(self.session, request)
        if isinstance(request, rq.PlanDownload):
            return {"ok": True, "plan": plan_text(started.value)}
        if isinstance(request, rq.PlanUpload):
            self.session.note(f"plan {Path(str(command.get('path'))).name}: {started.result}")
        return {"ok": True, "result": started.result} if started.result else {"ok": True}

    def _down(self, _request: dict[str, Any]) -> dict[str, Any]:
        self.stop_requested = True
        return {"ok": True}

    def _mission_progress(self, sysid: int, mode: str) -> str | None:
        """``item 3/5 active`` while a drone flies a mission or has finished one (its MISSION_CURRENT), else None."""
        progress = self.swarm.missions.progress.drones.get(sysid)
        if progress is None or progress.total == 0:
            return None
        state = MISSION_STATE_NAMES.get(progress.state, "")
        if mode != "AUTO.MISSION" and state != "complete":
            return None
        return f"item {progress.current_seq + 1}/{progress.total} {state}".rstrip()

    def status_rows(self) -> list[dict[str, Any]]:
        now = self.swarm.clock.now()
        rows = []
        for sysid in self.swarm.liveness.sysids:
            d = self.swarm.fleet.drones.get(sysid)
            loss = self.swarm.liveness.losses.get(sysid)
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
                    **_telemetry_row(d, self.swarm.picture.placed(d.sysid), now),
                    "mission": self._mission_progress(sysid, d.mode),
                }
            )
        for sysid, vehicle in self.swarm.attachments.vehicles.items():
            d = self.swarm.fleet.drones.get(sysid)
            if d is not None:
                lost = ", lost" if vehicle.lost else ""
                rows.append({**_telemetry_row(d, self.swarm.picture.placed(d.sysid), now),
                             "external": f"{vehicle.spec.role} on {vehicle.spec.url.describe()}{lost}"})  # fmt: skip
        return rows


def _telemetry_row(d: DroneView, placed: Placed | None, now_s: float) -> dict[str, Any]:
    """A vehicle's status row from its telemetry (a simulated drone's or an attached one's) and its place in the
    swarm frame (``pos_ned_m``, metres from the swarm's origin; None before it has said)."""
    return {"sysid": d.sysid, "mode": d.mode, "armed": d.armed, "lat_deg": d.lat_deg, "lon_deg": d.lon_deg,
            "alt_m": d.relative_alt_m, "battery": d.battery_remaining, "link_age_s": d.link_age_s(now_s),
            "failsafe": failsafe_text(d.system_status, d.texts),
            "pos_ned_m": list(placed.pos_ned_m) if placed is not None else None}  # fmt: skip


def swarm_note(say: Say) -> Say:
    """What a verb did, as the supervisor says it: ``swarm: ...``."""
    return lambda text: say(f"swarm: {text}")


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
