"""Link settings on the ground station's side (gcs/fleet/links.py): the ``--link-*`` options, a mission's
``[swarm.links]``, the same rules and messages as the drone's ``--link``, and their way into every drone's command
line."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from gcs.cli import main as swarm_main
from gcs.composition import launch_plan, link_profile
from gcs.fleet.harness import SpawnPlan
from gcs.fleet.links import LINK_KEYS, LinkPlan, LinkSettings, parse_link_value
from gcs.missions.mission_file import MissionFileError, parse_mission
from sitl.harness.processes import host_args, sitl_args
from sitl.world.linkmodel import LinkImpairment, LinkProfile
from sitl.world.linkmodel import link_profile as sitl_link_profile
from tests.unit.link_cases import PAIR_CASES, VALUE_CASES

pytestmark = pytest.mark.timeout(60)

MISSION = """\
name = "links"
[swarm]
drones = 2
{links}
[[steps]]
action = "takeoff"
alt_m = 2.0
"""
OPTIONS = {"loss": "--link-loss", "latency_ms": "--link-latency-ms", "jitter_ms": "--link-jitter-ms",
           "burst_good_s": "--link-burst-good-s", "burst_bad_s": "--link-burst-bad-s",
           "burst_loss": "--link-burst-loss", "bandwidth_bps": "--link-bandwidth-bps"}  # fmt: skip


def mission(links: str, path: Path = Path("m.toml")) -> LinkPlan:
    return parse_mission(MISSION.format(links=links), path).swarm.links


# ---- one table of cases, both sides ------------------------------------------------------------------------------


def test_both_sides_start_from_the_same_perfect_link() -> None:
    # the keys and rules are one module (swarmcommon/links.py); the defaults live in each side's settings type
    assert {k: getattr(LinkSettings(), k) for k in LINK_KEYS} == {k: getattr(LinkImpairment(), k) for k in LINK_KEYS}


@pytest.mark.parametrize(("key", "text", "message"), VALUE_CASES)
def test_the_swarm_and_the_drone_accept_and_refuse_the_same_values_alike(
    key: str, text: str, message: str | None
) -> None:
    try:
        sitl_says = None
        sitl_link_profile([f"all:{key}={text}"])
    except ValueError as exc:
        sitl_says = str(exc)
    try:
        gcs_says = None
        parse_link_value(key, text)
    except ValueError as exc:
        gcs_says = str(exc)
    assert gcs_says == sitl_says == message


@pytest.mark.parametrize(("values", "message"), PAIR_CASES)
def test_both_sides_refuse_half_a_burst_setting_alike(values: dict[str, float], message: str) -> None:
    with pytest.raises(ValueError) as gcs_side:
        LinkSettings(**values)
    with pytest.raises(ValueError) as sitl_side:
        LinkImpairment(**values)
    assert str(gcs_side.value) == str(sitl_side.value) == message


@pytest.mark.parametrize(("key", "text", "message"), [case for case in VALUE_CASES if case[2] is not None])
def test_a_bad_link_option_is_one_line_naming_the_option_and_exit_code_2(
    key: str, text: str, message: str, capsys: pytest.CaptureFixture[str]
) -> None:
    assert swarm_main(["up", "-n", "2", f"{OPTIONS[key]}={text}"]) == 2
    assert capsys.readouterr().err == f"swarm: error: argument {OPTIONS[key]}: {message}\n"


def test_half_a_burst_setting_from_the_options_is_one_line(capsys: pytest.CaptureFixture[str]) -> None:
    assert swarm_main(["up", "-n", "2", "--link-burst-good-s", "3"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("swarm: error: --link-* options: gcs: burst_good_s and burst_bad_s")


# ---- the mission's [swarm.links] -----------------------------------------------------------------------------------


def test_a_mission_sets_every_class_and_each_class_over_that() -> None:
    plan = mission("""
[swarm.links]
loss = 0.2
latency_ms = 40

[swarm.links.neighbour]
latency_ms = 200
jitter_ms = 50
""")
    assert plan.gcs == plan.api == LinkSettings(loss=0.2, latency_ms=40)
    assert plan.neighbour == LinkSettings(loss=0.2, latency_ms=200, jitter_ms=50)
    assert mission("") == LinkPlan() and LinkPlan().is_perfect


def test_options_override_the_mission_for_every_class() -> None:
    plan = mission("[swarm.links.api]\nloss = 0.3\nlatency_ms = 10\n").overridden({"loss": 0.1, "jitter_ms": 5.0})
    assert plan.api == LinkSettings(loss=0.1, latency_ms=10, jitter_ms=5)
    assert plan.gcs == plan.neighbour == LinkSettings(loss=0.1, jitter_ms=5)


@pytest.mark.parametrize(
    ("links", "expected"),
    [
        ("[swarm.links]\nloss = 1.5\n", "m.toml:5: swarm.links.loss: must be in [0, 1], got 1.5"),
        ("[swarm.links]\nloss = 0.1\n\n[swarm.links.gcs]\nlatency_ms = -3\n",
         "m.toml:8: swarm.links.gcs.latency_ms: must be >= 0, got -3"),
        ("[swarm.links.api]\nloss = \"high\"\n", "m.toml:5: swarm.links.api.loss: must be a finite number, got 'high'"),
        ("[swarm.links]\nspeed = 3\n", "m.toml:5: swarm.links.speed: unknown field (allowed: api, bandwidth_bps, "
         "burst_bad_s, burst_good_s, burst_loss, gcs, jitter_ms, latency_ms, loss, neighbour)"),
        ("[swarm.links.neighbour]\nburst_good_s = 2\n",
         "m.toml:4: swarm.links.neighbour: burst_good_s and burst_bad_s must both be > 0 (bursts) or both 0 (none), "
         "got 2 and 0"),
        ("[swarm.links]\nbandwidth_bps = 0\n",
         "m.toml:5: swarm.links.bandwidth_bps: must be > 0 (leave it out for no cap), got 0"),
    ],
)  # fmt: skip
def test_a_bad_links_table_is_one_line_with_file_line_and_key(links: str, expected: str) -> None:
    with pytest.raises(MissionFileError) as caught:
        mission(links)
    assert str(caught.value) == expected


def test_swarm_fly_refuses_a_bad_links_table_and_bad_options_with_exit_code_2(tmp_path: Path) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text(MISSION.format(links="[swarm.links]\nloss = 1.5\n"))
    good = tmp_path / "good.toml"
    good.write_text(MISSION.format(links=""))
    for argv, line in [
        ([str(bad)], f"swarm: error: {bad}:5: swarm.links.loss: must be in [0, 1], got 1.5"),
        ([str(good), "--link-latency-ms", "-3"], "swarm: error: argument --link-latency-ms: latency_ms must be >= 0, "
                                                 "got -3"),
    ]:  # fmt: skip
        result = subprocess.run([sys.executable, "-m", "gcs.cli", "fly", *argv, "--no-forward"],
                                capture_output=True, text=True, timeout=50)  # fmt: skip
        assert result.returncode == 2, result.stderr
        assert result.stderr == line + "\n"


# ---- into every drone's command line -------------------------------------------------------------------------------


def test_the_settings_reach_every_drone_s_command_line_as_link_options() -> None:
    links = LinkPlan(neighbour=LinkSettings(latency_ms=200, jitter_ms=50)).overridden({"loss": 0.2})
    plan = launch_plan(SpawnPlan(n_drones=3, first_instance=246, links=links))
    assert plan.links == LinkProfile(
        gcs=LinkImpairment(loss=0.2), api=LinkImpairment(loss=0.2),
        neighbour=LinkImpairment(loss=0.2, latency_ms=200, jitter_ms=50),
    )  # fmt: skip
    homes = plan.homes()
    for argv in (sitl_args(plan, 246, homes[0], 14550, None), host_args(plan, [246, 247, 248], homes, 14550, None)):
        given = [argv[k + 1] for k, arg in enumerate(argv) if arg == "--link"]
        assert sitl_link_profile(given) == plan.links
    assert "--link" not in sitl_args(launch_plan(SpawnPlan(n_drones=1)), 0, homes[0], 14550, None)


def test_the_two_sides_describe_a_profile_in_the_same_words() -> None:
    links = LinkPlan(api=LinkSettings(bandwidth_bps=57600)).overridden({"loss": 0.05, "latency_ms": 40})
    assert link_profile(links).describe() == links.describe()
    assert links.describe() == ("gcs loss=0.05,latency_ms=40; api loss=0.05,latency_ms=40,bandwidth_bps=57600; "
                                "neighbour loss=0.05,latency_ms=40")  # fmt: skip
