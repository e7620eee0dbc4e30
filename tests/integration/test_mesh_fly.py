"""The drone-to-drone mesh, judged by real ``swarm fly`` runs and their flight reports.

- The 9-drone grid_to_circle flies on the mesh alone (no relay: the supervisor forwards nothing), radio range 15 m,
  every link losing 10 %: it completes without a collision, and the report counts what the mesh delivered and what
  the path loss and the link model took.
- Paced and signed, the mesh still carries the reports: every drone signs what it broadcasts and, requiring
  signatures, takes what it hears only after checking them (none dropped, none bad).
- That what a drone hears over the mesh does not depend on the machine's load is judged with the relay's in one pair
  of runs: tests/integration/test_links_fly.py flies the antipodal swap with neighbours by both, idle and loaded.

Policy: loopback only (--no-forward); leased instances (tests/integration/instances.py); lockstep (but for the paced
test, whose outcome does not depend on timing), so no outcome depends on the machine's load; a time limit on every
test; the CPU burners are stopped by PID and reaped (tests/integration/test_links_fly.py).
"""

from __future__ import annotations

import re
import subprocess
from pathlib import Path
from typing import Any

import pytest

from tests.integration.instances import Leases
from tests.integration.mission_flight import MISSIONS, fly_mission

pytestmark = [pytest.mark.sim_only]

SIGNED_MESH = """
name = "signed_mesh"
[swarm]
drones = 2
layout = "line"
spacing_m = 3.0
neighbours = "mesh"

[[steps]]
action = "takeoff"
alt_m = 3.0

[[steps]]
action = "hold"
duration_s = 3.0

[[steps]]
action = "land"
"""


def mesh_mission(tmp_path: Path, name: str, swarm: str, tables: str) -> str:
    """A shipped mission with ``swarm`` added to its [swarm] table and ``tables`` after it, written to tmp_path."""
    text = (MISSIONS / name).read_text()
    assert text.count("\n[[steps]]") >= 1
    head, sep, rest = text.partition("\n[[steps]]")
    path = tmp_path / name
    path.write_text(f"{head}{swarm}\n{tables}{sep}{rest}")
    return str(path)


def first_instance(run: subprocess.CompletedProcess[str]) -> int:
    """The first instance a ``swarm fly`` run flew (the ``--first-instance`` fly_mission leased for it)."""
    args = [str(arg) for arg in run.args]
    return int(args[args.index("--first-instance") + 1])


def fly(mission: str, tmp_path: Path, instances: Leases) -> tuple[dict[str, Any], Path, int]:
    """Fly in lockstep; the report's metrics, the report and the first instance flown."""
    args = ["--lockstep", "--drones-per-process", "auto"]
    metrics, run = fly_mission(mission, args, tmp_path, 600, instances)
    return metrics, tmp_path / "report", first_instance(run)


@pytest.mark.timeout(600)
def test_nine_drones_fly_grid_to_circle_on_the_mesh_alone_with_a_tenth_of_every_link_lost(
    tmp_path: Path, instances: Leases
) -> None:
    # GIVEN the grid_to_circle mission with neighbours heard over the mesh only (range 15 m), every link 10 % lossy
    mission = mesh_mission(tmp_path, "grid_to_circle.toml", 'neighbours = "mesh"\n',
                           "[swarm.mesh]\nrange_m = 15\n\n[swarm.links]\nloss = 0.1\n")  # fmt: skip
    # WHEN it is flown in lockstep
    metrics, report, first = fly(mission, tmp_path, instances)
    # THEN it completes without a collision, the circle held as on the relay
    assert metrics["collisions"] == 0, metrics["collision_events"]
    circle = next(s for s in metrics["steps"] if s["name"] == "circle")
    assert circle["formation_rms_m"] is not None and circle["formation_rms_m"] < 0.3, circle
    # AND nothing was relayed: no neighbour position came on a ground-station link, the tables filled from the mesh
    # (a drone's API link streams to the API port of the instance 40 below it: another test's drones there, flying
    # at the same time, would be heard over that link, and counted apart as link_updates)
    mesh = metrics["links"]["neighbour mesh"]
    assert mesh["relay_updates"] == 0 and mesh["mesh_updates"] > 0, mesh
    # AND the report counts the mesh: 9 drones x 8 neighbours x ~10 reports/s x ~50 s offered, every one delivered
    # or lost for one reason; nobody beyond 15 m in a 6 m circle, some path loss, and the model's tenth of the rest
    assert mesh["frames_offered"] > 25_000, mesh
    assert mesh["frames_offered"] == mesh["frames_delivered"] + mesh["frames_lost"], mesh
    assert mesh["frames_lost"] == mesh["lost_range"] + mesh["lost_path"] + mesh["lost_model"] + mesh["lost_overrun"]
    assert mesh["lost_range"] == 0 and mesh["lost_overrun"] == 0, mesh
    assert 0 < mesh["lost_path"] < 0.05 * mesh["frames_offered"], mesh
    assert 0.08 < mesh["lost_model"] / (mesh["frames_offered"] - mesh["lost_path"]) < 0.12, mesh
    assert mesh["mesh_updates"] == mesh["frames_delivered"]  # the mesh alone: no copy of a report came another way
    # AND each drone's log says what its radio heard and what its table took from where
    log = (report / "logs" / f"drone-{first}.log").read_text()
    assert f"sitl {first}: mesh radio: range 15 m, path loss (d/range)^4" in log
    assert f"sitl {first}: mesh: " in log and " reports by mesh (mean age at use " in log and " by relay" not in log
    summary = (report / "summary.txt").read_text()
    assert "link model, neighbour mesh: " in summary and "0 from the relay" in summary
    assert metrics["neighbours"] == "mesh (range 15 m, path loss (d/range)^4)"
    assert "\nneighbours: mesh (range 15 m, path loss (d/range)^4)\n" in summary


@pytest.mark.timeout(240)
def test_a_paced_signed_swarm_hears_its_neighbours_signed_reports_over_the_mesh(
    tmp_path: Path, instances: Leases
) -> None:
    # GIVEN two drones 3 m apart on the mesh alone, every drone signing and requiring signatures
    key_file = tmp_path / "swarm.key"
    key_file.write_text("mesh signing test\n")
    mission = tmp_path / "signed_mesh.toml"
    mission.write_text(SIGNED_MESH)
    # WHEN the mission is flown paced (each drone on its own clock, reading whatever has been posted)
    args = ["--drones-per-process", "auto", "--signing-key", str(key_file)]
    metrics, run = fly_mission(str(mission), args, tmp_path, 200, instances)
    first = first_instance(run)
    # THEN each drone heard the other's reports over the mesh, signed, and dropped none for its signature
    assert metrics["collisions"] == 0
    for instance in (first, first + 1):
        log = (tmp_path / "report" / "logs" / f"drone-{instance}.log").read_text()
        heard = re.search(rf"sitl {instance}: neighbour table: (\d+) reports by mesh", log)
        assert heard is not None and int(heard.group(1)) > 50, log[-2000:]
        assert " by relay" not in log
        assert "0 unsigned dropped, 0 bad signatures, 0 replays" in log, log[-2000:]
    mesh = metrics["links"]["neighbour mesh"]
    assert mesh["lost_range"] == 0 and mesh["frames_delivered"] == mesh["frames_offered"] - mesh["lost_path"], mesh
