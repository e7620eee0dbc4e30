"""Benchmark: can the swarm see a silent drone? Collisions and CPU for each camera option, in one run.

A rotating circle of 8 drones and a silent drone (never relayed) that moves onto the circle's path and holds there
(tests/closed_loop/circle_swarm.py: 9 Simulations on one shared world, stepped together as in lockstep, with the
camera, the relay between the circle's drones and collision prevention as in a drone process). Options:

- ``hold, forward``: MPC_YAW_FOLLOW = 0, CAM_RIG = 0 (the defaults before this comparison)
- ``follow, forward``: the heading turns towards the direction of travel, one forward camera
- ``hold, omni``: four cameras all round
- ``follow, omni``: both

Every option flies every seed, interleaved, so a change in the machine's load hits all options alike. CPU is this
thread's CPU clock (``time.thread_time``) per drone per simulated second: the whole loop, its perception part
(render + detect + relay conversion) and its control part (sensors, estimator, autopilot, cascade).

    python bench/silent_drone.py [--seeds 1 2 3]
"""

from __future__ import annotations

import argparse
import statistics
from collections import defaultdict

from tests.closed_loop.circle_swarm import CircleOutcome, CircleScenario, fly_circle_past_a_silent_drone

OPTIONS = {
    "hold, forward": (0, 0),
    "follow, forward": (1, 0),
    "hold, omni": (0, 1),
    "follow, omni": (1, 1),
}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3])
    args = parser.parse_args()
    results: dict[str, list[CircleOutcome]] = defaultdict(list)
    for seed in args.seeds:
        for name, (follow, rig) in OPTIONS.items():
            out = fly_circle_past_a_silent_drone(CircleScenario(seed=seed, yaw_follow=follow, cam_rig=rig))
            results[name].append(out)
            print(f"seed {seed} {name:16s} collisions {out.collisions} closest {out.min_silent_distance_m:.2f} m "
                  f"episodes {out.avoidance_episodes:2d} cpu {out.cpu_ms_per_drone_sim_s:.1f} ms "
                  f"(perception {out.perception_ms_per_drone_sim_s:.1f}, control {out.control_ms_per_drone_sim_s:.1f})"
                  f" {list(out.events[:1])}", flush=True)  # fmt: skip
    print("\n| option | runs with a collision | closest approach (min / median) m | CPU ms per drone per sim s | "
          "of which perception |")  # fmt: skip
    print("|---|---|---|---|---|")
    for name, outs in results.items():
        hit = sum(o.collisions > 0 for o in outs)
        closest = [o.min_silent_distance_m for o in outs]
        cpu = statistics.median(o.cpu_ms_per_drone_sim_s for o in outs)
        perc = statistics.median(o.perception_ms_per_drone_sim_s for o in outs)
        print(f"| {name} | {hit} of {len(outs)} | {min(closest):.2f} / {statistics.median(closest):.2f} | "
              f"{cpu:.1f} | {perc:.1f} |")  # fmt: skip


if __name__ == "__main__":
    main()
