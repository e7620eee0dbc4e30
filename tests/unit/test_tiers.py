"""The suite's tiers and kinds (tests/tiers.py) and the order files are dealt in (tests/scheduling.py): every test has
one kind from its folder and one tier; the quick tier starts no process; the acceptance tier holds the campaigns, Ray,
the long attach flights and the scale flights; each tier's selection is what docs/testing.md says; files are dealt
longest first, each keeping its tests' order."""

from __future__ import annotations

import json
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

from tests.scheduling import UNKNOWN_FILE_S, load_table, longest_first
from tests.tiers import file_of

ROOT = Path(__file__).resolve().parents[2]

pytestmark = [pytest.mark.timeout(120), pytest.mark.suite]  # a collection of the whole suite, in a child: 10-20 s

# One collection of the whole suite, in a child, for a given --tier: every test's node id and the marks it was given.
_COLLECT = """
import json, sys, pytest

class Marks:
    def __init__(self): self.items = []
    def pytest_collection_finish(self, session):
        self.items = [(item.nodeid, sorted({m.name for m in item.iter_markers()} & NAMES)) for item in session.items]

NAMES = {"unit", "flight", "integration", "quick", "suite", "acceptance"}
marks = Marks()
code = pytest.main(["--collect-only", "-q", "-p", "no:cacheprovider", "-n", "0", *sys.argv[1:], "tests"],
                   plugins=[marks])
print("MARKS " + json.dumps(marks.items))
sys.exit(code)
"""

KINDS = {"unit": "tests/unit/", "flight": "tests/closed_loop/", "integration": "tests/integration/"}
TIERS = ("quick", "suite", "acceptance")
ACCEPTANCE_FILES = {"tests/integration/test_falsify.py"}  # every test of these files is an acceptance test
ACCEPTANCE_TESTS = {  # and these tests of files whose other tests stay in the suite (parameters left out)
    "tests/integration/test_attach.py::test_the_attach_and_the_intruders_silence_are_each_said_once",
    "tests/integration/test_attach.py::"
    "test_the_drones_keep_clear_of_the_intruder_as_it_crosses_and_farther_as_what_they_know_of_it_ages",
    "tests/integration/test_attach_links.py::test_four_drones_follow_a_leader_that_flies_itself_in_a_v_and_keep_clear_of_it",
    "tests/integration/test_attach_member.py::test_the_px4_member_flies_its_slot_and_is_left_holding_armed",
    "tests/integration/test_attach_member.py::"
    "test_the_ardupilot_member_is_armed_in_guided_flown_by_global_setpoints_and_released_at_its_keep_in",
    "tests/integration/test_attach_member.py::test_the_report_page_replays_the_members_beside_the_drones",
    "tests/integration/test_attach_member.py::"
    "test_a_member_the_swarm_may_not_arm_is_never_commanded_and_said_to_be_left_out",
    "tests/integration/test_attach_member.py::test_a_member_its_pilot_takes_over_is_released_and_never_asked_back",
    "tests/integration/test_avoidance_fly.py::test_sixteen_drones_change_from_grid_to_circle_without_a_collision",
    "tests/integration/test_behaviours_fly.py::test_the_drones_flock_out_and_back_aligned_and_without_a_collision[12-",
    "tests/integration/test_fuzz.py::"
    "test_a_hovering_drone_holds_its_position_under_20000_hostile_frames_not_addressed_to_it",
    "tests/integration/test_links_fly.py::test_the_same_lockstep_mission_flies_the_same_on_an_idle_and_a_loaded_machine",
    "tests/integration/test_sweep.py::test_the_same_sweep_on_a_local_ray_head_gives_the_same_runs_and_summary",
    "tests/integration/test_sweep.py::test_a_falsification_on_a_local_ray_head_finds_and_shrinks_what_it_does_here",
    "tests/unit/test_kernels.py::test_processes_compiling_at_once_into_an_empty_cache_fly_alike_and_the_next_only_loads",
}
# The test that compiles the kernels cold, into a cache of its own, in the suite (not the quick tier): the reference
# flight with kernels compiled for any CPU. Three processes compiling at once are an acceptance test.
COLD_COMPILES = {
    "tests/closed_loop/test_reference_flight.py::"
    "test_the_reference_flight_is_the_same_with_other_blas_kernels_and_kernels_compiled_for_any_cpu",
}
# The smaller versions that stay in the suite, proving the same as what moved
SMALLER_IN_THE_SUITE = {
    "tests/integration/test_sweep.py::test_a_small_falsification_finds_the_contact_and_shrinks_it_to_both_drones_avoidance_off",
    "tests/integration/test_behaviours_fly.py::test_the_drones_flock_out_and_back_aligned_and_without_a_collision[6-",
    "tests/integration/test_many_drones_ports.py::test_more_than_40_drones_each_talk_only_to_their_own_api_clients",
    "tests/integration/test_fuzz.py::test_a_drone_commanded_by_hostile_frames_survives_and_answers",
    "tests/integration/test_attach_links.py::"
    "test_a_vehicle_on_tcp_or_a_serial_line_is_attached_shown_in_the_status_detached_and_attached_again",
}


def _collected(tier: str) -> list[tuple[str, set[str]]]:
    out = subprocess.run([sys.executable, "-c", _COLLECT, "--tier", tier], cwd=ROOT, capture_output=True, text=True,
                         timeout=110)  # fmt: skip
    assert out.returncode == 0, out.stdout[-2000:] + out.stderr[-2000:]
    line = next(line for line in out.stdout.splitlines() if line.startswith("MARKS "))
    return [(nodeid, set(marks)) for nodeid, marks in json.loads(line[len("MARKS ") :])]


def _named(nodeid: str) -> str:
    """A test as the lists above name it: its node id without its parameters, or with the first of them where the
    lists give it (``name[12-``: a parameter that decides the tier)."""
    name, _, params = nodeid.partition("[")
    first = params.split("-")[0]
    listed = f"{name}[{first}-"
    return listed if listed in ACCEPTANCE_TESTS | SMALLER_IN_THE_SUITE else name


@pytest.fixture(scope="module")
def everything() -> list[tuple[str, set[str]]]:
    return _collected("all")


def test_every_test_has_one_kind_from_its_folder_and_one_tier(everything: list[tuple[str, set[str]]]) -> None:
    assert len(everything) > 1000
    for nodeid, names in everything:
        kinds = names & set(KINDS)
        assert len(kinds) == 1 and nodeid.startswith(KINDS[kinds.pop()]), (nodeid, names)
        assert len(names & set(TIERS)) == 1, (nodeid, names)


def test_the_quick_tier_starts_no_process_and_the_acceptance_tier_is_what_it_is_meant_to_be(
    everything: list[tuple[str, set[str]]],
) -> None:
    tier = {nodeid: (names & set(TIERS)).pop() for nodeid, names in everything}
    assert all(not nodeid.startswith(KINDS["integration"]) for nodeid, t in tier.items() if t == "quick")
    assert all(tier[nodeid] == "suite" for nodeid in COLD_COMPILES)
    acceptance = {nodeid for nodeid, t in tier.items() if t == "acceptance"}
    whole_files = {file_of(nodeid) for nodeid in acceptance} - {file_of(t) for t in ACCEPTANCE_TESTS}
    assert whole_files == ACCEPTANCE_FILES
    for path in ACCEPTANCE_FILES:  # every test of those files, none left in the suite
        assert all(t == "acceptance" for nodeid, t in tier.items() if file_of(nodeid) == path), path
    assert {_named(nodeid) for nodeid in acceptance if file_of(nodeid) not in ACCEPTANCE_FILES} == (ACCEPTANCE_TESTS)
    # AND the smaller versions that prove the same are in the suite
    suite = {_named(nodeid) for nodeid, t in tier.items() if t == "suite"}
    assert suite >= SMALLER_IN_THE_SUITE, SMALLER_IN_THE_SUITE - suite


@pytest.mark.parametrize("selection", ["quick", "suite", "acceptance"])
def test_each_selection_collects_its_tiers_and_nothing_else(
    selection: str, everything: list[tuple[str, set[str]]]
) -> None:
    wanted = {"quick": {"quick"}, "suite": {"quick", "suite"}, "acceptance": {"acceptance"}}[selection]
    expected = {nodeid for nodeid, names in everything if names & wanted}
    assert {nodeid for nodeid, _ in _collected(selection)} == expected


@dataclass
class _Item:
    nodeid: str
    whole_machine: bool = False
    tier: str = "suite"

    def get_closest_marker(self, name: str) -> object | None:
        return object() if name == "wall_clock" and self.whole_machine else None


def _tier(item: Any) -> str:
    return str(item.tier)


def test_a_file_is_dealt_by_what_this_run_flies_of_it() -> None:
    # GIVEN a file whose long flight is an acceptance test, and a shorter file all in the suite
    items: list[Any] = [_Item("split.py::short", tier="suite"), _Item("whole.py::1", tier="suite")]
    table = {"split.py": {"suite": 10.0, "acceptance": 300.0}, "whole.py": {"suite": 50.0}}
    # WHEN the suite is dealt THEN the split file counts its suite tests only
    longest_first(items, table, _tier)
    assert [i.nodeid for i in items] == ["whole.py::1", "split.py::short"]


def test_files_are_dealt_longest_first_each_keeping_its_tests_order_and_a_new_file_as_if_it_took_a_minute() -> None:
    items: list[Any] = [_Item(n) for n in ("a.py::1", "b.py::1", "a.py::2", "c.py::1", "new.py::1", "b.py::2")]
    for item in items:
        item.tier = "suite" if item.nodeid.startswith("b.py") else "quick"
    longest_first(items, {"a.py": {"quick": 5.0}, "b.py": {"suite": 300.0}, "c.py": {"quick": 5.0}}, _tier)
    assert [i.nodeid for i in items] == ["b.py::1", "b.py::2", "new.py::1", "a.py::1", "a.py::2", "c.py::1"]
    assert 5.0 < UNKNOWN_FILE_S < 300.0


def test_files_that_take_the_whole_machine_are_dealt_before_the_others_however_short() -> None:
    items: list[Any] = [_Item("long.py::1"), _Item("attach.py::1"), _Item("attach.py::2", whole_machine=True),
                        _Item("paced.py::1", whole_machine=True)]  # fmt: skip
    longest_first(
        items, {"long.py": {"suite": 600.0}, "attach.py": {"suite": 60.0}, "paced.py": {"suite": 90.0}}, _tier
    )
    assert [i.nodeid for i in items] == ["paced.py::1", "attach.py::1", "attach.py::2", "long.py::1"]


def test_the_committed_table_names_only_files_that_exist() -> None:
    table = load_table()
    assert table, "tests/durations.json is missing or empty"
    missing = [path for path in table if not (ROOT / path).is_file()]
    assert not missing, f"refresh tests/durations.json (tests/scheduling.py says how): {missing}"
