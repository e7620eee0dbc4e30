"""Onboard collision avoidance: fuse what the drone knows of nearby bodies, then bend its velocity setpoint around them.

The autopilot computes the horizontal velocity its position loop wants (feed-forward plus MPC_XY_P times the
position error, limited) and flies ``avoid(...).vel_ned_mps`` instead. Two pure functions do the work:

- ``fuse`` merges camera detections (fresh bearing, noisy range, no velocity, only in the field of view) with
  neighbour positions relayed over MAVLink (good position and velocity, but up to a few tenths of a second old and
  gone when the relay is cut) into one obstacle list.
- ``avoid`` is ORCA (optimal reciprocal collision avoidance, van den Berg, Guy, Lin, Manocha 2011) in the horizontal
  plane, solved as the 2-D linear program with the 3-D fallback when the constraints leave no feasible velocity, plus
  a braking/separation layer that holds whatever the linear program had to give up. Neighbours that share the
  algorithm (known velocity) take half of each avoidance manoeuvre; bodies of unknown velocity are treated as static
  and avoided in full. A small, deterministic preference for passing on the right breaks the exactly symmetric cases
  (head-on pairs, antipodal swaps) that otherwise end in a standstill.

Both functions are pure. Their arithmetic is compiled (sitl/kernels/avoidance.py, on obstacles as float64 rows); this
module holds the configuration and the records, and turns one into the other. docs/avoidance.md has the algorithm,
its limits and measured figures.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Final, Literal

import numpy as np
import numpy.typing as npt

from sitl.kernels import avoidance as ak
from sitl.kernels.avoidance import MAX_AGE_S as MAX_AGE_S
from sitl.kernels.avoidance import MAX_REL_POS_M as MAX_REL_POS_M
from sitl.kernels.avoidance import MAX_SPEED_MPS as MAX_SPEED_MPS
from sitl.mathutil import fast_constructor

Vec3 = tuple[float, float, float]
ObstacleSource = Literal["camera", "relay", "fused", "traffic", "fused traffic"]

_ZERO3: Final[Vec3] = (0.0, 0.0, 0.0)
_SOURCES: Final[dict[float, ObstacleSource]] = {
    ak.SOURCE_CAMERA: "camera",
    ak.SOURCE_RELAY: "relay",
    ak.SOURCE_FUSED: "fused",
    ak.SOURCE_TRAFFIC: "traffic",
    ak.SOURCE_FUSED_TRAFFIC: "fused traffic",
}
_SOURCE_CODES: Final[dict[str, float]] = {name: code for code, name in _SOURCES.items()}


@dataclass(frozen=True, slots=True, kw_only=True)
class Obstacle:
    """One body to keep away from, relative to this drone, as ``avoid`` wants it.

    ``rel_pos_ned_m`` is the obstacle centre minus this drone's position. ``vel_ned_mps`` is the obstacle's absolute
    velocity, meaningful only when ``vel_known`` (camera detections carry none). ``age_s`` is how old the position is:
    ``fuse`` uses it to bring a report up to now, ``avoid`` only reports it. ``sysid`` names a relayed body (0 for one
    only the camera knows): an avoidance event says whom it corrected for.
    """

    rel_pos_ned_m: Vec3
    vel_ned_mps: Vec3 = _ZERO3
    vel_known: bool = False
    radius_m: float = 0.35
    source: ObstacleSource = "camera"
    age_s: float = 0.0
    sysid: int = 0


# Obstacles are built for every neighbour at the avoidance rate, several times over (relay, fusion): the fast
# constructor builds the same frozen record at a third of the cost (sitl/mathutil.py).
new_obstacle = fast_constructor(Obstacle)


@dataclass(frozen=True, slots=True, kw_only=True)
class AvoidanceConfig:
    """Every knob of fusion and avoidance; defaults suit two F450s (collision radius 0.35 m) at a few m/s.

    The lead parameters (AVOID_ENABLE, AVOID_MIN_DIST, AVOID_HORIZON, AVOID_MAX_CORR) map onto ``enabled``,
    ``min_distance_m``, ``horizon_s`` and ``max_correction_mps``; ``max_speed_mps`` should follow MPC_XY_VEL_MAX
    and ``max_accel_mps2`` MPC_ACC_HOR, ``own_radius_m`` the airframe's collision radius.
    """

    enabled: bool = True
    own_radius_m: float = 0.35
    # Centre-to-centre separation kept from a body of our own size (contact at 0.7 m): the 0.8 m gap covers the
    # camera's range error where avoidance acts (12 % of ~3 m = 0.36 m), the velocity loop's lag behind the
    # corrected setpoint and relay latency (~0.3 m), with margin. Larger bodies get the same gap.
    min_distance_m: float = 1.5
    # Velocity obstacles are truncated here: a body that cannot be reached within this time is ignored. 2.5 s at
    # 4 m/s closing speed starts a manoeuvre 10 m out, leaving time for a velocity loop with a 0.3 s lag.
    horizon_s: float = 2.5
    # Inside min_distance the linear program asks for the separation to be restored within this time.
    recovery_time_s: float = 0.5
    max_correction_mps: float = 5.0  # |v_out - v_desired| horizontally; >= cruise speed, or head-on cannot stop
    max_speed_mps: float = 12.0  # horizontal output speed
    max_accel_mps2: float = 3.0  # braking the safety layer may count on
    # Bodies further than this above or below (and not converging vertically within the horizon) are ignored: two
    # drones 1 m apart vertically do not touch (contact is 0.7 m) and need not dodge horizontally.
    vertical_band_m: float = 1.0
    # Pass-on-the-right preference, which breaks exactly symmetric encounters: every constraint's half-plane is
    # tilted by this angle about its point so that passing an obstacle on the right costs less correction than
    # passing it on the left; 0 disables it (then an antipodal swap deadlocks, see docs/avoidance.md).
    pass_right_tilt_rad: float = 0.3
    # A tie between passing left and right (the relative velocity within this sine of the bearing) goes right.
    pass_right_tie_sin: float = 0.05
    # Only this many obstacles, the nearest by gap (centre distance less the separation to keep), are avoided, as
    # RVO2's maxNeighbors (10 in its examples) does: in a crowd, the constraints of bodies behind the nearest ring
    # are met by any velocity that meets the ring's, and without a bound the cost grows with the swarm (29
    # neighbours within reach each, on a 30-drone circle). 0 avoids every obstacle.
    max_obstacles: int = 10
    # Fusion.
    relay_max_age_s: float = 1.0  # older relayed positions are dropped: a neighbour may have turned since
    gate_m: float = 1.0  # association gate: gate_m + gate_range_frac * camera range
    gate_range_frac: float = 0.3
    camera_range_sigma_frac: float = 0.12  # 1-sigma camera range error, fraction of range
    relay_pos_sigma_m: float = 0.15  # 1-sigma relative position error of a fresh relayed report (two GPS)
    relay_age_sigma_mps: float = 1.5  # growth of that error per second of age (unknown acceleration, latency)


@dataclass(frozen=True, slots=True, kw_only=True)
class AvoidanceResult:
    """The velocity to fly and what shaped it.

    ``closest_m`` is the smallest centre distance (3-D) to any obstacle passed in (inf with none); ``constraining``
    counts the obstacles whose constraint the desired velocity violated, i.e. that forced a change.
    """

    vel_ned_mps: Vec3
    active: bool
    closest_m: float
    constraining: int


def config_row(config: AvoidanceConfig) -> npt.NDArray[np.float64]:
    """The configuration as the kernels take it (one float64 row)."""
    row = np.empty(ak.CONFIG_SIZE)
    row[ak.K_ENABLED] = 1.0 if config.enabled else 0.0
    row[ak.K_OWN_RADIUS] = config.own_radius_m
    row[ak.K_MIN_DIST] = config.min_distance_m
    row[ak.K_HORIZON] = config.horizon_s
    row[ak.K_RECOVERY] = config.recovery_time_s
    row[ak.K_MAX_CORR] = config.max_correction_mps
    row[ak.K_MAX_SPEED] = config.max_speed_mps
    row[ak.K_MAX_ACCEL] = config.max_accel_mps2
    row[ak.K_BAND] = config.vertical_band_m
    row[ak.K_TILT] = config.pass_right_tilt_rad
    row[ak.K_TIE] = config.pass_right_tie_sin
    row[ak.K_MAX_OBSTACLES] = config.max_obstacles
    row[ak.K_RELAY_MAX_AGE] = config.relay_max_age_s
    row[ak.K_GATE] = config.gate_m
    row[ak.K_GATE_FRAC] = config.gate_range_frac
    row[ak.K_CAM_SIGMA_FRAC] = config.camera_range_sigma_frac
    row[ak.K_RELAY_SIGMA] = config.relay_pos_sigma_m
    row[ak.K_RELAY_AGE_SIGMA] = config.relay_age_sigma_mps
    return row


def obstacle_rows(obstacles: Sequence[Obstacle]) -> npt.NDArray[np.float64]:
    """Obstacle records as the kernels take them, one row each."""
    rows = np.empty((len(obstacles), ak.OBSTACLE_SIZE))
    for row, ob in zip(rows, obstacles, strict=True):
        row[ak.O_POS : ak.O_POS + 3] = ob.rel_pos_ned_m
        row[ak.O_VEL : ak.O_VEL + 3] = ob.vel_ned_mps
        row[ak.O_VEL_KNOWN] = 1.0 if ob.vel_known else 0.0
        row[ak.O_RADIUS] = ob.radius_m
        row[ak.O_SOURCE] = _SOURCE_CODES[ob.source]
        row[ak.O_AGE] = ob.age_s
        row[ak.O_SYSID] = ob.sysid
    return rows


def obstacles_from_rows(rows: npt.NDArray[np.float64]) -> list[Obstacle]:
    """The records of obstacle rows (``obstacle_rows`` undone)."""
    return [
        new_obstacle(
            rel_pos_ned_m=(px, py, pz),
            vel_ned_mps=(vx, vy, vz),
            vel_known=known != 0.0,
            radius_m=radius,
            source=_SOURCES[source],
            age_s=age,
            sysid=int(sysid),
        )
        for px, py, pz, vx, vy, vz, known, radius, source, age, sysid in rows.tolist()
    ]


# ---------------------------------------------------------------------------------------------------------------------
# Fusion


def fuse(
    camera: Sequence[Obstacle],
    relay: Sequence[Obstacle],
    own_vel_ned_mps: Vec3,
    config: AvoidanceConfig,
) -> list[Obstacle]:
    """One obstacle list from camera detections and relayed neighbours, all brought up to now.

    Inputs: camera detections as ``Obstacle(source="camera")`` with the relative position measured ``age_s`` ago;
    relay entries as ``Obstacle(source="relay", vel_known=True)`` whose ``rel_pos_ned_m`` is the neighbour's reported
    position minus this drone's *current* position and ``age_s`` the report's age (``source="traffic"`` for a body
    that does not avoid in turn: it stays traffic, and fused with a detection "fused traffic", avoided in full).

    - Relay entries older than ``relay_max_age_s`` are dropped; the rest are moved forward by velocity x age.
    - A camera detection is moved by (obstacle - own velocity) x age; its obstacle velocity is zero until matched.
    - Each camera detection is matched to the nearest relay entry within a gate that grows with range (greedy,
      nearest pairs first, so the result does not depend on input order). A match keeps the camera's bearing (pixel
      accurate and fresh) and takes the inverse-variance mean of both ranges (camera error grows with range, relay
      error with age), with the relay's velocity: a fresh relay report dominates the range, a stale one yields to
      the camera.
    - Unmatched detections stay camera-only (relay cut or an unknown body); unmatched relay entries stay as relayed
      (the relay sees all around, the camera only ahead).
    """
    return fuse_fields(
        [(c.rel_pos_ned_m, c.radius_m, c.age_s) for c in camera],
        [(r.rel_pos_ned_m, r.vel_ned_mps, r.radius_m, r.age_s, r.source != "traffic", r.sysid) for r in relay],
        own_vel_ned_mps,
        config,
    )


# Camera detection for ``fuse_fields``: (relative position, radius, age); relay entry: (relative position, velocity,
# radius, age, whether it avoids in turn: a neighbour, not traffic; its sysid), each as ``Obstacle`` holds it.
CameraFields = tuple[Vec3, float, float]
RelayFields = tuple[Vec3, Vec3, float, float, bool, int]


def fuse_rows(
    camera: Sequence[CameraFields],
    relay: Sequence[RelayFields],
    own_vel_ned_mps: Vec3,
    config: npt.NDArray[np.float64],
) -> npt.NDArray[np.float64]:
    """``fuse`` on the obstacles' fields, to obstacle rows (``config`` as ``config_row`` gives it): what collision
    prevention runs at the avoidance rate, with no record built."""
    cams = np.array([(*pos, radius, age) for pos, radius, age in camera], dtype=np.float64).reshape(-1, ak.CAMERA_SIZE)
    rels = np.array([(*pos, *vel, radius, age, 1.0 if cooperative else 0.0, sysid)
                     for pos, vel, radius, age, cooperative, sysid in relay],
                    dtype=np.float64).reshape(-1, ak.RELAY_SIZE)  # fmt: skip
    out = np.empty((len(cams) + len(rels), ak.OBSTACLE_SIZE))
    own = np.array(own_vel_ned_mps, dtype=np.float64).reshape(3)
    return out[: ak.fuse(cams, rels, own, config, out)]


def fuse_fields(
    camera: Sequence[CameraFields], relay: Sequence[RelayFields], own_vel_ned_mps: Vec3, config: AvoidanceConfig
) -> list[Obstacle]:
    """``fuse`` on the obstacles' fields rather than on ``Obstacle`` records."""
    return obstacles_from_rows(fuse_rows(camera, relay, own_vel_ned_mps, config_row(config)))


# ---------------------------------------------------------------------------------------------------------------------
# Avoidance


def required_separation_m(radius_m: float, config: AvoidanceConfig) -> float:
    """Centre distance to keep from a body of this radius: min_distance for our own size, the same gap otherwise."""
    return ak.separation_m(radius_m, config_row(config))


def avoid(
    own_vel_ned_mps: Vec3,
    desired_vel_ned_mps: Vec3,
    obstacles: Sequence[Obstacle],
    config: AvoidanceConfig,
) -> AvoidanceResult:
    """The velocity closest to the desired one that keeps ``min_distance_m`` from every obstacle for ``horizon_s``.

    Horizontal only: the vertical component is passed through. Guarantees for finite input: horizontal output speed
    <= ``max_speed_mps`` and |output - desired| <= ``max_correction_mps`` horizontally, where desired is first limited
    to ``max_speed_mps``. A desired velocity with a NaN horizontal axis (acceleration control) is returned unchanged.
    Inputs beyond physical sense (NaN, or beyond MAX_REL_POS_M / MAX_SPEED_MPS) are corrupt data: such an obstacle is
    ignored, such an own velocity replaced by the desired one.

    Responsibility: an obstacle with a known velocity from the relay (alone or fused) is taken to be a neighbour
    running this same algorithm and gets the reciprocal half of each manoeuvre; anything else (unknown velocity, a
    camera track, traffic) is avoided in full, as if it would not move out of the way.
    """
    row = config_row(config)
    return avoid_prepared(own_vel_ned_mps, desired_vel_ned_mps, prepare_rows(obstacle_rows(obstacles), row), row)


@dataclass(frozen=True, slots=True)
class Prepared:
    """What ``avoid`` works out of its obstacles whatever the velocities: the closest centre distance, and each
    usable obstacle's row with its figures (``prepare_rows``), for ``avoid_prepared``. (Collision prevention's run does
    the same in its kernel, sitl/kernels/avoidance.py ``run``: it prepares once and asks ``avoid`` twice.)"""

    closest_m: float
    usable: npt.NDArray[np.float64]  # (n, USABLE_SIZE) of sitl/kernels/avoidance.py


def prepare_rows(obstacles: npt.NDArray[np.float64], config: npt.NDArray[np.float64]) -> Prepared:
    """The closest distance and the usable obstacles (those within physical sense) with the figures ``avoid`` needs of
    each, in input order."""
    usable = np.empty((len(obstacles), ak.USABLE_SIZE))
    count = np.zeros(1, np.int64)
    closest = ak.prepare(np.ascontiguousarray(obstacles), config, usable, count)
    return Prepared(closest_m=closest, usable=usable[: int(count[0])])


def prepare(obstacles: Sequence[Obstacle], config: AvoidanceConfig) -> Prepared:
    """``prepare_rows`` on obstacle records."""
    return prepare_rows(obstacle_rows(obstacles), config_row(config))


def avoid_prepared(
    own_vel_ned_mps: Vec3, desired_vel_ned_mps: Vec3, prepared: Prepared, config: npt.NDArray[np.float64]
) -> AvoidanceResult:
    """``avoid`` on obstacles already through ``prepare`` (``config`` as ``config_row`` gives it)."""
    closest = prepared.closest_m
    dvx, dvy, dvz = desired_vel_ned_mps
    if not (config[ak.K_ENABLED] != 0.0 and math.isfinite(dvx) and math.isfinite(dvy)):
        return AvoidanceResult(vel_ned_mps=desired_vel_ned_mps, active=False, closest_m=closest, constraining=0)
    ovx, ovy, ovz = own_vel_ned_mps
    vx, vy, active, constraining = ak.avoid(prepared.usable, len(prepared.usable), float(ovx), float(ovy),
                                            float(ovz), float(dvx), float(dvy), float(dvz), config)  # fmt: skip
    return AvoidanceResult(vel_ned_mps=(vx, vy, dvz), active=active, closest_m=closest, constraining=constraining)


@dataclass(frozen=True, slots=True, kw_only=True)
class Conflict:
    """Why a correction starts: the body predicted to come closer than its separation, and how close and when.

    ``sysid`` is the neighbour's (or traffic's) as the relay named it, 0 for a body only the camera knows;
    ``predicted_m`` the horizontal centre distance of the closest approach within the horizon, ``in_s`` the time until
    it (0: already inside), both for the velocity (current or desired) that brings it closer."""

    sysid: int
    source: ObstacleSource
    predicted_m: float
    in_s: float
    separation_m: float  # what is to be kept from it

    def describe(self) -> str:
        """The body as an avoidance event names it: "drone 3", "traffic 200", "a body seen by the camera"."""
        if self.source in ("relay", "fused"):
            return f"drone {self.sysid}"
        if self.source in ("traffic", "fused traffic"):
            return f"traffic {self.sysid}"
        return "a body seen by the camera"


def conflict_of(sysid: float, source: float, predicted_m: float, in_s: float, separation_m: float) -> Conflict:
    """The record of a conflict the kernels found: the body's relayed sysid, source code and separation (its usable
    row) and ``conflict``'s predicted distance and time."""
    return Conflict(sysid=int(sysid), source=_SOURCES[source], predicted_m=predicted_m, in_s=in_s,
                    separation_m=separation_m)  # fmt: skip
