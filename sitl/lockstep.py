"""Lockstep: every drone of a swarm advances simulated time together, as fast as the CPU allows.

Paced drones each follow the wall clock on their own, so their simulated clocks drift apart by whatever each
process's scheduling costs, and nothing can run faster than the slowest drone keeps up with. In lockstep the clock
lives in the shared world instead (sitl/world.py): every member publishes how many physics steps it has completed,
and a member may complete step k + 1 only when every other member has completed step k and the supervisor's gate
allows k + 1. Hence

- no member is ever more than one physics step ahead of any other (skew <= one step, by construction), and
- the supervisor, which moves the gate after each of its own loop iterations, is never more than its lead behind
  the drones: its setpoint streaming, timeouts and mission timing all run on the same simulated clock.

All members must share one physics rate (the supervisor starts them so). A row that is no member holds an infinite step
count, so the common time is simply the column's minimum; a member that leaves (exits, or is killed and removed by
the supervisor) goes back to infinity and no longer holds anyone back. Step counts only grow and every cell has a single
writer, so a stale read can only make a member wait a little longer, never run ahead; no lock is needed.
"""

from __future__ import annotations

import math

import numpy as np

from sitl.world import GATE_OPEN, GATE_STEP, STEP, SharedWorld


class LockstepMember:
    """A drone's side: join, ask how many steps it may take, publish each completed step, leave."""

    def __init__(self, world: SharedWorld, instance: int) -> None:
        self.world = world
        self.instance = instance
        self._steps = world.table[:, STEP]  # a view: reading it costs one reduction, no copy
        self._header = world.header

    def join(self) -> None:
        self._steps[self.instance] = 0.0

    def steps_allowed(self, completed: int) -> tuple[int, bool]:
        """(steps this member may take now, whether the supervisor's gate is what holds it).

        Its own count is in the column too: while another member is behind, the minimum is that member's and this
        one may go no further than one step past it; when this one is the slowest, it may take one step (everyone
        else has completed at least as many)."""
        header = self._header
        gate = float(header[GATE_STEP]) if header[GATE_OPEN] == 1.0 else 0.0
        peers = float(self._steps.min()) + 1.0
        limit = min(peers, gate)
        return max(0, int(limit) - completed), gate <= peers

    def completed(self, steps: int) -> None:
        self._steps[self.instance] = float(steps)

    def leave(self) -> None:
        self._steps[self.instance] = math.inf


class LockstepGate:
    """The supervisor's side: how far the members have got, and how far they may go."""

    def __init__(self, world: SharedWorld, dt_s: float) -> None:
        self.world = world
        self.dt_s = dt_s

    def members(self) -> int:
        return int(np.count_nonzero(np.isfinite(self.world.table[:, STEP])))

    def completed_steps(self) -> int:
        """Steps every member has completed (the swarm's common time, in steps); 0 before anyone joined."""
        low = float(self.world.table[:, STEP].min())
        return int(low) if math.isfinite(low) else 0

    def time_s(self) -> float:
        return self.completed_steps() * self.dt_s

    def open_until(self, sim_time_s: float) -> None:
        """Let every member run until ``sim_time_s`` (the gate never moves back)."""
        step = math.floor(sim_time_s / self.dt_s + 1e-9)
        header = self.world.header
        if step > header[GATE_STEP]:
            header[GATE_STEP] = float(step)
        header[GATE_OPEN] = 1.0

    def remove(self, instance: int) -> None:
        """A member that died without leaving must not hold the others back."""
        self.world.table[instance, STEP] = math.inf
