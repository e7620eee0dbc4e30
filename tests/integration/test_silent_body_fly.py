"""A rotating circle of 8 real drones (``swarm fly --lockstep``) passes a silent body hovering in its path.

The body is a drone-sized sphere declared in the shared world at the circle's altitude, on its path: no process
speaks for it, nothing relays it, so only the drones' cameras (default parameters: the four-camera rig) can find
it, and it does not move out of anyone's way. A contact with it crashes the drone and is counted in the report.

Policy: loopback only (--no-forward); leased instances (tests/integration/instances.py); a time limit.
"""

from __future__ import annotations

import json
import math
import subprocess
from pathlib import Path
from typing import Any

import pytest

from tests.integration.instances import Leases
from tests.integration.mission_flight import SWARM, mission_drones

pytestmark = [pytest.mark.sim_only]

RADIUS_M = 4.0
ALT_M = 3.0
BODY_ANGLE_RAD = math.pi / 8.0  # halfway between two slots at the start of the turn

MISSION = f"""
name = "silent_body_circle"
description = "a circle of 8 turning at 0.3 rad/s past a silent drone-sized body in its path"

[swarm]
drones = 8
layout = "grid"
spacing_m = 3.0
PARAMS

[[obstacles]]
shape = "sphere"
north_m = {RADIUS_M * math.cos(BODY_ANGLE_RAD):.3f}
east_m = {RADIUS_M * math.sin(BODY_ANGLE_RAD):.3f}
radius_m = 0.35
alt_m = {ALT_M}

[[steps]]
action = "takeoff"
alt_m = {ALT_M}

[[steps]]
action = "formation"
shape = "circle"
radius_m = {RADIUS_M}
alt_m = {ALT_M}
angular_rate_radps = 0.3
hold_s = 35.0

[[steps]]
action = "land"
"""


def fly(tmp_path: Path, instances: Leases, params: str = "") -> dict[str, Any]:
    """Fly the mission in lockstep (``params``: a TOML inline table of drone parameters); the report's metrics."""
    mission = tmp_path / "silent_body_circle.toml"
    mission.write_text(MISSION.replace("PARAMS", f"params = {params}" if params else ""))
    first = instances(mission_drones(mission))
    report = tmp_path / "report"
    result = subprocess.run(
        [*SWARM, "fly", str(mission), "--lockstep", "--quantum", "8", "--first-instance", str(first),
         "--report", str(report), "--no-forward"],
        capture_output=True, text=True, timeout=400,
    )  # fmt: skip
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    metrics: dict[str, Any] = json.loads((report / "metrics.json").read_text())
    return metrics


@pytest.mark.timeout(420)
def test_a_rotating_circle_of_8_real_drones_avoids_a_silent_body_in_its_path(tmp_path: Path, instances: Leases) -> None:
    # GIVEN default parameters WHEN the circle turns past the body for 35 s THEN nobody touched it, and they avoided
    metrics = fly(tmp_path, instances)
    assert metrics["collisions"] == 0, metrics["collision_events"]
    assert metrics["avoidance_events"] >= 8
