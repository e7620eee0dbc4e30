"""Pure MAVLink microservices that make a simulated drone look like a PX4 SITL vehicle on the wire.

Each service is a sans-IO state machine (``handle(msg, now_s)`` and ``poll(now_s)`` return effects; time is
injected, nothing here opens a socket or reads a clock). ``LinkServices`` composes them for one link and is what the
IO shell drives; ``VehicleApi`` (vehicle_api.py) is everything the services need from the autopilot.
"""

from sitl.protocol.core import (
    Effect,
    Identity,
    PeerInputError,
    ProtocolError,
    ProtocolUsageError,
    Send,
)
from sitl.protocol.link import LinkServices
from sitl.protocol.modes import Px4Mode
from sitl.protocol.vehicle_api import CommandOutcome, CommandResult, VehicleApi, VehicleSnapshot

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
