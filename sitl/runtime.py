"""The drone process's IO shell: pacing against the wall clock, MAVLink sockets, signals, and the main loop.

Everything that flies is in the pure Simulation and the MAVLink services are sans-IO; this module decides when to
step the simulation, when to read sockets and poll the services, and when to stop. Socket readiness wakes the loop
early, so a command is handled within a fraction of a physics step of its arrival, not at the next batch.
"""

from __future__ import annotations

import logging
import selectors
import signal
import socket
import time
from collections.abc import Callable
from dataclasses import dataclass
from types import FrameType
from typing import Protocol

from sitl.lockstep import MAX_SLEEP_S, LockstepMember
from sitl.mavlink_io import MavlinkEndpoint
from sitl.pacing import Pacer
from sitl.simulation import Simulation
from sitl.vehicle import VehicleEvent

log = logging.getLogger(__name__)


@dataclass(frozen=True, slots=True, kw_only=True)
class RunOptions:
    speed_factor: float = 1.0
    duration_s: float | None = None  # stop after this much simulation time


@dataclass(slots=True)
class LoopStats:
    """Time the loop spends on MAVLink (receive, poll, STATUSTEXT), in nanoseconds of ``clock_ns`` (see
    ``Simulation.part_clock_ns`` for the choice of clock)."""

    link_ns: int = 0
    clock_ns: Callable[[], int] = time.perf_counter_ns


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


class StepClock(Protocol):
    """Decides how many physics steps the loop may take now, and how to wait when it may take none."""

    def steps_due(self, sim_time_s: float, completed_steps: int, max_batch: int) -> int: ...

    def completed(self, steps: int) -> None: ...

    def wait(self, selector: selectors.BaseSelector, sim_time_s: float) -> None: ...

    def sockets(self) -> list[socket.socket]:
        """Sockets whose data should end a wait (registered with the loop's selector)."""
        ...

    def close(self) -> None: ...


PACED_WAKE_STEPS = 8  # 32 ms of simulated time at 250 Hz
BOOT_FAST_FORWARD_MAX_S = 10.0  # simulated seconds a boot may be fast-forwarded at most


class WallClockSteps:
    """Paced by the wall clock at a speed factor (0 = as fast as possible).

    ``booting``, when given, is asked before each batch: while it holds (and for at most BOOT_FAST_FORWARD_MAX_S of
    simulated time) the drone runs unpaced, then pacing starts from where it got to. A drone on the ground waiting
    for its GPS fix and estimator has nothing to show in real time, and those 4 simulated seconds were most of the
    wait before a swarm could arm; fast-forwarded they take some 40 ms of CPU. The sensors and the estimator run
    exactly as they would paced; only the wall clock does not wait for them.
    """

    def __init__(self, speed_factor: float, dt_s: float, booting: Callable[[], bool] | None = None) -> None:
        self.pacer = Pacer(speed_factor, dt_s, time.monotonic())
        self.dt_s = dt_s
        self._booting = booting if booting is not None and not self.pacer.unpaced else None

    def steps_due(self, sim_time_s: float, completed_steps: int, max_batch: int) -> int:
        if self._booting is not None:
            if sim_time_s < BOOT_FAST_FORWARD_MAX_S and self._booting():
                return max_batch
            self._booting = None
            self.pacer.rebase(time.monotonic(), sim_time_s)
        return self.pacer.steps_due(time.monotonic(), sim_time_s, max_batch)

    def completed(self, steps: int) -> None:
        pass

    def sockets(self) -> list[socket.socket]:
        return []

    def wait(self, selector: selectors.BaseSelector, sim_time_s: float) -> None:
        if self.pacer.unpaced or self._booting is not None:
            return
        # Sleep until a few steps are due, not one: a wake-up costs far more than its select, socket reads and
        # telemetry poll (the process comes back to cold caches), and waking at every step was the largest part of a
        # paced drone's time. At 400 Hz physics, every 4 steps cost a 9-drone swarm 85-96 ms of CPU per drone per
        # simulated second, every 8 steps 72-92 (docs/benchmarks.md). Arriving MAVLink still wakes the loop at
        # once, so commands are not delayed.
        wait_s = self.pacer.wall_time_of(sim_time_s + PACED_WAKE_STEPS * self.dt_s) - time.monotonic()
        if wait_s > 0:
            if selector.get_map():
                selector.select(wait_s)
            else:
                time.sleep(wait_s)

    def close(self) -> None:
        if self.pacer.dropped_s > 0:
            log.warning("fell behind real time by %.2f s of simulation time in total", self.pacer.dropped_s)


class LockstepSteps:
    """Advanced together with the other drones through the shared world (sitl/lockstep.py)."""

    def __init__(self, member: LockstepMember) -> None:
        self.member = member
        self._due = 0
        self._completed = 0
        member.join()

    def steps_due(self, sim_time_s: float, completed_steps: int, max_batch: int) -> int:
        due, _gated = self.member.steps_allowed(completed_steps)
        self._completed = completed_steps
        self._due = min(due, max_batch)
        return self._due

    def completed(self, steps: int) -> None:
        self.member.completed(steps)
        self._completed = steps

    def sockets(self) -> list[socket.socket]:
        return [self.member.wake_socket]

    def wait(self, selector: selectors.BaseSelector, sim_time_s: float) -> None:
        """Sleep until a peer or the supervisor wakes this member (or MAVLink arrives), after a last look."""
        if self._due > 0:
            return
        member = self.member
        member.begin_wait()
        try:
            if member.steps_allowed(self._completed)[0] == 0:
                selector.select(MAX_SLEEP_S)
        finally:
            member.end_wait()

    def close(self) -> None:
        self.member.leave()


def run_loop(
    sim: Simulation,
    options: RunOptions,
    stop: StopFlag,
    *,
    endpoint: MavlinkEndpoint | None = None,
    on_step: Callable[[], None] | None = None,
    on_event: Callable[[VehicleEvent], None] | None = None,
    finished: Callable[[], bool] | None = None,
    clock: StepClock | None = None,
    stats: LoopStats | None = None,
    booting: Callable[[], bool] | None = None,
) -> None:
    """Step the simulation (paced to the wall clock unless another clock is given) until stopped, finished, or
    the duration is reached; paced, a boot is fast-forwarded while ``booting()`` holds (see WallClockSteps)."""
    steps_clock = clock if clock is not None else WallClockSteps(options.speed_factor, sim.dt_s, booting)
    completed = 0
    selector = selectors.DefaultSelector()
    for sock in [*(endpoint.sockets() if endpoint is not None else []), *steps_clock.sockets()]:
        selector.register(sock, selectors.EVENT_READ)
    events = sim.vehicle.events
    # With MAVLink, read the sockets every few milliseconds of simulation (unpaced) rather than after every step. A
    # paced batch must hold a whole wake-up's steps: shorter, the drone would sleep again while steps are still due
    # and fall behind its clock by the difference.
    max_batch = 400 if endpoint is None else PACED_WAKE_STEPS
    loop_stats = stats if stats is not None else LoopStats()
    clock_ns = loop_stats.clock_ns
    try:
        while not stop.stopped:
            if endpoint is not None:
                t0 = clock_ns()
                endpoint.receive(sim.time_s)
                loop_stats.link_ns += clock_ns() - t0
            due = steps_clock.steps_due(sim.time_s, completed, max_batch)
            for _ in range(due):
                sim.step()
                completed += 1
                steps_clock.completed(completed)
                if on_step is not None:
                    on_step()
                if (finished is not None and finished()) or (
                    options.duration_s is not None and sim.time_s >= options.duration_s - 1e-9
                ):
                    return
            t0 = clock_ns()
            if events:
                for event in events:
                    if endpoint is not None:
                        endpoint.statustext(event.severity, event.text)
                    if on_event is not None:
                        on_event(event)
                events.clear()
            if endpoint is not None:
                endpoint.poll(sim.time_s)
            loop_stats.link_ns += clock_ns() - t0
            steps_clock.wait(selector, sim.time_s)
    finally:
        selector.close()
        steps_clock.close()
