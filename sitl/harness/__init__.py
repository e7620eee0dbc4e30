"""The simulation harness: spawning, the drone factory, the shared world and the lockstep gate behind one face.

The ground station depends on the interface it declares (gcs/fleet/harness.py); only its composition root
(gcs/composition.py) imports this package, and this package imports nothing from ``gcs``. See docs/architecture.md.
"""

from sitl.dynamics.plant import GeoPoint
from sitl.harness.harness import SitlHarness
from sitl.harness.processes import LaunchPlan, SpawnError, process_exit_cause
from sitl.world.linkmodel import LinkImpairment, LinkProfile
from sitl.world.mesh import MeshSettings

__all__ = [
    "GeoPoint",
    "LaunchPlan",
    "LinkImpairment",
    "LinkProfile",
    "MeshSettings",
    "SitlHarness",
    "SpawnError",
    "process_exit_cause",
]
