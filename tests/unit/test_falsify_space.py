"""The space a falsification searches (gcs/falsify/space.py): a mission's [falsify] table read and checked, each point
written back as a plain mission file that the mission loader takes, and hypothesis's shrinking going where a reader
would simplify."""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Any

import pytest
from hypothesis import find, given, settings

from gcs.falsify.space import (
    FalsifyError,
    FaultAt,
    ParamChange,
    Scenario,
    mission_text,
    parse_space,
    scenario_mission,
    strategy,
)
from gcs.missions.mission_file import load_mission

pytestmark = [pytest.mark.unit, pytest.mark.timeout(60)]

MISSION = """
name = "swap"
[swarm]
drones = 4
params = { AVOID_MIN_DIST = 1.5 }

[swarm.drone.1]
params = { MPC_XY_VEL_MAX = 3.0 }

[[invariants]]
kind = "contact"

[[steps]]
action = "takeoff"
alt_m = 3.0

[[steps]]
action = "swap"
speed_mps = 1.5

[[steps]]
action = "land"

[falsify]
seed = [0, 1000]
gust_mps = [0.0, 2.0]
params = { AVOID_ENABLE = [0] }
max_perturbations = 3

[falsify.faults]
kinds = ["link"]
drones = [2, 3]
at_s = [5.0, 20.0]
for_s = [1.0, 6.0]
"""


def space_of(text: str = MISSION) -> Any:
    return parse_space(tomllib.loads(text)["falsify"], drones=4)


def test_a_space_is_read_from_the_missions_falsify_table_and_the_mission_flies_it_as_its_own_keys(
    tmp_path: Path,
) -> None:
    space = space_of()
    assert space.seeds == (0, 1000) and space.max_perturbations == 3 and space.params == (("AVOID_ENABLE", (0,)),)
    assert space.faults is not None and space.faults.drones == (2, 3) and space.faults.for_s is not None
    # the mission with its [falsify] table flies as it is (swarm fly leaves the table to swarm falsify)
    original = tmp_path / "swap.toml"
    original.write_text(MISSION)
    assert load_mission(original).swarm.seed is None
    # GIVEN a point of it WHEN it is written back into the mission THEN the mission loader reads its own keys
    scenario = Scenario(seed=7, gust_mps=0.5, perturbations=(ParamChange(2, "AVOID_ENABLE", 0),
                                                             FaultAt(3, "link", 12.5, 2.0)))  # fmt: skip
    written = tmp_path / "found.toml"
    written.write_text(mission_text(scenario_mission(tomllib.loads(MISSION), scenario), header=["found"]))
    assert written.read_text().startswith("# found\n")
    mission = load_mission(written)
    assert (mission.swarm.seed, mission.swarm.gust_mps) == (7, 0.5)
    assert dict(mission.swarm.drone_params) == {1: (("MPC_XY_VEL_MAX", 3.0),), 2: (("AVOID_ENABLE", 0),)}
    assert [(f.drone, f.fault.kind, f.after_s, f.fault.for_s) for f in mission.faults] == [(3, "link", 12.5, 2.0)]
    assert "falsify" not in tomllib.loads(written.read_text())
    assert (
        scenario.describe()
        == "seed 7; gusts 0.5 m/s; drone 2 AVOID_ENABLE = 0; link fault on drone 3 at 12.5 s for 2 s"
    )


def test_a_scenario_cut_to_the_first_drones_and_steps_is_a_mission_that_loads_and_says_what_was_cut(
    tmp_path: Path,
) -> None:
    # GIVEN a scenario cut to 2 of the 4 drones and the first 2 steps, drone 1 with its own parameters
    scenario = Scenario(drones=2, steps=2, perturbations=(ParamChange(2, "AVOID_ENABLE", 0),))
    written = tmp_path / "cut.toml"
    written.write_text(mission_text(scenario_mission(tomllib.loads(MISSION), scenario)))
    # THEN the mission loader takes it: 2 drones, takeoff and swap, drone 1's and 2's parameters kept
    mission = load_mission(written)
    assert mission.swarm.drones == 2 and [type(s).__name__ for s in mission.steps] == ["TakeoffStep", "SwapStep"]
    assert dict(mission.swarm.drone_params) == {1: (("MPC_XY_VEL_MAX", 3.0),), 2: (("AVOID_ENABLE", 0),)}
    assert scenario.describe() == "2 drones; its first 2 step(s); drone 2 AVOID_ENABLE = 0"
    assert Scenario.from_json(scenario.to_json()) == scenario


@pytest.mark.parametrize(
    ("param_drones", "allowed"), [("", (1, 2, 3, 4)), ("param_drones = [4, 1]\n", (1, 4))], ids=["any", "chosen"]
)
def test_every_drawn_point_is_in_the_space(param_drones: str, allowed: tuple[int, ...]) -> None:
    space = space_of(MISSION.replace("max_perturbations", param_drones + "max_perturbations"))

    @settings(max_examples=200, deadline=None)
    def check(scenario: Scenario) -> None:
        assert scenario.seed is None or 0 <= scenario.seed <= 1000
        assert scenario.gust_mps is not None and 0.0 <= scenario.gust_mps <= 2.0
        assert len(scenario.perturbations) <= 3
        for p in scenario.perturbations:
            if isinstance(p, FaultAt):
                assert p.drone in (2, 3) and 5.0 <= p.at_s <= 20.0 and p.for_s is not None and 1.0 <= p.for_s <= 6.0
            else:
                assert p.drone in allowed and (p.name, p.value) == ("AVOID_ENABLE", 0)

    given(strategy(space))(check)()


def test_shrinking_goes_to_fewer_perturbations_a_later_and_shorter_fault_and_the_missions_own_seed() -> None:
    # the smallest point hypothesis finds with a link fault on drone 3 is that fault alone, at the latest time, for
    # the shortest while, everything else as the mission has it
    found = find(strategy(space_of()),
                 lambda s: any(isinstance(p, FaultAt) and p.drone == 3 for p in s.perturbations),
                 settings=settings(max_examples=500, database=None))  # fmt: skip
    assert found == Scenario(seed=None, gust_mps=0.0, perturbations=(FaultAt(3, "link", 20.0, 1.0),)), found


@pytest.mark.parametrize(
    ("change", "said"),
    [
        (("seed = [0, 1000]", "seed = [10, 2]"), r"seed: must be \[low, high\] with"),
        (("seed = [0, 1000]", "seed = [0.5, 2]"), "seed: must be whole numbers"),
        (("gust_mps = [0.0, 2.0]", "gusts = [0.0, 2.0]"), r"gusts: not a field of \[falsify\]"),
        (("params = { AVOID_ENABLE = [0] }", "params = { AVOID_ENABLE = [] }"), "params.AVOID_ENABLE: must be a list"),
        (('kinds = ["link"]', 'kinds = ["meteor"]'), "faults.kinds: must be a list of faults"),
        (("drones = [2, 3]", "drones = [2, 9]"), r"faults.drones: must be drones of the swarm, 1..4"),
        (("at_s = [5.0, 20.0]", "at = [5.0, 20.0]"), "faults.at: not a field"),
        (("for_s = [1.0, 6.0]", "for_s = [0.0, 6.0]"), "faults.for_s: a link fault lasts more than 0 s"),
        (("max_perturbations = 3", "max_perturbations = 40"), "max_perturbations: must be in 0..8"),
        (("max_perturbations = 3", "param_drones = [0]"), r"param_drones: must be drones of the swarm, 1..4"),
    ],
)
def test_a_bad_space_is_one_line_naming_its_field(change: tuple[str, str], said: str) -> None:
    old, new = change
    assert old in MISSION
    with pytest.raises(FalsifyError, match=said) as caught:
        space_of(MISSION.replace(old, new, 1))
    assert "\n" not in str(caught.value)
    with pytest.raises(FalsifyError, match="nothing to vary"):
        parse_space({}, drones=4)


def test_bad_falsify_commands_are_one_line_and_exit_2_before_anything_flies(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from gcs.cli import main

    good = tmp_path / "swap.toml"
    good.write_text(MISSION)
    no_invariants = tmp_path / "plain.toml"
    no_invariants.write_text(MISSION.replace('[[invariants]]\nkind = "contact"\n', ""))
    no_space = tmp_path / "nospace.toml"
    no_space.write_text(MISSION[: MISSION.index("[falsify]")])
    for argv, said in (
        (["falsify", str(good), "--budget", "0"], "--budget must be in 1..10000"),
        (["falsify", str(good), "--time", "-1"], "--time must be a positive number"),
        (["falsify", str(good), "--jobs", "0"], "--jobs must be at least 1"),
        (["falsify", str(good), "--jobs", "2", "--ray", "auto"], "--jobs is for this machine"),
        (["falsify", str(tmp_path / "none.toml")], "no such mission file"),
        (["falsify", str(no_invariants)], "no [[invariants]]: nothing a flight could break"),
        (["falsify", str(no_space)], "nothing to vary"),
    ):
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and said in err, (argv, err)
    assert not (tmp_path / "falsify").exists()


def test_the_files_a_mission_names_are_found_from_the_folder_its_scenarios_are_written_in(tmp_path: Path) -> None:
    # GIVEN the shipped plan mission, with a predicate of its own beside it
    home, elsewhere = tmp_path / "mine", tmp_path / "campaign" / "runs" / "0000"
    home.mkdir()
    elsewhere.mkdir(parents=True)
    shipped = Path(__file__).parents[2] / "missions"
    (home / "box.plan").write_text((shipped / "box.plan").read_text())
    (home / "checks.py").write_text("def fine(state):\n    return True\n")
    text = (
        shipped / "qgc_box.toml"
    ).read_text() + '\n[[invariants]]\nkind = "predicate"\nfunction = "checks.py:fine"\n'
    (home / "qgc_box.toml").write_text(text)
    # WHEN a scenario of it is written in another folder, as a campaign writes its flights
    written = elsewhere / "mission.toml"
    written.write_text(mission_text(scenario_mission(tomllib.loads(text), Scenario(seed=3), home.resolve())))
    # THEN it loads there, and names the plan and the predicate where they are
    mission = load_mission(written)
    assert mission.steps[0].file == home.resolve() / "box.plan"  # type: ignore[union-attr]
    assert str(home.resolve() / "checks.py") in written.read_text()
