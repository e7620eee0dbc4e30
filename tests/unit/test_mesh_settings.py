"""How neighbours' positions travel, as the ground station takes it (``[swarm] neighbours``, ``[swarm.mesh]``,
``--neighbours``, ``--mesh-range-m``) and hands it to every drone (``sitl --mesh-range-m``): the same rules and words
on both sides, contradictions refused, and one line with exit code 2 for every mistake."""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import pytest

from gcs.cli import _neighbour_plan, build_parser
from gcs.cli import main as swarm_main
from gcs.composition import launch_plan
from gcs.fleet.harness import SpawnPlan
from gcs.fleet.links import MeshPlan, NeighbourPlan
from gcs.fleet.relay import RelayScope
from gcs.missions.mission_file import MissionFileError, parse_mission
from sitl.cli import build_parser as sitl_parser
from sitl.cli import main as sitl_main
from sitl.harness.processes import host_args, sitl_args
from sitl.world.mesh import MeshSettings, mesh_problem
from swarmcommon.links import mesh_value_problem

pytestmark = pytest.mark.timeout(60)

MISSION = """\
name = "mesh"
[swarm]
drones = 2
{swarm}
[[steps]]
action = "takeoff"
alt_m = 2.0
{tables}"""


def mission(swarm: str = "", tables: str = "") -> NeighbourPlan:
    parsed = parse_mission(MISSION.format(swarm=swarm, tables=tables), Path("m.toml")).swarm
    return NeighbourPlan(relay=parsed.relay, mesh=parsed.mesh, relay_scope=parsed.relay_scope)


# ---- one set of rules, both sides ---------------------------------------------------------------------------------


def test_both_sides_have_the_same_defaults() -> None:
    assert MeshPlan().range_m == MeshSettings().range_m and MeshPlan().exponent == MeshSettings().exponent


@pytest.mark.parametrize(
    ("key", "value", "message"),
    [
        ("range_m", 15.0, None),
        ("range_m", 0.0, "range_m must be > 0, got 0"),
        ("range_m", -3.0, "range_m must be > 0, got -3"),
        ("range_m", math.nan, "range_m must be a finite number, got nan"),
        ("range_m", True, "range_m must be a finite number, got True"),
        ("exponent", 2.0, None),
        ("exponent", 0.0, "exponent must be in (0, 20], got 0"),
        ("exponent", 21.0, "exponent must be in (0, 20], got 21"),
        ("exponent", -math.inf, "exponent must be a finite number, got -inf"),
    ],
)
def test_the_swarm_and_the_drone_accept_and_refuse_the_same_mesh_values_alike(
    key: str, value: object, message: str | None
) -> None:
    others = {"range_m": 15.0, "exponent": 4.0}
    sitl_says = mesh_problem(**{**others, key: value})
    assert mesh_value_problem(key, value) == sitl_says == message


# ---- the mission ---------------------------------------------------------------------------------------------------


def test_a_mission_chooses_the_relay_the_mesh_both_or_neither() -> None:
    assert mission() == NeighbourPlan(relay=True, mesh=None)
    assert mission('neighbours = "relay"') == NeighbourPlan(relay=True, mesh=None)
    assert mission('neighbours = "mesh"') == NeighbourPlan(relay=False, mesh=MeshPlan())
    assert mission('neighbours = "both"', "[swarm.mesh]\nrange_m = 30\nexponent = 2\n") == NeighbourPlan(
        relay=True, mesh=MeshPlan(range_m=30.0, exponent=2.0)
    )
    assert mission("relay = false") == NeighbourPlan(relay=False, mesh=None)  # the cameras alone, as before
    assert mission('relay = false\nneighbours = "mesh"') == NeighbourPlan(relay=False, mesh=MeshPlan())
    assert mission('neighbours = "mesh"').mode == "mesh" and mission("relay = false").mode == "none"


@pytest.mark.parametrize(
    ("swarm", "tables", "expected"),
    [
        ('neighbours = "radio"', "", "m.toml:4: swarm.neighbours: must be one of relay, mesh, both, got 'radio'"),
        ('relay = true\nneighbours = "mesh"', "",
         "m.toml:4: swarm.relay: relay = true contradicts neighbours = 'mesh'"),
        ('relay = false\nneighbours = "both"', "",
         "m.toml:4: swarm.relay: relay = false contradicts neighbours = 'both'"),
        ("", "[swarm.mesh]\nrange_m = 15\n", 'm.toml:8: swarm.mesh: needs neighbours = "mesh" or "both" in [swarm]'),
        ('neighbours = "relay"', "[swarm.mesh]\nrange_m = 15\n",
         "m.toml:8: swarm.mesh: is set but neighbours = 'relay' has no mesh"),
        ('neighbours = "mesh"', "[swarm.mesh]\nrange_m = -15\n", "m.toml:9: swarm.mesh.range_m: must be > 0, got -15"),
        ('neighbours = "mesh"', "[swarm.mesh]\nexponent = 0\n",
         "m.toml:9: swarm.mesh.exponent: must be in (0, 20], got 0"),
        ('relay_scope = "nearest:0"', "",
         "m.toml:4: swarm.relay_scope: nearest: the count must be a whole number of drones >= 1, got 0"),
        ("relay_scope = 15", "", "m.toml:4: swarm.relay_scope: must be a string (reach, all, within:METRES or "
         "nearest:COUNT), got 15"),
        ('neighbours = "mesh"\nrelay_scope = "all"', "",
         "m.toml:5: swarm.relay_scope: is set but there is no relay (neighbours = 'mesh')"),
        ('neighbours = "mesh"', "[swarm.mesh]\nrange = 15\n",
         "m.toml:9: swarm.mesh.range: unknown field (allowed: exponent, range_m)"),
    ],
)  # fmt: skip
def test_a_bad_or_contradictory_neighbours_setting_is_one_line_with_file_line_and_key(
    swarm: str, tables: str, expected: str
) -> None:
    with pytest.raises(MissionFileError) as caught:
        mission(swarm, tables)
    assert str(caught.value) == expected


def test_a_mission_chooses_whom_the_relay_forwards_to() -> None:
    assert mission().relay_scope == RelayScope()  # reach
    assert mission('relay_scope = "within:12"').relay_scope == RelayScope(kind="within", radius_m=12.0)
    both = mission('neighbours = "both"\nrelay_scope = "nearest:6"')
    assert both.relay_scope == RelayScope(kind="nearest", count=6) and both.mesh == MeshPlan()
    assert both.describe().startswith("relay (to the 6 nearest drones) and mesh")


# ---- the options ---------------------------------------------------------------------------------------------------


def options(*argv: str) -> NeighbourPlan:
    return _neighbour_plan(build_parser().parse_args(["up", "-n", "2", *argv]), NeighbourPlan())


def test_the_options_choose_the_mode_and_range_over_a_mission() -> None:
    assert options() == NeighbourPlan()
    assert options("--neighbours", "mesh", "--mesh-range-m", "20") == NeighbourPlan(
        relay=False, mesh=MeshPlan(range_m=20.0)
    )
    args = build_parser().parse_args(["fly", "x.toml", "--neighbours", "relay"])
    assert _neighbour_plan(args, NeighbourPlan(relay=False, mesh=MeshPlan(range_m=9.0))) == NeighbourPlan()
    args = build_parser().parse_args(["fly", "x.toml", "--mesh-range-m", "30"])  # the mission's mesh, farther
    mesh_mission = NeighbourPlan(relay=True, mesh=MeshPlan(range_m=9.0, exponent=2.0))
    assert _neighbour_plan(args, mesh_mission) == NeighbourPlan(relay=True, mesh=MeshPlan(range_m=30.0, exponent=2.0))


def test_the_relay_scope_option_is_taken_over_a_missions() -> None:
    assert options("--relay-scope", "all").relay_scope == RelayScope(kind="all")
    args = build_parser().parse_args(["fly", "x.toml", "--relay-scope", "within:20"])
    scoped = _neighbour_plan(args, NeighbourPlan(relay_scope=RelayScope(kind="nearest", count=3)))
    assert scoped == NeighbourPlan(relay_scope=RelayScope(kind="within", radius_m=20.0))
    args = build_parser().parse_args(["bench", "--relay-scope", "nearest:5"])
    assert args.relay_scope == RelayScope(kind="nearest", count=5)
    assert build_parser().parse_args(["bench"]).relay_scope == RelayScope()


@pytest.mark.parametrize(
    ("argv", "line"),
    [
        (["--relay-scope", "everyone"],
         "swarm: error: argument --relay-scope: must be reach, all, within:METRES or nearest:COUNT, got 'everyone'"),
        (["--neighbours", "mesh", "--relay-scope", "all"],
         "swarm: error: --relay-scope needs the relay: --neighbours relay or both (or a mission that has it)"),
        (["--mesh-range-m", "-1"], "swarm: error: argument --mesh-range-m: range_m must be > 0, got -1"),
        (["--mesh-range-m", "far"], "swarm: error: argument --mesh-range-m: range_m must be a number, got 'far'"),
        (["--neighbours", "mesh", "--mesh-range-m", "inf"],
         "swarm: error: argument --mesh-range-m: range_m must be a finite number, got inf"),
        (["--mesh-range-m", "10"],
         "swarm: error: --mesh-range-m needs the mesh: --neighbours mesh or both (or a mission that has it)"),
    ],
)  # fmt: skip
def test_a_bad_neighbours_option_is_one_line_and_exit_code_2(
    argv: list[str], line: str, capsys: pytest.CaptureFixture[str]
) -> None:
    assert swarm_main(["up", "-n", "2", *argv]) == 2
    assert capsys.readouterr().err == line + "\n"


def test_an_unknown_mode_is_refused_by_the_parser(capsys: pytest.CaptureFixture[str]) -> None:
    assert swarm_main(["up", "-n", "2", "--neighbours", "radio"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "argument --neighbours: invalid choice: 'radio'" in err


def test_swarm_fly_refuses_a_contradictory_mission_with_exit_code_2(tmp_path: Path) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text(MISSION.format(swarm='relay = true\nneighbours = "mesh"', tables=""))
    result = subprocess.run([sys.executable, "-m", "gcs.cli", "fly", str(bad), "--no-forward"],
                            capture_output=True, text=True, timeout=50)  # fmt: skip
    assert result.returncode == 2, result.stderr
    assert result.stderr == f"swarm: error: {bad}:4: swarm.relay: relay = true contradicts neighbours = 'mesh'\n"


# ---- into every drone's command line -------------------------------------------------------------------------------


def test_the_mesh_reaches_every_drone_s_command_line_and_reads_back_the_same() -> None:
    plan = launch_plan(SpawnPlan(n_drones=3, first_instance=172, mesh=MeshPlan(range_m=12.5, exponent=3.0)))
    assert plan.mesh == MeshSettings(range_m=12.5, exponent=3.0)
    homes = plan.homes()
    for argv in (sitl_args(plan, 172, homes[0], 14550, "w"), host_args(plan, [172, 173, 174], homes, 14550, "w")):
        args = sitl_parser().parse_args(argv)
        assert MeshSettings(range_m=args.mesh_range_m, exponent=args.mesh_exponent) == plan.mesh
    assert "--mesh-range-m" not in sitl_args(launch_plan(SpawnPlan(n_drones=1)), 0, homes[0], 14550, "w")


@pytest.mark.parametrize(
    ("argv", "line"),
    [
        (["--mesh-range-m", "-2", "--world", "w"], "sitl: error: --mesh-range-m must be > 0, got -2"),
        (["--mesh-range-m", "15", "--mesh-exponent", "30", "--world", "w"],
         "sitl: error: --mesh-exponent must be in (0, 20], got 30"),
        (["--mesh-range-m", "15"],
         "sitl: error: --mesh-range-m needs --world (the mesh's medium is in the swarm's shared world)"),
        (["--mesh-exponent", "2"],
         "sitl: error: --mesh-exponent needs --mesh-range-m (the mesh is off without a range)"),
    ],
)  # fmt: skip
def test_a_bad_mesh_option_of_the_drone_is_one_line_and_exit_code_2(
    argv: list[str], line: str, capsys: pytest.CaptureFixture[str]
) -> None:
    assert sitl_main(argv) == 2
    assert capsys.readouterr().err == line + "\n"


def test_the_report_names_the_way_neighbours_travelled() -> None:
    assert NeighbourPlan().describe() == "relay (to drones within 15 m or closing to it within 5 s)"
    assert NeighbourPlan(relay=False, mesh=MeshPlan()).describe() == "mesh (range 15 m, path loss (d/range)^4)"
    assert NeighbourPlan(relay=True, mesh=MeshPlan(range_m=30.0, exponent=2.0)).describe() == (
        "relay (to drones within 15 m or closing to it within 5 s) and mesh (range 30 m, path loss (d/range)^2)"
    )
    assert NeighbourPlan(relay_scope=RelayScope(kind="all")).describe() == "relay (to every drone)"
    assert NeighbourPlan(relay=False).describe() == "none (cameras only)"
