"""A mission file says everything that makes its flight (docs/missions.md): seed, wind and gusts, spawn jitter,
lockstep quantum, one drone's own parameters and a link burst at a mission time. Flown twice from the file alone in
lockstep, the two flights are the same flight; each condition did what it says.

Policy: loopback only (--no-forward); leased instances; lockstep."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from tests.integration.instances import Leases
from tests.integration.mission_flight import fly_mission

pytestmark = [pytest.mark.sim_only]

MISSION = """
name = "windy_circle"
[swarm]
drones = 3
spacing_m = 3.0
seed = 41
wind_ned_mps = [2.0, 0.0, 0.0]
gust_mps = 0.5
spawn_jitter_m = 0.5
quantum = 2

[swarm.drone.2]
params = { MPC_XY_VEL_MAX = 1.0 }

[[faults]]
drone = 3
fault = "link"
at_s = 9.0
for_s = 4.0

[[steps]]
action = "takeoff"
alt_m = 3.0

[[steps]]
action = "formation"
shape = "circle"
radius_m = 3.0
alt_m = 3.0
hold_s = 10.0

[[steps]]
action = "land"
"""
WALL_CLOCK_KEYS = ("pace", "realtime_factor")  # what the machine's speed decides, not the flight


def _flight(metrics: dict[str, Any]) -> dict[str, Any]:
    return {k: v for k, v in metrics.items() if not any(w in k for w in WALL_CLOCK_KEYS)}


@pytest.mark.timeout(240)
def test_the_mission_file_alone_fixes_the_flight_and_each_condition_acts(tmp_path: Path, instances: Leases) -> None:
    mission = tmp_path / "windy_circle.toml"
    mission.write_text(MISSION)
    first = instances(3)
    runs = []
    for k in range(2):
        metrics, run = fly_mission(mission, ["--lockstep", "--no-view"], tmp_path / f"run{k}", 150, first)
        runs.append((metrics, run))
    (a, run_a), (b, _run_b) = runs
    # THEN the two flights are one: every figure of the report the same
    assert _flight(a) == _flight(b)
    out = run_a.stdout
    # AND drone 2 got its own parameter, drone 3 its link burst at 9 s (lost, then heard again)
    assert f"parameters set on drone 2 (sysid {first + 2}): MPC_XY_VEL_MAX = 1" in out, out[:3000]
    assert [(f["sysid"], f["time_s"]) for f in a["faults"]] == [(first + 3, pytest.approx(9.0, abs=0.1))], a["faults"]
    assert [(r["sysid"], r["regained_s"] > r["time_s"] > 9.0) for r in a["regained"]] == [(first + 3, True)]
    # AND every drone flew in the mission's weather
    for k in range(3):
        log = (tmp_path / "run0" / "report" / "logs" / f"drone-{first + k}.log").read_text()
        assert "wind 2, 0, 0 m/s NED, gusts 0.5 m/s RMS" in log, log[:500]
