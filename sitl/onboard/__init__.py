"""Onboard behaviours: a user's Python class that runs on every drone, at its own rate, and flies it from what a
real drone would know (docs/onboard.md). ``interface`` is what the class sees and returns (plain dataclasses, no
simulator inside: the same class can run on a companion computer beside PX4); ``loader`` reads it from a file;
``runner`` runs it in a simulated drone.
"""

from sitl.onboard.interface import (
    Detection,
    GroundMessage,
    NeighbourReport,
    OnboardSetpoint,
    OnboardState,
)

__all__ = ["Detection", "GroundMessage", "NeighbourReport", "OnboardSetpoint", "OnboardState"]
