"""The supervisor of an API session, in a thread of its own; both faces of the API (async and blocking) post work
to it and wait for the answer.

Why a thread: the supervisor (gcs/fleet/swarm.py) is a synchronous loop that waits on its sockets and, in lockstep, on
the simulation's gate. Run in the user's event loop it would stall every other task of theirs; rewritten for asyncio it
would be a second supervisor to keep in step with the first. In its own thread it stays the one supervisor that
``swarm up`` and ``swarm fly`` run, and the user's loop only awaits futures.

Clock: paced, the thread keeps the swarm going between calls (real time does not stop). In lockstep it does not: the
simulation advances only inside a call (``sleep``, ``wait_until``, ``takeoff``, ...), so a script's outcome does not
depend on how long its own Python takes between calls, and the same script with the same seeds flies the same.

Work runs one call at a time, in order. The user's code called from the thread (a controller each tick, a
``wait_until`` predicate) runs there too, between two pumps of the loop, so it sees a consistent swarm.
"""

from __future__ import annotations

import concurrent.futures
import json
import logging
import math
import queue
import threading
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar

from pymavlink.dialects.v20 import common as mavlink

from gcs.api.types import ControllerError, DroneState, Event, FlightResult, LaunchOptions
from gcs.fleet.harness import Simulation, SpawnPlan
from gcs.fleet.losses import MAV_STATE_CRITICAL
from gcs.fleet.swarm import Swarm, SwarmError
from gcs.flight.behaviours import NAN3, SwarmState
from gcs.flight.formation import SETPOINT_STREAM_HZ, Setpoint
from gcs.flight.frames import Vec3
from gcs.flight.onboard import absolute_spec
from gcs.mavlink.statustext import StatusTextAssembler
from gcs.supervisor import requests as rq
from gcs.supervisor.session import FlightSession
from gcs.supervisor.station import failsafe_text, swarm_note
from gcs.supervisor.verbs import carry_out, start
from gcs.view.report import METRICS_FILE
from gcs.view.server import ViewServer, serve_view

log = logging.getLogger(__name__)

T = TypeVar("T")
Controller = Callable[[float, Mapping[int, DroneState]], Mapping[int, "Setpoint | Vec3"]]
_IDLE_PUMP_S = 0.02  # paced: the idle loop's wait for traffic, and so the longest a posted call waits to start
_NOT_IN_AIR = (mavlink.MAV_LANDED_STATE_UNDEFINED, mavlink.MAV_LANDED_STATE_ON_GROUND)


class SessionClosed(RuntimeError):
    """The session has ended (closed, or its supervisor failed): nothing more can be asked of it."""


class _Cancelled(BaseException):
    """Raised inside the thread's current call when the session is closed under it (Ctrl-C)."""


def _as_setpoint(value: Setpoint | Vec3) -> Setpoint:
    """A user's setpoint: a ``Setpoint``, or a bare (north, east, down) position."""
    if isinstance(value, Setpoint):
        return value
    north, east, down = (float(v) for v in value)
    return Setpoint(pos_ned_m=(north, east, down), vel_ned_mps=NAN3, acc_ned_mps2=NAN3, yaw_rad=math.nan)


class ControllerBehaviour:
    """A user's function as a behaviour the streamer runs every tick (gcs/flight/behaviours.py ``Behaviour``): it gets
    the swarm's time and every drone's state and returns setpoints for the drones it commands. If it raises, the error
    is kept for the engine (which holds every drone) and it commands nothing more."""

    def __init__(self, controller: Controller, states: Callable[[], dict[int, DroneState]]) -> None:
        self.controller = controller
        self._states = states
        self._targets: dict[int, Vec3] = {}
        self.error: BaseException | None = None

    def setpoints(self, now_s: float, state: SwarmState) -> dict[int, Setpoint]:
        if self.error is not None:
            return {}
        try:
            out = {int(sysid): _as_setpoint(sp) for sysid, sp in self.controller(now_s, self._states()).items()}
        except Exception as exc:
            self.error = exc
            return {}
        self._targets = {s: sp.pos_ned_m for s, sp in out.items() if all(math.isfinite(v) for v in sp.pos_ned_m)}
        return out

    def targets(self) -> dict[int, Vec3]:
        return dict(self._targets)


@dataclass(slots=True)
class _Call:
    work: Callable[[], Any]
    future: concurrent.futures.Future[Any]


class Engine:
    """One swarm and its supervisor in a thread. ``start`` spawns it (and raises what stopped it), ``call`` runs
    work in the thread, ``close`` lands, stops every drone and writes the report."""

    def __init__(self, options: LaunchOptions, simulation: Simulation, *, say: Callable[[str], None] | None = None,
                 on_event: Callable[[Event], None] | None = None) -> None:  # fmt: skip
        self.options = options
        self._simulation = simulation
        self._say = say or (lambda text: log.info("%s", text))
        self._on_event = on_event
        self._calls: queue.SimpleQueue[_Call | None] = queue.SimpleQueue()
        self._ready: concurrent.futures.Future[None] = concurrent.futures.Future()
        self._result: concurrent.futures.Future[FlightResult] = concurrent.futures.Future()
        self._cancel = threading.Event()
        self._closing = False
        self._states: dict[int, DroneState] = {}  # replaced whole at each tick: readers in other threads see a snapshot
        self._time_s = 0.0
        self._texts = StatusTextAssembler()
        self._pending: ControllerError | None = None  # a controller that failed between calls (paced), for the next
        self._status: dict[int, int] = {}  # each drone's last HEARTBEAT system_status (failsafe events)
        self._thread = threading.Thread(target=self._main, name="swarm-supervisor", daemon=True)
        self.swarm: Swarm | None = None
        self.session: FlightSession | None = None
        self.view: ViewServer | None = None  # the live view, when asked for

    # ---- from any thread -------------------------------------------------------------------------------------------
    def start_thread(self) -> None:
        """Spawn the swarm in the supervisor's thread; ``ready`` completes once every drone is up (or with what
        stopped it: SpawnError, one line)."""
        self._thread.start()

    @property
    def ready(self) -> concurrent.futures.Future[None]:
        return self._ready

    def submit(self, work: Callable[[], T]) -> concurrent.futures.Future[T]:
        """Run ``work`` in the supervisor's thread after the calls before it; its result or exception in the future."""
        future: concurrent.futures.Future[T] = concurrent.futures.Future()
        if self._closing:
            future.set_exception(SessionClosed("the swarm session is closed"))
            return future
        self._calls.put(_Call(work, future))
        return future

    def close(self, *, interrupt: bool = False) -> concurrent.futures.Future[FlightResult]:
        """Land what flies, stop every drone, write the report; ``interrupt`` first ends the call in progress (Ctrl-C).
        The future holds the outcome; a second close returns the same future."""
        if interrupt:
            self._cancel.set()
        if not self._closing:
            self._closing = True
            self._calls.put(None)
        return self._result

    def drones(self) -> dict[int, DroneState]:
        """Every drone's state at the last tick (a snapshot: it does not change under the caller)."""
        return self._states

    @property
    def time_s(self) -> float:
        """The swarm's clock at the last tick: simulated seconds since the drones came up."""
        return self._time_s

    # ---- in the supervisor's thread ------------------------------------------------------------------------------
    def _main(self) -> None:
        try:
            self._up()
        except BaseException as exc:
            self._ready.set_exception(exc)
            self._result.set_exception(SessionClosed(f"the swarm did not start: {exc}"))
            self._stop_swarm()
            return
        self._ready.set_result(None)
        try:
            self._serve()
        finally:
            try:
                self._result.set_result(self._shut_down())
            except BaseException as exc:
                self._result.set_exception(exc)

    def _up(self) -> None:
        o = self.options
        speed = o.speed if o.speed is not None else (0.0 if o.lockstep else 1.0)
        plan = SpawnPlan(n_drones=o.drones, spacing_m=o.spacing_m, layout=o.layout, origin=o.origin,
                         speed_factor=speed, lockstep=o.lockstep, lockstep_quantum=o.quantum,
                         first_instance=o.first_instance, airframe=o.airframe, seed=o.seed, log_dir=o.log_dir,
                         drones_per_process=o.drones_per_process, signing_key_file=o.signing_key_file,
                         links=o.links, mesh=o.neighbours.mesh, behaviour=self._behaviour(),
                         gcs_sysid=o.gcs_sysid)  # fmt: skip
        contact = self._simulation.contact_distance_m(o.airframe)
        if o.view:  # before anything starts: a port that cannot be had is a ValueError (ViewError) of one line
            self.view = serve_view(o.view_port)
            self._say(f"swarm: live view on {self.view.url}")
        self.swarm = swarm = Swarm(plan, self._simulation.harness(plan), forward=o.forward, relay=o.neighbours.relayed)
        self.session = session = FlightSession.verb_by_verb(
            swarm,
            self._say,
            o.loss_policy,
            report_dir=o.report_dir,
            contact_distance_m=contact,
            note=swarm_note(self._say),
        )
        session.waiting_tick = self._tick
        if self.view is not None:
            session.serve(self.view)
        swarm.router.listeners.append(self._on_message)
        for spec in o.attach_specs():  # before the drones start: a bad one (AttachError, one line) starts nothing
            start(session, rq.Attach(spec=spec))
        swarm.up(ready_timeout_s=o.ready_timeout_s)
        for name, value in o.params.items():
            start(session, rq.SetParam(name=name, value=value))
        start(session, rq.Require(invariants=tuple(o.invariants), base=Path.cwd(), stop=o.stop_on_violation))
        # ready means every drone has a home and a position, so states and formations can use them at once
        if not swarm.pump.wait_until(lambda: all(math.isfinite(s.pos_ned_m[0]) for s in self._snapshot().values()),
                                     o.ready_timeout_s, tick=self._tick):  # fmt: skip
            raise SwarmError(f"not every drone reported its home and position within {o.ready_timeout_s:g} s")
        self._publish()

    def _behaviour(self) -> str | None:
        """The onboard behaviour, made absolute and loaded as the drones will (ValueError: one line)."""
        spec = self.options.behaviour
        if spec is None:
            return None
        absolute = absolute_spec(spec, Path.cwd())
        self._simulation.check_behaviour(absolute)
        return absolute

    def _serve(self) -> None:
        swarm = self.swarm
        assert swarm is not None
        while not self._cancel.is_set():
            try:
                call = self._calls.get(block=swarm.plan.lockstep)  # lockstep: the clock stands still between calls
            except queue.Empty:  # paced: keep the swarm going
                swarm.pump.once(_IDLE_PUMP_S)
                try:
                    self._tick(swarm.clock.now())
                except ControllerError as exc:
                    self._pending = exc
                except _Cancelled:
                    break
                continue
            if call is None:
                return
            if not call.future.set_running_or_notify_cancel():
                continue
            try:
                if self._pending is not None:
                    failed, self._pending = self._pending, None
                    raise failed
                result = call.work()
                self._publish()
                call.future.set_result(result)
            except _Cancelled:
                call.future.set_exception(SessionClosed("the swarm session was closed during this call"))
                return
            except BaseException as exc:
                self._publish()
                call.future.set_exception(exc)
        # closed under a call: whatever else was posted will not run
        while True:
            try:
                pending = self._calls.get_nowait()
            except queue.Empty:
                break
            if pending is not None:
                pending.future.set_exception(SessionClosed("the swarm session is closed"))

    def _tick(self, now_s: float) -> None:
        """Every pass of a waiting loop: the streamer's setpoints, losses and returns, the snapshot, the controller's
        health; a close (Ctrl-C) ends the call in progress from here."""
        if self._cancel.is_set():
            raise _Cancelled
        session, swarm = self.session, self.swarm
        assert session is not None and swarm is not None
        session.tick(session.mission_time())
        liveness = swarm.liveness
        losses, regained, policy = set(liveness.losses), len(liveness.regained), len(session.recording.policy_events)
        session.pace.tick()
        session.watch_losses(session.mission_time())
        t = session.mission_time()
        for sysid in sorted(set(liveness.losses) - losses):
            self._emit(Event(kind="lost", time_s=t, sysid=sysid, text=liveness.losses[sysid].cause))
        for loss in liveness.regained[regained:]:
            self._emit(Event(kind="regained", time_s=t, sysid=loss.sysid, text=f"link regained ({loss.cause})"))
        for record in session.recording.policy_events[policy:]:
            self._emit(Event(kind="policy", time_s=record.time_s, sysid=record.sysid, text=record.text))
        self._publish()
        controller = session.controller
        if isinstance(controller, ControllerBehaviour) and controller.error is not None:
            session.controller = None
            session.streamer.stop()
            held = swarm.commands.hold_all()
            self._say(f"swarm: the controller raised {type(controller.error).__name__}: {controller.error}; "
                      f"sysid {held} hold where they are")  # fmt: skip
            raise ControllerError(f"the controller raised {controller.error!r}") from controller.error

    def _publish(self) -> None:
        """A new snapshot for readers in other threads (``drones``, ``time_s``): at every tick and after every call,
        so a call's caller sees the state it ended in."""
        assert self.session is not None
        self._time_s = self.session.mission_time()
        self._states = self._snapshot()

    def _snapshot(self) -> dict[int, DroneState]:
        swarm, session = self.swarm, self.session
        assert swarm is not None and session is not None
        now = swarm.clock.now()
        t = session.mission_time()
        out: dict[int, DroneState] = {}
        for sysid in swarm.liveness.sysids:
            view = swarm.fleet.drones.get(sysid)
            if view is None:
                continue
            placed = swarm.picture.placed(sysid)  # gcs/fleet/picture.py: the swarm frame
            pos, vel = (placed.pos_ned_m, placed.vel_ned_mps) if placed is not None else (NAN3, NAN3)
            out[sysid] = DroneState(
                sysid=sysid, time_s=t, pos_ned_m=pos, vel_ned_mps=vel, armed=view.armed, mode=view.mode,
                in_air=view.landed_state not in _NOT_IN_AIR,
                battery_remaining=view.battery_remaining, link_age_s=view.link_age_s(now),
                lost=sysid in swarm.liveness.losses, failsafe=failsafe_text(view.system_status, view.texts),
            )  # fmt: skip
        return out

    def _on_message(self, msg: Any, _now_s: float) -> None:
        if self._on_event is None or self.session is None:
            return
        kind = msg.get_type()
        sysid = msg.get_srcSystem()
        if kind == "STATUSTEXT":
            text = self._texts.feed(sysid, msg)
            if text is not None:  # a long text comes out once, whole
                self._emit(Event(kind="statustext", time_s=self.session.mission_time(), sysid=sysid, text=text,
                                 severity=msg.severity))  # fmt: skip
        elif kind == "HEARTBEAT" and msg.get_srcComponent() == 1:
            before = self._status.get(sysid)
            self._status[sysid] = msg.system_status
            if msg.system_status == MAV_STATE_CRITICAL and before != MAV_STATE_CRITICAL:
                view = self.swarm.fleet.drones.get(sysid) if self.swarm is not None else None
                text = failsafe_text(msg.system_status, view.texts) if view is not None else None
                self._emit(Event(kind="failsafe", time_s=self.session.mission_time(), sysid=sysid,
                                 text=text or "failsafe"))  # fmt: skip

    def _emit(self, event: Event) -> None:
        if self._on_event is not None:
            try:
                self._on_event(event)
            except Exception:  # a subscriber's mistake must not take the supervisor down
                log.exception("an event subscriber raised")

    def _shut_down(self) -> FlightResult:
        session, swarm = self.session, self.swarm
        assert session is not None and swarm is not None
        self._cancel.clear()  # the shutdown's own waits run to their end
        session.streamer.stop()
        session.end_step(session.mission_time())  # the last step ends now; the shutdown's landing is still recorded
        try:
            swarm.shutdown()
        finally:
            try:
                report = session.write_report()
            finally:
                self._stop_view()
        metrics = json.loads((report / METRICS_FILE).read_text()) if report is not None else {}
        return FlightResult(report_dir=report, metrics=metrics)

    def _stop_swarm(self) -> None:
        """After a failed start: stop whatever did start."""
        if self.swarm is not None:
            try:
                self.swarm.shutdown()
            except Exception:
                log.exception("stopping the swarm after a failed start")
        self._stop_view()

    def _stop_view(self) -> None:
        if self.view is not None:
            self.view.stop()
            self.view = None

    # ---- the work the faces post (each runs in the supervisor's thread): the swarm's verbs ----------------------
    def do(self, request: rq.Request, *, wait: bool = True) -> Any:
        """Start a request (gcs/supervisor/verbs.py ``start``: a verb that changes what the swarm flies begins a report
        step) and, with ``wait``, fly until it is done; its value."""
        assert self.session is not None
        started = start(self.session, request)
        return carry_out(started, self._wait) if wait else started.value

    def _wait(self, condition: Callable[[], bool], timeout_s: float) -> bool:
        assert self.swarm is not None
        return self.swarm.pump.wait_until(condition, timeout_s, tick=self._tick)

    def control(self, controller: Controller) -> rq.Control:
        """A user's controller as the request that flies it: called every tick with this session's snapshot."""
        return rq.Control(controller=ControllerBehaviour(controller, self._snapshot))

    def sleep(self, hold: rq.Hold) -> None:
        """Fly on for the hold's time, with a tick at the setpoint stream's rate."""
        assert self.swarm is not None
        self.do(hold, wait=False)
        self.swarm.pump.run_for(hold.duration_s, tick=self._tick, tick_s=1.0 / SETPOINT_STREAM_HZ)

    def wait_until(self, predicate: Callable[[dict[int, DroneState]], bool], timeout_s: float) -> bool:
        return self._wait(lambda: bool(predicate(self._states)), timeout_s)


class Readings:
    """What both faces of a session read without waiting: the last tick's snapshot (gcs/api/session.py documents
    the asyncio face; the blocking face reads the same)."""

    _engine: Engine

    @property
    def sysids(self) -> list[int]:
        """Every drone's MAVLink system id, in spawn order."""
        return sorted(self._engine.drones())

    def drones(self) -> dict[int, DroneState]:
        """Every drone's state as of the last tick, by sysid (a snapshot: it does not change under you)."""
        return self._engine.drones()

    @property
    def time_s(self) -> float:
        """The swarm's clock: simulated seconds since the drones came up."""
        return self._engine.time_s

    @property
    def view_url(self) -> str | None:
        """The live view's address (``launch(..., view=True)``, docs/view.md), None without one."""
        view = self._engine.view
        return view.url if view is not None else None
