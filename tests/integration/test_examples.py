"""Every example in examples/ runs as a user runs it (a subprocess, short settings) and checks its own outcome
(exit code 0). The classic demo through the Python API flies like ``swarm fly missions/grid_to_circle.toml``: the
same figures within noise. (examples/test_my_swarm.py runs in tests/integration/test_pytest_plugin.py.)

Policy: loopback only; leased instances (tests/integration/instances.py); a time limit on each.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from tests.integration.instances import Leases
from tests.integration.mission_flight import MISSIONS, fly_mission

pytestmark = [pytest.mark.sim_only]

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
CIRCLE_S = 15.0  # simulated seconds on the circle in the comparison (the demo's 30 s add time, not evidence)


def run_example(name: str, *args: str, timeout_s: float = 240) -> subprocess.CompletedProcess[str]:
    result = subprocess.run([sys.executable, str(EXAMPLES / name), *args], capture_output=True, text=True,
                            timeout=timeout_s)  # fmt: skip
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    return result


def step(metrics: dict[str, Any], name: str) -> dict[str, Any]:
    return next(s for s in metrics["steps"] if s["name"] == name)


@pytest.mark.timeout(600)
def test_the_classic_demo_through_the_api_flies_like_the_mission_file(tmp_path: Path, instances: Leases) -> None:
    # GIVEN the grid-to-circle mission flown by ``swarm fly`` in lockstep (15 s on the circle instead of 30, as below)
    text = (MISSIONS / "grid_to_circle.toml").read_text()
    assert text.count("hold_s = 30.0") == 1
    short = tmp_path / "grid_to_circle.toml"
    short.write_text(text.replace("hold_s = 30.0", f"hold_s = {CIRCLE_S}"))
    mission, _ = fly_mission(str(short), ["--lockstep", "--drones-per-process", "auto"], tmp_path, 300, instances)
    # WHEN the API example flies the same steps (its nine drones by default)
    run_example("classic_demo.py", "--first-instance", str(instances(9)), "--circle-s", str(CIRCLE_S),
                "--report", str(tmp_path / "api"))  # fmt: skip
    api = json.loads((tmp_path / "api" / "metrics.json").read_text())
    # THEN both fly without a collision, with the same steps, and their figures agree within noise
    assert mission["collisions"] == api["collisions"] == 0
    assert [s["name"] for s in api["steps"]] == ["takeoff", "grid", "circle", "land"], api["steps"]
    assert abs(api["min_separation_m"] - mission["min_separation_m"]) < 0.15, (api["min_separation_m"],
                                                                               mission["min_separation_m"])  # fmt: skip
    for name in ("grid", "circle"):
        a, m = step(api, name)["formation_rms_m"], step(mission, name)["formation_rms_m"]
        assert a is not None and m is not None and abs(a - m) < 0.05, (name, a, m)
    assert abs(api["takeoff_time_s"] - mission["takeoff_time_s"]) < 0.5, (api["takeoff_time_s"],
                                                                          mission["takeoff_time_s"])  # fmt: skip


@pytest.mark.timeout(300)
def test_the_custom_controller_example_brings_four_drones_onto_its_ring(tmp_path: Path, instances: Leases) -> None:
    result = run_example("custom_controller.py", "--drones", "4", "--seconds", "25", "--first-instance",
                         str(instances(4)), "--report", str(tmp_path / "report"))  # fmt: skip
    assert "collisions 0" in result.stdout, result.stdout[-2000:]


@pytest.mark.timeout(200)
def test_the_pymavlink_example_takes_one_drone_off_and_lands_it(instances: Leases) -> None:
    result = run_example("pymavlink_takeoff_land.py", "--start-drone", "--instance", str(instances(1)))
    assert "landed and disarmed" in result.stdout, result.stdout


@pytest.mark.timeout(200)
def test_the_mavsdk_example_flies_two_drones_at_once(instances: Leases) -> None:
    result = run_example("mavsdk_several_drones.py", "--drones", "2", "--first-instance", str(instances(2)))
    assert result.stdout.count("landed and disarmed") == 2, result.stdout[-2000:]


@pytest.mark.timeout(300)
def test_the_onboard_behaviour_example_gathers_four_drones_that_decide_for_themselves(
    tmp_path: Path, instances: Leases
) -> None:
    result = run_example("onboard_behaviour.py", "--drones", "4", "--seconds", "20", "--first-instance",
                         str(instances(4)), "--report", str(tmp_path / "report"))  # fmt: skip
    assert "collisions 0" in result.stdout, result.stdout[-2000:]


@pytest.mark.timeout(120)
@pytest.mark.parametrize("name", sorted(p.name for p in EXAMPLES.glob("*.py") if p.name != "test_my_swarm.py"))
def test_every_example_parses_its_arguments_as_written(name: str) -> None:
    """What each example accepts, as its ``--help`` says it (about 1 s each: the imports): a front-end's names that
    an example uses keep working."""
    result = run_example(name, "--help", timeout_s=60)
    assert result.stdout.startswith("usage:"), result.stdout[:300]
