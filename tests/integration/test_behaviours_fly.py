"""``swarm fly`` of the behaviour missions with real processes: leader-follower and flocking, judged by the report.

Leader-follower is flown with the drones' onboard collision avoidance switched off (``AVOID_ENABLE = 0`` in the
mission's [swarm] params), so a follower's error is the law's own. The flock is flown as shipped, avoidance on, in
lockstep (one simulated clock, quantum 8 steps, the drones hosted several to a process), so the result does not
depend on the machine's load: the whole system, separation rule and onboard avoidance together, must keep 12 drones
apart and aligned, whether the ground station computes the flock or every drone flocks by itself (the shipped onboard
behaviour).

Policy: loopback only (--no-forward); leased instances (tests/integration/instances.py); a time limit on every test.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from tests.integration.instances import Leases
from tests.integration.mission_flight import MISSIONS, fly_mission, mission_drones

pytestmark = [pytest.mark.sim_only]


def fly(mission: str | Path, timing: list[str], instances: Leases, tmp_path: Path, timeout_s: float, *,
        avoidance: bool) -> dict[str, Any]:  # fmt: skip
    """Fly a shipped mission (optionally without onboard avoidance); the report's metrics."""
    metrics, result = fly_mission(mission, timing, tmp_path, timeout_s, instances, avoidance=avoidance)
    if not avoidance:
        assert "parameters set on every drone: AVOID_ENABLE = 0" in result.stdout
        assert metrics["avoidance_events"] == 0
    return metrics


@pytest.mark.timeout(240)
def test_leader_follower_mission_keeps_the_followers_on_their_slots_round_the_square(
    tmp_path: Path, instances: Leases
) -> None:
    # GIVEN the 5-drone mission: the middle drone of a line leads a 12 m square, four follow in a V
    # WHEN it is flown in lockstep (paced at 3x, a swarm this size needs more than one of this machine's two cores,
    # and what it flies would then depend on the other test worker's load)
    metrics = fly("leader_follower.toml", ["--lockstep"], instances, tmp_path, 220, avoidance=False)
    # THEN nobody touched anybody
    assert metrics["n_drones"] == 5 and len(metrics["sysids"]) == 5
    assert metrics["collisions"] == 0
    assert metrics["min_separation_m"] > 1.5
    # AND the follow step lasted the square (it ends only once the leader reports itself at its last waypoint)
    follow = next(s for s in metrics["steps"] if s["kind"] == "follow")
    assert follow["end_s"] - follow["start_s"] > 30.0
    # AND the drones were on their slots (followers: offsets from the leader's reported state; the leader: its
    # path) within 10 s of the step's start and stayed there until it ended: within 1 m each, 0.4 m RMS
    assert follow["time_to_formation_s"] is not None and follow["time_to_formation_s"] < 10.0
    assert follow["max_error_m"] < 1.0
    assert follow["formation_rms_m"] < 0.4
    # AND the leader (drone 3: the third sysid) flew the 44 m path
    assert metrics["distance_flown_m"][str(metrics["sysids"][2])] > 40.0


@pytest.mark.timeout(420)
@pytest.mark.parametrize("by", ["ground", "onboard"])
@pytest.mark.parametrize(
    "drones",
    [pytest.param(12, marks=pytest.mark.acceptance, id="12"), pytest.param(6, id="6")],  # 12: a scale flight
)
def test_the_drones_flock_out_and_back_aligned_and_without_a_collision(
    tmp_path: Path, instances: Leases, drones: int, by: str
) -> None:
    # GIVEN the flocking mission: 60 s towards a migration point 40 m north and back, then land; with its 12 drones as
    # shipped (the acceptance tier) or 6 (the suite: the same laws and the same promises)
    mission = MISSIONS / "flocking.toml"
    if drones != mission_drones(mission):
        text = mission.read_text()
        assert text.count("drones = 12\n") == 1
        mission = tmp_path / mission.name
        mission.write_text(text.replace("drones = 12\n", f"drones = {drones}\n"))
    # WHEN it is flown as shipped, onboard avoidance on, in lockstep: by the ground station's law, or by every drone
    # itself (the shipped onboard behaviour, from its own estimate and neighbour table)
    where = ["--onboard"] if by == "onboard" else []
    timing = ["--lockstep", "--quantum", "8", "--drones-per-process", "auto"]
    metrics = fly(mission, [*timing, *where], instances, tmp_path, 400, avoidance=True)
    # THEN no drone collided or came within 1 m of another
    assert metrics["n_drones"] == drones and len(metrics["sysids"]) == drones
    assert metrics["collisions"] == 0
    assert metrics["min_separation_m"] > 1.0
    # AND the flock aligned within 10 s and stayed aligned: mean order parameter above 0.9 from then on
    flock = next(s for s in metrics["steps"] if s["kind"] == "flock")
    assert flock["end_s"] - flock["start_s"] == pytest.approx(60.0, abs=1.0)
    alignment = flock["alignment"]
    assert alignment["converged_time_s"] is not None and alignment["converged_time_s"] < 10.0
    assert alignment["mean"] > 0.9
    # AND it migrated: every drone flew out and most of the way back
    assert min(metrics["distance_flown_m"].values()) > 60.0


@pytest.mark.timeout(240)
def test_onboard_leader_follower_flies_the_square_with_each_follower_keeping_its_own_slot(
    tmp_path: Path, instances: Leases
) -> None:
    # GIVEN the 5-drone leader-follower mission, flown by the drones themselves: the leader its own path, each
    # follower its slot from the leader's relayed reports (avoidance off: the error is the law's own)
    timing = ["--lockstep", "--drones-per-process", "auto"]
    metrics = fly("leader_follower.toml", [*timing, "--onboard"], instances, tmp_path, 220, avoidance=False)
    # THEN nobody touched anybody
    assert len(metrics["sysids"]) == 5 and metrics["collisions"] == 0
    assert metrics["min_separation_m"] > 1.5
    # AND the step lasted until the leader reported itself back at its last waypoint, having flown the 44 m path
    follow = next(s for s in metrics["steps"] if s["kind"] == "follow")
    assert follow["end_s"] - follow["start_s"] > 30.0
    assert metrics["distance_flown_m"][str(metrics["sysids"][2])] > 40.0
    # AND the followers kept to their slots as the ground station computes them from the same reports (its own law,
    # as an observer): within 1 m RMS over the whole step, the join from the line included
    assert follow["step_rms_m"] < 1.0
