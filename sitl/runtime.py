"""The drone process's IO shell: pacing against the wall clock, MAVLink sockets, signals, and the main loop.

Everything that flies is in the pure Simulation and the MAVLink services are sans-IO; this module decides when to
step the simulation, when to read sockets and poll the services, and when to stop. Socket readiness wakes the loop
early, so a command is handled within a fraction of a physics step of its arrival, not at the next batch.
"""

from __future__ import annotations

import logging
import selectors
import signal
import time
from collections.abc import Callable
from dataclasses import dataclass
from types import FrameType

from sitl.mavlink_io import MavlinkEndpoint
from sitl.pacing import Pacer
from sitl.simulation import Simulation
from sitl.vehicle import VehicleEvent

log = logging.getLogger(__name__)


@dataclass(frozen=True, slots=True, kw_only=True)
class RunOptions:
    speed_factor: float = 1.0
    duration_s: float | None = None  # stop after this much simulation time


class StopFlag:
    """Set by SIGINT/SIGTERM; the loop finishes its batch and exits cleanly."""

    def __init__(self) -> None:
        self.stopped = False
        self.signal_name = ""

    def install(self) -> None:
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, self._handler)

    def _handler(self, signum: int, _frame: FrameType | None) -> None:
        self.stopped = True
        self.signal_name = signal.Signals(signum).name


def run_loop(
    sim: Simulation,
    options: RunOptions,
    stop: StopFlag,
    *,
    endpoint: MavlinkEndpoint | None = None,
    on_step: Callable[[], None] | None = None,
    on_event: Callable[[VehicleEvent], None] | None = None,
    finished: Callable[[], bool] | None = None,
) -> None:
    """Step the simulation paced to the wall clock until stopped, finished, or the duration is reached."""
    pacer = Pacer(options.speed_factor, sim.dt_s, time.monotonic())
    selector = selectors.DefaultSelector()
    if endpoint is not None:
        for sock in endpoint.sockets():
            selector.register(sock, selectors.EVENT_READ)
    events = sim.vehicle.events
    # Unpaced, check the sockets every few milliseconds of simulation rather than after every step.
    max_batch = 400 if endpoint is None else 8
    try:
        while not stop.stopped:
            if endpoint is not None:
                endpoint.receive(sim.time_s)
            due = pacer.steps_due(time.monotonic(), sim.time_s, max_batch)
            for _ in range(due):
                sim.step()
                if on_step is not None:
                    on_step()
                if (finished is not None and finished()) or (
                    options.duration_s is not None and sim.time_s >= options.duration_s - 1e-9
                ):
                    return
            if events:
                for event in events:
                    if endpoint is not None:
                        endpoint.statustext(event.severity, event.text)
                    if on_event is not None:
                        on_event(event)
                events.clear()
            if endpoint is not None:
                endpoint.poll(sim.time_s)
            if not pacer.unpaced:
                wait_s = pacer.wall_time_of(sim.time_s + sim.dt_s) - time.monotonic()
                if wait_s > 0:
                    if selector.get_map():
                        selector.select(wait_s)
                    else:
                        time.sleep(wait_s)
    finally:
        selector.close()
        if pacer.dropped_s > 0:
            log.warning("fell behind real time by %.2f s of simulation time in total", pacer.dropped_s)
