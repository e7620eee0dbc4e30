"""Benchmark: what the drone-to-drone mesh costs against the ground station's relay, in CPU per drone.

Flies one generated mission twice with ``swarm fly --lockstep --drones-per-process auto``: ``--drones`` drones in a
grid ``--spacing`` metres apart take off, hover for ``--hold-s`` simulated seconds and land, once with their
neighbours' positions relayed by the supervisor (``neighbours = "relay"``, every drone to every other) and once
heard over the mesh alone (``neighbours = "mesh"``, range ``--range-m``). While the drones hover it reads the CPU
time (/proc/PID/stat: user + system) of every drone process and of the supervisor at the start and the end of a
window on the simulated clock, and prints per mode the CPU milliseconds per drone per simulated second of the drones
and of the supervisor, with what the mesh delivered. CPU time, not wall time: the figures hold on a loaded machine,
but runs minutes apart on a machine shared with other work differ by several per cent.

So it also measures the two ways in one process, on the thread's CPU clock, with nothing else in between: one
drone's side of hearing ``--drones - 1`` neighbours at 10 Hz each, over the mesh (``MeshRadio.after_step`` for every
physics step, the frames heard parsed together and put into the neighbour table, as ``MavlinkEndpoint.hear_mesh``
does) and over the relay (the supervisor's batches of frames, one datagram per 50 ms, parsed and put into the table
as a link does); every drone within range, all drones' radios stepped, only the measured drone's work timed.

    python bench/mesh_cost.py [--drones 50] [--hold-s 20] [--range-m 15] [--spacing 3] [--first-instance 200]
                              [--in-process-only]
"""

from __future__ import annotations

import argparse
import json
import math
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


def in_process(drones: int, sim_s: float = 20.0) -> dict[str, float]:
    """CPU ms per simulated second of one drone hearing ``drones - 1`` neighbours at 10 Hz, over the mesh and over
    the relay (see the module docstring)."""
    import numpy as np
    from pymavlink.dialects.v20 import common as mavlink

    from sitl.dynamics.geodesy import geo_from_ned
    from sitl.dynamics.plant import DEFAULT_HOME
    from sitl.protocol import framing
    from sitl.protocol.neighbours import MESH, RELAY, NeighbourTable
    from sitl.world.mesh import MeshMedium, MeshRadio, MeshSettings
    from sitl.world.shared import SharedWorld

    dt_s, steps = 0.004, int(sim_s / 0.004)
    world = SharedWorld.create()
    try:
        side = math.ceil(math.sqrt(drones))
        for i in range(drones):  # a grid 1 m apart: everyone within range of everyone
            geo = geo_from_ned((float(i // side), float(i % side), -3.0), DEFAULT_HOME)
            world.write(i, 0.0, (geo.lat_deg, geo.lon_deg, geo.alt_amsl_m), (0.0, 0.0, 0.0), 0.35, False,
                        rest_alt_amsl_m=DEFAULT_HOME.alt_amsl_m)  # fmt: skip
        radios = [MeshRadio(MeshMedium(world, i), MeshSettings(range_m=1e6), None, seed=i, quantum_steps=1)
                  for i in range(drones)]  # fmt: skip
        encoders = [mavlink.MAVLink(None, srcSystem=i + 1, srcComponent=1) for i in range(drones)]
        mesh_table, relay_table = NeighbourTable(1), NeighbourTable(1)
        mesh_ns = relay_ns = 0
        relayed: list[bytes] = []
        for step in range(1, steps + 1):
            now_s = step * dt_s
            for i, radio in enumerate(radios):
                t0 = time.thread_time_ns()
                frames = radio.after_step(now_s)
                if i == 0 and frames:
                    for msg in framing.parse_datagram(b"".join(frames)) or []:
                        mesh_table.receive(msg, now_s, MESH)
                if i == 0:
                    mesh_ns += time.thread_time_ns() - t0
            if step % 25 == 0:  # every drone's 10 Hz report: posted on the mesh, queued by the relay for drone 0
                for i, radio in enumerate(radios):
                    msg = mavlink.MAVLink_global_position_int_message(int(now_s * 1000), 473977420 + i, 85455940,
                                                                     491000, 3000, 0, 0, 0, 0)  # fmt: skip
                    frame = msg.pack(encoders[i])
                    radio.broadcast(frame, now_s)
                    if i != 0:
                        relayed.append(frame)
            if step % 12 == 0 and relayed:  # the supervisor's batch for drone 0, about every 50 ms
                t0 = time.thread_time_ns()
                for data in _datagrams(relayed):
                    for msg in framing.parse_datagram(data) or []:
                        relay_table.receive(msg, now_s, RELAY)
                relay_ns += time.thread_time_ns() - t0
                relayed.clear()
        heard = int(np.sum([c.updates for c in mesh_table.counts().values()]))
        return {"mesh_ms_per_sim_s": round(mesh_ns / 1e6 / sim_s, 3),
                "relay_ms_per_sim_s": round(relay_ns / 1e6 / sim_s, 3),
                "reports_heard_per_sim_s": round(heard / sim_s, 1)}  # fmt: skip
    finally:
        world.close()


def _datagrams(frames: list[bytes], max_bytes: int = 1400) -> list[bytes]:
    """Frames packed into datagrams of at most ``max_bytes``, as the supervisor's outbox packs them."""
    out, batch = [], b""
    for frame in frames:
        if batch and len(batch) + len(frame) > max_bytes:
            out.append(batch)
            batch = b""
        batch += frame
    return out + ([batch] if batch else [])


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--drones", type=int, default=50)
    parser.add_argument("--hold-s", type=float, default=20.0, help="simulated seconds of hover (default 20)")
    parser.add_argument("--range-m", type=float, default=15.0, help="mesh radio range (default 15)")
    parser.add_argument("--spacing", type=float, default=3.0, help="grid spacing in metres (default 3)")
    parser.add_argument("--first-instance", type=int, default=200)
    parser.add_argument("--in-process-only", action="store_true", help="only the in-process measurement")
    args = parser.parse_args()
    if args.drones < 2 or args.hold_s < 5 or args.range_m <= 0 or args.spacing <= 0:
        print("mesh_cost: error: --drones >= 2, --hold-s >= 5, --range-m and --spacing > 0", file=sys.stderr)
        return 2
    one = {n: in_process(n) for n in sorted({9, 25, 50, args.drones})}
    print(json.dumps({"in_process_one_drone": one}, indent=2), flush=True)
    if args.in_process_only:
        return 0
    work = Path(tempfile.mkdtemp(prefix="mesh-cost-"))
    results = {mode: fly(args, mode, work) for mode in ("relay", "mesh")}
    print(json.dumps({"drones": args.drones, "spacing_m": args.spacing, "range_m": args.range_m, **results},
                     indent=2))  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
