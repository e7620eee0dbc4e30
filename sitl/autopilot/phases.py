"""Typed phases of the modes that run in stages, so a phase is a name the type checker knows, not a string."""

from __future__ import annotations

from enum import Enum


class RtlPhase(Enum):
    """Return to launch, in the order it runs (PX4's RTL states for a multicopter)."""

    CLIMB = "climb"  # straight up to the return altitude (RTL_RETURN_ALT above home, never lower than now)
    RETURN = "return"  # level flight to above home at the return altitude
    DESCEND = "descend"  # down to RTL_DESCEND_ALT above home
    LAND = "land"  # the landing descent; the land detector ends it


class MissionPhase(Enum):
    """Where a mission run stands, beside the executor's own item progress (sitl/autopilot/mission_exec.py)."""

    NAVIGATE = "navigate"  # flying the items
    CLIMB = "climb"  # started on the ground with no takeoff item: climbing to MIS_TAKEOFF_ALT first, as PX4
    LAND = "land"  # descending onto a LAND item's point


class OrbitPhase(Enum):
    """Where an orbit stands (PX4's FlightTaskOrbit: ``_in_circle_approach`` or circling)."""

    APPROACH = "approach"  # the shared reference flies to the nearest point of the circle, at the circle's altitude
    CIRCLE = "circle"  # on the circle: the unit's own setpoint, the phase advancing at speed / radius
