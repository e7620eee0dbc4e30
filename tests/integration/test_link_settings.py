"""Link settings from a mission's ``[swarm.links]`` and ``swarm fly``'s ``--link-*`` options reach every drone.

Policy: loopback only; instances 246-247 (sysids 247-248); lockstep, so nothing depends on the machine's load; a
time limit on every test; ``swarm fly`` stops every drone it started (tests/integration/test_swarm.py tests that no
process outlives it), and a run cut short by its timeout is killed with its drones (they die with their parent).
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = [pytest.mark.sim_only]

SWARM = [sys.executable, "-m", "gcs.cli"]
FIRST_INSTANCE = 246

MISSION = """\
name = "links"
[swarm]
drones = 2
layout = "line"
spacing_m = 3.0

[swarm.links]
latency_ms = 20

[swarm.links.neighbour]
latency_ms = 200
jitter_ms = 50

[[steps]]
action = "takeoff"
alt_m = 3.0

[[steps]]
action = "land"
"""


@pytest.mark.timeout(240)
def test_a_mission_s_links_and_the_options_over_them_reach_every_hosted_drone(tmp_path: Path) -> None:
    # GIVEN a mission impairing every link class and the neighbour traffic more, and an option over it for all
    mission = tmp_path / "links.toml"
    mission.write_text(MISSION)
    report = tmp_path / "report"
    # WHEN it is flown in lockstep, both drones hosted by one process
    result = subprocess.run(
        [*SWARM, "fly", str(mission), "--lockstep", "--first-instance", str(FIRST_INSTANCE), "--report", str(report),
         "--no-forward", "--drones-per-process", "2", "--link-loss", "0.01"],
        capture_output=True, text=True, timeout=220,
    )  # fmt: skip
    # THEN it flies, and each drone's log says the profile it was given: the option over the mission, per class
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    expected = (
        "links: gcs loss=0.01,latency_ms=20; api loss=0.01,latency_ms=20; "
        "neighbour loss=0.01,latency_ms=200,jitter_ms=50"
    )
    for instance in (FIRST_INSTANCE, FIRST_INSTANCE + 1):
        log = (report / "logs" / f"drone-{instance}.log").read_text()
        assert f"sitl {instance}: {expected}\n" in log, log[:2000]
