"""The supervisor's clock: simulated seconds, paced on the wall clock or moved on in lockstep frames.

Paced, simulated time is the wall clock times the speed factor. In lockstep it is the drones' common time, which
the supervisor itself moves on through the harness, one frame at a time, pipelined: once every drone stands at the
gate (``reach_gate``) the supervisor opens the next one at once (``open_gate``: the drones fly ``LOCKSTEP_LEAD_S``
on), and then handles what they sent up to the gate they stood at while they fly. Its clock holds that gate's time
until the next frame, so everything it reads and computes between two frames meets one simulated time, and what it
sends leaves at the next gate, a frame later (gcs/fleet/pump.py says why that makes lockstep flights replay
exactly).
"""

from __future__ import annotations

import contextlib
import os
import selectors
import time
from collections.abc import Mapping
from typing import Final

from gcs.fleet.harness import SimulationHarness, SpawnPlan
from swarmcommon.cpus import RunQueue, look_again

# A lockstep frame: how far the drones fly on each time every one of them stands at the gate. The supervisor handles
# what they sent up to one gate while they fly to the next, and its answer is read at that next gate, so this is
# also the lag, in simulated time, between what a drone reports and the setpoint or relayed position that answers
# it (FLIGHT_VERSION 2; before, the drones waited while the supervisor worked and the answer came at the same gate).
# A 50 ms frame let an eight-drone swap touch on a busy machine.
LOCKSTEP_LEAD_S: Final = 0.02
# What lockstep flights are a function of, beside their seeds and mission: a change that moves the bits of a lockstep
# flight (the recorded flights' digests) bumps it, and a sweep or falsify campaign refuses to resume over flights
# recorded by code that flies differently (gcs/sweep/sweep.py, gcs/falsify/campaign.py). 2: the pipelined frame (the
# supervisor's answers a frame later) and kills at the gate.
FLIGHT_VERSION: Final = 2
LOCKSTEP_STALL_S: Final = 10.0  # wall seconds without progress before the supervisor calls the simulation stalled
LOCKSTEP_MAX_WAIT_S: Final = 0.005  # wall-clock cap on one wait in lockstep (simulated time has no wall rate)
EXIT_CHECK_S: Final = 0.5  # wall seconds between looks for ended drones while moving the lockstep clock
TICK_S: Final = 0.05  # the period of a waiting loop's ``tick`` (the setpoint stream's 20 Hz)


class ClockStalled(RuntimeError):
    """No drone advanced for LOCKSTEP_STALL_S wall seconds while some still run."""


class SwarmClock:
    """Simulated time for the supervisor; ``start`` once the drones are launched."""

    def __init__(self, plan: SpawnPlan, harness: SimulationHarness) -> None:
        self.plan = plan
        self.harness = harness
        self.lockstep_running = False
        # Lockstep: the common time of the gate every drone last stood at: the time of the frame the supervisor
        # handles while the drones fly the next one. It holds until the next frame, and the supervisor reads its clock
        # a dozen times between frames (a read of the drones' clock scans the world table).
        self._gate_time_s: float | None = None
        self._open_gate_s: float | None = None  # the gate the drones fly to now (None: none opened yet)
        self._wake_fd: int | None = None
        self._wall_t0 = time.monotonic()
        self._gate_progress = (0.0, time.monotonic())  # (common time, wall time it was first seen)
        self._next_exit_check = 0.0
        self._drones = 0
        self._gate_selector = selectors.DefaultSelector()  # lockstep: woken by the drones reaching the gate
        self._run_queue = RunQueue()  # lockstep: whether a CPU is idle, so that looking again costs nobody
        self._looks_again = False  # lockstep, every drone in one process: look again before sleeping at the gate

    def start(self, drones: int) -> None:
        """The drones are launched: paced time starts now, the lockstep gate runs (in lockstep)."""
        self._drones = drones
        # One process holds every drone: it and the supervisor wait for each other at every gate, so the supervisor
        # looks again before it sleeps. With several, the drones' processes wait for each other at every step and a
        # supervisor looking again would take the CPU of the one finishing last.
        self._looks_again = self.plan.lockstep and len(set(self.harness.process_ids().values())) == 1
        self._wall_t0 = time.monotonic()
        self._wake_fd = self.harness.wake_fileno()
        if self._wake_fd is not None:
            self._gate_selector.register(self._wake_fd, selectors.EVENT_READ)
        self.lockstep_running = self.plan.lockstep

    def now(self) -> float:
        """Simulated seconds: the drones' common clock in lockstep, else wall time times the speed factor."""
        if self.lockstep_running:
            if self._gate_time_s is not None:
                return self._gate_time_s
            return self.harness.lockstep_time_s()
        return (time.monotonic() - self._wall_t0) * self.plan.speed_factor

    def reach_gate(self) -> None:
        """Lockstep: wait until every drone stands at the gate the last frame opened (none opened yet: at once); the
        clock then reads that gate's time until the next frame."""
        target_s = self._open_gate_s
        if target_s is None:
            return
        target = target_s - 1e-9
        if self._looks_again:  # while a CPU is idle (``start`` says when): its wake-up is on every frame's path
            look_again(lambda: self.harness.lockstep_time_s() >= target, self._run_queue)
        while (now := self.harness.lockstep_time_s()) < target and len(self.harness.ended()) < self._drones:
            self._check_members(now)
            if self._gate_selector.select(LOCKSTEP_MAX_WAIT_S) and self._wake_fd is not None:
                _consume(self._wake_fd)  # that wake-up is read: the next one is news
        self._gate_time_s = now

    def open_gate(self, sent_to_drones: Mapping[int, int]) -> None:
        """Lockstep, every drone at the gate (``reach_gate``): let them fly LOCKSTEP_LEAD_S on (``sent_to_drones``:
        the datagrams the supervisor has sent each so far, which each reads before it steps on). Paced lockstep
        opens the frame when the wall clock has caught up with it. The clock keeps the time of the gate they stood
        at: the supervisor now handles that frame while they fly the next."""
        now = self.now()
        if self.plan.speed_factor > 0:
            ahead_s = (now + LOCKSTEP_LEAD_S) / self.plan.speed_factor - (time.monotonic() - self._wall_t0)
            if ahead_s > 0:
                time.sleep(ahead_s)
        self.harness.note_sent_to_drones(sent_to_drones)
        started_s = self.harness.advance_lockstep(LOCKSTEP_LEAD_S)
        if started_s is None:
            # Not every drone has joined yet (nobody starts before the rest): nothing runs, nothing to wait for, and
            # nothing stalls: the time has not started (the first run on a machine compiles the drones' kernels
            # before any drone exists, some 25 s).
            self._gate_time_s = None
            self._open_gate_s = None
            self._gate_progress = (now, time.monotonic())
            self._gate_selector.select(LOCKSTEP_MAX_WAIT_S)
            return
        self._gate_time_s = started_s
        self._open_gate_s = started_s + LOCKSTEP_LEAD_S

    def _check_members(self, now: float) -> None:
        """Notice a drone that ended (it leaves the lockstep gate: it must hold nobody back) and a stalled
        simulation; both on the wall clock, at most every EXIT_CHECK_S."""
        wall = time.monotonic()
        if wall < self._next_exit_check:
            return
        self._next_exit_check = wall + EXIT_CHECK_S
        self.harness.ended()
        if now != self._gate_progress[0]:
            self._gate_progress = (now, wall)
        elif wall - self._gate_progress[1] > LOCKSTEP_STALL_S and len(self.harness.ended()) < self._drones:
            raise ClockStalled(f"simulation stalled at t={now:.3f} s: no drone advanced for {LOCKSTEP_STALL_S:g} s")

    def close(self) -> None:
        if self._wake_fd is not None:
            self._gate_selector.unregister(self._wake_fd)
            self._wake_fd = None
        self._gate_selector.close()
        self._run_queue.close()


def _consume(fd: int) -> None:
    """Read every datagram waiting on a non-blocking descriptor."""
    with contextlib.suppress(BlockingIOError, InterruptedError):
        while True:
            os.read(fd, 64)


def next_tick_s(due_s: float, now_s: float, period_s: float) -> float:
    """When the next tick is due after one due at ``due_s`` ran at ``now_s``: a period after the one due, so that
    ticks keep their rate on average when the clock moves in steps that do not divide the period (lockstep frames
    of 0.02 s would otherwise tick every 0.06 s); a tick more than a period late starts the cadence afresh."""
    return due_s + period_s if now_s - due_s < period_s else now_s + period_s
