"""Fly a shipped mission with ``swarm fly`` in a subprocess and read its flight report (shared by the mission tests)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any

MISSIONS = Path(__file__).resolve().parents[2] / "missions"
SWARM = [sys.executable, "-m", "gcs.cli"]


def fly_mission(mission: str, args: list[str], tmp_path: Path, timeout_s: float, *, avoidance: bool = True,
                expect_ok: bool = True) -> tuple[dict[str, Any], subprocess.CompletedProcess[str]]:  # fmt: skip
    """Fly ``missions/<mission>`` (with AVOID_ENABLE = 0 on every drone unless ``avoidance``); metrics and the run.

    Always loopback only (--no-forward); the report goes to tmp_path/report."""
    path = MISSIONS / mission
    if not avoidance:
        text = path.read_text()
        assert text.count("[swarm]\n") == 1
        path = tmp_path / mission
        path.write_text(text.replace("[swarm]\n", "[swarm]\nparams = { AVOID_ENABLE = 0 }\n"))
    report = tmp_path / "report"
    result = subprocess.run([*SWARM, "fly", str(path), *args, "--report", str(report), "--no-forward"],
                            capture_output=True, text=True, timeout=timeout_s)  # fmt: skip
    if expect_ok:
        assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    metrics: dict[str, Any] = json.loads((report / "metrics.json").read_text())
    return metrics, result
