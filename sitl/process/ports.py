"""The UDP ports of drone instance i (sysid i + 1): the one place they are computed.

Instances 0-39 keep PX4 SITL's numbers exactly: the API link binds 14580+i and streams to 14540+i, the
ground-station link binds 18570+i (and streams to 14550). PX4's scheme cannot go on from 40: drone 40 would stream
its API link to 14580, drone 0's API port, and drone 0 would hear drone 40's telemetry as its own client's traffic.
From instance 40 on, the API link binds 16000+i and streams to 15000+i (drone 40: binds 16040, streams to 15040);
the ground-station link keeps 18570+i. Every port a drone binds (16040-16253 and 18570-18823 for the ground-station
links, next to PX4's 14580-14619) and every port a drone streams to (14540-14579, 15040-15253) is then distinct, no
drone streams to a port another binds, and none of the new ones is 14550, the ground station's. The last instance
is 253 (sysid 254): 255 is the ground station's own sysid, as QGroundControl's.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

MAX_INSTANCE: Final = 253  # sysid = instance + 1 <= 254; 255 is the ground station's
INSTANCES: Final = MAX_INSTANCE + 1
PX4_INSTANCES: Final = 40  # instances 0..39: PX4 SITL's own ports
PX4_API_BIND_BASE: Final = 14580
PX4_API_REMOTE_BASE: Final = 14540
API_BIND_BASE: Final = 16000  # instances 40.. bind 16000 + i
API_REMOTE_BASE: Final = 15000  # ...and stream to 15000 + i
GCS_BIND_BASE: Final = 18570  # every instance, as PX4
GCS_REMOTE_PORT: Final = 14550  # where the ground-station link streams by default (QGroundControl, MAVProxy)


@dataclass(frozen=True, slots=True)
class InstancePorts:
    """Where one instance's links bind and stream to (all on 127.0.0.1 by default)."""

    api_bind: int  # the API link's own port: a client sends commands here
    api_remote: int  # where the API link streams: a client (MAVSDK, pymavlink) listens here (udpin)
    gcs_bind: int  # the ground-station link's own port


def instance_ports(instance: int) -> InstancePorts:
    """The ports of ``instance`` (0..MAX_INSTANCE); ValueError for another number."""
    if not 0 <= instance <= MAX_INSTANCE:
        raise ValueError(f"instance must be in 0..{MAX_INSTANCE}, got {instance}")
    if instance < PX4_INSTANCES:
        api_bind, api_remote = PX4_API_BIND_BASE + instance, PX4_API_REMOTE_BASE + instance
    else:
        api_bind, api_remote = API_BIND_BASE + instance, API_REMOTE_BASE + instance
    return InstancePorts(api_bind=api_bind, api_remote=api_remote, gcs_bind=GCS_BIND_BASE + instance)
