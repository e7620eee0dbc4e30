"""The shipped onboard behaviours (sitl/onboard/behaviours) fly the ground station's laws (gcs/flight/behaviours.py),
one drone's view at a time: the same steering for the same neighbours, the same slots for the same leader; the ground
station's side (gcs/flight/onboard.py) writes parameters the drones read back; missions that fly them onboard load them,
and a mission they cannot fly is one line."""

from __future__ import annotations

import itertools
import math
from pathlib import Path

import numpy as np
import pytest

from gcs.flight.behaviours import FlockSpec, flock_acceleration, follower_slots, turn_towards
from gcs.flight.onboard import FLOCKING, LEADER_FOLLOWER, MAX_POINTS, OnboardSpecError, flock_params, point_values
from gcs.missions.mission_file import FlockStep, MissionFileError, flown_onboard, load_mission, parse_mission
from sitl.onboard import NeighbourReport, OnboardState
from sitl.onboard.behaviours import points
from sitl.onboard.behaviours.flocking import Flocking, steering
from sitl.onboard.behaviours.leader_follower import HEADING_TIME_CONSTANT_S, LeaderFollower
from sitl.onboard.behaviours.leader_follower import Path as LeaderPath
from sitl.onboard.loader import BehaviourError, load_behaviour
from tests.integration.mission_flight import MISSIONS

FLOCK_SPEC = FlockSpec(alt_m=4.0, migration_ne_m=((30.0, 5.0),), separation_lookahead_s=1.0)


def defaults(cls: type) -> dict[str, float]:
    return {name: default for name, (default, _low, _high) in cls.PARAMS.items()}  # type: ignore[attr-defined]


def state(sysid: int, pos: tuple[float, float, float], vel: tuple[float, float, float], t_s: float,
          neighbours: tuple[NeighbourReport, ...], params: dict[str, float]) -> OnboardState:  # fmt: skip
    return OnboardState(time_s=t_s, sysid=sysid, pos_ned_m=pos, vel_ned_mps=vel, yaw_rad=0.0, armed=True,
                        in_air=True, neighbours=neighbours, detections=(), params=params, messages=())  # fmt: skip


def test_the_flocking_defaults_and_parameters_are_the_ground_specs() -> None:
    table = defaults(Flocking)
    plain = FlockSpec(alt_m=table["FLK_ALT"])
    assert flock_params(plain) == {name: table[name] for name in flock_params(plain)}
    assert set(point_values("FLK_MIG", ((1.0, 2.0),))) <= set(table)
    assert MAX_POINTS == points.MAX_POINTS


@pytest.mark.parametrize("seed", range(20))
def test_one_drones_flocking_steering_is_the_ground_laws_row_for_it(seed: int) -> None:
    # GIVEN a drone and up to eight others around it, moving, some close enough to push, some beyond the radius
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 9)) + 1
    pos = rng.uniform(-6.0, 6.0, (n, 2))
    vel = rng.uniform(-1.5, 1.5, (n, 2))
    cmd = rng.uniform(-1.5, 1.5, (n, 2))
    sysids = list(rng.permutation(np.arange(1, n + 1)))
    params = {**defaults(Flocking), **flock_params(FLOCK_SPEC)}
    table = tuple(NeighbourReport(sysid=int(sysids[k]), pos_ned_m=(pos[k, 0], pos[k, 1], -4.0),
                                  vel_ned_mps=(vel[k, 0], vel[k, 1], 0.0), age_s=0.05)
                  for k in range(1, n))  # fmt: skip
    goal = FLOCK_SPEC.migration_ne_m[0]
    # WHEN the onboard law steers drone 0 from its table
    onboard = steering((pos[0, 0], pos[0, 1]), (vel[0, 0], vel[0, 1]), (cmd[0, 0], cmd[0, 1]), int(sysids[0]), table,
                       goal, params)  # fmt: skip
    # THEN it is the ground law's acceleration for drone 0 (rows in sysid order, as the ground station holds them)
    order = np.argsort(sysids)
    ground = flock_acceleration(pos[order], vel[order], cmd[order], np.array(goal), FLOCK_SPEC)
    row = int(np.nonzero(order == 0)[0][0])
    assert onboard == pytest.approx(tuple(ground[row]), abs=1e-9)


def test_points_the_ground_station_sets_are_the_points_the_drone_reads() -> None:
    given = ((12.0, -3.5), (0.25, 7.0), (-40.0, 0.0))
    params = {**defaults(LeaderFollower), **point_values("LF_WP", given)}
    assert points.read_points(params, "LF_WP") == given
    with pytest.raises(OnboardSpecError, match=f"at most {MAX_POINTS} points"):
        point_values("LF_WP", ((1.0, 1.0),) * (MAX_POINTS + 1))


def test_the_onboard_leaders_path_rounds_each_corner_and_ends_at_rest_on_the_last_waypoint() -> None:
    # GIVEN the 12 m square with corners rounded at 3 m
    path = LeaderPath((0.0, 0.0), ((12.0, 0.0), (12.0, 12.0), (0.0, 12.0), (0.0, 0.0)), 3.0, 1.0)
    # THEN it is 48 m less what three arcs of 3 m cut off, and the course turns continuously
    assert path.length_m == pytest.approx(48.0 - 3 * (6.0 - 1.5 * math.pi), abs=1e-9)
    samples = [path.at(s) for s in np.arange(0.0, path.length_m, 0.05)]
    for (p0, t0), (p1, t1) in itertools.pairwise(samples):
        assert math.dist(p0, p1) == pytest.approx(0.05, abs=1e-6)
        assert math.dist(t0, t1) < 0.05 / 3.0 + 1e-6  # no turn sharper than the 3 m arc
    assert path.at(path.length_m)[0] == pytest.approx((0.0, 0.0), abs=1e-9)
    # AND its speed limit is the turn's on an arc (v^2 / R = a) and zero at the end
    assert path.speed_limit(10.0, 1.0) == pytest.approx(math.sqrt(3.0))
    assert path.speed_limit(path.length_m, 1.0) == 0.0


def test_an_onboard_follower_flies_the_ground_laws_slot() -> None:
    # GIVEN a follower at its slot behind a leader heard flying north-east, its heading frame still north
    params = {**defaults(LeaderFollower), "LF_LEADER": 1.0, "LF_FWD": -2.0, "LF_RIGHT": 1.5, "LF_ALT": 3.0}
    leader = NeighbourReport(sysid=1, pos_ned_m=(10.0, 4.0, -3.0), vel_ned_mps=(1.0, 1.0, 0.0), age_s=0.05)
    behaviour = LeaderFollower()
    slot0 = (8.0, 5.5, -3.0)
    behaviour.step(state(2, slot0, (1.0, 1.0, 0.0), 10.0, (leader,), params))
    # WHEN it steps 0.05 s later
    out = behaviour.step(state(2, slot0, (1.0, 1.0, 0.0), 10.05, (leader,), params))
    # THEN its setpoint is the ground law's slot for the same heading filter step
    heading, rate = turn_towards(0.0, math.atan2(1.0, 1.0), 0.05, time_constant_s=HEADING_TIME_CONSTANT_S,
                                 max_rate_radps=params["LF_TURN_RATE"])  # fmt: skip
    slots, slot_vel = follower_slots(np.array(leader.pos_ned_m), np.array(leader.vel_ned_mps), heading, rate,
                                     np.array([[-2.0, 1.5]]), 3.0)  # fmt: skip
    assert out is not None
    assert out.pos_ned_m == pytest.approx(tuple(slots[0]), abs=0.02)  # within what its join moves in one step
    assert out.vel_ned_mps[:2] == pytest.approx(tuple(slot_vel[0, :2]), abs=1e-9)


def test_an_onboard_leader_hovers_its_wait_then_leaves_along_its_path() -> None:
    params = {**defaults(LeaderFollower), "LF_LEADER": 3.0, "LF_WAIT": 2.0,
              **point_values("LF_WP", ((10.0, 0.0),))}  # fmt: skip
    behaviour = LeaderFollower()
    moves = []
    for k in range(100):  # 5 s at 20 Hz
        out = behaviour.step(state(3, (0.0, 0.0, -3.0), (0.0, 0.0, 0.0), k * 0.05, (), params))
        assert out is not None
        moves.append(out.pos_ned_m[0])
    assert max(moves[:40]) == 0.0 < moves[41]  # still until 2 s, then along the first leg
    # 3 s on the way: 1.5 s accelerating at 1 m/s^2 to the cruise speed (1.125 m), then 1.5 s at 1.5 m/s
    assert moves[-1] == pytest.approx(1.125 + 1.5 * 1.5, abs=0.1)


def test_the_shipped_behaviours_load_by_module_name_and_a_bad_module_is_one_line() -> None:
    for spec, name in ((FLOCKING, "Flocking"), (LEADER_FOLLOWER, "LeaderFollower")):
        loaded = load_behaviour(spec)
        assert loaded.name == name and loaded.file.name.endswith(".py")
    with pytest.raises(BehaviourError, match=r"^sitl\.onboard\.behaviours\.nothing: no such module$"):
        load_behaviour("sitl.onboard.behaviours.nothing:Flocking")
    with pytest.raises(BehaviourError, match=r"no class Nothing$"):
        load_behaviour("sitl.onboard.behaviours.flocking:Nothing")


def test_flying_a_mission_onboard_makes_the_drones_carry_the_shipped_behaviour() -> None:
    flock = flown_onboard(load_mission(MISSIONS / "flocking.toml"))
    assert flock.swarm.behaviour == FLOCKING
    assert all(s.onboard for s in flock.steps if isinstance(s, FlockStep))
    assert flown_onboard(load_mission(MISSIONS / "leader_follower.toml")).swarm.behaviour == LEADER_FOLLOWER
    with pytest.raises(MissionFileError, match=r"grid_to_circle\.toml: --onboard: the mission has no flock or follow"):
        flown_onboard(load_mission(MISSIONS / "grid_to_circle.toml"))


MISSION = """
[swarm]
drones = 3
{behaviour}

[[steps]]
action = "takeoff"
alt_m = 3.0

[[steps]]
action = "flock"
duration_s = 10.0
alt_m = 3.0
migration_ne_m = {points}
onboard = {onboard}
"""


@pytest.mark.parametrize(
    ("behaviour", "points", "onboard", "problem"),
    [
        ('behaviour = "x.py:X"', "[[1.0, 0.0]]", "true", "steps[1].onboard: flown onboard with "
         "sitl.onboard.behaviours.flocking:Flocking, but the drones carry"),
        ("", "[[1.0, 0.0]]", '"yes"', "steps[1].onboard: must be true or false, got 'yes'"),
        ("", str([[float(k), 0.0] for k in range(MAX_POINTS + 1)]), "true",
         f"steps[1].migration_ne_m: an onboard step takes at most {MAX_POINTS} points, got {MAX_POINTS + 1}"),
    ],
)  # fmt: skip
def test_a_mission_that_cannot_fly_onboard_is_one_line(tmp_path: Path, behaviour: str, points: str, onboard: str,
                                                       problem: str) -> None:  # fmt: skip
    text = MISSION.format(behaviour=behaviour, points=points, onboard=onboard)
    with pytest.raises(MissionFileError) as caught:
        parse_mission(text, tmp_path / "m.toml")
    assert problem in str(caught.value) and "\n" not in str(caught.value)


def test_a_mission_step_flown_onboard_parses_with_the_behaviour_set() -> None:
    text = MISSION.format(behaviour="", points="[[1.0, 0.0]]", onboard="true")
    mission = parse_mission(text, Path("m.toml"))
    assert mission.swarm.behaviour == FLOCKING
    step = mission.steps[1]
    assert isinstance(step, FlockStep) and step.onboard
