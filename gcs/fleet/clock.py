"""The supervisor's clock: simulated seconds, paced on the wall clock or moved on in lockstep frames.

Paced, simulated time is the wall clock times the speed factor. In lockstep it is the drones' common time, which
the supervisor itself moves on through the harness, one frame at a time (``frame``): the drones run
``LOCKSTEP_LEAD_S`` on and wait at the gate, and the time then holds until the next frame, so everything read and
sent between two frames meets one simulated time on both sides (gcs/fleet/pump.py says why that makes lockstep
flights replay exactly).
"""

from __future__ import annotations

import contextlib
import os
import selectors
import time
from collections.abc import Mapping
from typing import Final

from gcs.fleet.harness import SimulationHarness, SpawnPlan

# How far the drones may run ahead of the supervisor's last look. Under load the drones sit at this limit, so it is
# the lag of setpoints and relayed positions in simulated time: 50 ms let an eight-drone swap touch on a busy machine.
LOCKSTEP_LEAD_S: Final = 0.02
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
        # Lockstep: the common time once every drone stands at the gate. Nothing moves it until the next frame opens
        # the gate, and the supervisor reads its clock a dozen times between frames (a read scans the world table).
        self._gate_time_s: float | None = None
        self._wake_fd: int | None = None
        self._wall_t0 = time.monotonic()
        self._gate_progress = (0.0, time.monotonic())  # (common time, wall time it was first seen)
        self._next_exit_check = 0.0
        self._drones = 0
        self._gate_selector = selectors.DefaultSelector()  # lockstep: woken by the drones reaching the gate

    def start(self, drones: int) -> None:
        """The drones are launched: paced time starts now, the lockstep gate runs (in lockstep)."""
        self._drones = drones
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

    def frame(self, sent_to_drones: Mapping[int, int]) -> None:
        """One frame of the lockstep clock: let the drones run LOCKSTEP_LEAD_S on and wait until every one of them
        stands at the gate (``sent_to_drones``: the datagrams the supervisor has sent each so far, which each waits
        for before it steps). Paced lockstep starts the frame when the wall clock has caught up with it."""
        now = self.now()
        if self.plan.speed_factor > 0:
            ahead_s = (now + LOCKSTEP_LEAD_S) / self.plan.speed_factor - (time.monotonic() - self._wall_t0)
            if ahead_s > 0:
                time.sleep(ahead_s)
        self.harness.note_sent_to_drones(sent_to_drones)
        self._gate_time_s = None
        if self.harness.advance_lockstep(LOCKSTEP_LEAD_S) is None:
            # Not every drone has joined yet (nobody starts before the rest): nothing runs, nothing to wait for, and
            # nothing stalls: the time has not started (the first run on a machine compiles the drones' kernels
            # before any drone exists, some 25 s).
            self._gate_progress = (now, time.monotonic())
            self._gate_selector.select(LOCKSTEP_MAX_WAIT_S)
            return
        target = now + LOCKSTEP_LEAD_S - 1e-9
        while (now := self.now()) < target and len(self.harness.ended()) < self._drones:
            self._check_members(now)
            if self._gate_selector.select(LOCKSTEP_MAX_WAIT_S) and self._wake_fd is not None:
                _consume(self._wake_fd)  # that wake-up is read: the next one is news
        if now >= target:
            self._gate_time_s = now  # every drone stands at the gate: the time holds until the next frame

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
