"""Fly a shipped mission with ``swarm fly`` in a subprocess and read its flight report (shared by the mission tests)."""

from __future__ import annotations

import json
import subprocess
import sys
import tomllib
from pathlib import Path
from typing import Any

from tests.integration.instances import Leases

MISSIONS = Path(__file__).resolve().parents[2] / "missions"
SWARM = [sys.executable, "-m", "gcs.cli"]


def mission_drones(path: Path) -> int:
    """How many drones a mission file flies (its ``[swarm] drones``)."""
    return int(tomllib.loads(path.read_text())["swarm"]["drones"])


def fly_mission(mission: str | Path, args: list[str], tmp_path: Path, timeout_s: float, instances: Leases | int, *,
                avoidance: bool = True, expect_ok: bool = True,
                ) -> tuple[dict[str, Any], subprocess.CompletedProcess[str]]:  # fmt: skip
    """Fly ``missions/<mission>`` (or a mission file's path) on instances leased for it, or from the first instance
    of a block the caller leased (``instances`` an int: two flights that must carry the same sysids); with
    AVOID_ENABLE = 0 on every drone unless ``avoidance``; metrics and the run.

    Always loopback only (--no-forward); the report goes to tmp_path/report, its plots drawn only if the flight broke
    something (--plots failed: they cost a flight about 3 s; test_swarm_fly.py checks a report's plots)."""
    path = MISSIONS / mission
    first = instances if isinstance(instances, int) else instances(mission_drones(path))
    args = [*args, "--first-instance", str(first)]
    if not avoidance:
        text = path.read_text()
        assert text.count("[swarm]\n") == 1
        path = tmp_path / path.name
        path.write_text(text.replace("[swarm]\n", "[swarm]\nparams = { AVOID_ENABLE = 0 }\n"))
    report = tmp_path / "report"
    result = subprocess.run([*SWARM, "fly", str(path), *args, "--report", str(report), "--plots", "failed",
                             "--no-forward"], capture_output=True, text=True, timeout=timeout_s)  # fmt: skip
    if expect_ok:
        assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    metrics: dict[str, Any] = json.loads((report / "metrics.json").read_text())
    return metrics, result
