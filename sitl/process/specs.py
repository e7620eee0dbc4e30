"""What a drone process is asked to run: the drones it hosts and what they share (light: the command line builds
these before the heavy imports)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

from sitl.dynamics.airframe import Airframe
from sitl.dynamics.plant import GeoPoint
from sitl.dynamics.wind import WindConfig
from sitl.process.mavlink_io import LinkConfig
from sitl.world.linkmodel import LinkProfile
from sitl.world.mesh import MeshSettings

if TYPE_CHECKING:
    from sitl.onboard.loader import LoadedBehaviour


@dataclass(frozen=True, slots=True, kw_only=True)
class DroneSpec:
    """What differs between the drones of one process."""

    instance: int
    seed: int
    home: GeoPoint
    links: tuple[LinkConfig, ...]
    camera_frames: Path | None = None
    log_path: Path | None = None  # this drone's own output; None: the process's stdout and stderr


@dataclass(frozen=True, slots=True, kw_only=True)
class ProcessSpec:
    """What every drone of one process shares: one airframe, one clock, one world, one wind, one link profile (each
    drone draws its own link decisions from its seed and instance: sitl/world/linkmodel.py ``drone_channels``)."""

    airframe: Airframe
    speed_factor: float
    wind: WindConfig
    duration_s: float | None = None
    demo: bool = False
    world_name: str | None = None
    lockstep: bool = False
    lockstep_quantum: int = 1
    signing_key: bytes | None = None  # MAVLink 2 signing key every drone signs with (one key per swarm)
    signing_required: bool = False  # MAV_SIGN_CFG = 2 at boot: unsigned messages dropped once a key is set
    links: LinkProfile = field(default_factory=LinkProfile)
    mesh: MeshSettings | None = None  # the drone-to-drone mesh radio (needs the shared world); None: no mesh
    behaviour: LoadedBehaviour | None = None  # an onboard behaviour every drone of the process runs (sitl/onboard)
