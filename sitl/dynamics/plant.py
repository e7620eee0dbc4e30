"""The Plant interface: what the rest of the drone needs from a flight-dynamics model.

A plant advances the true physical state by one fixed physics step given normalised motor commands. Everything
downstream (sensors, the shared world, collision checks) reads the true state from ``PlantState``; the controller
never does, it flies on the estimate built from sensors.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

from sitl.mathutil import Quat, Vec3

# The physics step rate every plant and simulation uses by default: PX4's SITL rate (docs/control.md).
PHYSICS_RATE_HZ = 250.0

# PX4 SITL default home (Zurich), used when no home is given.
DEFAULT_HOME_LAT_DEG = 47.397742
DEFAULT_HOME_LON_DEG = 8.545594
DEFAULT_HOME_ALT_AMSL_M = 488.0


@dataclass(frozen=True, slots=True, kw_only=True)
class GeoPoint:
    lat_deg: float
    lon_deg: float
    alt_amsl_m: float


DEFAULT_HOME = GeoPoint(lat_deg=DEFAULT_HOME_LAT_DEG, lon_deg=DEFAULT_HOME_LON_DEG, alt_amsl_m=DEFAULT_HOME_ALT_AMSL_M)


@dataclass(frozen=True, slots=True, kw_only=True)
class PlantState:
    """True state of the vehicle after a physics step. NED is the local frame anchored at home (ground level)."""

    time_s: float
    pos_ned_m: Vec3
    vel_ned_mps: Vec3
    att_q_frd_to_ned: Quat  # (w, x, y, z)
    rates_frd_radps: Vec3
    # What an ideal accelerometer at the CG reads: (total non-gravitational force) / mass, body frame.
    specific_force_frd_mps2: Vec3
    geo: GeoPoint
    on_ground: bool
    motor_speeds_radps: tuple[float, ...]


class Plant(Protocol):
    """A fixed-step flight-dynamics model."""

    @property
    def dt_s(self) -> float: ...

    def state(self) -> PlantState: ...

    def step(self, motor_cmds: tuple[float, ...] | list[float]) -> PlantState:
        """Advance one physics step with motor commands in [0, 1] (0 = stopped, 1 = max rotor speed)."""
        ...

    def set_wind(self, wind_ned_mps: Vec3) -> None:
        """Steady wind plus any gust the caller adds, in NED (the direction the air moves towards)."""
        ...
