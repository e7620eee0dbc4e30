"""The auto-mode reference trajectory: speed and acceleration limits per axis, arrival at rest, retargeting."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pytest

from sitl.autopilot.guidance import MotionLimits, Reference, StraightLineTrajectory

pytestmark = pytest.mark.timeout(30)

DT_S = 1.0 / 400.0
# The autopilot's defaults: MPC_XY_CRUISE, MPC_Z_V_AUTO_UP/DN, MPC_ACC_HOR, MPC_ACC_UP_MAX.
LIMITS = MotionLimits(speed_xy_mps=5.0, speed_up_mps=3.0, speed_down_mps=1.5, accel_xy_mps2=3.0, accel_z_mps2=3.0)
EPS = 1e-9


@dataclass
class Run:
    refs: list[Reference]

    @property
    def pos(self) -> np.ndarray:
        return np.array([r.pos_ned_m for r in self.refs])

    @property
    def vel(self) -> np.ndarray:
        return np.array([r.vel_ned_mps for r in self.refs])

    @property
    def acc(self) -> np.ndarray:
        return np.array([r.acc_ned_mps2 for r in self.refs])


def _fly(
    trajectory: StraightLineTrajectory,
    target: tuple[float, float, float],
    duration_s: float,
    limits: MotionLimits = LIMITS,
    max_speed_mps: float = math.inf,
) -> Run:
    goal = np.array(target)
    return Run([trajectory.update(goal, limits, DT_S, max_speed_mps) for _ in range(round(duration_s / DT_S))])


def _assert_within_limits(vel: np.ndarray, acc: np.ndarray, limits: MotionLimits) -> None:
    horizontal_speed = np.hypot(vel[:, 0], vel[:, 1])
    assert horizontal_speed.max() <= limits.speed_xy_mps + EPS
    assert (-vel[:, 2]).max() <= limits.speed_up_mps + EPS  # climbing is negative down
    assert vel[:, 2].max() <= limits.speed_down_mps + EPS
    assert np.hypot(acc[:, 0], acc[:, 1]).max() <= limits.accel_xy_mps2 + 1e-6
    assert np.abs(acc[:, 2]).max() <= limits.accel_z_mps2 + 1e-6


TARGETS = [
    (20.0, 0.0, 0.0),  # long horizontal leg: reaches cruise
    (-7.0, 12.0, 0.0),
    (0.0, 0.0, -15.0),  # straight up
    (0.0, 0.0, 12.0),  # straight down (slower than up)
    (7.0, 3.0, -4.0),  # oblique climb
    (10.0, -10.0, 6.0),  # oblique descent: the vertical limit binds
    (0.3, 0.0, 0.0),  # too short to reach cruise
]


@pytest.mark.parametrize("target", TARGETS)
def test_reference_never_exceeds_speed_or_acceleration_limits_on_any_axis(target: tuple[float, float, float]) -> None:
    # GIVEN a reference at rest at the origin
    trajectory = StraightLineTrajectory(np.zeros(3))
    # WHEN it moves to the target
    run = _fly(trajectory, target, duration_s=20.0)
    # THEN the velocity and acceleration it feeds forward respect every per-axis limit
    _assert_within_limits(run.vel, run.acc, LIMITS)
    # and so do the finite differences of what it commands (no jumps hidden from the feed-forward)
    vel = np.vstack((np.zeros(3), run.vel))
    _assert_within_limits(run.vel, np.diff(vel, axis=0) / DT_S, LIMITS)


@pytest.mark.parametrize("target", TARGETS)
def test_reference_reaches_the_target_without_overshoot_and_arrives_at_rest(target: tuple[float, float, float]) -> None:
    trajectory = StraightLineTrajectory(np.zeros(3))
    goal = np.array(target)
    run = _fly(trajectory, target, duration_s=20.0)
    # THEN the distance along the line grows monotonically and never passes the target
    along = run.pos @ (goal / np.linalg.norm(goal))
    assert np.all(np.diff(along) >= -EPS)
    assert along.max() <= np.linalg.norm(goal) + EPS
    # and it never leaves the line
    off_line = np.linalg.norm(run.pos - np.outer(along, goal / np.linalg.norm(goal)), axis=1)
    assert off_line.max() < 1e-9
    # and it is at the target at rest at the end
    np.testing.assert_allclose(run.pos[-1], goal, atol=1e-9)
    assert np.linalg.norm(run.vel[-1]) == 0.0
    # and when the position first reaches the target the velocity is already (nearly) zero: the feed-forward
    # never pushes the vehicle past it
    arrival = int(np.argmax(np.linalg.norm(run.pos - goal, axis=1) < 1e-6))
    assert np.linalg.norm(run.vel[arrival]) <= LIMITS.accel_xy_mps2 * DT_S


@pytest.mark.parametrize("target", TARGETS)
def test_velocity_reference_is_the_rate_of_change_of_the_position_reference(
    target: tuple[float, float, float],
) -> None:
    trajectory = StraightLineTrajectory(np.zeros(3))
    run = _fly(trajectory, target, duration_s=20.0)
    pos = np.vstack((np.zeros(3), run.pos))
    vel = np.vstack((np.zeros(3), run.vel))
    # Trapezoidal integration: each position step is the mean of the velocities at its ends times dt, to within
    # one step of acceleration (the last step is cut short at the target).
    one_step_of_accel_m = LIMITS.accel_xy_mps2 * DT_S * DT_S
    np.testing.assert_allclose(np.diff(pos, axis=0), 0.5 * (vel[1:] + vel[:-1]) * DT_S, atol=one_step_of_accel_m)


def test_long_horizontal_leg_cruises_at_the_horizontal_speed_limit() -> None:
    trajectory = StraightLineTrajectory(np.zeros(3))
    run = _fly(trajectory, (30.0, 40.0, 0.0), duration_s=15.0)
    speed = np.linalg.norm(run.vel, axis=1)
    assert speed.max() == pytest.approx(LIMITS.speed_xy_mps)
    # trapezoid: 50 m at 5 m/s with 3 m/s^2 takes 50/5 + 5/3 s
    arrival_s = (int(np.argmax(np.linalg.norm(run.pos - (30.0, 40.0, 0.0), axis=1) < 1e-6)) + 1) * DT_S
    assert arrival_s == pytest.approx(50.0 / 5.0 + 5.0 / 3.0, abs=0.05)


def test_an_explicit_speed_limit_caps_the_cruise_speed() -> None:
    trajectory = StraightLineTrajectory(np.zeros(3))
    run = _fly(trajectory, (30.0, 0.0, 0.0), duration_s=15.0, max_speed_mps=2.0)
    assert np.linalg.norm(run.vel, axis=1).max() == pytest.approx(2.0)


def test_at_the_target_the_reference_holds_still() -> None:
    trajectory = StraightLineTrajectory(np.array((1.0, 2.0, -3.0)))
    ref = trajectory.update(np.array((1.0, 2.0, -3.0)), LIMITS, DT_S)
    np.testing.assert_array_equal(ref.pos_ned_m, (1.0, 2.0, -3.0))
    assert not ref.vel_ned_mps.any() and not ref.acc_ned_mps2.any()


def _cruise_north() -> StraightLineTrajectory:
    """A reference cruising north at 5 m/s, far from its target."""
    trajectory = StraightLineTrajectory(np.zeros(3))
    run = _fly(trajectory, (200.0, 0.0, 0.0), duration_s=3.0)
    np.testing.assert_allclose(run.vel[-1], (5.0, 0.0, 0.0))
    return trajectory


def test_retargeting_mid_flight_carries_only_the_speed_along_the_new_direction() -> None:
    # GIVEN a reference cruising north at 5 m/s
    trajectory = _cruise_north()
    here = trajectory.position.copy()
    # WHEN the target moves to a point 60 degrees off its course, far away
    new_dir = np.array((math.cos(math.radians(60)), math.sin(math.radians(60)), 0.0))
    ref = trajectory.update(here + 100.0 * new_dir, LIMITS, DT_S)
    # THEN the velocity points at the new target with the old velocity's component along it (5 cos 60 = 2.5 m/s),
    # give or take one step of acceleration
    speed = float(np.linalg.norm(ref.vel_ned_mps))
    np.testing.assert_allclose(ref.vel_ned_mps / speed, new_dir, atol=1e-9)
    assert speed == pytest.approx(2.5, abs=LIMITS.accel_xy_mps2 * DT_S + 1e-9)


def test_retargeting_behind_restarts_from_rest_towards_the_new_target() -> None:
    trajectory = _cruise_north()
    here = trajectory.position.copy()
    ref = trajectory.update(here + np.array((-50.0, 0.0, 0.0)), LIMITS, DT_S)
    assert ref.vel_ned_mps[0] <= 0.0
    assert np.linalg.norm(ref.vel_ned_mps) <= LIMITS.accel_xy_mps2 * DT_S + 1e-9


def test_retargeting_downwards_from_cruise_respects_the_descent_speed_limit() -> None:
    # GIVEN a reference cruising north at 5 m/s (horizontal limit), faster than the 1.5 m/s descent limit
    trajectory = _cruise_north()
    here = trajectory.position.copy()
    # WHEN the target moves to a point 45 degrees below its course
    run = _fly(trajectory, tuple(here + np.array((20.0, 0.0, 20.0))), duration_s=2.0)
    # THEN the carried speed is cut to what the new line allows: it never descends faster than 1.5 m/s
    assert run.vel[:, 2].max() <= LIMITS.speed_down_mps + EPS
    _assert_within_limits(run.vel, run.acc, LIMITS)


def test_reset_puts_the_reference_at_rest_at_a_new_point() -> None:
    trajectory = _cruise_north()
    trajectory.reset(np.array((0.0, 5.0, -2.0)))
    ref = trajectory.update(np.array((0.0, 100.0, -2.0)), LIMITS, DT_S)
    assert np.linalg.norm(ref.vel_ned_mps) == pytest.approx(LIMITS.accel_xy_mps2 * DT_S)
    assert ref.vel_ned_mps[1] > 0.0


def test_reset_moving_brakes_from_the_given_velocity_to_a_target_a_braking_distance_ahead() -> None:
    # GIVEN a reference restarted where a vehicle is, moving east at cruise speed (a Hold entered at speed)
    trajectory = StraightLineTrajectory(np.zeros(3))
    speed = LIMITS.speed_xy_mps
    trajectory.reset_moving(np.array((1.0, 2.0, -3.0)), np.array((0.0, speed, 0.0)))
    # WHEN it goes to the point v^2 / (2 a) ahead
    braking_m = speed**2 / (2.0 * LIMITS.accel_xy_mps2)
    run = _fly(trajectory, (1.0, 2.0 + braking_m, -3.0), 3.0)
    # THEN it brakes at once from that speed, never faster than the limit, and stops there without stopping before
    east_speed = run.vel[:, 1]
    assert east_speed[0] == pytest.approx(speed - LIMITS.accel_xy_mps2 * DT_S)
    assert np.all(np.diff(east_speed) <= EPS)  # slowing all the way: no stop-and-go
    _assert_within_limits(run.vel, run.acc, LIMITS)
    assert run.pos[-1] == pytest.approx((1.0, 2.0 + braking_m, -3.0), abs=1e-6)
