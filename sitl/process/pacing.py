"""Wall-clock pacing of simulation time (pure: the caller passes clock readings in).

At speed factor s, simulation time t_sim should equal s * (wall - wall_at_start). The runtime asks how many physics
steps are due, runs them in one batch (cheaper than waking 400 times a second), then sleeps until the next one is
due. If the machine falls behind, it catches up at most ``max_catchup_s`` of simulation time at once and then
drops the remaining lag (re-anchors), so a stall does not turn into a long burst of unpaced flight.
A speed factor of 0 means unpaced: run as fast as the CPU allows.
"""

from __future__ import annotations

import math


class Pacer:
    def __init__(self, speed_factor: float, dt_s: float, start_wall_s: float, max_catchup_s: float = 0.25) -> None:
        if speed_factor < 0 or not math.isfinite(speed_factor):
            raise ValueError(f"speed factor must be >= 0, got {speed_factor}")
        self.speed_factor = speed_factor
        self.dt_s = dt_s
        self._anchor_wall_s = start_wall_s
        self._anchor_sim_s = 0.0
        self._max_catchup_s = max_catchup_s
        self.dropped_s = 0.0  # simulation time given up to lag (0 when the machine keeps up)

    @property
    def unpaced(self) -> bool:
        return self.speed_factor == 0.0

    def target_sim_s(self, now_wall_s: float) -> float:
        return self._anchor_sim_s + (now_wall_s - self._anchor_wall_s) * self.speed_factor

    def steps_due(self, now_wall_s: float, sim_time_s: float, max_batch: int = 400) -> int:
        if self.unpaced:
            return max_batch
        lag_s = self.target_sim_s(now_wall_s) - sim_time_s
        if lag_s > self._max_catchup_s:
            self.dropped_s += lag_s - self._max_catchup_s
            self._anchor_wall_s = now_wall_s
            self._anchor_sim_s = sim_time_s + self._max_catchup_s
            lag_s = self._max_catchup_s
        return max(0, min(max_batch, int(lag_s / self.dt_s + 1e-9)))

    def rebase(self, now_wall_s: float, sim_time_s: float) -> None:
        """Pace from here on: ``sim_time_s`` is due now (after a stretch run unpaced on purpose)."""
        self._anchor_wall_s = now_wall_s
        self._anchor_sim_s = sim_time_s

    def wall_time_of(self, sim_time_s: float) -> float:
        """When (wall clock) simulation time ``sim_time_s`` is due."""
        if self.unpaced:
            return -math.inf
        return self._anchor_wall_s + (sim_time_s - self._anchor_sim_s) / self.speed_factor
