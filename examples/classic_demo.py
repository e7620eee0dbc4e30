"""The classic demo through the Python API: nine drones take off, hold a 3 x 3 grid, change into a rotating circle
with a gentle altitude wave, and land; then the flight report's figures. The same flight as
``swarm fly missions/grid_to_circle.toml`` (tests/integration/test_examples.py compares the two).

    python examples/classic_demo.py [--drones 9] [--paced] [--report DIR]

Exits 1 if the drones touched or the circle did not hold to 0.3 m RMS.
"""

from __future__ import annotations

import argparse
import asyncio
import math
import sys
from pathlib import Path

from gcs.api import CircleSpec, GridSpec, launch


async def fly(args: argparse.Namespace) -> dict[str, object]:
    rows = math.ceil(math.sqrt(args.drones))
    async with launch(args.drones, lockstep=not args.paced, first_instance=args.first_instance,
                      drones_per_process="auto", report_dir=args.report, say=print) as swarm:  # fmt: skip
        await swarm.takeoff(3.0)
        await swarm.formation(GridSpec(rows=rows, cols=math.ceil(args.drones / rows), spacing_m=2.0, alt_m=3.0))
        await swarm.sleep(8.0)
        await swarm.formation(CircleSpec(radius_m=3.0, alt_m=3.0, angular_rate_radps=0.2, alt_osc_amp_m=0.3,
                                         alt_osc_rate_radps=0.5))  # fmt: skip
        await swarm.sleep(args.circle_s)
        await swarm.land()
    assert swarm.result is not None
    return swarm.result.metrics


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--drones", type=int, default=9)
    parser.add_argument("--paced", action="store_true", help="real time instead of lockstep")
    parser.add_argument("--circle-s", type=float, default=30.0, help="simulated seconds on the circle (default 30)")
    parser.add_argument("--first-instance", type=int, default=0)
    parser.add_argument("--report", type=Path, default=Path("reports") / "classic-demo")
    args = parser.parse_args()
    metrics = asyncio.run(fly(args))
    circle = next(s for s in metrics["steps"] if s["name"] == "circle")  # type: ignore[attr-defined]
    print(f"min separation {metrics['min_separation_m']} m, collisions {metrics['collisions']}, "
          f"circle RMS {circle['formation_rms_m']} m; report in {args.report}")  # fmt: skip
    ok = metrics["collisions"] == 0 and circle["formation_rms_m"] is not None and circle["formation_rms_m"] < 0.3
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
