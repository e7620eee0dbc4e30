"""Benchmark: what the drone-to-drone mesh costs against the ground station's relay, in CPU per drone.

Flies one generated mission twice with ``swarm fly --lockstep --drones-per-process auto``: ``--drones`` drones in a
grid ``--spacing`` metres apart take off, hover for ``--hold-s`` simulated seconds and land, once with their
neighbours' positions relayed by the supervisor (``neighbours = "relay"``, every drone to every other) and once
heard over the mesh alone (``neighbours = "mesh"``, range ``--range-m``). While the drones hover it reads the CPU
time (/proc/PID/stat: user + system) of every drone process and of the supervisor at the start and the end of a
window on the simulated clock, and prints per mode the CPU milliseconds per drone per simulated second of the drones
and of the supervisor, with what the mesh delivered. CPU time, not wall time: the figures hold on a loaded machine.

    python bench/mesh_cost.py [--drones 50] [--hold-s 20] [--range-m 15] [--spacing 3] [--first-instance 200]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from soak import PAGE_TICKS, STATUS_TIME, drone_processes, sample

HOVER_FROM_S = 10.0  # simulated time by which every drone is up and hovering (takeoff done at about 8 s)


def mission_text(drones: int, spacing_m: float, hold_s: float, neighbours: str, range_m: float) -> str:
    mesh = f"\n[swarm.mesh]\nrange_m = {range_m:g}\n" if neighbours != "relay" else ""
    return f"""name = "mesh_cost"
[swarm]
drones = {drones}
layout = "grid"
spacing_m = {spacing_m:g}
neighbours = "{neighbours}"
{mesh}
[[steps]]
action = "takeoff"
alt_m = 3.0

[[steps]]
action = "hold"
duration_s = {hold_s:g}

[[steps]]
action = "land"
"""


def process_cpu_s(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / PAGE_TICKS


def fly(args: argparse.Namespace, neighbours: str, work: Path) -> dict[str, Any]:
    mission = work / f"{neighbours}.toml"
    mission.write_text(mission_text(args.drones, args.spacing, args.hold_s, neighbours, args.range_m))
    report = work / neighbours
    cmd = [sys.executable, "-m", "gcs.cli", "fly", str(mission), "--lockstep", "--drones-per-process", "auto",
           "--first-instance", str(args.first_instance), "--report", str(report), "--no-forward"]  # fmt: skip
    last = args.first_instance + args.drones - 1
    window_end_s = HOVER_FROM_S + args.hold_s - 2.0
    marks: list[tuple[float, float, float]] = []  # (sim time, drones' CPU s, supervisor's CPU s)
    sim_s = 0.0
    with subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, bufsize=1) as proc:
        os.set_blocking(proc.stdout.fileno(), False)  # type: ignore[union-attr]
        while proc.poll() is None:
            for line in proc.stdout or []:
                if match := STATUS_TIME.search(line):
                    sim_s = float(match.group(1))
            due = HOVER_FROM_S if not marks else window_end_s if len(marks) == 1 else None
            if due is not None and sim_s >= due:
                _, drones_cpu_s = sample(drone_processes(args.first_instance, last))
                marks.append((sim_s, drones_cpu_s, process_cpu_s(proc.pid)))
            time.sleep(0.05)
        code = proc.returncode
    if code != 0 or len(marks) != 2:
        raise SystemExit(f"mesh_cost: error: swarm fly ({neighbours}) exited with {code}, {len(marks)} marks")
    (t0, d0, s0), (t1, d1, s1) = marks
    metrics: dict[str, Any] = json.loads((report / "metrics.json").read_text())
    per = 1000.0 / (args.drones * (t1 - t0))
    return {
        "window_sim_s": round(t1 - t0, 2),
        "drone_cpu_ms_per_drone_sim_s": round((d1 - d0) * per, 2),
        "supervisor_cpu_ms_per_drone_sim_s": round((s1 - s0) * per, 2),
        "collisions": metrics["collisions"],
        "mesh": metrics["links"].get("neighbour mesh"),
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--drones", type=int, default=50)
    parser.add_argument("--hold-s", type=float, default=20.0, help="simulated seconds of hover (default 20)")
    parser.add_argument("--range-m", type=float, default=15.0, help="mesh radio range (default 15)")
    parser.add_argument("--spacing", type=float, default=3.0, help="grid spacing in metres (default 3)")
    parser.add_argument("--first-instance", type=int, default=200)
    args = parser.parse_args()
    if args.drones < 2 or args.hold_s < 5 or args.range_m <= 0 or args.spacing <= 0:
        print("mesh_cost: error: --drones >= 2, --hold-s >= 5, --range-m and --spacing > 0", file=sys.stderr)
        return 2
    work = Path(tempfile.mkdtemp(prefix="mesh-cost-"))
    results = {mode: fly(args, mode, work) for mode in ("relay", "mesh")}
    print(json.dumps({"drones": args.drones, "spacing_m": args.spacing, "range_m": args.range_m, **results},
                     indent=2))  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
