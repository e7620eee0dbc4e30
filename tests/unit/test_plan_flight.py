"""Choosing drones and offsets for a plan's copies (gcs/missions/plan_flight.py), and `swarm plan`'s mistakes before
sending."""

from __future__ import annotations

from pathlib import Path

import pytest

from gcs.cli import main
from gcs.missions.plan_flight import PlanUsageError, copy_offsets, parse_drones, parse_offsets

SYSIDS = [14, 15, 16, 17, 18]
SPAWN = {14: (0.0, -8.0), 15: (0.0, 0.0), 16: (0.0, 8.0), 17: (8.0, -8.0), 18: (8.0, 0.0)}


def test_drones_are_all_or_a_list_of_numbers_and_ranges_in_the_swarms_order() -> None:
    assert parse_drones("all", SYSIDS) == SYSIDS
    assert parse_drones("18,14-15", SYSIDS) == [14, 15, 18]
    assert parse_drones(" 16 , 16-17 ", SYSIDS) == [16, 17]


@pytest.mark.parametrize(
    ("text", "problem"),
    [
        ("1,3", "drones: 1 is not one of 14..18"),
        ("15-14", "drones: the range 15-14 runs backwards"),
        ("14;15", "drones: '14;15' is not 'all' or a list like 1,3-5"),
        ("", "drones: '' is not 'all' or a list like 1,3-5"),
    ],
)
def test_a_wrong_choice_of_drones_is_one_line(text: str, problem: str) -> None:
    with pytest.raises(PlanUsageError, match=f"^{problem}$"):
        parse_drones(text, SYSIDS)


def test_each_copy_moves_by_its_spawn_offset_by_none_or_by_the_offsets_given() -> None:
    assert copy_offsets(SPAWN, [14, 16], "spawn") == {14: (0.0, -8.0), 16: (0.0, 8.0)}
    assert copy_offsets(SPAWN, [14, 16], "none") == {14: (0.0, 0.0), 16: (0.0, 0.0)}
    assert copy_offsets(SPAWN, [14, 16], parse_offsets("0,0; 0,20")) == {14: (0.0, 0.0), 16: (0.0, 20.0)}
    with pytest.raises(PlanUsageError, match=r"^offsets: 1 given for 2 drones: give one N,E each$"):
        copy_offsets(SPAWN, [14, 16], parse_offsets("5,5"))
    with pytest.raises(PlanUsageError, match=r"^offsets: '5' is not N,E \(metres north, east\)$"):
        parse_offsets("5")


def test_swarm_plan_upload_checks_the_file_before_it_asks_any_supervisor(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    # GIVEN no supervisor running (an empty state directory) and a plan that is not JSON
    monkeypatch.setenv("SWARM_STATE_DIR", str(tmp_path / "state"))
    bad = tmp_path / "bad.plan"
    bad.write_text("{\n  'fileType': 'Plan'\n}\n")
    # WHEN it is uploaded THEN one line names the file, exit code 2, before the missing supervisor matters
    assert main(["plan", "upload", str(bad)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [
        f"swarm: error: {bad}:2: not valid JSON: Expecting property name enclosed in double quotes (column 3)"
    ]
    # AND a bad offset is one line too
    assert main(["plan", "upload", str(Path(__file__).parents[2] / "missions" / "box.plan"), "--offsets", "x"]) == 2
    assert capsys.readouterr().err.strip() == "swarm: error: offsets: 'x' is not N,E (metres north, east)"
    # AND with a good file and no supervisor, the command fails as every control command does (exit code 1)
    assert main(["plan", "start"]) == 1
    assert "no swarm is running" in capsys.readouterr().err


def test_swarm_fly_names_a_broken_plan_of_a_plan_step_in_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    (tmp_path / "broken.plan").write_text('{"fileType": "Plan", "version": 1}')
    mission = tmp_path / "m.toml"
    mission.write_text('[swarm]\ndrones = 2\n[[steps]]\naction = "plan"\nfile = "broken.plan"\n')
    assert main(["fly", str(mission)]) == 2
    assert capsys.readouterr().err.strip().splitlines() == [
        f"swarm: error: {mission}:5: steps[0].file: {tmp_path / 'broken.plan'}: missing key 'mission'"
    ]
