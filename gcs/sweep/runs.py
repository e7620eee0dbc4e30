"""Flying one run of a sweep: a ``swarm fly --lockstep`` in a process of its own, on instances nobody else holds.

Runs that share a machine must not share UDP ports, and a drone's ports follow its instance (PX4's convention:
18570+instance, 14580+instance, and a block of their own from instance 40 on: docs/mavlink.md), so every run holds a
lock on each instance it flies (gcs/sweep/instance_locks.py). The rest is already per run: each swarm's shared
world has a name of its own, its lockstep sockets are named after it, its report goes to the run's folder, and its
supervisor's ports are chosen by the system. Which
instances a run gets does not change what it does: a drone's randomness comes from its seed alone (drone k of the
swarm: seed + k).

A run is complete when its ``run.json`` exists: written last, after the report, so a run cut short by Ctrl-C or a
lost node leaves no ``run.json`` and is flown again when the sweep resumes.
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final

from gcs.invariants.monitor import EXIT_VIOLATED
from gcs.sweep.child import RUN_MODULE, parent_named
from gcs.sweep.instance_locks import POLL_S
from gcs.sweep.plan import Run, SweepPlan, fly_command
from gcs.sweep.stats import run_metrics

RUN_FILE: Final = "run.json"
LOG_FILE: Final = "fly.log"
RUN_TIMEOUT_S: Final = 3600.0


@dataclass(frozen=True, slots=True)
class Flight:
    """One run to fly: the plan it belongs to (its mission file and options), the run, and the folder it flies into.
    A sweep's flights share one plan; a falsification's each have their own mission file."""

    plan: SweepPlan
    run: Run
    folder: Path


@dataclass(frozen=True, slots=True)
class RunResult:
    """What one run gave: its figures from metrics.json, or why it failed."""

    index: int
    name: str
    setting: tuple[tuple[str, float], ...]
    seed: int
    ok: bool
    wall_s: float
    metrics: dict[str, float | None]
    error: str | None
    command: tuple[str, ...]

    def to_json(self) -> dict[str, Any]:
        return {"index": self.index, "name": self.name, "setting": [list(s) for s in self.setting], "seed": self.seed,
                "ok": self.ok, "wall_s": round(self.wall_s, 3), "metrics": self.metrics, "error": self.error,
                "command": list(self.command)}  # fmt: skip

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> RunResult:
        return cls(index=int(data["index"]), name=str(data["name"]),
                   setting=tuple((str(n), float(v)) for n, v in data["setting"]), seed=int(data["seed"]),
                   ok=bool(data["ok"]), wall_s=float(data["wall_s"]), metrics=dict(data["metrics"]),
                   error=data.get("error"), command=tuple(data.get("command", ())))  # fmt: skip


def completed(run_dir: Path) -> RunResult | None:
    """The result of a complete run in ``run_dir`` (None: not flown, or cut short)."""
    try:
        return RunResult.from_json(json.loads((run_dir / RUN_FILE).read_text()))
    except (OSError, ValueError, KeyError, TypeError):
        return None


def _last_line(path: Path) -> str:
    with contextlib.suppress(OSError):
        lines = [ln.strip() for ln in path.read_text(errors="replace").splitlines() if ln.strip()]
        errors = [ln for ln in lines if "error" in ln.lower()]
        return (errors or lines or ["no output"])[-1]
    return "no output"


class Stopped(Exception):
    """The sweep was interrupted while this run flew; the run is not complete."""


def fly(
    plan: SweepPlan,
    run: Run,
    run_dir: Path,
    first_instance: int,
    stop: threading.Event | None = None,
    lock_fds: tuple[int, ...] = (),
) -> RunResult:
    """Fly ``run`` into ``run_dir`` (its report, fly.log, then run.json) on instances from ``first_instance``."""
    run_dir.mkdir(parents=True, exist_ok=True)
    (run_dir / RUN_FILE).unlink(missing_ok=True)
    args = fly_command(plan, run, first_instance=first_instance, report=run_dir / "report")
    started = time.monotonic()
    with (run_dir / LOG_FILE).open("w") as log:
        # The run holds its instances' locks itself (pass_fds), so they stay taken while it flies even if whoever
        # started it is gone; and it ends with its parent (gcs/sweep/child.py), which names itself to it.
        proc = subprocess.Popen([sys.executable, "-m", RUN_MODULE, *args], stdout=log, stderr=subprocess.STDOUT,
                                stdin=subprocess.DEVNULL, start_new_session=True, pass_fds=lock_fds,
                                env={**os.environ, **parent_named()})  # fmt: skip
        try:
            while True:
                try:
                    code = proc.wait(timeout=POLL_S)
                    break
                except subprocess.TimeoutExpired:
                    if stop is not None and stop.is_set():
                        raise Stopped() from None
                    if time.monotonic() - started > RUN_TIMEOUT_S:
                        proc.send_signal(signal.SIGTERM)
                        code = proc.wait(60)
                        break
        finally:
            if proc.poll() is None:  # stopped, or something went wrong here: the run's swarm lands nothing
                proc.send_signal(signal.SIGTERM)  # it stops its drones and exits (swarm fly's own clean-up)
                try:
                    proc.wait(30)
                except subprocess.TimeoutExpired:
                    os.killpg(proc.pid, signal.SIGKILL)
                    proc.wait()
    wall = time.monotonic() - started
    metrics_file = run_dir / "report" / "metrics.json"
    ok = code in (0, EXIT_VIOLATED) and metrics_file.exists()  # a broken invariant is an outcome, counted
    result = RunResult(
        index=run.index, name=run.name, setting=run.setting, seed=run.seed, ok=ok, wall_s=wall,
        metrics=run_metrics(json.loads(metrics_file.read_text())) if ok else {},
        error=None if ok else f"swarm fly exited with {code}: {_last_line(run_dir / LOG_FILE)}",
        command=("swarm", *args),
    )  # fmt: skip
    (run_dir / RUN_FILE).write_text(json.dumps(result.to_json(), indent=1) + "\n")
    return result
