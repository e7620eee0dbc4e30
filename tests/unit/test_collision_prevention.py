"""Where avoidance acts (the decision to correct on what the drone would really fly is exercised by the pole swap in
tests/integration/test_avoidance_fly.py)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sitl.avoidance.algorithm import Obstacle, avoid, fuse, obstacles_from_rows
from sitl.avoidance.collision_prevention import NO_CAMERA, CollisionPrevention, RelayedNeighbour, neighbour_rows
from sitl.control.cascade import TrajectorySetpoint
from sitl.control.configs import position_config
from sitl.control.position import PositionController
from sitl.drone.param_table import build_param_store
from sitl.mathutil import vec3

pytestmark = pytest.mark.timeout(10)


def prevention() -> tuple[CollisionPrevention, list[str]]:
    params = build_param_store()
    events: list[str] = []
    return CollisionPrevention(
        params, PositionController(position_config(params)), 0.35, lambda _s, t: events.append(t)
    ), events


def test_a_drone_alone_flies_its_setpoint_untouched() -> None:
    cp, events = prevention()
    setpoint = TrajectorySetpoint(pos_ned_m=(6.0, 0.0, -3.0), vel_ned_mps=(1.0, 0.0, 0.0), acc_ned_mps2=(0.0, 0.0, 0.0))
    cp.set_relay([RelayedNeighbour(sysid=9, pos_ned_m=(-30.0, 0.0, -3.0), vel_ned_mps=(0.0, 0.0, 0.0), received_s=0.0)])
    assert cp.apply(setpoint, vec3(0.0, 0.0, -3.0), vec3(3.0, 0.0, 0.0), 0.0) is setpoint
    assert events == []


def test_in_a_crowd_only_the_nearest_neighbours_are_fused_and_the_correction_is_the_same() -> None:
    # GIVEN a drone at the origin heading north, and 60 relayed neighbours on rings from 2 to 31.5 m
    setpoint = TrajectorySetpoint(pos_ned_m=(6.0, 0.0, -3.0), vel_ned_mps=(1.0, 0.0, 0.0), acc_ned_mps2=(0.0, 0.0, 0.0))
    crowd = [
        RelayedNeighbour(
            sysid=k + 2,
            pos_ned_m=((2.0 + 0.5 * k) * math.cos(1.3 * k), (2.0 + 0.5 * k) * math.sin(1.3 * k), -3.0),
            vel_ned_mps=(0.0, -0.5, 0.0),
            received_s=0.0,
        )
        for k in range(60)
    ]
    corrected = []
    for neighbours in (crowd, crowd[:20]):  # all of them; the 20 nearest (two per obstacle avoided)
        cp, _events = prevention()
        cp.set_relay(neighbours)
        corrected.append(cp.apply(setpoint, vec3(0.0, 0.0, -3.0), vec3(1.0, 0.0, 0.0), 0.0))
    # THEN the drone corrects, and exactly as if only the nearest had been reported
    assert corrected[0] != setpoint
    assert corrected[0] == corrected[1]


def test_the_obstacles_fused_from_fields_are_those_fused_from_records() -> None:
    # GIVEN a drone with a dozen camera detections of a second-old frame and thirty relayed neighbours around it
    rng = np.random.default_rng(7)
    cp, _events = prevention()
    detections = [Obstacle(rel_pos_ned_m=tuple(rng.uniform(-8.0, 8.0, 3).tolist()), radius_m=0.35) for _ in range(12)]
    neighbours = [
        RelayedNeighbour(sysid=k + 2, pos_ned_m=tuple(rng.uniform(-9.0, 9.0, 3).tolist()),
                         vel_ned_mps=tuple(rng.uniform(-1.0, 1.0, 3).tolist()),
                         received_s=float(rng.uniform(9.0, 10.0)))
        for k in range(30)
    ]  # fmt: skip
    cp.set_camera(detections, 9.6)
    cp.set_relay(neighbours)
    pos, vel, now_s = (0.3, -0.2, -3.0), (1.0, 0.5, 0.0), 10.0
    # WHEN collision prevention builds its obstacles, and the records are built as fusion's docstring describes
    got = obstacles_from_rows(cp.obstacles(pos, vel, now_s))
    config = cp.config()
    nearest = sorted(neighbours, key=lambda n: math.dist(n.pos_ned_m, pos))[: 2 * config.max_obstacles]
    relay = [
        Obstacle(rel_pos_ned_m=(n.pos_ned_m[0] - pos[0], n.pos_ned_m[1] - pos[1], n.pos_ned_m[2] - pos[2]),
                 vel_ned_mps=n.vel_ned_mps, vel_known=True, radius_m=0.35, source="relay",
                 age_s=max(0.0, now_s - n.received_s), sysid=n.sysid)
        for n in nearest  # nearest first, as collision prevention picks them
    ]  # fmt: skip
    camera = [Obstacle(rel_pos_ned_m=d.rel_pos_ned_m, radius_m=0.35, age_s=now_s - 9.6) for d in detections]
    # THEN both give the same obstacles, every figure equal
    assert got == fuse(camera, relay, vel, config)
    assert any(o.source == "fused" for o in got)


def test_inputs_given_as_rows_fuse_as_the_same_records_and_are_read_back_as_records() -> None:
    # GIVEN the same detections and neighbours (some traffic, some known from stale reports, two equally far) given
    # to one drone as records and to another as the rows the camera and the relay hand it
    rng = np.random.default_rng(11)
    detections = [Obstacle(rel_pos_ned_m=tuple(rng.uniform(-6.0, 6.0, 3).tolist()), radius_m=0.35) for _ in range(5)]
    neighbours = [
        RelayedNeighbour(sysid=k + 2, pos_ned_m=tuple(rng.uniform(-9.0, 9.0, 3).tolist()),
                         vel_ned_mps=tuple(rng.uniform(-1.0, 1.0, 3).tolist()),
                         received_s=float(rng.uniform(9.0, 10.5)), cooperative=k % 3 != 0, stale_s=float(k % 4))
        for k in range(24)
    ]  # fmt: skip
    x, y, z = neighbours[0].pos_ned_m
    neighbours.append(RelayedNeighbour(sysid=90, pos_ned_m=(x, -y, z), vel_ned_mps=(0.0, 0.0, 0.0), received_s=9.5))
    by_records, _ = prevention()
    by_records.set_camera(detections, 9.8)
    by_records.set_relay(neighbours)
    by_rows, _ = prevention()
    camera_rows = np.array([(*d.rel_pos_ned_m, 0.35, 0.0) for d in detections])
    by_rows.set_camera_rows(camera_rows, 9.8)
    by_rows.set_relay_rows(neighbour_rows(neighbours))
    pos, vel = (0.0, 0.0, -3.0), (1.0, 0.5, 0.0)
    # THEN both fuse the same obstacles to the bit (the nearest 20 of 25 neighbours, traffic and stale margins too)
    for now_s in (10.0, 10.4, 11.0):
        assert cp_bits(by_rows.obstacles(pos, vel, now_s)) == cp_bits(by_records.obstacles(pos, vel, now_s))
    # AND a reader of the rows (an onboard behaviour) is given the records they came from
    assert by_rows.relayed() == tuple(neighbours)
    assert by_rows.camera() == tuple(detections)
    # AND an empty frame clears the camera
    by_rows.set_camera_rows(NO_CAMERA, 10.0)
    assert by_rows.camera() == ()


def cp_bits(rows: np.ndarray) -> bytes:
    return rows.tobytes()


def test_the_keep_out_around_traffic_known_from_old_reports_grows_with_their_age_up_to_its_bound() -> None:
    # GIVEN traffic 5 m north, reported now from knowledge 0 s, 4 s and 60 s old (a vehicle the ground station no
    # longer hears, where it was last known)
    cp, _events = prevention()
    radii = []
    for stale_s in (0.0, 4.0, 60.0):
        cp.set_relay([RelayedNeighbour(sysid=250, pos_ned_m=(5.0, 0.0, -3.0), vel_ned_mps=(0.0, 0.0, 0.0),
                                       received_s=10.0, cooperative=False, stale_s=stale_s)])  # fmt: skip
        (row,) = obstacles_from_rows(cp.obstacles((0.0, 0.0, -3.0), (0.0, 0.0, 0.0), 10.0))
        radii.append(row.radius_m)
    # THEN its radius is the drone's own, then grows at AVOID_STALE_RATE (0.25 m/s), up to AVOID_STALE_MAX (3 m)
    assert radii == pytest.approx([0.35, 0.35 + 1.0, 0.35 + 3.0])
    # AND the avoidance keeps the wider berth: a drone cruising at it at 1.5 m/s from 7 m acts only on the wider one
    setpoint = TrajectorySetpoint(pos_ned_m=(0.0, 0.0, -3.0), vel_ned_mps=(1.5, 0.0, 0.0), acc_ned_mps2=(0.0, 0.0, 0.0))
    acted = []
    for stale_s in (0.0, 60.0):
        cp, _events = prevention()
        cp.set_relay([RelayedNeighbour(sysid=250, pos_ned_m=(7.0, 0.3, -3.0), vel_ned_mps=(0.0, 0.0, 0.0),
                                       received_s=10.0, cooperative=False, stale_s=stale_s)])  # fmt: skip
        acted.append(cp.apply(setpoint, vec3(0.0, 0.0, -3.0), vec3(1.5, 0.0, 0.0), 10.0) != setpoint)
    assert acted == [False, True]


def test_a_hovering_drone_whose_demand_wobbles_towards_a_neighbour_2_m_away_does_not_correct() -> None:
    # GIVEN a drone hovering 2 m from a hovering neighbour, its setpoint 12 cm towards it and its measured velocity
    # 5 cm/s away from it (a hover's tracking error and estimate noise): ORCA, anchored at the measured velocity,
    # would trim the demand, though at neither velocity would the two come within AVOID_MIN_DIST (1.5 m) in 2.5 s
    cp, events = prevention()
    setpoint = TrajectorySetpoint(
        pos_ned_m=(0.0, 0.12, -3.0), vel_ned_mps=(0.0, 0.0, 0.0), acc_ned_mps2=(0.0, 0.0, 0.0)
    )
    cp.set_relay([RelayedNeighbour(sysid=3, pos_ned_m=(0.0, 2.0, -3.0), vel_ned_mps=(0.0, 0.0, 0.0), received_s=10.0)])
    demand = cp._position.update((0.0, 0.0, -3.0), setpoint.pos_ned_m, setpoint.vel_ned_mps)
    neighbour = Obstacle(rel_pos_ned_m=(0.0, 2.0, 0.0), vel_known=True, source="relay")
    assert avoid((0.0, -0.05, 0.0), demand, [neighbour], cp.config()).active
    # WHEN collision prevention runs
    out = cp.apply(setpoint, vec3(0.0, 0.0, -3.0), vec3(0.0, -0.05, 0.0), 10.0)
    # THEN it flies its setpoint, and says nothing
    assert out is setpoint and events == []


def test_a_correction_starts_for_a_predicted_conflict_and_says_with_whom_how_close_and_when() -> None:
    # GIVEN a drone at the origin whose setpoint is 6 m north (the position loop asks 6.7 m/s), towards drone 9,
    # hovering 4 m ahead and 0.5 m east
    cp, events = prevention()
    setpoint = TrajectorySetpoint(pos_ned_m=(6.0, 0.0, -3.0), vel_ned_mps=(1.0, 0.0, 0.0), acc_ned_mps2=(0.0, 0.0, 0.0))
    cp.set_relay([RelayedNeighbour(sysid=9, pos_ned_m=(4.0, 0.5, -3.0), vel_ned_mps=(0.0, 0.0, 0.0), received_s=10.0)])
    # WHEN collision prevention runs
    out = cp.apply(setpoint, vec3(0.0, 0.0, -3.0), vec3(1.0, 0.0, 0.0), 10.0)
    # THEN it corrects, and the episode's first text names the neighbour, the predicted closest approach (0.5 m abeam,
    # 4 m / 6.7 m/s from now) and the separation to keep
    assert out != setpoint
    assert events == ["Avoidance: drone 9 predicted 0.50 m in 0.6 s (keeping 1.50 m)"], events
    # AND a body already inside the separation, beside the drone, is said as where it is
    cp, events = prevention()
    cp.set_camera([Obstacle(rel_pos_ned_m=(0.0, 1.2, 0.0), radius_m=0.35)], 10.0)
    assert cp.apply(setpoint, vec3(0.0, 0.0, -3.0), vec3(1.0, 0.0, 0.0), 10.0) != setpoint
    assert events == ["Avoidance: a body seen by the camera at 1.20 m (keeping 1.50 m)"], events
