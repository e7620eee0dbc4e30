"""Benchmark: what serving the live view costs a swarm, and whether the view keeps up with a large one.

1. **The cost** (the issue's budget: under 5 % of the real-time factor). One ``swarm fly --lockstep
   --drones-per-process auto`` of ``--drones`` drones (default 50) that take off in a grid and hold it for
   ``--hold-s`` simulated seconds, with the view served; through the hold, windows of ``--window-s`` simulated
   seconds alternate between no page watching and one client watching (a WebSocket client in this process that
   takes and parses every frame, as a browser tab does, without a browser's drawing, whose CPU is the viewer's and
   would compete with the swarm for this machine's cores). The view builds no frame while nobody watches, so an
   unwatched window costs what no view costs. Lockstep runs as fast as the CPUs allow, so whatever the view takes
   shows as a lower real-time factor (simulated over wall seconds, from the supervisor's status lines), and as
   more CPU in the supervisor's process, where the view runs: CPU seconds per simulated second, which hold still
   where the real-time factor of a machine shared with other work drifts by several per cent from window to window.
2. **Keeping up**: how long the supervisor takes to build and encode one frame (measured in this process on fleet
   views of ``--drones`` and 100 drones, median of 200), and ``swarm up -n 100`` (``--big``), paced, with one
   client: the frames per wall second it gets and how many drones each holds. In lockstep a frame follows the
   supervisor's tick, so a swarm running at a fraction of real time shows as many frames as it has ticks (each
   with everything new); paced, the supervisor ticks on the wall clock and the page gets its 10 frames a second
   however far behind the drones are.

    python bench/view_cost.py [--drones 50] [--hold-s 100] [--window-s 5] [--big 100] [--first-instance 120]
                              [--json FILE]

Prints one line per window and a summary; ``--json`` writes every figure.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import math
import os
import re
import signal
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

TICKS_PER_S = os.sysconf("SC_CLK_TCK")
WINDOW_FROM_S = 12.0  # simulated time by which the grid has taken off (takeoff to 3 m takes about 8 s)
STATUS = re.compile(r"^\[\s*(\d+\.\d+) s\]")
VIEW_URL = re.compile(r"live view on (http://127\.0\.0\.1:\d+/)")


def mission_text(drones: int, hold_s: float) -> str:
    cols = math.ceil(math.sqrt(drones))
    rows = math.ceil(drones / cols)
    return f"""name = "view_cost"
[swarm]
drones = {drones}
layout = "grid"
spacing_m = 3.0

[[steps]]
action = "takeoff"
alt_m = 3.0

[[steps]]
action = "formation"
shape = "grid"
rows = {rows}
cols = {cols}
spacing_m = 3.0
alt_m = 3.0
hold_s = {hold_s:g}

[[steps]]
action = "land"
"""


class Watcher:
    """One view client in a thread of its own: counts the frames and bytes the server sends between marks."""

    def __init__(self, url: str) -> None:
        self.frames = 0
        self.bytes = 0
        self.last_drones = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=lambda: asyncio.run(self._run(url)), daemon=True)
        self._thread.start()

    async def _run(self, url: str) -> None:
        import aiohttp

        async with aiohttp.ClientSession() as session, session.ws_connect(url + "ws", max_msg_size=0) as ws:
            while not self._stop.is_set():
                try:
                    msg = await ws.receive(timeout=0.5)
                except TimeoutError:
                    continue
                if msg.type != aiohttp.WSMsgType.TEXT:
                    break
                self.last_drones = len(json.loads(msg.data)["drones"])  # what a page does with each frame first
                self.frames += 1
                self.bytes += len(msg.data)

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(5.0)


def descendants(pid: int) -> list[int]:
    out: list[int] = []
    todo = [pid]
    while todo:
        for task in Path(f"/proc/{todo.pop()}/task").glob("*"):
            with contextlib.suppress(OSError):
                kids = [int(k) for k in (task / "children").read_text().split()]
                out += kids
                todo += kids
    return out


def cpu_s(pids: list[int]) -> float:
    total = 0
    for pid in pids:
        with contextlib.suppress(OSError):
            fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
            total += int(fields[11]) + int(fields[12])  # utime, stime
    return total / TICKS_PER_S


def fly_windows(args: argparse.Namespace, work: Path) -> list[dict[str, Any]]:
    """The swarm's hold cut into windows, watched and unwatched in turn (unwatched first): each window's real-time
    factor, and the CPU seconds per simulated second of the supervisor (where the view runs) and of the drones."""
    mission = work / "view_cost.toml"
    mission.write_text(mission_text(args.drones, args.hold_s))
    cmd = [sys.executable, "-m", "gcs.cli", "fly", str(mission), "--lockstep", "--drones-per-process", "auto",
           "--first-instance", str(args.first_instance), "--no-forward", "--view-port", "0",
           "--report", str(work / "report")]  # fmt: skip
    bounds = [WINDOW_FROM_S + k * args.window_s for k in range(int((args.hold_s - 4.0) // args.window_s) + 1)]
    watcher: Watcher | None = None
    url = None
    windows: list[dict[str, Any]] = []
    start: tuple[float, float, float, float] | None = None  # (simulated s, wall s, supervisor CPU s, drones CPU s)
    with subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, bufsize=1) as proc:
        assert proc.stdout is not None
        for line in proc.stdout:
            url = found.group(1) if (found := VIEW_URL.search(line)) else url
            match = STATUS.search(line)
            marks = len(windows) + (start is not None)  # bounds passed so far
            if match is None or marks == len(bounds) or float(match.group(1)) < bounds[marks]:
                continue
            now = (float(match.group(1)), time.monotonic(), cpu_s([proc.pid]), cpu_s(descendants(proc.pid)))
            if start is not None:
                sim, wall = now[0] - start[0], now[1] - start[1]
                window = {"watched": watcher is not None, "sim_s": round(sim, 2), "rtf": round(sim / wall, 4),
                          "supervisor_cpu_s_per_sim_s": round((now[2] - start[2]) / sim, 4),
                          "drones_cpu_s_per_sim_s": round((now[3] - start[3]) / sim, 4),
                          "frames_per_s": round(watcher.frames / wall, 2) if watcher is not None else 0.0,
                          "frame_kb": round(watcher.bytes / watcher.frames / 1024.0, 1)
                          if watcher is not None and watcher.frames else None}  # fmt: skip
                windows.append(window)
                print(json.dumps(window), flush=True)
            if watcher is not None:
                watcher.stop()
                watcher = None
            elif start is not None and url is not None:
                watcher = Watcher(url)
            start = (now[0], time.monotonic(), cpu_s([proc.pid]), cpu_s(descendants(proc.pid)))
        code = proc.wait()
    if watcher is not None:
        watcher.stop()
    if code != 0 or len(windows) < 2:
        raise SystemExit(f"view_cost: error: swarm fly exited with {code}, {len(windows)} windows")
    return windows


def big_swarm(n: int, first_instance: int, watch_s: float = 10.0) -> dict[str, Any]:
    """``swarm up -n N`` paced, one client for ``watch_s`` wall seconds once every drone is up: frames per second
    and drones per frame."""
    cmd = [sys.executable, "-m", "gcs.cli", "up", "-n", str(n), "--drones-per-process", "auto", "--first-instance",
           str(first_instance), "--no-forward", "--view-port", "0"]  # fmt: skip
    with tempfile.TemporaryDirectory(prefix="view-cost-state-") as state:
        env = {**os.environ, "SWARM_STATE_DIR": state}
        with subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env) as proc:
            assert proc.stdout is not None
            url = None
            try:
                for line in proc.stdout:
                    url = found.group(1) if (found := VIEW_URL.search(line)) else url
                    if "drones up" in line:
                        break
                if url is None:
                    raise SystemExit("view_cost: error: swarm up did not come up with a view")
                watcher = Watcher(url)
                time.sleep(2.0)  # connected and streaming
                f0, t0 = watcher.frames, time.monotonic()
                time.sleep(watch_s)
                frames, seconds = watcher.frames - f0, time.monotonic() - t0
                drones = watcher.last_drones
                watcher.stop()
            finally:
                proc.send_signal(signal.SIGINT)
                try:
                    proc.wait(60)
                except subprocess.TimeoutExpired:
                    proc.kill()
                    proc.wait()
    return {"drones": n, "frames_per_s": round(frames / seconds, 2), "drones_per_frame": drones}


def frame_build_ms(drones: int, repeats: int = 200) -> float:
    """Median wall ms to build one frame of ``drones`` drones and encode it as the server does (JSON)."""
    from gcs.fleet.telemetry import DroneView
    from gcs.view.scene import frame

    views = {}
    for sysid in range(1, drones + 1):
        view = DroneView(sysid, 0.0, 12.3, armed=True, mode="OFFBOARD", vel_ned_mps=(0.1, 0.2, 0.0),
                         heading_deg=90.0, battery_remaining=0.93)  # fmt: skip
        view.texts.append((1.0, 6, "Avoidance ended: closest approach 1.91 m"))
        views[sysid] = view
    positions = {s: (float(s), 2.0 * s, -3.0) for s in views}
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        built = frame(time_s=12.3, drones=views, positions_ned_m=positions, homes_ned_m=positions,
                      slots_ned_m=positions, lost=(), now_s=12.3, separation_m=2.0, min_separation_m=1.9,
                      realtime_factor=0.5)  # fmt: skip
        json.dumps(built, separators=(",", ":"))
        times.append(time.perf_counter() - t0)
    return round(statistics.median(times) * 1000.0, 3)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--drones", type=int, default=50)
    parser.add_argument("--hold-s", type=float, default=100.0)
    parser.add_argument("--window-s", type=float, default=5.0)
    parser.add_argument("--big", type=int, default=100, help="drones of the paced keeping-up run (0: none)")
    parser.add_argument("--first-instance", type=int, default=120)
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()
    if args.drones < 2 or args.window_s < 2 or args.hold_s < 2 * args.window_s + 4:
        parser.error("--drones >= 2, --window-s >= 2 and --hold-s >= two windows and 4 s")
    with tempfile.TemporaryDirectory(prefix="view-cost-") as tmp:
        windows = fly_windows(args, Path(tmp))

    def median(key: str, watched: bool) -> float:
        return float(statistics.median(x[key] for x in windows if x["watched"] is watched))

    rtf = {w: median("rtf", w) for w in (False, True)}
    supervisor = {w: median("supervisor_cpu_s_per_sim_s", w) for w in (False, True)}
    drones = median("drones_cpu_s_per_sim_s", False)
    summary = {
        "drones": args.drones,
        "rtf_unwatched": rtf[False],
        "rtf_one_client": rtf[True],
        "cost_pct_of_rtf": round(100.0 * (1.0 - rtf[True] / rtf[False]), 2),
        "supervisor_cpu_s_per_sim_s_unwatched": supervisor[False],
        "supervisor_cpu_s_per_sim_s_one_client": supervisor[True],
        "view_cpu_pct_of_swarm": round(
            100.0 * (supervisor[True] - supervisor[False]) / (supervisor[False] + drones), 2
        ),
        "client_frames_per_s": statistics.median(x["frames_per_s"] for x in windows if x["watched"]),
        "frame_kb": statistics.median(x["frame_kb"] for x in windows if x["watched"] and x["frame_kb"]),
        "frame_build_ms": {n: frame_build_ms(n) for n in sorted({args.drones, 100})},
        "paced_big_swarm": big_swarm(args.big, 1) if args.big else None,
        "windows": windows,
    }
    print(json.dumps({k: v for k, v in summary.items() if k != "windows"}, indent=1))
    if args.json is not None:
        args.json.write_text(json.dumps(summary, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
