"""Drones the swarm has lost, as the ground station records them: when, why, and where each came down.

A drone is lost when its flight software ends for any reason (the simulation harness says how), when it crashes
(a collision, a motor failure), or when its link stays silent (no HEARTBEAT for the link-loss time). The supervisor
records each loss once; formations and behaviours plan over the drones that are not lost, and the flight report
lists every loss.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass


@dataclass(frozen=True, slots=True, kw_only=True)
class DroneLoss:
    sysid: int
    time_s: float  # on the supervisor's clock (simulated seconds)
    cause: str  # one line: "process killed by SIGKILL", "crashed: Collision with drone 2 at 0.61 m", "link lost"
    down_ne_m: tuple[float, float] | None = None  # where it came to rest, north/east of the swarm origin, once known


# HEARTBEAT system_status values the ground station acts on (MAV_STATE): PX4 reports CRITICAL while a failsafe acts
# and FLIGHT_TERMINATION once the vehicle has crashed or terminated; the latter is a lost drone.
MAV_STATE_CRITICAL = 5
MAV_STATE_FLIGHT_TERMINATION = 8


class LossPolicy(enum.Enum):
    """What the survivors do when the swarm loses a drone (``swarm up --loss-policy``, ``[swarm] loss_policy``).

    continue: the current formation or behaviour re-plans over the survivors (a circle of 6 becomes a circle of 5);
    hold: the survivors stop where they are (PX4 Hold mode); land: they land where they are; abort: they return to
    launch and land (PX4 Return), as a pilot aborts a flight.
    """

    CONTINUE = "continue"
    HOLD = "hold"
    LAND = "land"
    ABORT = "abort"


LOSS_POLICIES = tuple(p.value for p in LossPolicy)


def loss_line(loss: DroneLoss) -> str:
    """The supervisor's one line for a loss: ``drone 3 lost at t=22.4 s: process killed by SIGKILL``."""
    return f"drone {loss.sysid} lost at t={loss.time_s:.1f} s: {loss.cause}"
