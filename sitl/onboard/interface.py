"""What an onboard behaviour sees each step and what it returns: plain frozen dataclasses, no simulator inside.

A behaviour is a class with a ``step(state) -> OnboardSetpoint | None`` method, a ``RATE_HZ`` and a ``PARAMS``
table; it knows only what a real drone knows: its own estimate, its neighbour table (positions heard by relay or
mesh), its camera's detections, its own parameters and the messages a ground station sent it. Positions are in the
drone's own local NED frame (origin where it booted), as PX4's local position is. Because nothing here depends on
the simulator, the same class can run on a companion computer beside a real PX4, fed from MAVLink and returning
offboard setpoints (docs/onboard.md says what that takes).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import ClassVar, Protocol

Vec3 = tuple[float, float, float]
NAN3: Vec3 = (math.nan, math.nan, math.nan)


@dataclass(frozen=True, slots=True, kw_only=True)
class NeighbourReport:
    """Another drone as its last position report said, converted to this drone's local frame."""

    sysid: int
    pos_ned_m: Vec3
    vel_ned_mps: Vec3
    age_s: float  # since the report was true (lockstep) or arrived (paced)


@dataclass(frozen=True, slots=True, kw_only=True)
class Detection:
    """A body the camera saw, relative to this drone (its centre minus this drone's position), NED."""

    rel_pos_ned_m: Vec3
    radius_m: float
    age_s: float


@dataclass(frozen=True, slots=True, kw_only=True)
class GroundMessage:
    """A value a ground station sent this drone (MAVLink NAMED_VALUE_FLOAT: a name of at most 10 characters)."""

    name: str
    value: float
    time_s: float  # when it arrived


@dataclass(frozen=True, slots=True, kw_only=True)
class OnboardState:
    """Everything a behaviour gets at one step."""

    time_s: float
    sysid: int
    pos_ned_m: Vec3  # the drone's own estimate, local frame
    vel_ned_mps: Vec3
    yaw_rad: float
    armed: bool
    in_air: bool
    neighbours: tuple[NeighbourReport, ...]
    detections: tuple[Detection, ...]
    params: Mapping[str, float]  # the behaviour's own parameters (``PARAMS``), their current values
    messages: tuple[GroundMessage, ...]  # arrived since the last step


@dataclass(frozen=True, slots=True, kw_only=True)
class OnboardSetpoint:
    """What the behaviour asks of the position controller, local frame: as SET_POSITION_TARGET_LOCAL_NED, a NaN
    component is not commanded (a velocity alone is tracked as a velocity)."""

    pos_ned_m: Vec3 = NAN3
    vel_ned_mps: Vec3 = NAN3
    acc_ned_mps2: Vec3 = NAN3
    yaw_rad: float = math.nan


class OnboardBehaviour(Protocol):
    """The shape of a user's class (it need not inherit anything)."""

    RATE_HZ: ClassVar[float]  # steps per simulated second (at most the physics rate)
    # The behaviour's parameters: MAVLink parameters of the drone (settable from QGroundControl, MAVSDK, missions),
    # name (at most 16 characters: A-Z, 0-9, _) -> (default, min, max).
    PARAMS: ClassVar[Mapping[str, tuple[float, float, float]]]

    def step(self, state: OnboardState) -> OnboardSetpoint | None:
        """The setpoint for now; None keeps the drone where it is (a position hold at the current estimate)."""
        ...
