"""Every parameter of one simulated drone, as one table: the declarations of each part, in the order the MAVLink
parameter protocol indexes them.

Apart from the drone itself, so that whatever only checks a parameter (the ground station before it spawns a swarm,
an onboard behaviour's loader, the parameter reference) imports the declarations alone, not the flight code and its
compiled kernels: that import costs a ground station about two seconds a flight.
"""

from __future__ import annotations

from collections.abc import Iterable

from sitl.autopilot.params import AUTOPILOT_PARAMS
from sitl.avoidance.params import AVOIDANCE_PARAMS
from sitl.control.params import CONTROL_PARAMS
from sitl.faults.params import FAULT_PARAMS
from sitl.params import ParamDef, ParamStore
from sitl.protocol.signing_params import SIGNING_PARAMS


def build_param_store(extra: Iterable[ParamDef] = ()) -> ParamStore:
    """Every parameter of one drone, in the order the MAVLink parameter protocol indexes them; ``extra`` (an onboard
    behaviour's, sitl/onboard) come last."""
    return ParamStore((*CONTROL_PARAMS, *AUTOPILOT_PARAMS, *AVOIDANCE_PARAMS, *FAULT_PARAMS, *SIGNING_PARAMS, *extra))
