"""PX4's Orbit (flight_mode_manager/tasks/Orbit/FlightTaskOrbit.cpp), the pure half: what circle a
MAV_CMD_DO_ORBIT asks for, where the circle is entered, and the setpoint on it at a phase.

A command is read against the orbit flown now, as PX4's ``applyCommandParameters``: what it leaves out (NaN) keeps
the current value, or for a new orbit takes PX4's default (radius ``ORBIT_RADIUS_MIN_M``, ``ORBIT_DEFAULT_SPEED_MPS``
clockwise, centre and altitude where the vehicle is). The radius' sign is the direction (> 0 clockwise seen from
above), a negative speed reverses it. A radius outside 1 m .. MC_ORBIT_RAD_MAX is refused; a speed is cut to
MPC_XY_VEL_MAX and then to the centripetal limit ``ORBIT_ACCEL_MAX_MPS2``, a smaller circle being safer than a faster
one. The mode unit that flies a plan is ``Orbit`` in sitl/autopilot/modes.py; the request that starts one is
``RequestHandler.orbit`` (sitl/autopilot/requests.py).

Plain floats and ``math`` only: this runs at every commander tick of an orbit and must give the same bits on every
CPU (docs/architecture.md, "The same flight on every CPU").
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Final

from sitl.autopilot.guidance import Floats3
from sitl.autopilot.vehicle_api import OrbitYaw

ORBIT_RADIUS_MIN_M: Final = 1.0  # PX4's _radius_min: the smallest circle, and a new orbit's radius when none is given
ORBIT_DEFAULT_SPEED_MPS: Final = 1.0  # a new orbit's tangential speed when none is given (PX4: 1 m/s clockwise)
ORBIT_ACCEL_MAX_MPS2: Final = 2.0  # PX4's hard-coded centripetal limit: v^2 / r stays below it
# The vehicle is on the circle within these (PX4's _horizontal_acceptance_radius and NAV_MC_ALT_RAD's default): a new
# command flown from there keeps circling instead of approaching the circle again.
ORBIT_ON_CIRCLE_M: Final = 1.0
ORBIT_ON_CIRCLE_ALT_M: Final = 0.8


@dataclass(frozen=True, slots=True, kw_only=True)
class OrbitCommand:
    """MAV_CMD_DO_ORBIT in the local frame (sitl/drone/sim_vehicle_api.py converts the geodetic centre). NaN (None
    for the yaw) means "not given"."""

    radius_m: float = math.nan  # signed: > 0 clockwise seen from above
    velocity_mps: float = math.nan  # negative reverses the direction
    yaw: OrbitYaw | None = None
    centre_north_m: float = math.nan  # the centre is given when north and east both are
    centre_east_m: float = math.nan
    centre_down_m: float = math.nan  # the circle's altitude


@dataclass(frozen=True, slots=True, kw_only=True)
class OrbitPlan:
    """The circle being flown."""

    centre_ned_m: Floats3  # its down coordinate is the circle's altitude
    radius_m: float  # > 0
    clockwise: bool  # seen from above (kept apart from the speed, which may be zero)
    speed_mps: float  # tangential, >= 0, within MPC_XY_VEL_MAX and the centripetal limit
    yaw: OrbitYaw
    initial_yaw_rad: float  # the heading when the command came (OrbitYaw.INITIAL_HEADING)

    @property
    def signed_speed_mps(self) -> float:
        """The speed along the direction of increasing phase (the phase grows clockwise seen from above)."""
        return self.speed_mps if self.clockwise else -self.speed_mps

    @property
    def signed_radius_m(self) -> float:
        """The radius as MAV_CMD_DO_ORBIT and ORBIT_EXECUTION_STATUS sign it: > 0 clockwise."""
        return self.radius_m if self.clockwise else -self.radius_m


def plan_orbit(
    command: OrbitCommand,
    current: OrbitPlan | None,
    pos_ned_m: Floats3,
    yaw_rad: float,
    *,
    radius_max_m: float,
    speed_max_mps: float,
) -> OrbitPlan | None:
    """The circle ``command`` asks for, read against ``current`` (None: not orbiting) from the vehicle at
    ``pos_ned_m`` heading ``yaw_rad``; None when its radius is outside ``ORBIT_RADIUS_MIN_M`` .. ``radius_max_m``
    (PX4: "Orbit radius limit exceeded")."""
    radius = current.radius_m if current is not None else ORBIT_RADIUS_MIN_M
    clockwise = current.clockwise if current is not None else True
    speed = current.speed_mps if current is not None else ORBIT_DEFAULT_SPEED_MPS
    if math.isfinite(command.radius_m):
        clockwise = command.radius_m > 0.0
        radius = abs(command.radius_m)
    if math.isfinite(command.velocity_mps):
        speed = command.velocity_mps
    if not ORBIT_RADIUS_MIN_M <= radius <= radius_max_m:
        return None
    if speed < 0.0:  # PX4 multiplies the direction by the signed speed
        clockwise, speed = not clockwise, -speed
    speed = min(speed, abs(speed_max_mps))
    if speed * speed >= ORBIT_ACCEL_MAX_MPS2 * radius:
        speed = math.sqrt(ORBIT_ACCEL_MAX_MPS2 * radius)
    yaw = command.yaw if command.yaw is not None else (current.yaw if current is not None else OrbitYaw.FRONT_TO_CENTRE)
    north, east, down = current.centre_ned_m if current is not None else pos_ned_m
    if math.isfinite(command.centre_north_m) and math.isfinite(command.centre_east_m):
        north, east = command.centre_north_m, command.centre_east_m
    if math.isfinite(command.centre_down_m):
        down = command.centre_down_m
    return OrbitPlan(
        centre_ned_m=(north, east, down),
        radius_m=radius,
        clockwise=clockwise,
        speed_mps=speed,
        yaw=yaw,
        initial_yaw_rad=yaw_rad,
    )


def on_circle(plan: OrbitPlan, pos_ned_m: Floats3) -> bool:
    """Is the vehicle on the circle (PX4's ``_is_position_on_circle``)?"""
    north, east, down = plan.centre_ned_m
    off_m = math.hypot(pos_ned_m[0] - north, pos_ned_m[1] - east) - plan.radius_m
    return abs(off_m) < ORBIT_ON_CIRCLE_M and abs(pos_ned_m[2] - down) < ORBIT_ON_CIRCLE_ALT_M


def entry_phase_rad(plan: OrbitPlan, pos_ned_m: Floats3) -> float:
    """The phase of the circle's point nearest ``pos_ned_m`` (0 north of the centre, growing clockwise seen from
    above); due north from the centre itself, as PX4 enters from its phase 0."""
    north, east, _ = plan.centre_ned_m
    d_north, d_east = pos_ned_m[0] - north, pos_ned_m[1] - east
    if math.hypot(d_north, d_east) < 1e-6:
        return 0.0
    return math.atan2(d_east, d_north) % math.tau


def circle_point(plan: OrbitPlan, phase_rad: float) -> Floats3:
    """The point of the circle at ``phase_rad``, at the circle's altitude."""
    north, east, down = plan.centre_ned_m
    return (north + plan.radius_m * math.cos(phase_rad), east + plan.radius_m * math.sin(phase_rad), down)


def bearing_to_centre_rad(plan: OrbitPlan, pos_ned_m: Floats3) -> float:
    """The heading that faces the centre from ``pos_ned_m``."""
    north, east, _ = plan.centre_ned_m
    return math.atan2(east - pos_ned_m[1], north - pos_ned_m[0])


def heading_on_circle(plan: OrbitPlan, pos_ned_m: Floats3, speed_mps: float) -> tuple[float, float]:
    """(yaw, yaw rate) on the circle for the plan's yaw behaviour, at the vehicle's position and the signed speed
    flown now, as PX4's ``_generate_circle_yaw_setpoints``; NaN where the heading is left to the controller (a NaN
    yaw with a zero rate holds the heading, both NaN keep the last heading setpoint)."""
    rate = speed_mps / plan.radius_m  # the turn rate of a heading fixed to the circle
    yaw = plan.yaw
    if yaw is OrbitYaw.INITIAL_HEADING:
        return plan.initial_yaw_rad, math.nan
    if yaw is OrbitYaw.UNCONTROLLED:
        return math.nan, 0.0
    if yaw is OrbitYaw.RC_CONTROLLED:  # no RC: the yaw stick stays centred
        return math.nan, math.nan
    if yaw is OrbitYaw.TANGENT:
        north, east, _ = plan.centre_ned_m
        sign = 1.0 if plan.clockwise else -1.0
        return math.atan2(sign * (pos_ned_m[0] - north), -sign * (pos_ned_m[1] - east)), rate
    return bearing_to_centre_rad(plan, pos_ned_m), rate
