"""Leader-follower and Reynolds flocking laws (pure), checked term by term and in closed-loop kinematic simulations.

The simulations stand in for the drones with what matters to the laws: each agent's velocity follows its commanded
velocity with a first-order lag (the drones' velocity loop, ~0.33 s), positions integrate velocities, and the
laws see the agents only through reports at 10 Hz (as the ground station sees telemetry), called at 20 Hz.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink

from gcs.cli import main as swarm_main
from gcs.command.streamer import TYPE_MASK_POS_VEL_ACC, TYPE_MASK_VEL_XY_POS_Z, type_mask
from gcs.flight.behaviours import (
    ARRIVAL_TOLERANCE_M,
    JOIN_CLEARANCE_M,
    Flock,
    FlockSpec,
    FollowSpec,
    LeaderFollower,
    LeaderPath,
    SwarmState,
    alignment_term,
    cohesion_term,
    course_of,
    default_offsets,
    follower_slots,
    migration_term,
    neighbours,
    priority_sum,
    separation_term,
    turn_towards,
)
from gcs.flight.formation import FormationError, Setpoint, TransitionLimits, min_pairwise_distance_m
from gcs.missions.mission_file import FlockStep, FollowStep, load_mission
from gcs.record.metrics import alignment_order_parameter

pytestmark = pytest.mark.timeout(60)

MISSIONS = Path(__file__).resolve().parents[2] / "missions"
LIMITS = TransitionLimits(max_speed_mps=1.5, max_accel_mps2=1.0)
VELOCITY_LAG_S = 0.33  # the drones' velocity loop: MPC_XY_VEL_P_ACC = 3 /s
POSITION_GAIN = 0.95  # MPC_XY_P
SIM_STEP_S = 0.01
REPORT_S = 0.1  # telemetry at 10 Hz
TICK_S = 0.05  # setpoints at 20 Hz


def state(ids: tuple[int, ...], pos_ne: np.ndarray, vel_ne: np.ndarray, alt_m: float = 4.0) -> SwarmState:
    n = len(ids)
    return SwarmState(
        sysids=ids,
        pos_ned_m=np.column_stack([pos_ne, np.full(n, -alt_m)]),
        vel_ned_mps=np.column_stack([vel_ne, np.zeros(n)]),
    )


def grid(n: int, spacing_m: float) -> np.ndarray:
    cols = math.ceil(math.sqrt(n))
    rows = math.ceil(n / cols)
    return np.array(
        [((i // cols - (rows - 1) / 2) * spacing_m, (i % cols - (cols - 1) / 2) * spacing_m) for i in range(n)]
    )


# ---- flocking terms ------------------------------------------------------------------------------------------------
def test_separation_pushes_close_drones_apart_harder_the_closer_they_are() -> None:
    # GIVEN two drones 1 m apart on a north-south line, a third 10 m away, separation radius 2.5 m
    pos = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 10.0]])
    still = np.zeros((3, 2))
    # WHEN the separation term is computed
    sep = separation_term(pos, still, 2.5)
    # THEN the close pair is pushed apart along their line by 2.5 / 1 - 1, the far drone feels nothing
    np.testing.assert_allclose(sep, [[-1.5, 0.0], [1.5, 0.0], [0.0, 0.0]], atol=1e-12)
    # AND closer means stronger, at the radius it is zero
    closer = separation_term(np.array([[0.0, 0.0], [0.5, 0.0]]), np.zeros((2, 2)), 2.5)
    at_radius = separation_term(np.array([[0.0, 0.0], [2.5, 0.0]]), np.zeros((2, 2)), 2.5)
    assert closer[1, 0] == pytest.approx(4.0) and at_radius[1, 0] == 0.0


def test_separation_feels_an_approaching_drone_early_and_a_receding_one_late() -> None:
    # GIVEN two drones 3 m apart (outside the 2.5 m radius)
    pos = np.array([[0.0, 0.0], [3.0, 0.0]])
    closing = np.array([[1.0, 0.0], [-1.0, 0.0]])  # 2 m/s towards each other
    # WHEN they fly at each other / apart, with a 1 s look-ahead
    approaching = separation_term(pos, closing, 2.5, lookahead_s=1.0)
    receding = separation_term(pos, -closing, 2.5, lookahead_s=1.0)
    # THEN approaching they are pushed apart as if 1 m apart; receding, not at all
    np.testing.assert_allclose(approaching, [[-1.5, 0.0], [1.5, 0.0]], atol=1e-12)
    np.testing.assert_allclose(receding, 0.0)


def test_alignment_steers_towards_the_neighbours_mean_velocity() -> None:
    # GIVEN a drone flying east among two neighbours flying north, and one out of range flying south
    pos = np.array([[0.0, 0.0], [2.0, 0.0], [0.0, 2.0], [50.0, 0.0]])
    vel = np.array([[0.0, 1.0], [1.0, 0.0], [1.0, 0.0], [-1.0, 0.0]])
    mask = neighbours(pos, 6.0)
    # WHEN the alignment term is computed
    align = alignment_term(vel, vel, mask)
    # THEN drone 0 is steered from east to north; the lone drone has no neighbours and is left alone
    np.testing.assert_allclose(align[0], [1.0, -1.0])
    np.testing.assert_allclose(align[3], [0.0, 0.0])


def test_cohesion_pulls_a_drone_towards_its_neighbours_centroid() -> None:
    # GIVEN a drone 4 m west of two neighbours at (1, 0) and (-1, 0)
    pos = np.array([[0.0, -4.0], [1.0, 0.0], [-1.0, 0.0]])
    mask = neighbours(pos, 6.0)
    # WHEN the cohesion term is computed / THEN it points 4 m east, to their centroid
    np.testing.assert_allclose(cohesion_term(pos, mask)[0], [0.0, 4.0], atol=1e-12)


def test_migration_pulls_the_flock_to_the_goal_and_tapers_near_it() -> None:
    # GIVEN a hovering pair 30 m south of the goal
    pos = np.array([[-30.0, -1.0], [-30.0, 1.0]])
    still = np.zeros((2, 2))
    mask = neighbours(pos, 6.0)
    goal = np.array([0.0, 0.0])
    # WHEN the migration term is computed / THEN both are steered north at full speed
    far = migration_term(pos, still, mask, goal, 1.5, 3.0)
    np.testing.assert_allclose(far, [[1.5, 0.0], [1.5, 0.0]], atol=1e-12)
    # AND 1.5 m from the goal (half the slowing radius) at half speed, already flying that fast: no steering
    near = migration_term(pos + np.array([28.5, 0.0]), np.array([[0.75, 0.0], [0.75, 0.0]]), mask, goal, 1.5, 3.0)
    np.testing.assert_allclose(near, 0.0, atol=1e-12)


def test_separation_comes_first_in_the_acceleration_budget() -> None:
    # GIVEN a separation demand of 1 m/s^2 north and a limit of 1.5 m/s^2
    sep = np.array([[1.0, 0.0]])
    # WHEN other terms ask for 5 m/s^2 east / THEN they get only what is left: the total is on the limit circle
    np.testing.assert_allclose(priority_sum(sep, np.array([[0.0, 5.0]]), 1.5), [[1.0, math.sqrt(1.5**2 - 1.0)]])
    # AND a separation demand beyond the limit is scaled to it, the rest dropped
    np.testing.assert_allclose(priority_sum(np.array([[3.0, 0.0]]), np.array([[0.0, 5.0]]), 1.5), [[1.5, 0.0]])
    # AND the total never exceeds the limit, whatever the other terms ask
    rng = np.random.default_rng(3)
    totals = priority_sum(rng.normal(0, 1, (200, 2)), rng.normal(0, 5, (200, 2)), 1.5)
    assert np.linalg.norm(totals, axis=1).max() <= 1.5 + 1e-12


# ---- flocking in closed loop ---------------------------------------------------------------------------------------
def fly_flock(
    spec: FlockSpec, pos_ne: np.ndarray, vel_ne: np.ndarray, duration_s: float
) -> tuple[np.ndarray, np.ndarray, float, Flock]:
    """Kinematic flight: (times, phi per report, min distance over every step, the flock)."""
    ids = tuple(range(1, pos_ne.shape[0] + 1))
    pos, vel = pos_ne.copy(), vel_ne.copy()
    flock = Flock(spec, 0.0, state(ids, pos, vel, spec.alt_m))
    report = state(ids, pos, vel, spec.alt_m)
    command = vel.copy()
    times, phis = [], []
    closest = math.inf
    steps = round(duration_s / SIM_STEP_S)
    report_every, tick_every = round(REPORT_S / SIM_STEP_S), round(TICK_S / SIM_STEP_S)
    for k in range(steps):
        t = k * SIM_STEP_S
        if k % report_every == 0:
            report = state(ids, pos, vel, spec.alt_m)
            times.append(t)
            phis.append(float(alignment_order_parameter(vel)))
        if k % tick_every == 0:
            setpoints = flock.setpoints(t, report)
            command = np.array([setpoints[i].vel_ned_mps[:2] for i in ids])
        vel += (command - vel) * SIM_STEP_S / VELOCITY_LAG_S
        pos += vel * SIM_STEP_S
        closest = min(closest, min_pairwise_distance_m(pos))
    return np.array(times), np.array(phis), closest, flock


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_twelve_drones_flying_every_which_way_align_and_never_come_closer_than_1_m(seed: int) -> None:
    # GIVEN the shipped flocking mission's law, and 12 drones 3 m apart flying in random directions
    step = next(s for s in load_mission(MISSIONS / "flocking.toml").steps if isinstance(s, FlockStep))
    rng = np.random.default_rng(seed)
    vel = rng.normal(0.0, 0.8, (12, 2))
    assert alignment_order_parameter(vel) < 0.6
    # WHEN they flock for the mission's 60 s
    times, phi, closest, flock = fly_flock(step.spec, grid(12, 3.0), vel, step.duration_s)
    # THEN they align (phi > 0.9 from 5 s on, wherever defined) and no two come within 1 m
    after = phi[(times >= 5.0) & np.isfinite(phi)]
    assert after.size > 0.9 * np.sum(times >= 5.0)
    assert after.min() > 0.9, after.min()
    assert closest > 1.0, closest
    # AND the flock went on to its second migration point
    assert flock.goal_index == 1


def test_separation_alone_stops_two_drones_flying_head_on_at_full_speed() -> None:
    # GIVEN two drones 8 m apart flying at each other at 1.5 m/s, slightly offset, with only separation on
    spec = FlockSpec(alt_m=4.0, alignment_weight_per_s=0.0, cohesion_weight_per_s2=0.0, migration_weight_per_s=0.0)
    pos = np.array([[0.0, 0.0], [8.0, 0.3]])
    vel = np.array([[1.5, 0.0], [-1.5, 0.0]])
    # WHEN they fly for 10 s
    _, _, closest, _ = fly_flock(spec, pos, vel, 10.0)
    # THEN they never come within 2 m (the separation radius is 2.5 m)
    assert closest > 2.0, closest


def test_without_separation_the_same_drones_collide() -> None:
    # The previous test can fail: with a 1 cm separation radius and no look-ahead the pair passes 0.3 m apart.
    spec = FlockSpec(
        alt_m=4.0,
        separation_radius_m=0.01,
        separation_lookahead_s=0.0,
        alignment_weight_per_s=0.0,
        cohesion_weight_per_s2=0.0,
        migration_weight_per_s=0.0,
    )
    _, _, closest, _ = fly_flock(spec, np.array([[0.0, 0.0], [8.0, 0.3]]), np.array([[1.5, 0.0], [-1.5, 0.0]]), 10.0)
    assert closest < 0.5


def test_flock_setpoints_hold_altitude_by_position_and_steer_by_velocity() -> None:
    # GIVEN a hovering pair and a migration point to the north
    spec = FlockSpec(alt_m=5.0, migration_ne_m=((20.0, 0.0),))
    ids = (7, 9)
    flock = Flock(spec, 0.0, state(ids, np.array([[0.0, 0.0], [0.0, 3.0]]), np.zeros((2, 2)), 5.0))
    # WHEN a tick 50 ms later is computed
    setpoints = flock.setpoints(0.05, state(ids, np.array([[0.0, 0.0], [0.0, 3.0]]), np.zeros((2, 2)), 5.0))
    # THEN every drone gets a horizontal velocity (with its acceleration) and an altitude, nothing else
    for sp in setpoints.values():
        assert math.isnan(sp.pos_ned_m[0]) and math.isnan(sp.pos_ned_m[1]) and sp.pos_ned_m[2] == -5.0
        assert sp.vel_ned_mps[0] > 0.0 and math.isnan(sp.vel_ned_mps[2])
        assert sp.vel_ned_mps[0] == pytest.approx(0.05 * sp.acc_ned_mps2[0])
        assert type_mask(sp) == TYPE_MASK_VEL_XY_POS_Z
    # AND the message ignores position x/y, vz, az, yaw and yaw rate: bits 0, 1, 5, 8, 10, 11
    assert TYPE_MASK_VEL_XY_POS_Z == 0b1101_0010_0011
    full = Setpoint(
        pos_ned_m=(1.0, 2.0, 3.0), vel_ned_mps=(0.0, 0.0, 0.0), acc_ned_mps2=(0.0, 0.0, 0.0), yaw_rad=math.nan
    )
    assert type_mask(full) == TYPE_MASK_POS_VEL_ACC
    # a finite yaw is commanded (yaw rate never is)
    facing = Setpoint(pos_ned_m=(1.0, 2.0, 3.0), vel_ned_mps=(0.0, 0.0, 0.0), acc_ned_mps2=(0.0, 0.0, 0.0), yaw_rad=0.5)
    assert type_mask(facing) == TYPE_MASK_POS_VEL_ACC & ~mavlink.POSITION_TARGET_TYPEMASK_YAW_IGNORE
    # finite components whose sum overflows are every one given; an infinite one is ignored, as a NaN is
    huge = Setpoint(
        pos_ned_m=(1e308, 1e308, 3.0), vel_ned_mps=(1e308, 0.0, 0.0), acc_ned_mps2=(0.0, 0.0, 0.0), yaw_rad=math.nan
    )
    assert type_mask(huge) == TYPE_MASK_POS_VEL_ACC
    endless = Setpoint(
        pos_ned_m=(1.0, 2.0, 3.0), vel_ned_mps=(0.0, 0.0, 0.0), acc_ned_mps2=(0.0, 0.0, math.inf), yaw_rad=math.nan
    )
    assert type_mask(endless) == TYPE_MASK_POS_VEL_ACC | mavlink.POSITION_TARGET_TYPEMASK_AZ_IGNORE
    assert flock.targets() == {}


def test_the_flock_moves_on_to_the_next_migration_point_once_its_centroid_arrives() -> None:
    spec = FlockSpec(alt_m=4.0, migration_ne_m=((10.0, 0.0), (0.0, 0.0)), arrival_radius_m=3.0)
    ids = (1, 2)
    flock = Flock(spec, 0.0, state(ids, np.array([[0.0, -1.0], [0.0, 1.0]]), np.zeros((2, 2))))
    flock.setpoints(0.05, state(ids, np.array([[0.0, -1.0], [0.0, 1.0]]), np.zeros((2, 2))))
    assert flock.goal_ne_m == (10.0, 0.0)
    flock.setpoints(0.10, state(ids, np.array([[7.5, -1.0], [7.5, 1.0]]), np.zeros((2, 2))))
    assert flock.goal_ne_m == (0.0, 0.0)
    flock.setpoints(0.15, state(ids, np.array([[0.0, -1.0], [0.0, 1.0]]), np.zeros((2, 2))))
    assert flock.goal_ne_m == (0.0, 0.0)  # the last one stays


@pytest.mark.parametrize(
    ("changes", "fragment"),
    [
        ({"max_speed_mps": 0.0}, "max_speed_mps must be positive"),
        ({"separation_radius_m": 8.0}, "must not exceed the neighbour radius"),
        ({"cohesion_weight_per_s2": -1.0}, "cohesion_weight_per_s2 must not be negative"),
        ({"migration_ne_m": ((1.0, math.nan),)}, "migration_ne_m"),
    ],
)
def test_bad_flock_specs_are_refused(changes: dict[str, object], fragment: str) -> None:
    with pytest.raises(FormationError, match=fragment):
        FlockSpec(alt_m=4.0, **changes)  # type: ignore[arg-type]


# ---- leader-follower -------------------------------------------------------------------------------------------------
def test_follower_offsets_rotate_with_the_leader_heading() -> None:
    # GIVEN offsets 2 m behind and 2 m behind-right of a leader at (10, 5), 3 m up
    offsets = np.array([[-2.0, 0.0], [-2.0, 2.0]])
    leader = (10.0, 5.0, -3.0)
    # WHEN the leader heads north, then east
    north, _ = follower_slots(leader, (1.0, 0.0, 0.0), 0.0, 0.0, offsets, 3.0)
    east, _ = follower_slots(leader, (0.0, 1.0, 0.0), math.pi / 2, 0.0, offsets, 3.0)
    # THEN "behind" is south, then west; "right" is east, then south
    np.testing.assert_allclose(north, [[8.0, 5.0, -3.0], [8.0, 7.0, -3.0]], atol=1e-12)
    np.testing.assert_allclose(east, [[10.0, 3.0, -3.0], [8.0, 3.0, -3.0]], atol=1e-12)
    # AND the distances between slots do not change
    assert np.linalg.norm(north[0] - north[1]) == pytest.approx(np.linalg.norm(east[0] - east[1]))


def test_follower_velocity_is_the_leaders_plus_the_turn_of_its_arm() -> None:
    # GIVEN a leader flying north at 1.5 m/s, turning right at 0.2 rad/s, a follower 3 m behind
    _, vel = follower_slots((0.0, 0.0, -3.0), (1.5, 0.0, 0.1), 0.0, 0.2, np.array([[-3.0, 0.0]]), 3.0)
    # THEN the follower swings west (its arm turns clockwise seen from above) and holds altitude
    np.testing.assert_allclose(vel, [[1.5, -0.6, 0.0]], atol=1e-12)
    # AND the velocity is the time derivative of the slot
    h = 1e-4
    a, _ = follower_slots((0.0, 0.0, -3.0), (0, 0, 0), -0.2 * h, 0.0, np.array([[-3.0, 0.0]]), 3.0)
    b, _ = follower_slots((1.5 * 2 * h, 0.0, -3.0), (0, 0, 0), 0.2 * h, 0.0, np.array([[-3.0, 0.0]]), 3.0)
    np.testing.assert_allclose((b - a) / (2 * h), vel, atol=1e-6)


def test_heading_filter_turns_the_short_way_at_a_limited_rate_without_overshoot() -> None:
    # GIVEN a heading of 170 deg and a course of -170 deg (20 deg away through 180)
    heading, rate = turn_towards(math.radians(170), math.radians(-170), 0.05, time_constant_s=0.5, max_rate_radps=0.3)
    # THEN it turns positive (through 180) at the rate limit
    assert rate == pytest.approx(0.3)
    assert math.degrees(heading) == pytest.approx(170 + math.degrees(0.3 * 0.05))
    # AND a long step stops at the course
    heading, _ = turn_towards(0.0, 0.1, 10.0, time_constant_s=0.5, max_rate_radps=0.3)
    assert heading == pytest.approx(0.1)
    # AND a slow leader has no course
    assert course_of((0.1, 0.1)) is None and course_of((0.0, 2.0)) == pytest.approx(math.pi / 2)


def test_default_offsets_are_a_v_behind_the_leader() -> None:
    offsets = default_offsets(4, 2.5, math.pi / 2)
    s = 2.5 / math.sqrt(2)
    np.testing.assert_allclose(offsets, [[-s, s], [-s, -s], [-2 * s, 2 * s], [-2 * s, -2 * s]], atol=1e-12)


def test_leader_path_rounds_corners_within_speed_and_acceleration_and_ends_at_rest_on_the_last_waypoint() -> None:
    # GIVEN a 12 m square from the origin at 1.5 m/s, 1 m/s^2, corners of radius 3 m
    waypoints = [(12.0, 0.0, -3.0), (12.0, 12.0, -3.0), (0.0, 12.0, -3.0), (0.0, 0.0, -3.0)]
    path = LeaderPath((0.0, 0.0, -3.0), waypoints, speed_mps=1.5, max_accel_mps2=1.0, turn_radius_m=3.0)
    # WHEN it is sampled every 20 ms
    times = np.arange(-1.0, path.duration_s + 1.0, 0.02)
    samples = [path.sample(float(t)) for t in times]
    pos = np.array([s[0] for s in samples])
    vel = np.array([s[1] for s in samples])
    acc = np.array([s[2] for s in samples])
    # THEN it starts and ends at rest on the start and the last waypoint
    np.testing.assert_allclose(pos[0], (0.0, 0.0, -3.0))
    np.testing.assert_allclose(pos[-1], waypoints[-1], atol=1e-9)
    assert np.linalg.norm(vel[0]) == 0.0 and np.linalg.norm(vel[-1]) == 0.0
    # AND stays within the speed, with along- and across-track acceleration each within the limit
    speed = np.linalg.norm(vel, axis=1)
    assert speed.max() <= 1.5 + 1e-9 and speed.max() > 1.45
    tangent = vel / np.maximum(speed, 1e-9)[:, None]
    along = np.einsum("ij,ij->i", acc, tangent)
    across = np.linalg.norm(acc - along[:, None] * tangent, axis=1)
    assert np.abs(along).max() <= 1.0 + 1e-6 and across.max() <= 1.0 + 1e-6
    # AND velocity is the derivative of position (central differences)
    np.testing.assert_allclose(np.gradient(pos, 0.02, axis=0)[1:-1], vel[1:-1], atol=0.03)
    # AND each corner is cut by R (1 / cos 45 deg - 1) = 1.24 m at most, and the path is shorter than 48 m
    for corner in waypoints[:3]:
        assert np.linalg.norm(pos - corner, axis=1).min() == pytest.approx(3.0 * (math.sqrt(2) - 1), abs=0.02)
    assert 44.0 < path.length_m < 48.0


def test_leader_path_stops_to_reverse() -> None:
    path = LeaderPath((0, 0, -3), [(10, 0, -3), (0, 0, -3)], speed_mps=1.5, max_accel_mps2=1.0, turn_radius_m=3.0)
    times, speed = path.speed_profile()
    turn = int(np.argmax(np.linalg.norm(np.array([path.sample(t)[0] for t in times]) - (10, 0, -3), axis=1) < 1e-9))
    assert speed[turn] == 0.0 and speed.max() == pytest.approx(1.5)


def simulate_follow(
    spec: FollowSpec, ids: tuple[int, ...], start_ne: np.ndarray, alt_m: float, extra_s: float = 5.0
) -> tuple[LeaderFollower, float, float, float]:
    """Kinematic agents tracking position setpoints with velocity feed-forward, as the drones' cascade does:
    (behaviour, max follower error from 2 s after departure, min pairwise distance, flight time)."""
    pos = np.column_stack([start_ne, np.full(len(ids), -alt_m)]).astype(float)
    vel = np.zeros_like(pos)
    behaviour = LeaderFollower(spec, 0.0, SwarmState(sysids=ids, pos_ned_m=pos.copy(), vel_ned_mps=vel.copy()), LIMITS)
    report = SwarmState(sysids=ids, pos_ned_m=pos.copy(), vel_ned_mps=vel.copy())
    setpoints: dict[int, Setpoint] = {}
    targets: dict[int, tuple[float, float, float]] = {}
    worst, closest, t, k = 0.0, math.inf, 0.0, 0
    report_every, tick_every = round(REPORT_S / SIM_STEP_S), round(TICK_S / SIM_STEP_S)
    while t < behaviour.finish_s + extra_s:
        if k % report_every == 0:
            report = SwarmState(sysids=ids, pos_ned_m=pos.copy(), vel_ned_mps=vel.copy())
        if k % tick_every == 0:
            setpoints = behaviour.setpoints(t, report)
            targets = behaviour.targets()
        for row, sysid in enumerate(ids):
            sp = setpoints[sysid]
            command = POSITION_GAIN * (np.array(sp.pos_ned_m) - pos[row]) + np.nan_to_num(np.array(sp.vel_ned_mps))
            vel[row] += (command - vel[row]) * SIM_STEP_S / VELOCITY_LAG_S
        pos += vel * SIM_STEP_S
        t, k = t + SIM_STEP_S, k + 1
        closest = min(closest, min_pairwise_distance_m(pos))
        if t > behaviour.depart_s + 2.0 and k % tick_every == 0:
            worst = max(
                [worst]
                + [float(np.linalg.norm(pos[r] - targets[s])) for r, s in enumerate(ids) if s != spec.leader_sysid]
            )
    return behaviour, worst, closest, t


def test_followers_hold_a_v_behind_a_leader_flying_a_square() -> None:
    # GIVEN the shipped leader-follower mission: five drones on a line 2.5 m apart, the middle one leading
    step = next(s for s in load_mission(MISSIONS / "leader_follower.toml").steps if isinstance(s, FollowStep))
    assert step.leader_drone == 3
    spec = dataclasses.replace(step.spec, leader_sysid=3)
    ids = (1, 2, 3, 4, 5)
    start = np.array([[0.0, -5.0], [0.0, -2.5], [0.0, 0.0], [0.0, 2.5], [0.0, 5.0]])
    # WHEN flown in the kinematic simulation
    behaviour, worst, closest, t = simulate_follow(spec, ids, start, spec.alt_m)
    # THEN the followers join without passing near the leader, stay within 0.5 m of their slots all the way round,
    # nobody comes within 2 m of anybody, and the leader ends on its last waypoint
    assert behaviour.join_clearance_m >= JOIN_CLEARANCE_M
    assert worst < 0.5, worst
    assert closest > 2.0, closest
    assert behaviour.done(t)
    # AND the followers' slots are the V behind the leader's last report, facing its last leg (west)
    leader = np.array(behaviour.targets()[3])
    assert np.linalg.norm(leader - (0.0, 0.0, -3.0)) < ARRIVAL_TOLERANCE_M
    behind = [np.array(behaviour.targets()[s]) - leader for s in (1, 2, 4, 5)]
    assert all(b[1] > 1.0 for b in behind)  # all east of a leader heading west


def test_the_join_turns_the_v_when_facing_the_first_leg_would_sweep_followers_past_the_leader() -> None:
    # GIVEN a leader at the south end of a north-south line of three, its first leg to the north: a V facing north
    # would put both followers south of the leader, and the one north of it would pass it on the way
    spec = FollowSpec(waypoints_ne_m=((20.0, 0.0),), alt_m=3.0, leader_sysid=1)
    ids = (1, 2, 3)
    start = np.array([[0.0, 0.0], [2.5, 0.0], [5.0, 0.0]])
    # WHEN flown
    behaviour, worst, closest, t = simulate_follow(spec, ids, start, 3.0, extra_s=10.0)
    # THEN the join kept its clearance (by facing another way first), and the flight stayed apart and on the slots
    assert behaviour.join_clearance_m >= JOIN_CLEARANCE_M
    assert closest > 1.5, closest
    assert worst < 0.6, worst
    assert behaviour.done(t)


def test_done_needs_the_leaders_report_at_the_last_waypoint() -> None:
    spec = FollowSpec(waypoints_ne_m=((5.0, 0.0),), alt_m=3.0)
    ids = (1,)
    here = SwarmState(sysids=ids, pos_ned_m=np.array([[0.0, 0.0, -3.0]]), vel_ned_mps=np.zeros((1, 3)))
    behaviour = LeaderFollower(spec, 0.0, here, LIMITS)
    behaviour.setpoints(behaviour.finish_s + 1.0, here)
    assert not behaviour.done(behaviour.finish_s + 1.0)  # the reference is there, the leader is not
    there = SwarmState(sysids=ids, pos_ned_m=np.array([[5.0, 0.0, -3.0]]), vel_ned_mps=np.zeros((1, 3)))
    behaviour.setpoints(behaviour.finish_s + 2.0, there)
    assert behaviour.done(behaviour.finish_s + 2.0)


def test_leader_follower_refuses_an_unknown_leader_and_too_few_offsets() -> None:
    here = SwarmState(sysids=(1, 2, 3), pos_ned_m=np.zeros((3, 3)), vel_ned_mps=np.zeros((3, 3)))
    with pytest.raises(FormationError, match="leader sysid 9 is not in the swarm"):
        LeaderFollower(FollowSpec(waypoints_ne_m=((5.0, 0.0),), alt_m=3.0, leader_sysid=9), 0.0, here, LIMITS)
    with pytest.raises(FormationError, match="1 follower offsets for 2 followers"):
        LeaderFollower(
            FollowSpec(waypoints_ne_m=((5.0, 0.0),), alt_m=3.0, offsets_fr_m=((-2.0, 0.0),)), 0.0, here, LIMITS
        )


# ---- command line --------------------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("args", "fragment"),
    [
        (["flock", "--speed", "-1"], "argument --speed: must be a positive number"),
        (["flock", "--goals", "10;0"], "argument --goals: must be pairs like"),
        (
            ["flock", "--separation", "8", "--radius", "5"],
            "argument --separation: (8) must not exceed the neighbour radius (5)",
        ),
        (["flock", "--w-cohesion", "-0.1"], "argument --w-cohesion: must be a number >= 0"),
        (["follow", "--alt", "3"], "one of the arguments --waypoints --attached is required"),
        (["follow", "--waypoints", "10,0", "--offsets=0.1,0"], "argument --offsets: (0.1, 0.0) puts a follower on"),
        (["follow", "--waypoints", "10,0", "--angle", "270"], "argument --angle: must be in (0, 180] degrees"),
        (["follow", "--waypoints", "10,0", "--leader", "256"], "argument --leader: must be a sysid in 1..255, got 256"),
        (["follow", "--attached", "--leader", "300"], "argument --leader: must be a sysid in 1..255, got 300"),
        (["follow", "--waypoints", "10,0", "--leader", "0"], "argument --leader: must be a whole number >= 1, got 0"),
    ],
)
def test_bad_flock_and_follow_options_give_one_line_before_anything_is_sent(
    args: list[str], fragment: str, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    monkeypatch.setenv("SWARM_STATE_DIR", str(tmp_path))  # no supervisor: a request would fail differently
    assert swarm_main(args) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("swarm: error: ") and fragment in lines[0], lines
