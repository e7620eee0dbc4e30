"""PX4's Orbit, pure: what a DO_ORBIT asks for against the orbit flown (``plan_orbit``), and the mode unit given its
``ModeInputs`` (the approach to the circle's nearest point, the circle's setpoints, the yaw behaviours)."""

from __future__ import annotations

import itertools
import math
from dataclasses import replace

import numpy as np
import pytest

from sitl.autopilot.guidance import MotionLimits
from sitl.autopilot.mode_io import ModeInputs, ModeParams, Track
from sitl.autopilot.modes import Orbit
from sitl.autopilot.orbit import (
    ORBIT_ACCEL_MAX_MPS2,
    ORBIT_DEFAULT_SPEED_MPS,
    ORBIT_RADIUS_MIN_M,
    OrbitCommand,
    OrbitPlan,
    on_circle,
    plan_orbit,
)
from sitl.autopilot.phases import OrbitPhase
from sitl.autopilot.vehicle_api import OrbitYaw
from sitl.control.cascade import TrajectorySetpoint
from sitl.estimation.estimator import Estimate

NAN = math.nan
RAD_MAX_M = 1000.0  # MC_ORBIT_RAD_MAX's default
VEL_MAX_MPS = 12.0  # MPC_XY_VEL_MAX's default
ACCEL_XY_MPS2 = 3.0  # MPC_ACC_HOR's default
HERE = (10.0, 20.0, -5.0)


def plan(command: OrbitCommand, current: OrbitPlan | None = None, pos: tuple[float, float, float] = HERE) -> OrbitPlan:
    result = plan_orbit(command, current, pos, 0.3, radius_max_m=RAD_MAX_M, speed_max_mps=VEL_MAX_MPS)
    assert result is not None
    return result


# ---- the command read against the orbit flown ------------------------------------------------------------------
def test_a_new_orbit_without_parameters_takes_px4s_defaults_around_the_vehicle() -> None:
    p = plan(OrbitCommand())
    assert (p.radius_m, p.clockwise, p.speed_mps) == (ORBIT_RADIUS_MIN_M, True, ORBIT_DEFAULT_SPEED_MPS)
    assert p.centre_ned_m == HERE and p.yaw is OrbitYaw.FRONT_TO_CENTRE and p.initial_yaw_rad == 0.3


def test_what_a_command_leaves_out_keeps_the_orbit_flown() -> None:
    flown = plan(OrbitCommand(radius_m=-20.0, velocity_mps=4.0, yaw=OrbitYaw.TANGENT, centre_north_m=1.0,
                              centre_east_m=2.0, centre_down_m=-30.0))  # fmt: skip
    again = plan(OrbitCommand(velocity_mps=2.0), current=flown, pos=(99.0, 99.0, -1.0))
    assert (again.radius_m, again.clockwise, again.speed_mps, again.yaw) == (20.0, False, 2.0, OrbitYaw.TANGENT)
    assert again.centre_ned_m == (1.0, 2.0, -30.0)


@pytest.mark.parametrize(
    ("radius_m", "velocity_mps", "clockwise"),
    [(10.0, 2.0, True), (-10.0, 2.0, False), (10.0, -2.0, False), (-10.0, -2.0, True)],
)
def test_the_radius_sign_is_the_direction_and_a_negative_speed_reverses_it(
    radius_m: float, velocity_mps: float, clockwise: bool
) -> None:
    p = plan(OrbitCommand(radius_m=radius_m, velocity_mps=velocity_mps))
    assert (p.radius_m, p.speed_mps, p.clockwise) == (10.0, 2.0, clockwise)
    assert p.signed_radius_m == (10.0 if clockwise else -10.0)


@pytest.mark.parametrize("radius_m", [0.0, 0.5, -0.99, RAD_MAX_M + 0.1, -5000.0])
def test_a_radius_outside_one_metre_to_mc_orbit_rad_max_is_refused(radius_m: float) -> None:
    assert (
        plan_orbit(OrbitCommand(radius_m=radius_m), None, HERE, 0.0, radius_max_m=RAD_MAX_M, speed_max_mps=12.0) is None
    )


def test_the_speed_is_cut_to_mpc_xy_vel_max_then_to_the_centripetal_limit() -> None:
    assert plan(OrbitCommand(radius_m=500.0, velocity_mps=30.0)).speed_mps == VEL_MAX_MPS
    small = plan(OrbitCommand(radius_m=2.0, velocity_mps=5.0))
    assert small.speed_mps == pytest.approx(math.sqrt(ORBIT_ACCEL_MAX_MPS2 * 2.0))


def test_a_centre_needs_both_coordinates_and_the_altitude_stands_alone() -> None:
    p = plan(OrbitCommand(radius_m=5.0, centre_north_m=3.0, centre_down_m=-12.0))
    assert p.centre_ned_m == (HERE[0], HERE[1], -12.0)


# ---- the mode unit ---------------------------------------------------------------------------------------------
LIMITS = MotionLimits(speed_xy_mps=5.0, speed_up_mps=3.0, speed_down_mps=1.5, accel_xy_mps2=ACCEL_XY_MPS2,
                      accel_z_mps2=3.0)  # fmt: skip
PARAMS = ModeParams(limits=LIMITS, takeoff_speed_mps=1.5, land_speed_mps=0.7, acceptance_radius_m=1.0,
                    mission_takeoff_alt_m=2.5, rtl_return_alt_m=30.0, rtl_descend_alt_m=10.0)  # fmt: skip


def inputs(pos: tuple[float, float, float], *, reference: tuple[float, float, float], target: np.ndarray,
           yaw_rad: float = 0.0) -> ModeInputs:  # fmt: skip
    est = Estimate(
        time_s=0.0, pos_ned_m=np.array(pos), vel_ned_mps=np.zeros(3), att_q_frd_to_ned=np.array([1.0, 0, 0, 0]),
        rates_frd_radps=np.zeros(3), roll_rad=0.0, pitch_rad=0.0, yaw_rad=yaw_rad, attitude_valid=True,
        position_valid=True, altitude_valid=True,
    )  # fmt: skip
    return ModeInputs(est=est, now_s=0.0, landed=False, home_ned_m=np.zeros(3), home_yaw_rad=0.0,
                      reference_ned_m=reference, target_ned_m=target, target_yaw_rad=NAN,
                      speed_override_mps=math.inf, params=PARAMS)  # fmt: skip


CIRCLE = OrbitPlan(centre_ned_m=(0.0, 0.0, -10.0), radius_m=10.0, clockwise=True, speed_mps=3.0,
                   yaw=OrbitYaw.FRONT_TO_CENTRE, initial_yaw_rad=0.5)  # fmt: skip


def on_the_circle(unit: Orbit, entry: np.ndarray) -> None:
    """Approach done: the shared reference stands at the entry point."""
    ref = (float(entry[0]), float(entry[1]), float(entry[2]))
    unit.advance(inputs(ref, reference=ref, target=entry))
    assert unit.phase is OrbitPhase.CIRCLE


def test_the_approach_flies_the_shared_reference_to_the_nearest_point_of_the_circle_facing_the_centre() -> None:
    unit = Orbit()
    approach = unit.start(CIRCLE, (0.0, 30.0, -4.0), orbiting=False)
    # Due east of the centre, 20 m outside the circle: the point 10 m east of the centre, at the circle's altitude
    assert approach is not None
    assert approach.target_ned_m.tolist() == pytest.approx([0.0, 10.0, -10.0])
    assert approach.yaw_rad == pytest.approx(-math.pi / 2)  # west, to the centre
    # Until the reference arrives the unit flies a Track of it
    sp = unit.setpoint(inputs((0.0, 25.0, -6.0), reference=(0.0, 25.0, -6.0), target=approach.target_ned_m), 0.01)
    assert isinstance(sp, Track) and unit.phase is OrbitPhase.APPROACH


def test_from_the_centre_itself_the_circle_is_entered_due_north() -> None:
    approach = Orbit().start(CIRCLE, (0.0, 0.0, -10.0), orbiting=False)
    assert approach is not None and approach.target_ned_m.tolist() == pytest.approx([10.0, 0.0, -10.0])


def test_on_the_circle_the_setpoint_starts_at_the_entry_from_rest_and_speeds_up_at_mpc_acc_hor() -> None:
    unit = Orbit()
    approach = unit.start(CIRCLE, (0.0, 30.0, -10.0), orbiting=False)
    assert approach is not None
    on_the_circle(unit, approach.target_ned_m)
    dt = 0.01
    speeds = []
    for _ in range(200):
        sp = unit.setpoint(inputs((0.0, 10.0, -10.0), reference=(0.0, 10.0, -10.0), target=approach.target_ned_m), dt)
        assert isinstance(sp, TrajectorySetpoint)
        n, e, d = sp.pos_ned_m
        assert math.hypot(n, e) == pytest.approx(10.0) and d == -10.0
        speeds.append(math.hypot(*sp.vel_ned_mps[:2]))
        # the velocity is along the circle, the acceleration's radial part is the centripetal v^2 / r
        assert n * sp.vel_ned_mps[0] + e * sp.vel_ned_mps[1] == pytest.approx(0.0, abs=1e-9)
        radial = -(n * sp.acc_ned_mps2[0] + e * sp.acc_ned_mps2[1]) / 10.0
        assert radial == pytest.approx(speeds[-1] ** 2 / 10.0)
    assert speeds[0] == pytest.approx(ACCEL_XY_MPS2 * dt)  # from rest: no jump at the entry
    assert speeds[-1] == pytest.approx(CIRCLE.speed_mps)
    assert max(b - a for a, b in itertools.pairwise(speeds)) <= ACCEL_XY_MPS2 * dt + 1e-12
    # Clockwise seen from above: from due east of the centre it moves south
    assert isinstance(sp, TrajectorySetpoint) and sp.vel_ned_mps[0] < 0.0 and sp.pos_ned_m[0] < 0.0


@pytest.mark.parametrize(
    ("yaw", "expected_yaw", "expected_rate"),
    [
        (OrbitYaw.FRONT_TO_CENTRE, -math.pi / 2, 0.3),  # at due east of the centre: facing west
        (OrbitYaw.TANGENT, math.pi, 0.3),  # clockwise from due east: flying south
        (OrbitYaw.INITIAL_HEADING, 0.5, NAN),
        (OrbitYaw.UNCONTROLLED, NAN, 0.0),  # heading held by a zero rate
        (OrbitYaw.RC_CONTROLLED, NAN, NAN),  # no RC: the last heading setpoint kept
    ],
)
def test_each_yaw_behaviour_as_px4_flies_it(yaw: OrbitYaw, expected_yaw: float, expected_rate: float) -> None:
    unit = Orbit()
    circle = replace(CIRCLE, yaw=yaw)
    approach = unit.start(circle, (0.0, 30.0, -10.0), orbiting=False)
    assert approach is not None
    on_the_circle(unit, approach.target_ned_m)
    unit.speed_mps = circle.speed_mps  # at cruise on the circle
    sp = unit.setpoint(inputs((0.0, 10.0, -10.0), reference=(0.0, 10.0, -10.0), target=approach.target_ned_m), 1e-9)
    assert isinstance(sp, TrajectorySetpoint)
    if math.isnan(expected_yaw):
        assert math.isnan(sp.yaw_rad)
    else:
        assert math.remainder(sp.yaw_rad - expected_yaw, math.tau) == pytest.approx(0.0, abs=1e-6)
    if math.isnan(expected_rate):
        assert math.isnan(sp.yawspeed_radps)
    else:
        assert sp.yawspeed_radps == pytest.approx(expected_rate)


def test_a_new_command_on_the_new_circle_keeps_circling_and_off_it_approaches_again() -> None:
    unit = Orbit()
    approach = unit.start(CIRCLE, (0.0, 30.0, -10.0), orbiting=False)
    assert approach is not None
    on_the_circle(unit, approach.target_ned_m)
    on = (0.0, 10.4, -10.2)
    assert on_circle(CIRCLE, on)
    assert unit.start(replace(CIRCLE, speed_mps=5.0), on, orbiting=True) is None
    assert unit.phase is OrbitPhase.CIRCLE
    assert unit.start(replace(CIRCLE, radius_m=20.0), on, orbiting=True) is not None
    assert unit.phase is OrbitPhase.APPROACH


def test_leaving_the_mode_forgets_the_orbit() -> None:
    unit = Orbit()
    unit.start(CIRCLE, HERE, orbiting=False)
    unit.exit()
    assert unit.plan is None and unit.phase is OrbitPhase.APPROACH and unit.speed_mps == 0.0
