"""The drone process's IO shell: pacing against the wall clock, MAVLink sockets, signals, and the main loop.

Everything that flies is in the pure ClosedLoop and the MAVLink services are sans-IO; this module decides when to
step the simulation, when to read sockets and poll the services, and when to stop. Socket readiness wakes the loop
early, so a command is handled within a fraction of a physics step of its arrival, not at the next batch.
"""

from __future__ import annotations

import functools
import logging
import math
import selectors
import signal
import socket
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from types import FrameType
from typing import Protocol

from sitl.process.drone import Drone, DroneLogRouter
from sitl.process.pacing import Pacer
from sitl.world.lockstep import MAX_SLEEP_S, LockstepMember
from sitl.world.shared import END_STOPPED
from swarmcommon.cpus import RunQueue, look_again

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


class StepClock(Protocol):
    """Decides how many physics steps the loop may take now, and how to wait when it may take none."""

    def steps_due(self, sim_time_s: float, completed_steps: int, max_batch: int) -> int: ...

    def completed(self, steps: int) -> None: ...

    def drop(self, instance: int) -> None:
        """Drone ``instance`` of this process ended: it no longer takes part in the clock."""
        ...

    def wait(self, selector: selectors.BaseSelector, sim_time_s: float) -> None: ...

    def sockets(self) -> list[socket.socket]:
        """Sockets whose data should end a wait (registered with the loop's selector)."""
        ...

    def close(self) -> None: ...


PACED_WAKE_STEPS = 8  # 32 ms of simulated time at 250 Hz
# In lockstep the telemetry is polled (and the autopilot's events sent) after every this many steps of the common
# clock, before the step is published as completed: whoever sees a step completed has everything sent up to it, and
# what is sent when does not depend on how the barrier happened to cut the batches (reproducible flights).
LOCKSTEP_POLL_STEPS = 4  # 16 ms of simulated time at 250 Hz
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

    def drop(self, instance: int) -> None:
        pass

    def sockets(self) -> list[socket.socket]:
        return []

    def wait(self, selector: selectors.BaseSelector, sim_time_s: float) -> None:
        if self.pacer.unpaced or self._booting is not None:
            return
        # Sleep until a few steps are due, not one: a wake-up costs far more than its select, socket reads and
        # telemetry poll (the process comes back to cold caches), and waking at every step was the largest part of a
        # paced drone's time. At 400 Hz physics, every 4 steps cost a 9-drone swarm 85-96 ms of CPU per drone per
        # simulated second, every 8 steps 72-92 (docs/benchmark-history.md). Arriving MAVLink still wakes the loop at
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
    """Advanced together with the other drones through the shared world (sitl/world/lockstep.py).

    A member waiting at the gate is woken by its wake-up socket alone, not by MAVLink: the loop reads no socket while
    the gate holds it (``run_loop``), so that whatever the supervisor sends, and a kill it orders, meet the drone at
    the gate's step, never between two looks at the gate; a datagram left unread must not end every wait at once."""

    def __init__(self, member: LockstepMember) -> None:
        self.member = member
        self._due = 0
        self._completed = 0
        self._wake = selectors.DefaultSelector()
        self._wake.register(member.wake_socket, selectors.EVENT_READ)
        self._run_queue = RunQueue()
        self._looks_again: bool | None = None  # holds every drone, so it waits for the supervisor alone (``wait``)
        member.join()

    def steps_due(self, sim_time_s: float, completed_steps: int, max_batch: int) -> int:
        due, _gated = self.member.steps_allowed(completed_steps)
        self._completed = completed_steps
        self._due = min(due, max_batch)
        return self._due

    def completed(self, steps: int) -> None:
        self.member.completed(steps)
        self._completed = steps

    def drop(self, instance: int) -> None:
        self.member.drop(instance)

    def sockets(self) -> list[socket.socket]:
        return []  # the wake-up socket is this clock's own (see the class docstring)

    def wait(self, selector: selectors.BaseSelector, sim_time_s: float) -> None:
        """Sleep until a peer or the supervisor wakes this member, after a last look. A member that holds every drone
        waits for the supervisor alone, at every gate: while no task waits for a CPU it looks again for a while first
        (swarmcommon/cpus.py ``look_again``: a wake-up costs more than a frame of a few drones, and nobody is kept
        from a CPU meanwhile). Members that wait for each other at every step never do: each would take the CPU of
        the peer it waits for whenever the supervisor wakes (measured: the 9-drone swarm in two hosts ran at half its
        speed)."""
        if self._due > 0:
            return
        member = self.member
        if self._looks_again is None:
            self._looks_again = member.alone()
        if self._looks_again and look_again(lambda: member.steps_allowed(self._completed)[0] > 0, self._run_queue):
            return
        member.begin_wait()
        try:
            if member.steps_allowed(self._completed)[0] == 0:
                self._wake.select(MAX_SLEEP_S)
        finally:
            member.end_wait()

    def close(self) -> None:
        self._wake.close()
        self._run_queue.close()
        self.member.leave()


def run_loop(
    drones: Sequence[Drone],
    options: RunOptions,
    stop: StopFlag,
    *,
    clock: StepClock | None = None,
    router: DroneLogRouter | None = None,
) -> None:
    """Step every drone of the process (paced to the wall clock unless another clock is given) until stopped, every
    drone finished or ended, or the duration reached. Paced, the boot is fast-forwarded while a drone still boots
    (see WallClockSteps).

    The drones advance together: one wake-up, one look at the sockets and one clock decision serve them all. Which
    drone has traffic waiting comes from one ``select`` over every socket, so a host of many drones does not try
    every socket every time. An exception in one drone's code ends that drone alone (``Drone.fail``); a drone the
    supervisor asked to stop (``Drone.stop_requested``) ends as if its process had been killed."""
    if not drones:
        return
    dt_s = drones[0].sim.dt_s
    live = list(drones)

    def booting() -> bool:
        return any(d.booting() for d in live)

    steps_clock = clock if clock is not None else WallClockSteps(options.speed_factor, dt_s, booting)
    selector = selectors.DefaultSelector()
    for drone in drones:
        for sock in drone.endpoint.sockets() if drone.endpoint is not None else []:
            selector.register(sock, selectors.EVENT_READ, drone)
    for sock in steps_clock.sockets():
        selector.register(sock, selectors.EVENT_READ, None)
    # With MAVLink, read the sockets every few milliseconds of simulation (unpaced) rather than after every step. A
    # paced batch must hold a whole wake-up's steps: shorter, the drone would sleep again while steps are still due
    # and fall behind its clock by the difference.
    max_batch = 400 if all(d.endpoint is None for d in drones) else PACED_WAKE_STEPS
    # In lockstep the drones of a host take each step together, so none is ever more than a step ahead of another
    # (the barrier's promise); paced, each runs its whole batch at once, which keeps its data in the caches.
    step_major = isinstance(steps_clock, LockstepSteps)
    completed = 0

    def end(drone: Drone, exc: BaseException | None) -> None:
        for sock in drone.endpoint.sockets() if drone.endpoint is not None else []:
            selector.unregister(sock)
        steps_clock.drop(drone.instance)
        if exc is not None:
            drone.fail(exc)
        else:
            drone.close(END_STOPPED, f"stopped on request at t={drone.time_s:.2f} s, as a killed process stops")

    def each(action: Callable[[Drone], None], drones_now: Iterable[Drone]) -> None:
        for drone in drones_now:
            if router is not None:
                router.current = drone.output
            try:
                action(drone)
            except Exception as exc:
                end(drone, exc)

    try:
        while not stop.stopped:
            # How far the drones may go is asked before the sockets are read and before a stop request is looked
            # at: in lockstep the supervisor sends, and asks for a stop, before it opens the gate, so whatever it sent
            # for this time is read now, before the first step it allows, and a drone it stops ends at the gate,
            # however the processes happened to interleave (reproducible flights). While the gate holds the drones
            # in lockstep nothing is read at all: a datagram read there could be answered before a stop is seen.
            time_s = live[0].time_s
            due = steps_clock.steps_due(time_s, completed, max_batch)
            for drone in live:
                if drone.stop_requested():
                    end(drone, None)
            live = [d for d in live if not d.ended]
            if not live:
                return
            if due > 0 or not step_major:
                ready = {key.data for key, _ in selector.select(0)}
                each(Drone.receive, [d for d in live if d in ready])
                live = [d for d in live if not d.ended]
                if not live:
                    return
            if options.duration_s is not None:
                due = min(due, max(0, math.ceil((options.duration_s - time_s) / dt_s - 1e-9)))
            if due > 0:
                if step_major:
                    each(Drone.await_supervisor, live)
                    for _ in range(due):
                        each(Drone.step, [d for d in live if not d.ended])
                        completed += 1
                        flying = [d for d in live if not d.ended]
                        if completed % LOCKSTEP_POLL_STEPS == 0:
                            each(Drone.after_batch, flying)
                        each(Drone.publish_sent, [d for d in flying if not d.ended])
                        steps_clock.completed(completed)
                else:
                    each(functools.partial(_run_steps, steps=due), live)
                    completed += due
                    steps_clock.completed(completed)
            live = [d for d in live if not d.ended]
            if not live or all(d.finished for d in live):
                return
            if options.duration_s is not None and live[0].time_s >= options.duration_s - 1e-9:
                return
            if not step_major:
                each(Drone.after_batch, live)
            if router is not None:
                router.current = None
            steps_clock.wait(selector, live[0].time_s)
    finally:
        if router is not None:
            router.current = None
        selector.close()
        steps_clock.close()


def _run_steps(drone: Drone, steps: int) -> None:
    """A paced batch of one drone; a demo flight ends it at the step where it is over."""
    for _ in range(steps):
        drone.step()
        if drone.finished:
            return
