"""Benchmark: how long the neighbour relay takes to move a position report from one drone to another.

Brings up N drones (on the ground, idle: the relay's load is the same as in flight, every drone reports its
position at 10 Hz), then runs the relay probe (gcs/bench/probe.py) in a process of its own for a while and prints the
hop's median, 95th percentile and maximum. One run on the current machine; compare with the machine's load.

    python bench/relay_latency.py [--drones 9] [--seconds 10]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys

from gcs.composition import SITL
from gcs.fleet.harness import SpawnPlan
from gcs.fleet.swarm import Swarm


def measure(n_drones: int, seconds: float) -> dict[str, float]:
    plan = SpawnPlan(n_drones=n_drones, first_instance=120)
    swarm = Swarm(plan, SITL.harness(plan))
    try:
        swarm.up()
        home = swarm.plan.origin
        probe = subprocess.Popen(
            [sys.executable, "-m", "gcs.bench.probe", str(swarm.link.port), "--seconds", str(seconds),
             "--anchor", f"{home.lat_deg},{home.lon_deg},{home.alt_amsl_m}"],
            stdout=subprocess.PIPE, text=True,
        )  # fmt: skip
        while probe.poll() is None:
            swarm.pump(0.02)
        out, _ = probe.communicate()
        result: dict[str, float] = json.loads(out)
        return result
    finally:
        swarm.shutdown()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--drones", type=int, default=9)
    parser.add_argument("--seconds", type=float, default=10.0)
    args = parser.parse_args()
    stats = measure(args.drones, args.seconds)
    print(
        f"relay hop with {args.drones} drones: median {stats['median_ms']:.2f} ms, 95th percentile "
        f"{stats['p95_ms']:.2f} ms, max {stats['max_ms']:.2f} ms ({stats['received']}/{stats['sent']} arrived)"
    )


if __name__ == "__main__":
    main()
