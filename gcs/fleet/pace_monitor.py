"""Is the swarm keeping the pace it was asked for? The drones' own clocks against the wall clock.

A paced drone that cannot keep up gives the lag up (sitl/process/pacing.py): it runs slower than asked instead of
accumulating a debt. The supervisor's clock is the wall clock times the speed factor, so on an overloaded machine
the mission's timing (holds, timeouts, the formation's rotation) would run ahead of the drones without anyone
noticing. This monitor compares how far the slowest drone's simulated clock advanced with how far the wall clock
did, over a sliding window, so the status line can show the real-time factor and the user can be told once when the
swarm runs clearly slower than requested. Pure logic: the caller supplies both clocks.
"""

from __future__ import annotations

from collections import deque

from gcs.fleet.harness import SpawnPlan

WINDOW_S = 5.0  # wall seconds over which the achieved rate is measured
SLOW_FRACTION = 0.9  # below this fraction of the requested speed, the swarm is said to fall behind


class PaceMonitor:
    def __init__(
        self,
        speed_factor: float,
        *,
        window_s: float = WINDOW_S,
        slow_fraction: float = SLOW_FRACTION,
        hosted: bool = False,
    ) -> None:
        self.speed_factor = speed_factor
        self.hosted = hosted  # the drones already share processes: hosting is no longer the remedy
        self.window_s = window_s
        self.slow_fraction = slow_fraction
        self._samples: deque[tuple[float, float]] = deque()
        self._warned = False

    @classmethod
    def for_plan(cls, plan: SpawnPlan) -> PaceMonitor | None:
        """A monitor for a paced swarm; None in lockstep, whose clock is the drones' own."""
        if plan.lockstep or plan.speed_factor <= 0:
            return None
        return cls(plan.speed_factor, hosted=plan.drones_per_process != 1)

    def observe(self, wall_s: float, drone_time_s: float | None) -> None:
        """One sample: the wall clock and the slowest drone's simulated time (None while unknown)."""
        if drone_time_s is None:
            return
        self._samples.append((wall_s, drone_time_s))
        while len(self._samples) > 2 and wall_s - self._samples[1][0] >= self.window_s:
            self._samples.popleft()

    def update(self, wall_s: float, drone_time_s: float | None) -> str | None:
        """``observe``, then ``warning``: what the supervisor's loop calls on each tick."""
        self.observe(wall_s, drone_time_s)
        return self.warning()

    def rate(self) -> float | None:
        """Simulated seconds per wall second over the last full window; None until a window has passed."""
        if len(self._samples) < 2:
            return None
        (w0, t0), (w1, t1) = self._samples[0], self._samples[-1]
        if w1 - w0 < self.window_s:
            return None
        return (t1 - t0) / (w1 - w0)

    def warning(self) -> str | None:
        """A one-line warning the first time the swarm runs clearly slower than requested, else None."""
        rate = self.rate()
        if self._warned or rate is None or rate >= self.slow_fraction * self.speed_factor:
            return None
        self._warned = True
        # Each drone process pays for its own wake-ups and cache refills; hosting several drones per process
        # removes most of that cost (docs/benchmark-history.md), so it is the first remedy while each drone has its own.
        remedies = "" if self.hosted else "--drones-per-process auto (several drones share each process), "
        return (
            f"swarm: warning: the drones run at {rate:.2f}x real time, slower than the requested "
            f"{self.speed_factor:g}x (this machine is short of CPU); the supervisor's timing runs ahead of them. "
            f"{remedies}Fewer drones, a lower --speed, or --lockstep (results independent of the machine's load) "
            "avoid it"
        )
