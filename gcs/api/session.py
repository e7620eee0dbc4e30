"""The asyncio face of the API: ``async with launch(9) as swarm: await swarm.takeoff(3) ...``.

Every call is posted to the session's supervisor (gcs/api/engine.py) and awaited, so the user's event loop stays
free for their own tasks (a MAVSDK connection to one of the drones, a web server, ...). Calls run one at a time, in
the order they were made. Leaving the ``async with`` block, normally or by an exception (Ctrl-C included), lands
every drone, stops every process the session started and writes the flight report; ``result`` holds it.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import contextlib
from collections.abc import AsyncIterator, Callable, Iterable
from contextlib import asynccontextmanager
from types import TracebackType
from typing import Any, TypeVar

from gcs.api.engine import Controller, Engine, Readings
from gcs.api.types import DroneState, Event, FlightResult, LaunchOptions
from gcs.fleet.faults import fault_request
from gcs.fleet.harness import Simulation
from gcs.flight.behaviours import FlockSpec, FollowSpec
from gcs.flight.formation import Formation
from gcs.missions.mission_file import LAND_TIMEOUT_S, RTL_TIMEOUT_S, TAKEOFF_ALT_M, TAKEOFF_TIMEOUT_S
from gcs.supervisor import requests as rq

T = TypeVar("T")


class Session(Readings):
    """A running swarm, driven from asyncio. Made by ``launch`` (or ``Session.start``)."""

    def __init__(self, engine: Engine) -> None:
        self._engine = engine
        self._subscribers: list[asyncio.Queue[Event]] = []
        self._loop = asyncio.get_running_loop()
        self.result: FlightResult | None = None  # the flight report, once the session is closed

    @classmethod
    async def start(cls, options: LaunchOptions, simulation: Simulation,
                    say: Callable[[str], None] | None = None) -> Session:  # fmt: skip
        """Spawn the swarm of ``options`` and return once every drone is up, with a home and a position."""
        holder: list[Session] = []
        engine = Engine(options, simulation, say=say, on_event=lambda e: holder[0]._publish(e) if holder else None)
        session = cls(engine)
        holder.append(session)
        engine.start_thread()
        try:
            await asyncio.wrap_future(engine.ready)
        except BaseException:
            # interrupted while the drones start, or they did not: whatever started is stopped before this returns
            with contextlib.suppress(Exception):
                await asyncio.shield(asyncio.wrap_future(engine.close(interrupt=True)))
            raise
        return session

    async def _run(self, work: Callable[[], T]) -> T:
        return await asyncio.wrap_future(self._engine.submit(work))

    # ---- what the swarm knows (``sysids``, ``drones()``, ``time_s``: ``Readings``) --------------------------------
    async def events(self) -> AsyncIterator[Event]:
        """Everything that happens from now on (warnings, losses, returns, failsafes), as it happens:
        ``async for event in swarm.events(): ...``. Each iterator gets every event."""
        queue: asyncio.Queue[Event] = asyncio.Queue()
        self._subscribers.append(queue)
        try:
            while True:
                yield await queue.get()
        finally:
            self._subscribers.remove(queue)

    def _publish(self, event: Event) -> None:
        """From the supervisor's thread: hand ``event`` to every iterator, on the user's loop."""
        for queue in list(self._subscribers):
            self._loop.call_soon_threadsafe(queue.put_nowait, event)

    # ---- flying --------------------------------------------------------------------------------------------------
    async def takeoff(self, alt_m: float = TAKEOFF_ALT_M, timeout_s: float = TAKEOFF_TIMEOUT_S) -> None:
        """Arm every drone (after its pre-arm checks) and take it off to ``alt_m`` above its home; returns once every
        drone has held that altitude for a second (SwarmError if not within ``timeout_s`` simulated seconds)."""
        takeoff = rq.Takeoff(alt_m=alt_m, timeout_s=timeout_s)
        await self._run(lambda: self._engine.do(takeoff))

    async def formation(self, formation: Formation) -> float:
        """Fly a formation (``GridSpec``, ``CircleSpec``, ``LineSpec``, ``VSpec``) from where the drones are, with a
        synchronised, collision-aware transition; returns the seconds until every drone is due in its slot. The
        drones keep flying it (a rotating circle keeps turning) until the next command."""
        request = rq.FlyFormation(formation=formation)
        return await self._run(lambda: self._engine.do(request))

    async def flock(self, spec: FlockSpec, *, onboard: bool = False) -> None:
        """Reynolds flocking of every drone, computed by the ground station; ``onboard=True``: by every drone itself,
        from its own estimate and neighbour table (``launch(behaviour=FLOCKING)``; docs/onboard.md). Stop an
        onboard flock with ``stop_behaviours`` (or any other command)."""
        request = rq.Flock(spec=spec, onboard=onboard)
        await self._run(lambda: self._engine.do(request))

    async def follow(self, spec: FollowSpec, *, onboard: bool = False) -> None:
        """Leader-follower: the leader flies the waypoints, the others hold their slots around it; ``onboard=True``:
        each drone flies its part itself (``launch(behaviour=LEADER_FOLLOWER)``; docs/onboard.md)."""
        request = rq.Follow(spec=spec, onboard=onboard)
        await self._run(lambda: self._engine.do(request, wait=False))

    async def control(self, controller: Controller) -> None:
        """Stream your own setpoints: ``controller(t_s, drones)`` is called every tick (20 Hz of simulated time)
        with the swarm's clock and every drone's ``DroneState`` and returns ``{sysid: Setpoint or (n, e, d)}`` in the
        swarm frame for the drones it commands. It runs in the supervisor's thread and must return quickly (in
        lockstep the simulation waits for it). If it raises, every drone holds where it is and the call in
        progress (or the next one) raises ``ControllerError``."""
        await self._run(lambda: self._engine.do(self._engine.control(controller)))

    async def start_behaviours(self) -> list[int]:
        """Every drone runs its onboard behaviour (``launch(behaviour="file.py:Class")``, docs/onboard.md): the
        ground station stops its own setpoints and sets BHV_EN = 1; returns the sysids."""
        return await self._run(lambda: self._engine.do(rq.Behaviours(run=True)))

    async def stop_behaviours(self) -> list[int]:
        """BHV_EN = 0 on every drone, then Hold where they are; returns the sysids put in Hold."""
        return await self._run(lambda: self._engine.do(rq.Behaviours(run=False)))

    async def require(self, **fields: Any) -> None:
        """Check an invariant at every tick from now on, given as a mission's ``[[invariants]]`` table
        (``await swarm.require(kind="separation", min_m=1.0)``; docs/invariants.md). Its first violation is said,
        marked on the report's timeline and listed in ``FlightResult.metrics["violations"]``; ValueError (one line)
        for a bad one."""
        request = rq.Require(invariants=(fields,))
        await self._run(lambda: self._engine.do(request))

    async def sleep(self, seconds: float) -> None:
        """Let the swarm fly for ``seconds`` of simulated time."""
        hold = rq.Hold(duration_s=seconds)
        await self._run(lambda: self._engine.sleep(hold))

    async def wait_until(self, predicate: Callable[[dict[int, DroneState]], bool], timeout_s: float) -> bool:
        """Fly until ``predicate(drones)`` is true (checked every tick) or ``timeout_s`` simulated seconds pass;
        whether it came true."""
        return await self._run(lambda: self._engine.wait_until(predicate, timeout_s))

    async def pause(self) -> list[int]:
        """Every drone holds where it is in PX4 Hold (QGroundControl's Pause, MAVSDK's ``action.hold()``): your
        controller, the drones' behaviours and the stream stop until the next command; returns the sysids held."""
        return await self._run(lambda: self._engine.do(rq.Pause()))

    async def land(self, timeout_s: float = LAND_TIMEOUT_S) -> None:
        """Land every flying drone where it is (clear of any wreck) and wait until all have disarmed."""
        land = rq.Land(timeout_s=timeout_s)
        await self._run(lambda: self._engine.do(land))

    async def return_to_launch(self, timeout_s: float = RTL_TIMEOUT_S) -> None:
        """Every flying drone returns to its launch point and lands (PX4 Return); waits until all have disarmed."""
        rtl = rq.ReturnToLaunch(timeout_s=timeout_s)
        await self._run(lambda: self._engine.do(rtl))

    async def set_param(self, name: str, value: float, sysids: Iterable[int] | None = None) -> None:
        """Set a drone parameter (PARAM_SET, confirmed by the drone's echo) on every drone or on ``sysids``."""
        request = rq.SetParam(name=name, value=value, sysids=None if sysids is None else tuple(sysids))
        await self._run(lambda: self._engine.do(request))

    # ---- breaking things on purpose ------------------------------------------------------------------------------
    async def inject_fault(self, sysid: int, kind: str, *, motor: int | None = None, for_s: float | None = None) -> str:
        """MAV_CMD_INJECT_FAILURE (``motor``, ``gps``, ``gps-glitch``, ``battery-low``, ..., ``link``; docs/faults.md);
        ``for_s`` cuts a link for that long. Returns the drone's answer (``accepted``)."""
        request = rq.InjectFault(sysid=sysid, fault=fault_request(kind, motor, for_s))
        return await self._run(lambda: self._engine.do(request))

    async def kill(self, sysid: int) -> str:
        """Kill the drone's flight software (SIGKILL of its process, or its end inside a host process)."""
        request = rq.Kill(sysid=sysid)
        return await self._run(lambda: self._engine.do(request))

    # ---- the end -------------------------------------------------------------------------------------------------
    async def close(self) -> FlightResult:
        """Land what flies, stop every drone process and write the report (once; later calls return the same)."""
        if self.result is None:
            self.result = await asyncio.shield(asyncio.wrap_future(self._engine.close()))
        return self.result

    async def _abort(self) -> FlightResult:
        """Close at once: the call in progress ends (Ctrl-C, an exception in the user's code)."""
        future: concurrent.futures.Future[FlightResult] = self._engine.close(interrupt=True)
        self.result = await asyncio.shield(asyncio.wrap_future(future))
        return self.result

    async def __aenter__(self) -> Session:
        return self

    async def __aexit__(self, kind: type[BaseException] | None, exc: BaseException | None,
                        tb: TracebackType | None) -> None:  # fmt: skip
        if kind is None:
            await self.close()
        else:
            await self._abort()


@asynccontextmanager
async def launch(drones: int, *, simulation: Simulation | None = None, say: Callable[[str], None] | None = None,
                 **options: Any) -> AsyncIterator[Session]:  # fmt: skip
    """``async with launch(9, lockstep=True, report_dir=Path("report")) as swarm:`` spawns ``drones`` simulated
    drones (``LaunchOptions`` lists every option), waits until they are up and yields the session; at the end of the
    block every drone lands and stops and the report is written (``swarm.result``). ``say`` receives the
    supervisor's lines (losses, warnings); by default they go to the ``gcs.api`` logger."""
    session = await Session.start(LaunchOptions(drones=drones, **options), simulation or _default_simulation(), say)
    async with session:
        yield session


def _default_simulation() -> Simulation:
    """This project's simulation (sitl), through the composition root, as the ``swarm`` command uses it."""
    from gcs.composition import SITL

    return SITL
