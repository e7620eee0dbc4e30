"""Onboard collision avoidance with real processes, judged by the flight report (issue acceptance scenarios).

Each test flies a shipped mission with ``swarm fly --lockstep`` (all drones on one simulated clock, as fast as the
two cores allow, with a quantum of 8 physics steps = 20 ms), so the outcome does not depend on how loaded the machine
is. Collisions are real: the shared world crashes both drones of any pair closer than two collision radii (0.7 m).
The 8-drone swap flies both ways (a process per drone, and hosted); the other large swarms fly hosted, which costs
this 2-CPU machine less (docs/benchmark-history.md).

Policy: loopback only (--no-forward); leased instances (tests/integration/instances.py); a time limit on every test.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import cv2
import pytest

from tests.integration.instances import Leases
from tests.integration.mission_flight import fly_mission

pytestmark = [pytest.mark.sim_only]


def fly(mission: str, instances: Leases, tmp_path: Path, timeout_s: float, *, avoidance: bool = True,
        expect_ok: bool = True, extra: tuple[str, ...] = ()) -> dict[str, Any]:  # fmt: skip
    """Fly a shipped mission in lockstep (optionally with avoidance off on every drone); the report's metrics."""
    args = ["--lockstep", "--quantum", "8", *extra]
    metrics, _ = fly_mission(mission, args, tmp_path, timeout_s, instances, avoidance=avoidance, expect_ok=expect_ok)
    return metrics


@pytest.mark.timeout(240)
@pytest.mark.parametrize("per_process", ["1", "auto"], ids=["process-per-drone", "hosted"])
def test_eight_drones_swap_through_the_centre_without_touching(
    tmp_path: Path, instances: Leases, per_process: str
) -> None:
    # GIVEN 8 drones on a circle of radius 6 m (each in its own process, or shared between one process per CPU)
    # WHEN each is sent straight to the opposite point at 2 m/s
    metrics = fly("antipodal_swap.toml", instances, tmp_path, 220, extra=("--drones-per-process", per_process))
    # THEN nobody collided and nobody came closer than 0.8 m (centre to centre)
    assert metrics["collisions"] == 0, metrics["collision_events"]
    assert metrics["min_separation_m"] >= 0.8
    # AND everyone reached the opposite point (the step ends only when every drone is within 0.5 m of it) in 30 s
    swap = next(s for s in metrics["steps"] if s["kind"] == "swap")
    assert swap["end_s"] - swap["start_s"] <= 30.0
    # AND the drones did avoid: every one of them corrected its course
    assert metrics["avoidance_events"] >= 8


@pytest.mark.timeout(240)
def test_the_same_swap_without_avoidance_collides(tmp_path: Path, instances: Leases) -> None:
    # GIVEN the same mission with AVOID_ENABLE = 0 on every drone WHEN it is flown
    metrics = fly("antipodal_swap.toml", instances, tmp_path, 220, avoidance=False, expect_ok=False,
                  extra=("--drones-per-process", "auto"))  # fmt: skip
    # THEN drones collide in the centre: the scenario is a real test
    assert metrics["collisions"] >= 1
    assert metrics["avoidance_events"] == 0


@pytest.mark.timeout(180)
def test_a_head_on_pair_with_the_relay_cut_avoids_with_cameras_alone(tmp_path: Path, instances: Leases) -> None:
    # GIVEN two drones 12 m apart, no neighbour relay (each one's table stays empty)
    # WHEN they fly straight at each other at 2 m/s, facing the way they fly
    metrics = fly("head_on_camera.toml", instances, tmp_path, 160, extra=("--camera-frames", "1"))
    # THEN they pass without a collision, seeing each other only through their cameras
    assert metrics["collisions"] == 0, metrics["collision_events"]
    assert metrics["min_separation_m"] >= 0.8
    assert metrics["avoidance_events"] >= 1
    # AND drone 1's frames were saved, and the other drone is in some of them (a bright blob on the dark sky)
    first_instance = metrics["sysids"][0] - 1
    frames = sorted((tmp_path / "report" / "camera" / f"drone-{first_instance}").glob("*.png"))
    assert len(frames) > 100
    assert any(cv2.imread(str(f), cv2.IMREAD_GRAYSCALE).max() > 150 for f in frames)


@pytest.mark.timeout(420)
@pytest.mark.acceptance  # a scale flight; the suite flies 9 drones from grid to circle (test_links_fly.py)
def test_sixteen_drones_change_from_grid_to_circle_without_a_collision(tmp_path: Path, instances: Leases) -> None:
    metrics = fly("grid_to_circle_16.toml", instances, tmp_path, 400, extra=("--drones-per-process", "auto"))
    assert metrics["n_drones"] == 16 and len(metrics["sysids"]) == 16
    assert metrics["collisions"] == 0, metrics["collision_events"]
    circle = next(s for s in metrics["steps"] if s["name"] == "circle")
    assert circle["formation_rms_m"] is not None and circle["formation_rms_m"] < 0.3


@pytest.mark.timeout(180)
def test_four_drones_swap_round_a_pole_the_mission_declares(tmp_path: Path, instances: Leases) -> None:
    # GIVEN a pole at the centre of a 5 m circle of 4 drones WHEN they swap straight through it
    metrics = fly("pole_swap.toml", instances, tmp_path, 160)
    # THEN nobody hit the pole or another drone (a contact with either crashes the drone and is counted)
    assert metrics["collisions"] == 0, metrics["collision_events"]
    assert metrics["min_separation_m"] >= 0.8
