"""Deprecated path, kept so that scripts written against it keep working: a drone's ports are computed in
sitl/process/ports.py; import ``instance_ports`` and the port constants from ``sitl.process.ports``."""

from __future__ import annotations

import warnings

from sitl.process.ports import (
    API_BIND_BASE,
    API_REMOTE_BASE,
    GCS_BIND_BASE,
    GCS_REMOTE_PORT,
    INSTANCES,
    MAX_INSTANCE,
    PX4_INSTANCES,
    InstancePorts,
    instance_ports,
)

__all__ = [
    "API_BIND_BASE",
    "API_REMOTE_BASE",
    "GCS_BIND_BASE",
    "GCS_REMOTE_PORT",
    "INSTANCES",
    "MAX_INSTANCE",
    "PX4_INSTANCES",
    "InstancePorts",
    "instance_ports",
]

warnings.warn("sitl.ports moved to sitl.process.ports", DeprecationWarning, stacklevel=2)
