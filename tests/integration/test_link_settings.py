"""Link settings from a mission's ``[swarm.links]`` and ``swarm fly``'s ``--link-*`` options reach every drone.

Policy: loopback only; two leased instances (tests/integration/instances.py); lockstep, so nothing depends on the
machine's load; a time limit on every test; ``swarm fly`` stops every drone it started (tests/integration/test_swarm.py
tests that no process outlives it), and a run cut short by its timeout is killed with its drones (they die with their
parent).
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from tests.integration.instances import Leases

pytestmark = [pytest.mark.sim_only]

SWARM = [sys.executable, "-m", "gcs.cli"]

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
def test_a_mission_s_links_and_the_options_over_them_reach_every_hosted_drone(
    tmp_path: Path, instances: Leases
) -> None:
    # GIVEN a mission impairing every link class and the neighbour traffic more, and an option over it for all
    mission = tmp_path / "links.toml"
    mission.write_text(MISSION)
    report = tmp_path / "report"
    first = instances(2)
    # WHEN it is flown in lockstep, both drones hosted by one process
    result = subprocess.run(
        [*SWARM, "fly", str(mission), "--lockstep", "--first-instance", str(first), "--report", str(report),
         "--no-forward", "--drones-per-process", "2", "--link-loss", "0.01"],
        capture_output=True, text=True, timeout=220,
    )  # fmt: skip
    # THEN it flies, and each drone's log says the profile it was given: the option over the mission, per class
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    expected = (
        "links: gcs loss=0.01,latency_ms=20; api loss=0.01,latency_ms=20; "
        "neighbour loss=0.01,latency_ms=200,jitter_ms=50"
    )
    for instance in (first, first + 1):
        log = (report / "logs" / f"drone-{instance}.log").read_text()
        assert f"sitl {instance}: {expected}\n" in log, log[:2000]
