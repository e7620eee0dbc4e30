"""Invariants checked at every tick of a real flight (docs/invariants.md): three drones in lockstep take off to 3 m
and fly a circle of radius 3 m, under invariants that hold and two that do not (an altitude band capped at 2.5 m,
a fence of 2 m). Flown to its end, each violation is said once, with its time and drones, and lands in
summary.txt, metrics.json and the report's timeline; the command exits 3. With --stop-on-violation the flight ends
at the first one, the drones brought down and the report written.

Policy: loopback only (--no-forward); leased instances; lockstep, so what is checked does not depend on the load."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from tests.integration.instances import Leases
from tests.integration.mission_flight import fly_mission
from tests.unit.test_replay import unpack

pytestmark = [pytest.mark.sim_only]

MISSION = """
name = "circle_under_invariants"
[swarm]
drones = 3
spacing_m = 3.0

[[invariants]]
kind = "separation"
min_m = 1.0

[[invariants]]
kind = "contact"

[[invariants]]
kind = "no_failsafe"

[[invariants]]
kind = "answered"
within_s = 5.0

[[invariants]]
kind = "connected"
range_m = 20.0

[[invariants]]
name = "formed"
kind = "formation"
max_m = 0.5
form = "eventually"
after = "step"
within_s = 15.0

[[invariants]]
name = "low"
kind = "altitude"
min_m = 0.0
max_m = 2.5

[[invariants]]
name = "small_fence"
kind = "fence"
radius_m = 2.0
drones = [1, 2]

[[steps]]
action = "takeoff"
alt_m = 3.0

[[steps]]
action = "formation"
shape = "circle"
radius_m = 3.0
alt_m = 3.0
hold_s = 8.0

[[steps]]
action = "land"
"""


def replay_document_marks(report: Path) -> list[dict[str, object]]:
    """The timeline marks of a report page's replay document, as the page has them."""
    marks: list[dict[str, object]] = json.loads(unpack((report / "report.html").read_text(), "flight"))["marks"]
    return marks


@pytest.mark.timeout(240)
def test_violations_are_said_reported_and_fail_the_run_and_can_stop_the_flight(
    tmp_path: Path, instances: Leases
) -> None:
    mission = tmp_path / "circle_under_invariants.toml"
    mission.write_text(MISSION)
    first = instances(3)
    # GIVEN a flight flown to its end
    metrics, run = fly_mission(mission, ["--lockstep", "--no-view"], tmp_path / "whole", 150, first, expect_ok=False)
    # THEN it fails (exit 3: flown, an invariant broken) naming the first violation, and each violated invariant is
    # said once, when it broke
    assert run.returncode == 3, run.stdout[-3000:] + run.stderr[-2000:]
    assert "invariant(s) violated, first invariant" in run.stderr
    said = [line for line in run.stdout.splitlines() if re.search(r"swarm: invariant \w+ violated", line)]
    assert sorted(line.split()[2] for line in said) == ["low", "small_fence"], said
    # AND the report has them: metrics.json (in time order), summary.txt, the replay's timeline
    assert len(metrics["invariants"]) == 8
    violations = {v["name"]: v for v in metrics["violations"]}
    assert set(violations) == {"low", "small_fence"}
    low = violations["low"]
    assert low["kind"] == "altitude" and len(low["sysids"]) >= 1 and "band 0..2.5 m" in low["detail"]
    fence = violations["small_fence"]
    assert set(fence["sysids"]) <= {first + 1, first + 2}, fence  # only the drones it names (1 and 2)
    assert [v["time_s"] for v in metrics["violations"]] == sorted(v["time_s"] for v in metrics["violations"])
    summary = (tmp_path / "whole" / "report" / "summary.txt").read_text()
    assert "invariants: 8 checked, 2 violated" in summary
    marks = [m for m in replay_document_marks(tmp_path / "whole" / "report") if m["kind"] == "violation"]
    assert sorted(str(m["text"]).split(":")[0] for m in marks) == ["low", "small_fence"], marks
    # WHEN the same flight stops on a violation
    stopped, run = fly_mission(mission, ["--lockstep", "--no-view", "--stop-on-violation"], tmp_path / "stop", 150,
                               first, expect_ok=False)  # fmt: skip
    # THEN it ends at the first one (drones 1 and 2 stand 2.1 m from the origin: outside the fence before they even
    # take off), exit 3, the report written
    assert run.returncode == 3 and "stopped on a violation: invariant" in run.stderr, run.stderr[-2000:]
    assert [v["name"] for v in stopped["violations"]][:1] == [metrics["violations"][0]["name"]]
    assert stopped["violations"][0]["time_s"] == pytest.approx(metrics["violations"][0]["time_s"], abs=0.2)
    assert stopped["duration_s"] < metrics["duration_s"] - 5.0
    assert json.loads((tmp_path / "stop" / "report" / "metrics.json").read_text())["collisions"] == 0


BLIND_PAIR = """
name = "blind_pair"
[swarm]
drones = 2
layout = "line"
spacing_m = 12.0
relay = false
seed = 7
wind_ned_mps = [0.8, -0.6, 0.0]
gust_mps = 0.4
[swarm.drone.1]
params = { CAM_RANGE = 2.0 }
[swarm.drone.2]
params = { CAM_RANGE = 2.0 }
[[steps]]
action = "takeoff"
alt_m = 3.0
[[steps]]
action = "swap"
speed_mps = 2.0
timeout_s = 30.0
[[steps]]
action = "land"
[[invariants]]
kind = "contact"
[[invariants]]
kind = "separation"
min_m = 1.0
"""


@pytest.mark.timeout(240)
def test_two_drones_that_touch_report_the_contact_as_their_minimum_and_exit_3(tmp_path: Path,
                                                                           instances: Leases) -> None:  # fmt: skip
    """Two drones head-on, the relay cut and both cameras shortened to 2 m, in a light wind (seed pinned): they touch,
    both crash and the swap cannot finish. Costs one 2-drone lockstep flight (about 6 s)."""
    mission = tmp_path / "blind_pair.toml"
    mission.write_text(BLIND_PAIR)
    first = instances(2)
    metrics, run = fly_mission(mission, ["--lockstep", "--no-view"], tmp_path, 150, first, expect_ok=False)
    pair = [first + 1, first + 2]
    # THEN the flight broke its invariants and a step failed: exit 3, both said
    assert run.returncode == 3, run.stdout[-3000:] + run.stderr[-2000:]
    assert "not every drone reached the opposite point" in run.stderr, run.stderr[-2000:]
    assert "2 invariant(s) violated, first invariant separation" in run.stderr, run.stderr[-2000:]
    assert metrics["collisions"] == 1 and {v["name"] for v in metrics["violations"]} == {"contact", "separation"}
    # AND the minimum separation is the contact's: at most the contact distance, between the two, when it was said
    contact = metrics["collision_events"][0]
    assert metrics["min_separation_m"] <= metrics["collision_radius_m"], metrics["min_separation_m"]
    assert f"at {metrics['min_separation_m']:.2f} m" in contact["text"], contact
    assert sorted(metrics["min_separation_pair"]) == pair
    assert metrics["min_separation_time_s"] == pytest.approx(contact["time_s"], abs=0.2)
    # AND the separation invariant broke no later than the contact
    separation = next(v for v in metrics["violations"] if v["name"] == "separation")
    assert separation["time_s"] <= contact["time_s"] and sorted(separation["sysids"]) == pair, separation
    # AND summary.txt says the same minimum
    summary = (tmp_path / "report" / "summary.txt").read_text()
    assert f"min separation: {metrics['min_separation_m']:.2f} m" in summary, summary
