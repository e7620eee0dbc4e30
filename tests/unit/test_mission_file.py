"""Mission files: every shipped mission parses; every mistake names the file, the line and the field."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
from pymavlink.dialects.v20 import common as mavlink

from gcs.fleet.harness import SpawnPlan
from gcs.flight.formation import CircleSpec, GridSpec
from gcs.mavlink.params import param_set_message, param_value
from gcs.missions.mission_file import (
    BehaviourStep,
    FlockStep,
    FollowStep,
    FormationStep,
    LandStep,
    MissionFileError,
    PlanStep,
    TakeoffStep,
    build_flock,
    build_follow,
    load_mission,
    parse_mission,
)

MISSIONS = Path(__file__).resolve().parents[2] / "missions"

GOOD = """\
name = "t"
[swarm]
drones = 4
spacing_m = 2.5

[[steps]]
action = "takeoff"
alt_m = 3.0

[[steps]]
action = "formation"
shape = "circle"
radius_m = 2.5
alt_m = 3.0
hold_s = 10.0

[[steps]]
action = "land"
"""


@pytest.mark.parametrize("path", sorted(MISSIONS.glob("*.toml")), ids=lambda p: p.stem)
def test_every_shipped_mission_parses(path: Path) -> None:
    mission = load_mission(path)
    assert isinstance(mission.steps[0], TakeoffStep | PlanStep)  # a plan's mission takes off itself
    assert mission.swarm.drones >= 1


def test_grid_to_circle_is_the_classic_demo() -> None:
    mission = load_mission(MISSIONS / "grid_to_circle.toml")
    assert mission.swarm.drones == 9 and mission.swarm.spacing_m == 2.0
    grid, circle = mission.steps[1], mission.steps[2]
    assert isinstance(grid, FormationStep) and isinstance(grid.formation, GridSpec)
    assert (grid.formation.rows, grid.formation.cols, grid.formation.spacing_m) == (3, 3, 2.0)
    assert isinstance(circle, FormationStep) and isinstance(circle.formation, CircleSpec)
    assert circle.formation.radius_m == 3.0 and circle.formation.angular_rate_radps == 0.2
    assert isinstance(mission.steps[-1], LandStep)


@pytest.mark.parametrize(
    ("old", "new", "line", "expected"),
    [
        ("radius_m = 2.5", "radius_m = -1", 13, "steps[1].radius_m: must be a positive number"),
        ("radius_m = 2.5", "radius = 2.5", 13, "steps[1].radius: unknown field"),
        ('shape = "circle"', 'shape = "hexagon"', 12, "steps[1].shape: must be one of"),
        ("drones = 4", "drones = 0", 3, "swarm.drones: must be a whole number >= 1"),
        ("drones = 4", "drones = 500", 3, "swarm.drones: at most 254"),
        ('action = "land"', 'action = "teleport"', 18, "steps[2].action: must be takeoff"),
        (
            'alt_m = 3.0\n\n[[steps]]\naction = "formation"',
            '\n[[steps]]\naction = "formation"',
            6,
            "missing field 'alt_m'",
        ),
        ("hold_s = 10.0", "", 10, "missing field 'hold_s'"),
        ("spacing_m = 2.5", 'spacing_m = "wide"', 4, "swarm.spacing_m: must be a number"),
    ],
)
def test_mistakes_name_file_line_and_field(old: str, new: str, line: int, expected: str) -> None:
    text = GOOD.replace(old, new, 1)
    with pytest.raises(MissionFileError) as info:
        parse_mission(text, Path("m.toml"))
    message = str(info.value)
    assert message.startswith(f"m.toml:{line}: "), message
    assert expected in message
    assert "\n" not in message


def test_invalid_toml_is_reported_with_its_position() -> None:
    with pytest.raises(MissionFileError, match=r"m.toml: not valid TOML: .*line 3"):
        parse_mission(GOOD.replace("drones = 4", "drones = = 4"), Path("m.toml"))


def test_first_step_must_be_a_takeoff() -> None:
    text = GOOD.replace('action = "takeoff"\nalt_m = 3.0', 'action = "hold"\nduration_s = 2')
    with pytest.raises(MissionFileError, match="first step must be a takeoff"):
        parse_mission(text, Path("m.toml"))


def test_missing_file_is_one_line(tmp_path: Path) -> None:
    with pytest.raises(MissionFileError, match="cannot read"):
        load_mission(tmp_path / "nope.toml")


BEHAVIOURS = """\
name = "b"
[swarm]
drones = 4

[[steps]]
action = "takeoff"
alt_m = 3.0

[[steps]]
action = "flock"
duration_s = 20.0
alt_m = 3.0
migration_ne_m = [
  [20.0, 0.0],
  [0.0, 0.0],
]
max_speed_mps = 1.5

[[steps]]
action = "follow"
leader_drone = 2
waypoints_ne_m = [[10.0, 0.0], [10.0, 10.0]]
alt_m = 3.0
offsets_fr_m = [[-2.0, 2.0], [-2.0, -2.0], [-4.0, 0.0]]
max_turn_rate_degps = 20

[[steps]]
action = "land"
"""


def test_flock_and_follow_steps_parse_into_their_specs() -> None:
    mission = parse_mission(BEHAVIOURS, Path("m.toml"))
    flock, follow = mission.steps[1], mission.steps[2]
    assert isinstance(flock, FlockStep) and flock.name == "flock" and flock.duration_s == 20.0
    assert flock.spec.migration_ne_m == ((20.0, 0.0), (0.0, 0.0)) and flock.spec.max_speed_mps == 1.5
    assert isinstance(follow, FollowStep) and follow.leader_drone == 2 and follow.duration_s is None
    assert follow.spec.waypoints_ne_m == ((10.0, 0.0), (10.0, 10.0)) and follow.spec.leader_sysid is None
    assert follow.spec.offsets_fr_m == ((-2.0, 2.0), (-2.0, -2.0), (-4.0, 0.0))
    assert follow.spec.max_turn_rate_radps == pytest.approx(math.radians(20))


def test_the_shipped_behaviour_missions_are_what_the_docs_say() -> None:
    flocking = load_mission(MISSIONS / "flocking.toml")
    assert flocking.swarm.drones == 12
    flock = flocking.steps[1]
    assert isinstance(flock, FlockStep) and flock.duration_s == 60.0 and len(flock.spec.migration_ne_m) == 2
    assert isinstance(flocking.steps[-1], LandStep)
    leader = load_mission(MISSIONS / "leader_follower.toml")
    follow = leader.steps[1]
    assert leader.swarm.drones == 5 and isinstance(follow, FollowStep) and len(follow.spec.waypoints_ne_m) == 4


@pytest.mark.parametrize(
    ("old", "new", "line", "expected"),
    [
        ("max_speed_mps = 1.5", "max_speed_mps = -1", 17, "steps[1].max_speed_mps: must be a positive number"),
        ("max_speed_mps = 1.5", "speed = 1.5", 17, "steps[1].speed: unknown field"),
        ("  [0.0, 0.0],", '  [0.0, "x"],', 13, "steps[1].migration_ne_m: must be a list of [north, east] pairs"),
        ("duration_s = 20.0\n", "", 9, "missing field 'duration_s' for a flock step"),
        (
            "max_speed_mps = 1.5",
            "separation_radius_m = 9.0",
            17,
            "steps[1].separation_radius_m: (9) must not exceed the neighbour radius (6)",
        ),
        ("leader_drone = 2", "leader_drone = 5", 21, "steps[2].leader_drone: must be one of the swarm's drones 1..4"),
        ("leader_drone = 2", "leader_sysid = 2", 21, "steps[2].leader_sysid: unknown field"),
        ("waypoints_ne_m = [[10.0, 0.0], [10.0, 10.0]]", "", 19, "missing field 'waypoints_ne_m' for a follow step"),
        ("waypoints_ne_m = [[10.0, 0.0], [10.0, 10.0]]", "waypoints_ne_m = []", 22, "steps[2].waypoints_ne_m: must be"),
        (", [-4.0, 0.0]]", "]", 24, "steps[2].offsets_fr_m: 2 offsets for 3 followers: give one each"),
        ("[-4.0, 0.0]]", "[0.0, 0.1]]", 24, "steps[2].offsets_fr_m: (0.0, 0.1) puts a follower on the leader"),
        ("max_turn_rate_degps = 20", "max_turn_rate_degps = 0", 25, "steps[2].max_turn_rate_degps: must be a positive"),
    ],
)
def test_behaviour_mistakes_name_file_line_and_field(old: str, new: str, line: int, expected: str) -> None:
    assert old in BEHAVIOURS
    text = BEHAVIOURS.replace(old, new, 1)
    with pytest.raises(MissionFileError) as info:
        parse_mission(text, Path("m.toml"))
    message = str(info.value)
    assert message.startswith(f"m.toml:{line}: "), message
    assert expected in message
    assert "\n" not in message


def test_behaviour_specs_from_plain_fields_name_the_bad_field() -> None:
    assert build_flock({"alt_m": 4}).alt_m == 4.0
    with pytest.raises(ValueError, match=r"^alt_m: must be a positive number"):
        build_flock({"alt_m": 0})
    with pytest.raises(ValueError, match="missing field 'alt_m' for flocking"):
        build_flock({})
    with pytest.raises(ValueError, match=r"^radius: not a field of flocking"):
        build_flock({"alt_m": 4, "radius": 3})
    assert build_follow({"waypoints_ne_m": [[1, 2]], "alt_m": 3, "leader_sysid": 7}).leader_sysid == 7
    with pytest.raises(ValueError, match=r"^leader_sysid: must be a whole number >= 1"):
        build_follow({"waypoints_ne_m": [[1, 2]], "alt_m": 3, "leader_sysid": 0.5})


def test_swarm_params_are_read_in_order_with_their_number_type() -> None:
    text = GOOD.replace("spacing_m = 2.5", "spacing_m = 2.5\nparams = { AVOID_ENABLE = 0, MPC_XY_P = 0.9 }")
    params = parse_mission(text, Path("m.toml")).swarm.params
    assert params == (("AVOID_ENABLE", 0), ("MPC_XY_P", 0.9))
    assert isinstance(params[0][1], int) and isinstance(params[1][1], float)
    with pytest.raises(MissionFileError, match=r"^m.toml:5: swarm.params: 'BAD-NAME' is not a parameter name"):
        parse_mission(GOOD.replace("spacing_m = 2.5", "spacing_m = 2.5\nparams = { BAD-NAME = 1 }"), Path("m.toml"))
    with pytest.raises(MissionFileError, match=r"^m.toml:5: swarm.params: X must be a number"):
        parse_mission(GOOD.replace("spacing_m = 2.5", 'spacing_m = 2.5\nparams = { X = "on" }'), Path("m.toml"))


@pytest.mark.parametrize("value", [0, 1, -3, 0.95, 12.5])
def test_a_param_set_carries_ints_bytewise_and_floats_as_floats(value: int | float) -> None:
    # GIVEN the PARAM_SET the runner sends, through the wire and back
    mav = mavlink.MAVLink(None)
    wire = param_set_message(7, "SOME_PARAM", value).pack(mav)
    parsed = mavlink.MAVLink(None).decode(bytearray(wire))
    # THEN the drone reads the number that was meant, with the type PX4 expects
    assert parsed.param_type == (
        mavlink.MAV_PARAM_TYPE_INT32 if isinstance(value, int) else mavlink.MAV_PARAM_TYPE_REAL32
    )
    assert param_value(parsed) == pytest.approx(value, rel=1e-7)
    assert parsed.target_system == 7 and parsed.param_id == "SOME_PARAM"


POLES = (
    GOOD
    + """
[[obstacles]]
shape = "cylinder"
north_m = 1.0
east_m = -2.0
radius_m = 0.25
height_m = 8.0

[[obstacles]]
shape = "sphere"
north_m = 5.0
east_m = 0.0
radius_m = 1.0
alt_m = 4.0

[[steps]]
action = "swap"
speed_mps = 2.0
"""
)


def test_obstacles_swap_steps_and_relay_are_read() -> None:
    mission = parse_mission(POLES.replace("spacing_m = 2.5", "spacing_m = 2.5\nrelay = false"), Path("m.toml"))
    pole, ball = mission.obstacles
    assert pole.cylinder and (pole.north_m, pole.east_m, pole.radius_m, pole.height_m) == (1.0, -2.0, 0.25, 8.0)
    assert pole.centre_alt_m == 4.0
    assert not ball.cylinder and ball.centre_alt_m == 4.0
    swap = mission.steps[-1]
    assert type(swap).__name__ == "SwapStep" and swap.speed_mps == 2.0 and swap.timeout_s == 30.0
    assert mission.swarm.relay is False


@pytest.mark.parametrize(
    ("old", "new", "expected"),
    [
        ('shape = "cylinder"', 'shape = "cube"', "obstacles[0].shape: must be cylinder or sphere"),
        ("height_m = 8.0", "", "missing field 'height_m' for a cylinder"),
        ("radius_m = 1.0", "radius_m = -1.0", "obstacles[1].radius_m: must be a positive number"),
        ("speed_mps = 2.0", "speed_mps = 0", "speed_mps: must be a positive number"),
    ],
)
def test_obstacle_and_swap_mistakes_are_one_line(old: str, new: str, expected: str) -> None:
    with pytest.raises(MissionFileError) as info:
        parse_mission(POLES.replace(old, new, 1), Path("m.toml"))
    assert expected in str(info.value) and "\n" not in str(info.value)


def test_relay_must_be_true_or_false() -> None:
    with pytest.raises(MissionFileError, match=r"swarm\.relay: must be true or false"):
        parse_mission(GOOD.replace("spacing_m = 2.5", 'spacing_m = 2.5\nrelay = "off"'), Path("m.toml"))


def test_a_mission_names_its_onboard_behaviour_beside_it_and_runs_it_in_a_behaviour_step(tmp_path: Path) -> None:
    text = ('name = "b"\n[swarm]\ndrones = 2\nbehaviour = "behaviours/climb.py:Climb"\n'
            '[[steps]]\naction = "takeoff"\nalt_m = 3.0\n'
            '[[steps]]\naction = "behaviour"\nduration_s = 12.0\n')  # fmt: skip
    mission = parse_mission(text, tmp_path / "m.toml")
    assert mission.swarm.behaviour == f"{tmp_path.resolve()}/behaviours/climb.py:Climb"
    assert mission.steps[1] == BehaviourStep(duration_s=12.0)
    with pytest.raises(MissionFileError, match=r'm.toml:4: swarm.behaviour: must be "path/to/file.py:ClassName"'):
        parse_mission(text.replace(":Climb", ""), tmp_path / "m.toml")
    with pytest.raises(MissionFileError, match=r"steps\[1\].action: a behaviour step needs \[swarm\] behaviour"):
        parse_mission(text.replace('behaviour = "behaviours/climb.py:Climb"\n', ""), tmp_path / "m.toml")


CONDITIONS = """
[swarm]
drones = 3
seed = 41
wind_ned_mps = [1.5, -0.5, 0.0]
gust_mps = 0.8
spawn_jitter_m = 0.6
quantum = 4

[swarm.drone.2]
params = { AVOID_ENABLE = 0, MPC_XY_VEL_MAX = 3.0 }

[[faults]]
drone = 3
fault = "link"
at_s = 12.5
for_s = 4.0

[[faults]]
drone = 1
fault = "gps"
at_s = 3.0

[[steps]]
action = "takeoff"
alt_m = 3.0
"""


def test_a_mission_says_its_seed_weather_jitter_quantum_per_drone_parameters_and_timed_faults(tmp_path: Path) -> None:
    """Everything a search varies is a key of the mission file, so a found failure replays from the file alone."""
    path = tmp_path / "conditions.toml"
    path.write_text(CONDITIONS)
    mission = load_mission(path)
    swarm = mission.swarm
    assert (swarm.seed, swarm.wind_ned_mps, swarm.gust_mps, swarm.spawn_jitter_m, swarm.quantum) == (
        41, (1.5, -0.5, 0.0), 0.8, 0.6, 4)  # fmt: skip
    assert swarm.drone_params == ((2, (("AVOID_ENABLE", 0), ("MPC_XY_VEL_MAX", 3.0))),)
    # the faults in time order, at mission times
    assert [(f.drone, f.fault.kind, f.after_s, f.fault.for_s) for f in mission.faults] == [
        (1, "gps", 3.0, None), (3, "link", 12.5, 4.0)]  # fmt: skip
    # a spawn plan's jitter is the seed's: the same seed the same spawn, another seed another, never over the bound
    plan = SpawnPlan(n_drones=3, spacing_m=2.0, seed=41, spawn_jitter_m=0.6)
    assert plan.offsets_ne_m() == SpawnPlan(n_drones=3, spacing_m=2.0, seed=41, spawn_jitter_m=0.6).offsets_ne_m()
    assert plan.offsets_ne_m() != SpawnPlan(n_drones=3, spacing_m=2.0, seed=42, spawn_jitter_m=0.6).offsets_ne_m()
    still = SpawnPlan(n_drones=3, spacing_m=2.0).offsets_ne_m()
    moved = [max(abs(a - b) for a, b in zip(p, q, strict=True)) for p, q in zip(plan.offsets_ne_m(), still,
                                                                                strict=True)]  # fmt: skip
    assert 0.0 < max(moved) <= 0.6


@pytest.mark.parametrize(
    ("change", "said"),
    [
        (("seed = 41", "seed = -1"), r"conditions.toml:4: swarm.seed: must be a whole number"),
        (("wind_ned_mps = [1.5, -0.5, 0.0]", "wind_ned_mps = [1.5, 0.0]"), "swarm.wind_ned_mps: must be"),
        (("wind_ned_mps = [1.5, -0.5, 0.0]", "wind_ned_mps = [30, 0, 0]"), "swarm.wind_ned_mps: at most 20"),
        (("gust_mps = 0.8", "gust_mps = -1"), "swarm.gust_mps"),
        (("spawn_jitter_m = 0.6", "spawn_jitter_m = 50"), "swarm.spawn_jitter_m: at most 10"),
        (("quantum = 4", "quantum = 0"), "swarm.quantum"),
        (("[swarm.drone.2]", "[swarm.drone.7]"), r"swarm.drone: \[swarm.drone.7\]: must name a drone 1..3"),
        (("params = { AVOID_ENABLE = 0, MPC_XY_VEL_MAX = 3.0 }", "speed = 2"), "unknown field"),
        (("at_s = 12.5", "at_s = -2"), r"faults\[0\].at_s"),
        (("at_s = 12.5", "after_s = 12.5"), r"faults\[0\]: missing field 'at_s'"),
        (("drone = 3", "drone = 9"), r"faults\[0\].drone: must be one of the swarm's drones 1..3"),
    ],
)
def test_a_bad_condition_is_one_line_naming_its_field(tmp_path: Path, change: tuple[str, str], said: str) -> None:
    path = tmp_path / "conditions.toml"
    old, new = change
    assert old in CONDITIONS
    path.write_text(CONDITIONS.replace(old, new, 1))
    with pytest.raises(MissionFileError, match=said) as caught:
        load_mission(path)
    assert "\n" not in str(caught.value)
