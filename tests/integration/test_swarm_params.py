"""``swarm fly`` mission parameters through the ground station's parameter client, against real drones.

A value out of the drones' declared range is refused before anything is spawned (the ground station checks every
parameter against the drones' table first: one line, exit code 2). A name the drones do not know can only reach
them when an onboard behaviour may declare it; then no drone echoes it (as PX4) and the flight ends before arming
with one line naming the parameter and the drones.

Policy: loopback only (--no-forward); lockstep, so the retries' timing does not depend on the machine's load;
leased instances (tests/integration/instances.py); a time limit on every test.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from tests.integration.instances import Leases

pytestmark = [pytest.mark.sim_only]

SWARM = [sys.executable, "-m", "gcs.cli"]


def fly_with_params(
    tmp_path: Path, params: str, first_instance: int, behaviour: str = ""
) -> subprocess.CompletedProcess[str]:
    mission = tmp_path / "params.toml"
    mission.write_text(
        f'name = "params"\n[swarm]\ndrones = 2\nspacing_m = 3.0\nparams = {{ {params} }}\n{behaviour}'
        '[[steps]]\naction = "takeoff"\nalt_m = 2.0\n[[steps]]\naction = "land"\n'
    )
    return subprocess.run(
        [*SWARM, "fly", str(mission), "--lockstep", "--first-instance", str(first_instance), "--report",
         str(tmp_path / "report"), "--no-forward"],
        capture_output=True, text=True, timeout=100,
    )  # fmt: skip


@pytest.mark.timeout(120)
def test_a_value_the_drones_refuse_ends_the_mission_naming_the_drones_and_the_value_they_kept(
    tmp_path: Path, instances: Leases
) -> None:
    # GIVEN a mission that sets MPC_XY_CRUISE far above its range (the drones keep 5 m/s)
    # WHEN it is flown
    result = fly_with_params(tmp_path, "MPC_XY_CRUISE = 1000.0", instances(2))
    # THEN it is refused before any drone is spawned, in one line naming the parameter and its range
    assert result.returncode == 2, result.stdout[-2000:] + result.stderr[-2000:]
    assert result.stderr.count("\n") == 1 and "swarm.params: MPC_XY_CRUISE: 1000 outside [0.5, 20] m/s" in result.stderr
    assert "spawning" not in result.stdout


@pytest.mark.timeout(120)
def test_a_parameter_the_drones_do_not_know_ends_the_mission_with_no_answer(tmp_path: Path, instances: Leases) -> None:
    # GIVEN a mission with an onboard behaviour (whose own parameters the drones' table does not list) that sets a
    # parameter no drone has (PX4 sends no PARAM_VALUE for it)
    # WHEN it is flown
    behaviour = 'behaviour = "sitl.onboard.behaviours.flocking:Flocking"\n'
    first = instances(2)
    result = fly_with_params(tmp_path, "NO_SUCH_PARAM = 1", first, behaviour)
    # THEN every retry goes unanswered and the flight ends before arming, naming the drones
    assert result.returncode == 1, result.stdout[-2000:] + result.stderr[-2000:]
    assert f"swarm: error: parameter NO_SUCH_PARAM: no answer from sysid [{first + 1}, {first + 2}]" in result.stderr
    assert "step 1/2" not in result.stdout
