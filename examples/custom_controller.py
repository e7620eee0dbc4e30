"""Your own centralised swarm algorithm through the Python API: every tick the ground station computes each drone's
setpoint from everyone's reported state. Here, a potential-field controller: each drone is pulled towards its place
on a ring (the ring's slots shared out by angle) and pushed away from any drone closer than 2.5 m. Onboard avoidance
stays under it as the safety layer.

    python examples/custom_controller.py [--drones 6] [--seconds 40]

Exits 1 unless every drone ends within 0.5 m of the ring and nobody touched.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

from gcs.api import DroneState, Setpoint, launch_blocking

RING_M = 5.0
ALT_M = 3.0
GAIN_PER_S = 0.6  # velocity per metre from the slot
REPULSION_M = 2.5
MAX_SPEED_MPS = 1.5


def ring_controller(t_s: float, drones: dict[int, DroneState]) -> dict[int, Setpoint]:
    """Velocity setpoints: to the slot on the ring, away from near neighbours, capped at MAX_SPEED_MPS."""
    flying = {s: d for s, d in drones.items() if not d.lost and all(math.isfinite(v) for v in d.pos_ned_m)}
    order = sorted(flying, key=lambda s: math.atan2(flying[s].pos_ned_m[1], flying[s].pos_ned_m[0]))
    out: dict[int, Setpoint] = {}
    for k, sysid in enumerate(order):
        here = np.array(flying[sysid].pos_ned_m[:2])
        angle = 2.0 * math.pi * k / len(order) + 0.1 * t_s  # the ring turns slowly
        slot = RING_M * np.array([math.cos(angle), math.sin(angle)])
        velocity = GAIN_PER_S * (slot - here)
        for other, state in flying.items():
            away = here - np.array(state.pos_ned_m[:2])
            distance = float(np.linalg.norm(away))
            if other != sysid and 1e-6 < distance < REPULSION_M:
                velocity += (REPULSION_M - distance) / distance * away
        speed = float(np.linalg.norm(velocity))
        if speed > MAX_SPEED_MPS:
            velocity *= MAX_SPEED_MPS / speed
        out[sysid] = Setpoint(pos_ned_m=(math.nan, math.nan, -ALT_M), vel_ned_mps=(velocity[0], velocity[1], math.nan),
                              acc_ned_mps2=(math.nan, math.nan, math.nan), yaw_rad=math.nan)  # fmt: skip
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--drones", type=int, default=6)
    parser.add_argument("--seconds", type=float, default=40.0)
    parser.add_argument("--first-instance", type=int, default=0)
    parser.add_argument("--report", type=Path, default=Path("reports") / "custom-controller")
    args = parser.parse_args()
    with launch_blocking(args.drones, first_instance=args.first_instance, drones_per_process="auto",
                         report_dir=args.report, say=print) as swarm:  # fmt: skip
        swarm.takeoff(ALT_M)
        swarm.control(ring_controller)
        swarm.sleep(args.seconds)
        off_ring = {s: round(abs(math.hypot(d.pos_ned_m[0], d.pos_ned_m[1]) - RING_M), 2)
                    for s, d in swarm.drones().items()}  # fmt: skip
        swarm.land()
    metrics = swarm.result.metrics if swarm.result is not None else {}
    print(f"distance from the ring: {off_ring}; collisions {metrics.get('collisions')}, "
          f"min separation {metrics.get('min_separation_m')} m")  # fmt: skip
    return 0 if max(off_ring.values()) < 0.5 and metrics.get("collisions") == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
