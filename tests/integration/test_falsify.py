"""``swarm falsify`` finds a planted weakness and shrinks it (docs/falsify.md): two drones swap places, avoiding each
other with the relay alone (no cameras); the space may turn drone 1's avoidance off, add gusts, and cut drone 2's links
for a while. Within a budget of 40 flights the search finds a contact and shrinks it to at most two perturbations; the
minimal mission file replays the same contact twice with swarm fly alone; the regression test it writes is a pytest
file.

Policy: loopback only; lockstep flights on instances held through the sweep's instance locks; a time limit."""

from __future__ import annotations

import ast
import json
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = [pytest.mark.sim_only, pytest.mark.acceptance]  # a budget-40 campaign; its budget-6 version: test_sweep.py

SWARM = [sys.executable, "-m", "gcs.cli"]
PLANTED = """
name = "planted_swap"
[swarm]
drones = 2
layout = "line"
spacing_m = 6.0
params = { CAM_ENABLE = 0 }

[[invariants]]
kind = "contact"

[[steps]]
action = "takeoff"
alt_m = 3.0

[[steps]]
action = "swap"
speed_mps = 1.5
timeout_s = 15.0

[[steps]]
action = "land"

[falsify]
params = { AVOID_ENABLE = [0] }
param_drones = [1]
gust_mps = [0.0, 1.0]
max_perturbations = 3

[falsify.faults]
kinds = ["link"]
drones = [2]
at_s = [2.0, 12.0]
for_s = [1.0, 5.0]
"""


@pytest.mark.timeout(900)
def test_a_planted_weakness_is_found_shrunk_and_replays_from_its_minimal_file(tmp_path: Path) -> None:
    mission = tmp_path / "planted_swap.toml"
    mission.write_text(PLANTED)
    out = tmp_path / "campaign"
    # (one flight at a time: the suite runs a test file per CPU, and flights on every CPU starve the other's paced ones)
    run = subprocess.run([*SWARM, "falsify", str(mission), "--budget", "40", "--shrink-budget", "40", "--seed", "1",
                          "--jobs", "1", "--out", str(out), "--emit-tests", str(tmp_path / "regressions")],
                         capture_output=True, text=True, timeout=850)  # fmt: skip
    # THEN it found a contact (exit 3) within the budget, and shrank it to at most two perturbations
    assert run.returncode == 3, run.stdout[-3000:] + run.stderr[-2000:]
    summary = json.loads((out / "summary.json").read_text())
    assert summary["search_flights"] <= 40 and len(summary["failures"]) == 1, summary
    assert summary["flights"] - summary["search_flights"] <= 40, summary
    (failure,) = summary["failures"]
    assert failure["invariant"] == "contact" and failure["perturbations"] <= 2, failure
    assert failure["first_flight"] < 40
    assert "link fault on drone 2" in failure["scenario"], failure
    # AND the mission was cut after the swap it broke in: the landing is not needed to break it
    assert "its first 2 step(s)" in failure["scenario"], failure
    # AND its minimal file replays the same contact, twice, with swarm fly alone
    minimal = Path(failure["mission"])
    contacts = []
    for k in range(2):
        replay = subprocess.run([*SWARM, "fly", str(minimal), "--lockstep", "--no-view", "--no-forward",
                                 "--report", str(tmp_path / f"replay{k}")], capture_output=True, text=True,
                                timeout=120)  # fmt: skip
        assert replay.returncode == 3, replay.stderr[-2000:]  # broken (and a swap that cannot finish: still 3)
        metrics = json.loads((tmp_path / f"replay{k}" / "metrics.json").read_text())
        contacts.append([(v["name"], v["time_s"], v["detail"]) for v in metrics["violations"]])
    assert contacts[0] == contacts[1] and contacts[0] and contacts[0][0][0] == "contact", contacts
    # AND the regression test it wrote is a pytest file beside its mission
    (test,) = (tmp_path / "regressions").glob("test_*.py")
    ast.parse(test.read_text())
    assert (test.parent / f"{test.stem.removeprefix('test_')}.toml").is_file()
    assert "campaign seed 1" in run.stdout
