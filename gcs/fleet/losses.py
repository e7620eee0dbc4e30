"""Drones the swarm has lost, as the ground station records them: when, why, and where each came down.

A drone is lost when its flight software ends for any reason (the simulation harness says how), when it crashes
(a collision, a motor failure), or when its link stays silent (nothing heard for the link-loss time). The supervisor
records each loss once; formations and behaviours plan over the drones that are not lost, and the flight report
lists every loss. A silent drone that is heard again is taken back, as QGroundControl says "communication regained":
its loss ends (``regained_s``) and what the swarm flies takes it in again (gcs/command/degrade.py ``apply_regain``).
"""

from __future__ import annotations

import enum
import math
from collections.abc import Sequence
from dataclasses import dataclass


@dataclass(frozen=True, slots=True, kw_only=True)
class DroneLoss:
    sysid: int
    time_s: float  # on the supervisor's clock (simulated seconds)
    cause: str  # one line: "process killed by SIGKILL", "crashed: Collision with drone 2 at 0.61 m", "link lost"
    down_ne_m: tuple[float, float] | None = None  # where it came to rest, north/east of the swarm origin, once known
    silent: bool = False  # lost because nothing was heard from it: taken back when it is heard again
    regained_s: float | None = None  # when it was heard again (supervisor's clock), for a silent loss that ended


# How far from a wreck (centre to centre, horizontally) a survivor lands: two collision radii (0.7 m for the F450)
# and twice a landing's lateral error to spare.
WRECK_CLEARANCE_M = 1.5
LANDING_SEARCH_STEP_M = 0.25  # the rings searched for a clear landing point, up to 10 m out, 16 bearings each
LANDING_SEARCH_RINGS = 40
LANDING_SEARCH_BEARINGS = 16


def landing_clear_of(position_ne_m: tuple[float, float], wrecks_ne_m: Sequence[tuple[float, float]],
                     clearance_m: float = WRECK_CLEARANCE_M) -> tuple[float, float] | None:  # fmt: skip
    """Where a drone hovering at ``position_ne_m`` should land to stay ``clearance_m`` from every wreck: None when
    straight down is clear already; else the nearest clear point on rings of LANDING_SEARCH_STEP_M around it, each
    ring searched from the direction straight away from the nearest wreck (north when right above it). A pilot
    side-steps a wreck before descending; PX4 lands where it is."""
    north, east = position_ne_m

    def clear(n: float, e: float) -> bool:
        return all(math.hypot(n - wn, e - we) >= clearance_m - 1e-9 for wn, we in wrecks_ne_m)

    if clear(north, east):
        return None
    _, wn, we = min((math.hypot(north - wn, east - we), wn, we) for wn, we in wrecks_ne_m)
    away = math.atan2(east - we, north - wn) if math.hypot(north - wn, east - we) > 1e-6 else 0.0
    for ring in range(1, LANDING_SEARCH_RINGS + 1):
        radius = ring * LANDING_SEARCH_STEP_M
        for k in range(LANDING_SEARCH_BEARINGS):  # away first, then alternately either side of it
            bearing = away + (k + 1) // 2 * (1 if k % 2 else -1) * 2.0 * math.pi / LANDING_SEARCH_BEARINGS
            n, e = north + radius * math.cos(bearing), east + radius * math.sin(bearing)
            if clear(n, e):
                return n, e
    return None  # wrecks all around for 10 m: nothing better than straight down


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


def regain_line(loss: DroneLoss) -> str:
    """The supervisor's one line for a silent drone heard again: ``drone 3 link regained at t=27.0 s (lost 1.6 s)``."""
    regained_s = loss.time_s if loss.regained_s is None else loss.regained_s
    return f"drone {loss.sysid} link regained at t={regained_s:.1f} s (lost {regained_s - loss.time_s:.1f} s)"
