"""The Python API: launch a simulated swarm, fly it, break it, and get its flight report, from your own code.

```python
import asyncio
from pathlib import Path
from gcs.api import CircleSpec, launch

async def main() -> None:
    async with launch(9, lockstep=True, report_dir=Path("report")) as swarm:
        await swarm.takeoff(3.0)
        await swarm.formation(CircleSpec(radius_m=4.0, alt_m=3.0, angular_rate_radps=0.3))
        await swarm.sleep(20.0)
        await swarm.land()
    print(swarm.result.metrics["min_separation_m"])

asyncio.run(main())
```

``launch_blocking`` is the same without asyncio. docs/api.md has the guide and the reference.
"""

from gcs.api.blocking import BlockingSession, launch_blocking
from gcs.api.checks import assert_min_separation, assert_no_collisions, assert_no_failsafe, assert_reached
from gcs.api.engine import SessionClosed
from gcs.api.session import Session, launch
from gcs.api.types import ControllerError, DroneState, Event, FlightResult, LaunchOptions
from gcs.fleet.links import LinkPlan, MeshPlan, NeighbourPlan
from gcs.fleet.losses import LossPolicy
from gcs.fleet.relay import RelayScope
from gcs.fleet.swarm import SwarmError
from gcs.flight.behaviours import FlockSpec, FollowSpec
from gcs.flight.formation import CircleSpec, GridSpec, LineSpec, Setpoint, VSpec
from gcs.flight.onboard import FLOCKING, LEADER_FOLLOWER

__all__ = [
    "FLOCKING",
    "LEADER_FOLLOWER",
    "BlockingSession",
    "CircleSpec",
    "ControllerError",
    "DroneState",
    "Event",
    "FlightResult",
    "FlockSpec",
    "FollowSpec",
    "GridSpec",
    "LaunchOptions",
    "LineSpec",
    "LinkPlan",
    "LossPolicy",
    "MeshPlan",
    "NeighbourPlan",
    "RelayScope",
    "Session",
    "SessionClosed",
    "Setpoint",
    "SwarmError",
    "VSpec",
    "assert_min_separation",
    "assert_no_collisions",
    "assert_no_failsafe",
    "assert_reached",
    "launch",
    "launch_blocking",
]
