"""The blocking face of the API, for scripts and notebooks: ``with launch_blocking(9) as swarm: swarm.takeoff(3)``.

The same calls as ``Session`` (gcs/api/session.py documents each), waiting for their answer instead of being
awaited. Ctrl-C during a call ends it, lands every drone, stops every process the session started and writes the
report before the KeyboardInterrupt goes on.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from types import TracebackType
from typing import Any, TypeVar

from gcs.api.engine import Controller, Engine, Readings
from gcs.api.session import _default_simulation
from gcs.api.types import DroneState, Event, FlightResult, LaunchOptions
from gcs.fleet.faults import fault_request
from gcs.fleet.harness import Simulation
from gcs.flight.behaviours import FlockSpec, FollowSpec
from gcs.flight.formation import Formation
from gcs.missions.mission_file import LAND_TIMEOUT_S, RTL_TIMEOUT_S, TAKEOFF_ALT_M, TAKEOFF_TIMEOUT_S
from gcs.supervisor import requests as rq

T = TypeVar("T")


class BlockingSession(Readings):
    """A running swarm, driven by blocking calls. Made by ``launch_blocking`` (or ``BlockingSession.start``)."""

    def __init__(self, engine: Engine) -> None:
        self._engine = engine
        self.result: FlightResult | None = None

    @classmethod
    def start(cls, options: LaunchOptions, simulation: Simulation, say: Callable[[str], None] | None = None,
              on_event: Callable[[Event], None] | None = None) -> BlockingSession:  # fmt: skip
        """Spawn the swarm of ``options``; returns once every drone is up. ``on_event`` is called (in the
        supervisor's thread: keep it short) with every ``Event``."""
        engine = Engine(options, simulation, say=say, on_event=on_event)
        engine.start_thread()
        try:
            engine.ready.result()
        except BaseException:
            with contextlib.suppress(Exception):  # whatever started is stopped before this returns
                engine.close(interrupt=True).result()
            raise
        return cls(engine)

    def _run(self, work: Callable[[], T]) -> T:
        return self._engine.submit(work).result()

    def takeoff(self, alt_m: float = TAKEOFF_ALT_M, timeout_s: float = TAKEOFF_TIMEOUT_S) -> None:
        takeoff = rq.Takeoff(alt_m=alt_m, timeout_s=timeout_s)
        self._run(lambda: self._engine.do(takeoff))

    def formation(self, formation: Formation) -> float:
        request = rq.FlyFormation(formation=formation)
        return self._run(lambda: self._engine.do(request))

    def flock(self, spec: FlockSpec, *, onboard: bool = False) -> None:
        request = rq.Flock(spec=spec, onboard=onboard)
        self._run(lambda: self._engine.do(request))

    def follow(self, spec: FollowSpec, *, onboard: bool = False) -> None:
        request = rq.Follow(spec=spec, onboard=onboard)
        self._run(lambda: self._engine.do(request, wait=False))

    def control(self, controller: Controller) -> None:
        self._run(lambda: self._engine.do(self._engine.control(controller)))

    def start_behaviours(self) -> list[int]:
        return self._run(lambda: self._engine.do(rq.Behaviours(run=True)))

    def stop_behaviours(self) -> list[int]:
        return self._run(lambda: self._engine.do(rq.Behaviours(run=False)))

    def require(self, **fields: Any) -> None:
        request = rq.Require(invariants=(fields,))
        self._run(lambda: self._engine.do(request))

    def sleep(self, seconds: float) -> None:
        hold = rq.Hold(duration_s=seconds)
        self._run(lambda: self._engine.sleep(hold))

    def wait_until(self, predicate: Callable[[dict[int, DroneState]], bool], timeout_s: float) -> bool:
        return self._run(lambda: self._engine.wait_until(predicate, timeout_s))

    def pause(self) -> list[int]:
        """Every drone holds where it is in PX4 Hold (QGroundControl's Pause, MAVSDK's ``action.hold()``): your
        controller, the drones' behaviours and the stream stop until the next command; returns the sysids held."""
        return self._run(lambda: self._engine.do(rq.Pause()))

    def land(self, timeout_s: float = LAND_TIMEOUT_S) -> None:
        land = rq.Land(timeout_s=timeout_s)
        self._run(lambda: self._engine.do(land))

    def return_to_launch(self, timeout_s: float = RTL_TIMEOUT_S) -> None:
        rtl = rq.ReturnToLaunch(timeout_s=timeout_s)
        self._run(lambda: self._engine.do(rtl))

    def set_param(self, name: str, value: float, sysids: Iterable[int] | None = None) -> None:
        request = rq.SetParam(name=name, value=value, sysids=None if sysids is None else tuple(sysids))
        self._run(lambda: self._engine.do(request))

    def inject_fault(self, sysid: int, kind: str, *, motor: int | None = None, for_s: float | None = None) -> str:
        request = rq.InjectFault(sysid=sysid, fault=fault_request(kind, motor, for_s))
        return self._run(lambda: self._engine.do(request))

    def kill(self, sysid: int) -> str:
        request = rq.Kill(sysid=sysid)
        return self._run(lambda: self._engine.do(request))

    def close(self, *, interrupt: bool = False) -> FlightResult:
        """Land what flies, stop every drone process and write the report (once; later calls return the same)."""
        if self.result is None:
            self.result = self._engine.close(interrupt=interrupt).result()
        return self.result

    def __enter__(self) -> BlockingSession:
        return self

    def __exit__(self, kind: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None) -> None:
        self.close(interrupt=kind is not None)


@contextmanager
def launch_blocking(
    drones: int, *, simulation: Simulation | None = None, say: Callable[[str], None] | None = None,
    on_event: Callable[[Event], None] | None = None, **options: Any,
) -> Iterator[BlockingSession]:  # fmt: skip
    """``with launch_blocking(9, report_dir=Path("report")) as swarm:`` as ``launch``, for code without asyncio."""
    options_ = LaunchOptions(drones=drones, **options)
    with BlockingSession.start(options_, simulation or _default_simulation(), say, on_event) as session:
        yield session
