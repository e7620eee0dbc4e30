"""Pure MAVLink microservices that make a simulated drone look like a PX4 SITL vehicle on the wire.

Each service is a sans-IO state machine: ``handle(msg, now_s)`` and ``poll(now_s)`` return effects, time is
injected (simulation seconds), and nothing here opens a socket or reads a clock. ``VehicleApi`` (vehicle_api.py) is
everything the services need from the autopilot; ``LinkServices`` (link.py) composes all services for one link and is
the only object an IO shell has to drive:

    link = LinkServices(Identity(sysid=i + 1), vehicle, param_store)      # one per link (API port, GCS port)
    mav = pymavlink.dialects.v20.common.MAVLink(None, srcSystem=i + 1, srcComponent=1)
    for msg in parser.parse_buffer(datagram) or []:                        # robust_parsing = True
        send_all(link.handle(msg, sim_time_s))
    send_all(link.poll(sim_time_s))                                        # every loop turn, >= 2x the fastest stream
    send_all(link.statustext(event.severity, event.text))                  # autopilot events, on every link

where ``send_all`` packs each ``Send(msg)`` effect with ``mav`` and writes it to the link's remote address.

The names below are loaded when first used (PEP 562), not when the package is: importing one module of it (the signing
parameters' declarations, say) must not load every service and, through the offboard service, the controller's
compiled kernels.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from sitl.autopilot.px4_modes import Px4Mode
    from sitl.autopilot.vehicle_api import CommandOutcome, CommandResult, VehicleApi, VehicleSnapshot
    from sitl.protocol.core import Effect, Identity, PeerInputError, ProtocolError, ProtocolUsageError, Send
    from sitl.protocol.link import LinkServices

_HOMES = {
    "Px4Mode": "sitl.autopilot.px4_modes",
    "CommandOutcome": "sitl.autopilot.vehicle_api",
    "CommandResult": "sitl.autopilot.vehicle_api",
    "VehicleApi": "sitl.autopilot.vehicle_api",
    "VehicleSnapshot": "sitl.autopilot.vehicle_api",
    "Effect": "sitl.protocol.core",
    "Identity": "sitl.protocol.core",
    "PeerInputError": "sitl.protocol.core",
    "ProtocolError": "sitl.protocol.core",
    "ProtocolUsageError": "sitl.protocol.core",
    "Send": "sitl.protocol.core",
    "LinkServices": "sitl.protocol.link",
}

__all__ = [
    "CommandOutcome",
    "CommandResult",
    "Effect",
    "Identity",
    "LinkServices",
    "PeerInputError",
    "ProtocolError",
    "ProtocolUsageError",
    "Px4Mode",
    "Send",
    "VehicleApi",
    "VehicleSnapshot",
]


def __getattr__(name: str) -> Any:
    home = _HOMES.get(name)
    if home is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(home), name)
    globals()[name] = value
    return value
