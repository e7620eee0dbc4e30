"""What a mode unit (sitl/autopilot/modes.py) is given and what it gives back.

A unit reads only the values of ``ModeInputs``, taken for the one call, and answers with what it decided: from
``setpoint`` a setpoint, or a ``Track`` of the shared smooth reference; from ``advance`` and ``on_touchdown`` a
``ModeDecision`` (a text, a speed limit, a new target, a mode it asks for). It never calls back into the commander:
the commander carries the decision out, and stays the one authority for mode transitions (a unit asks for a mode,
the commander enters it its own way: a return to launch is planned and refused when not flying, as when the operator
asks for one). A unit is then a function of its own state and its inputs, which is what lets a compiled steady-state
tick later replace the loop without calling back into Python.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from sitl.autopilot.guidance import Floats3, MotionLimits
from sitl.autopilot.px4_modes import Px4Mode
from sitl.estimation.estimator import Estimate
from sitl.mathutil import Vec3, fast_constructor
from sitl.params import ParamStore


@dataclass(frozen=True, slots=True, kw_only=True)
class ModeParams:
    """The parameters the units read, taken from the store once per change of it (the units run on every tick)."""

    limits: MotionLimits  # the auto modes' speeds and accelerations (MPC_XY_CRUISE, MPC_Z_V_AUTO_*, MPC_ACC_*)
    takeoff_speed_mps: float  # MPC_TKO_SPEED
    land_speed_mps: float  # MPC_LAND_SPEED
    acceptance_radius_m: float  # NAV_ACC_RAD: a mission item without its own radius is reached within this
    mission_takeoff_alt_m: float  # MIS_TAKEOFF_ALT: a mission started on the ground climbs this far above home
    rtl_return_alt_m: float  # RTL_RETURN_ALT above home
    rtl_descend_alt_m: float  # RTL_DESCEND_ALT above home

    @classmethod
    def from_store(cls, params: ParamStore) -> ModeParams:
        return cls(
            limits=MotionLimits(
                speed_xy_mps=params["MPC_XY_CRUISE"],
                speed_up_mps=params["MPC_Z_V_AUTO_UP"],
                speed_down_mps=params["MPC_Z_V_AUTO_DN"],
                accel_xy_mps2=params["MPC_ACC_HOR"],
                accel_z_mps2=params["MPC_ACC_UP_MAX"],
            ),
            takeoff_speed_mps=params["MPC_TKO_SPEED"],
            land_speed_mps=params["MPC_LAND_SPEED"],
            acceptance_radius_m=params["NAV_ACC_RAD"],
            mission_takeoff_alt_m=params["MIS_TAKEOFF_ALT"],
            rtl_return_alt_m=params["RTL_RETURN_ALT"],
            rtl_descend_alt_m=params["RTL_DESCEND_ALT"],
        )


@dataclass(frozen=True, slots=True, kw_only=True)
class ModeInputs:
    """Everything a unit reads in one call, taken just before it. The arrays are the commander's own, lent for the
    call: a unit reads them and keeps none of them."""

    est: Estimate
    now_s: float  # simulation time
    landed: bool  # the land detector's verdict
    home_ned_m: Vec3
    home_yaw_rad: float
    reference_ned_m: Floats3  # where the shared smooth reference is now
    target_ned_m: Vec3  # the point the reference is heading for
    target_yaw_rad: float  # NaN: keep the heading
    speed_override_mps: float  # DO_CHANGE_SPEED's limit on the auto modes' speed; inf: none
    params: ModeParams


new_mode_inputs = fast_constructor(ModeInputs)  # built at least twice per tick


@dataclass(frozen=True, slots=True, kw_only=True)
class Goto:
    """Send the shared smooth reference to a new target; it continues from where it is, so a new target, or a new
    mode, never makes the reference jump."""

    target_ned_m: Vec3
    yaw_rad: float = math.nan  # NaN: keep the heading
    from_rest: bool = False  # first restart the reference at rest at the vehicle's position (leaving the ground)


@dataclass(frozen=True, slots=True, kw_only=True)
class Track:
    """A unit's setpoint when it flies the shared reference: the commander advances the reference towards the
    target within these limits and flies it. ``descend_to_land``: descend into the ground at the landing speed
    instead of to the target's altitude, the land detector ending the descent."""

    limits: MotionLimits
    max_speed_mps: float
    descend_to_land: bool = False


@dataclass(frozen=True, slots=True, kw_only=True)
class ModeDecision:
    """What a unit decided besides its setpoint. The commander carries it out in the order of the fields: the text,
    the speed limit, the target, then the mode asked for."""

    text: str | None = None  # something the ground station should hear (an info STATUSTEXT)
    speed_limit_mps: float | None = None  # a mission's DO_CHANGE_SPEED; <= 0 restores the default
    goto: Goto | None = None
    request: Px4Mode | None = None  # the mode the unit asks the commander for


NO_CHANGE = ModeDecision()
