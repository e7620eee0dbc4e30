"""The shipped onboard behaviours as the ground station names and configures them (pure: specs in, parameters out).

A mission's ``flock`` or ``follow`` step with ``onboard = true`` flies the same spec (``FlockSpec``, ``FollowSpec``)
as the ground station's law, but every drone computes its own setpoint (sitl/onboard/behaviours/); the drones carry
``FLOCKING`` or ``LEADER_FOLLOWER``. The ground station converts the spec into each drone's MAVLink parameters
(``flock_params`` for what all share, ``point_values`` for points, which gcs/command/onboard_flight.py first converts
into each drone's own local frame) and turns the behaviour on.
"""

from __future__ import annotations

from pathlib import Path
from typing import Final

from gcs.flight.behaviours import FlockSpec

FLOCKING: Final = "sitl.onboard.behaviours.flocking:Flocking"
LEADER_FOLLOWER: Final = "sitl.onboard.behaviours.leader_follower:LeaderFollower"
MAX_POINTS: Final = 6  # points a shipped behaviour holds in its parameters (sitl/onboard/behaviours/points.py)


class OnboardSpecError(ValueError):
    """Something a shipped behaviour cannot take (one line)."""


def absolute_spec(spec: str, base: Path) -> str:
    """A behaviour as the drones load it, wherever they start: a file relative to ``base`` made absolute, a module
    (``package.module:Class``) as it is."""
    if is_module_spec(spec):
        return spec
    file, _, cls = spec.rpartition(":")
    return f"{(base / file).resolve()}:{cls}" if file else spec


def is_module_spec(spec: str) -> bool:
    """``package.module:Class`` (an installed module, kept as it is) rather than ``path/to/file.py:Class``."""
    module = spec.rpartition(":")[0]
    return bool(module) and not module.endswith(".py") and all(p.isidentifier() for p in module.split("."))


def point_values(prefix: str, points_ne_m: tuple[tuple[float, float], ...]) -> dict[str, float]:
    """A point list as a shipped behaviour's parameters: ``<PREFIX>_CNT``, ``<PREFIX><k>_N``, ``<PREFIX><k>_E``."""
    if len(points_ne_m) > MAX_POINTS:
        raise OnboardSpecError(f"an onboard behaviour holds at most {MAX_POINTS} points, got {len(points_ne_m)}")
    values = {f"{prefix}_CNT": float(len(points_ne_m))}
    for k, (north, east) in enumerate(points_ne_m, start=1):
        values[f"{prefix}{k}_N"], values[f"{prefix}{k}_E"] = float(north), float(east)
    return values


def flock_params(spec: FlockSpec) -> dict[str, float]:
    """The spec's values every drone shares (FLK_*)."""
    return {
        "FLK_VMAX": spec.max_speed_mps,
        "FLK_AMAX": spec.max_accel_mps2,
        "FLK_NBR_R": spec.neighbour_radius_m,
        "FLK_SEP_R": spec.separation_radius_m,
        "FLK_SEP_W": spec.separation_weight_mps2,
        "FLK_SEP_LOOK": spec.separation_lookahead_s,
        "FLK_ALI_W": spec.alignment_weight_per_s,
        "FLK_COH_W": spec.cohesion_weight_per_s2,
        "FLK_MIG_W": spec.migration_weight_per_s,
        "FLK_ARR_R": spec.arrival_radius_m,
    }
