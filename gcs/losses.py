"""Drones the swarm has lost, as the ground station records them: when, why, and where each came down.

A drone is lost when its process ends for any reason, when it crashes (a collision, a motor failure), or when its
link stays silent (no HEARTBEAT for the link-loss time). The supervisor records each loss once; formations and
behaviours plan over the drones that are not lost, and the flight report lists every loss.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True, slots=True, kw_only=True)
class DroneLoss:
    sysid: int
    time_s: float  # on the supervisor's clock (simulated seconds)
    cause: str  # one line: "process killed by SIGKILL", "crashed: Collision with drone 2 at 0.61 m", "link lost"
    down_ne_m: tuple[float, float] | None = None  # where it came to rest, north/east of the swarm origin, once known
