"""Your own distributed swarm algorithm, run on the drones themselves: each drone decides from its own estimate and
its neighbour table, with no ground station in the loop. Here, a rendezvous: every drone steers towards the centroid
of the drones it hears (itself included) while keeping ``GTH_SPACING`` metres from each of them, so a scattered swarm
gathers into a tight, evenly spaced cluster wherever its members agree, not where anybody told it.

The class below is the whole behaviour; the drones load it from this file (``behaviour="this_file.py:Gather"``), its
``PARAMS`` become their MAVLink parameters, and the script around it only launches, starts, watches and lands.

    python examples/onboard_behaviour.py [--drones 6] [--seconds 30]

Exits 1 unless the cluster shrank to within GTH_SPACING + 1 m of its centroid on every drone and nobody touched.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path
from typing import ClassVar

from sitl.onboard import OnboardSetpoint, OnboardState

ALT_M = 3.0
SPACING_M = 2.0  # the default of GTH_SPACING, and what the check below expects


class Gather:
    """Rendezvous with spacing: towards the centroid of everyone heard, away from anyone closer than GTH_SPACING."""

    RATE_HZ: ClassVar[float] = 10
    PARAMS: ClassVar[dict[str, tuple[float, float, float]]] = {
        "GTH_SPACING": (SPACING_M, 0.5, 10.0),  # m kept from each neighbour
        "GTH_GAIN": (0.4, 0.0, 2.0),  # m/s per metre from the centroid
        "GTH_VMAX": (1.0, 0.1, 5.0),  # m/s
    }

    def step(self, state: OnboardState) -> OnboardSetpoint:
        p = state.params
        north, east = state.pos_ned_m[0], state.pos_ned_m[1]
        heard = [(n.pos_ned_m[0], n.pos_ned_m[1]) for n in state.neighbours]
        centre_n = (north + sum(h[0] for h in heard)) / (len(heard) + 1)
        centre_e = (east + sum(h[1] for h in heard)) / (len(heard) + 1)
        vn, ve = p["GTH_GAIN"] * (centre_n - north), p["GTH_GAIN"] * (centre_e - east)
        for other_n, other_e in heard:  # a spring that only pushes, stiff enough to beat the pull of the centre
            dn, de = north - other_n, east - other_e
            distance = math.hypot(dn, de)
            if 1e-6 < distance < p["GTH_SPACING"]:
                push = 2.0 * (p["GTH_SPACING"] - distance) / distance
                vn, ve = vn + push * dn, ve + push * de
        speed = math.hypot(vn, ve)
        if speed > p["GTH_VMAX"]:
            vn, ve = vn * p["GTH_VMAX"] / speed, ve * p["GTH_VMAX"] / speed
        return OnboardSetpoint(pos_ned_m=(math.nan, math.nan, -ALT_M), vel_ned_mps=(vn, ve, math.nan))


def spread_m(positions: list[tuple[float, float]]) -> float:
    """The largest distance of a drone from the swarm's centroid."""
    cn = sum(p[0] for p in positions) / len(positions)
    ce = sum(p[1] for p in positions) / len(positions)
    return max(math.hypot(p[0] - cn, p[1] - ce) for p in positions)


def main() -> int:
    from gcs.api import launch_blocking  # the ground station: only the script needs it, not the drones

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--drones", type=int, default=6)
    parser.add_argument("--seconds", type=float, default=30.0)
    parser.add_argument("--first-instance", type=int, default=0)
    parser.add_argument("--report", type=Path, default=Path("reports") / "onboard-behaviour")
    args = parser.parse_args()
    with launch_blocking(args.drones, first_instance=args.first_instance, drones_per_process="auto", spacing_m=5.0,
                         behaviour=f"{Path(__file__).resolve()}:Gather", report_dir=args.report,
                         say=print) as swarm:  # fmt: skip
        swarm.takeoff(ALT_M)
        before = spread_m([d.pos_ned_m[:2] for d in swarm.drones().values()])
        swarm.start_behaviours()  # BHV_EN = 1 on every drone: from here on each flies itself
        swarm.sleep(args.seconds)
        after = spread_m([d.pos_ned_m[:2] for d in swarm.drones().values()])
        swarm.stop_behaviours()  # BHV_EN = 0 and Hold
        swarm.land()
    metrics = swarm.result.metrics if swarm.result is not None else {}
    print(f"spread from the centroid: {before:.2f} m before, {after:.2f} m after; collisions "
          f"{metrics.get('collisions')}, min separation {metrics.get('min_separation_m')} m")  # fmt: skip
    return 0 if after < SPACING_M + 1.0 < before and metrics.get("collisions") == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
