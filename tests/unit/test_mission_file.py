"""Mission files: every shipped mission parses; every mistake names the file, the line and the field."""

from __future__ import annotations

from pathlib import Path

import pytest

from gcs.formation import CircleSpec, GridSpec
from gcs.mission_file import FormationStep, LandStep, MissionFileError, TakeoffStep, load_mission, parse_mission

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
    assert isinstance(mission.steps[0], TakeoffStep)
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
        ("drones = 4", "drones = 500", 3, "swarm.drones: at most 100"),
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
