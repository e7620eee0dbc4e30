"""Soak run: a lockstep swarm flying a rotating circle for a long simulated time over lossy links.

Flies a generated mission (takeoff, a 9-drone circle of radius 4 m turning at 0.2 rad/s for ``--minutes`` simulated
minutes, land) with ``swarm fly --lockstep --drones-per-process auto --link-loss LOSS`` and, while it flies, samples
every drone process's memory (PSS, /proc/PID/smaps_rollup) and CPU time (/proc/PID/stat) every ``--sample-s`` wall
seconds, with the simulated time the flight has reached (from its status line). At the end it compares what the
link model says it dropped with what is missing from the flight log:

- per drone, frames its ground-station link offered to the model on the way down (``gcs down``), minus those the
  model lost, should all be in flight.tlog (a frame still delayed when the flight ended aside);
- anything else missing was lost by something the model does not know of: a full socket buffer, a bug.

It prints one JSON document: the memory and CPU per drone over time, the growth of memory per drone after the
first simulated minute (the target: flat within 10 %), the loss accounting, and the circle's formation error and
minimum separation from the report (drift shows there).

    python bench/soak.py [--minutes 60] [--loss 0.1] [--drones 9] [--first-instance 4] [--out DIR]
"""

from __future__ import annotations

import argparse
import json
import os
import re
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from pymavlink import mavutil

STATUS_TIME = re.compile(r"\bt (\d+\.\d+) s\b")
PAGE_TICKS = os.sysconf("SC_CLK_TCK")


def mission_text(drones: int, minutes: float) -> str:
    return f"""name = "soak"
description = "{drones} drones on a rotating circle for {minutes:g} simulated minutes"

[swarm]
drones = {drones}
layout = "grid"
spacing_m = 2.0

[[steps]]
action = "takeoff"
alt_m = 3.0

[[steps]]
action = "formation"
shape = "circle"
radius_m = 4.0
alt_m = 3.0
angular_rate_radps = 0.2
hold_s = {minutes * 60.0:g}

[[steps]]
action = "land"
"""


def drone_processes(first: int, last: int) -> dict[int, str]:
    """PID -> process name of every drone process of the run (named ``sitl-<first>[-<last>]`` by the factory)."""
    out: dict[int, str] = {}
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            name = (entry / "comm").read_text().strip()
        except OSError:
            continue
        match = re.fullmatch(r"sitl-(\d+)(?:-(\d+))?", name)
        if match and first <= int(match.group(1)) <= last:
            out[int(entry.name)] = name
    return out


def sample(pids: dict[int, str]) -> tuple[float, float]:
    """Summed PSS (MB) and CPU seconds of ``pids`` (those that are gone are left out)."""
    pss_kb = 0
    cpu_ticks = 0
    for pid in pids:
        try:
            for line in Path(f"/proc/{pid}/smaps_rollup").read_text().splitlines():
                if line.startswith("Pss:"):
                    pss_kb += int(line.split()[1])
            fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
            cpu_ticks += int(fields[11]) + int(fields[12])  # utime, stime
        except OSError:
            continue
    return pss_kb / 1024.0, cpu_ticks / PAGE_TICKS


def tlog_counts(path: Path) -> dict[int, int]:
    """Messages per sending drone in a flight log (the supervisor's own, sysid 255, left out)."""
    log = mavutil.mavlogfile(str(path))
    counts: dict[int, int] = {}
    while (msg := log.recv_match()) is not None:
        sysid = msg.get_srcSystem()
        if msg.get_type() != "BAD_DATA" and sysid != 255:
            counts[sysid] = counts.get(sysid, 0) + 1
    return counts


def _interrupt(_signum: int, _frame: object) -> None:
    raise KeyboardInterrupt


def watch(proc: subprocess.Popen[str], first: int, last: int, sample_s: float, samples: list[dict[str, float]],
          start: float) -> None:  # fmt: skip
    """Until the swarm ends: follow its simulated time from its status lines and sample its drones' memory and CPU
    every ``sample_s`` wall seconds (each sample also to stderr, so a long soak shows its progress)."""
    sim_s = 0.0
    next_sample = start
    drones = last - first + 1
    while proc.poll() is None:
        for line in proc.stdout or []:
            if match := STATUS_TIME.search(line):
                sim_s = float(match.group(1))
        if time.monotonic() >= next_sample:
            pids = drone_processes(first, last)
            if pids:
                pss_mb, cpu_s = sample(pids)
                samples.append({"wall_s": round(time.monotonic() - start, 1), "sim_s": sim_s,
                                "pss_mb_per_drone": round(pss_mb / drones, 2),
                                "cpu_s_per_drone": round(cpu_s / drones, 2)})  # fmt: skip
                print(f"soak: {samples[-1]}", file=sys.stderr, flush=True)
            next_sample += sample_s
        time.sleep(0.5)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--minutes", type=float, default=60.0, help="simulated minutes on the circle (default 60)")
    parser.add_argument("--loss", type=float, default=0.1, help="loss on every link, both ways (default 0.1)")
    parser.add_argument("--drones", type=int, default=9)
    parser.add_argument("--first-instance", type=int, default=4)
    parser.add_argument("--sample-s", type=float, default=10.0, help="wall seconds between samples (default 10)")
    parser.add_argument("--out", type=Path, default=None, help="report directory (default: a temporary one)")
    args = parser.parse_args()
    if args.minutes <= 0 or not 0.0 <= args.loss <= 1.0 or args.drones < 1 or args.sample_s <= 0:
        print("soak: error: --minutes, --drones and --sample-s must be positive, --loss in [0, 1]", file=sys.stderr)
        return 2
    work = Path(tempfile.mkdtemp(prefix="soak-"))
    out = args.out or work / "report"
    mission = work / "soak.toml"
    mission.write_text(mission_text(args.drones, args.minutes))
    cmd = [sys.executable, "-m", "gcs.cli", "fly", str(mission), "--lockstep", "--drones-per-process", "auto",
           "--first-instance", str(args.first_instance), "--link-loss", str(args.loss), "--report", str(out),
           "--no-forward"]  # fmt: skip
    last = args.first_instance + args.drones - 1
    samples: list[dict[str, float]] = []
    start = time.monotonic()
    interrupted = False
    signal.signal(signal.SIGTERM, _interrupt)  # a soak stopped from outside stops its swarm and still reports
    with subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, bufsize=1) as proc:
        os.set_blocking(proc.stdout.fileno(), False)  # type: ignore[union-attr]
        try:
            watch(proc, args.first_instance, last, args.sample_s, samples, start)
        except KeyboardInterrupt:
            interrupted = True
            proc.terminate()  # swarm fly lands, stops every drone and writes its report
        proc.wait()
        rest = proc.stdout.read() if proc.stdout else ""
        code = proc.returncode
    if code != 0 and not interrupted:
        print(f"soak: error: swarm fly exited with {code}: {rest[-500:]}", file=sys.stderr)
        return 1
    metrics: dict[str, Any] = json.loads((out / "metrics.json").read_text())
    down = metrics["links"].get("gcs down", {})
    delivered = down.get("frames_offered", 0) - down.get("frames_lost", 0)
    logged = sum(tlog_counts(out / "flight.tlog").values())
    after_first_minute = [s for s in samples if s["sim_s"] >= 60.0]
    growth = None
    if len(after_first_minute) >= 2:
        first, final = after_first_minute[0]["pss_mb_per_drone"], after_first_minute[-1]["pss_mb_per_drone"]
        growth = round((final - first) / first, 4)
    circle: dict[str, Any] = next((s for s in metrics["steps"] if s["name"] == "circle"), {})
    print(json.dumps({
        "simulated_minutes": args.minutes, "loss": args.loss, "drones": args.drones, "interrupted": interrupted,
        "simulated_s_flown": samples[-1]["sim_s"] if samples else 0.0,
        "wall_s": round(time.monotonic() - start, 1), "report": str(out),
        "memory_growth_after_first_minute": growth,
        "links": metrics["links"],
        "downlink_frames_delivered_by_the_model": delivered, "downlink_messages_in_the_tlog": logged,
        "missing_beyond_the_model": delivered - logged,
        "collisions": metrics["collisions"], "min_separation_m": metrics["min_separation_m"],
        "circle_formation_rms_m": circle.get("formation_rms_m"), "circle_max_error_m": circle.get("max_error_m"),
        "samples": samples,
    }, indent=1))  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
