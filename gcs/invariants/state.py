"""One instant of a flight as the invariants see it (pure data, built by the supervisor at each tick).

Everything is what the ground station knows: reported positions in the swarm frame (NED metres from the origin,
down negative above it), the slots it commands, its own record of losses, failsafes, injected faults and commands
awaiting their answer. The one piece of truth is a contact, which the simulated drone itself reports from its world
(a STATUSTEXT ``Collision with drone N``), as the flight report counts it.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

Vec3 = tuple[float, float, float]

# The events an ``eventually`` invariant's window opens on (gcs/invariants/spec.py ``TRIGGERS``)
START = "start"  # the flight's first tick
LOSS = "loss"  # a drone was lost (a crash, a silent link)
FAULT = "fault"  # a fault was injected
STEP = "step"  # a mission step (a verb that changes what the swarm flies) began


@dataclass(frozen=True, slots=True, kw_only=True)
class TickState:
    """What the supervisor knows at one tick (see the module docstring)."""

    time_s: float  # mission time
    positions_ned_m: Mapping[int, Vec3]  # live drones (not lost) with a position, by sysid
    airborne: frozenset[int] = frozenset()  # of those, the ones armed and in the air
    attached_ned_m: Mapping[int, Vec3] = field(default_factory=dict)  # attached vehicles' last known positions
    slots_ned_m: Mapping[int, Vec3] = field(default_factory=dict)  # the slots commanded now, by sysid
    contacts: tuple[tuple[int, str], ...] = ()  # contacts reported since the last tick: (sysid, text)
    failsafes: tuple[tuple[int, str], ...] = ()  # failsafes entered since the last tick: (sysid, text)
    faulted: frozenset[int] = frozenset()  # drones a fault was injected into, so far
    unanswered_s: Mapping[int, float] = field(default_factory=dict)  # oldest command awaiting an answer: its age
    events: frozenset[str] = frozenset()  # triggers at this tick (START, LOSS, FAULT, STEP)
    lost: frozenset[int] = frozenset()  # drones lost so far
