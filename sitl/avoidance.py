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

Both functions are pure and allocate only a few small lists per call: plain float arithmetic, because numpy's call
overhead on 2-vectors would cost more than the algorithm itself. docs/avoidance.md has the algorithm, its limits and
measured figures.
"""

from __future__ import annotations

import heapq
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Final, Literal

import numpy as np

from sitl.mathutil import fast_constructor

Vec3 = tuple[float, float, float]
ObstacleSource = Literal["camera", "relay", "fused"]

_ZERO3: Final[Vec3] = (0.0, 0.0, 0.0)
_EPS: Final = 1e-9
# Bounds of physical sense for inputs (a relative position beyond 1000 km, a speed beyond 1 km/s, an age beyond
# 1000 s is corrupt data, not an obstacle); they keep every intermediate product finite.
MAX_REL_POS_M: Final = 1e6
MAX_SPEED_MPS: Final = 1e3
MAX_AGE_S: Final = 1e3


@dataclass(frozen=True, slots=True, kw_only=True)
class Obstacle:
    """One body to keep away from, relative to this drone, as ``avoid`` wants it.

    ``rel_pos_ned_m`` is the obstacle centre minus this drone's position. ``vel_ned_mps`` is the obstacle's absolute
    velocity, meaningful only when ``vel_known`` (camera detections carry none). ``age_s`` is how old the position is:
    ``fuse`` uses it to bring a report up to now, ``avoid`` only reports it.
    """

    rel_pos_ned_m: Vec3
    vel_ned_mps: Vec3 = _ZERO3
    vel_known: bool = False
    radius_m: float = 0.35
    source: ObstacleSource = "camera"
    age_s: float = 0.0


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


def _finite3(v: Sequence[float]) -> bool:
    return len(v) == 3 and math.isfinite(v[0]) and math.isfinite(v[1]) and math.isfinite(v[2])


def _within3(v: Sequence[float], limit: float) -> bool:
    """All three components in [-limit, limit] (false for NaN): inputs beyond physical sense are ignored, so no
    intermediate product can overflow."""
    return len(v) == 3 and -limit <= v[0] <= limit and -limit <= v[1] <= limit and -limit <= v[2] <= limit


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
    position minus this drone's *current* position and ``age_s`` the report's age.

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
        [(r.rel_pos_ned_m, r.vel_ned_mps, r.radius_m, r.age_s) for r in relay],
        own_vel_ned_mps,
        config,
    )


# Camera detection for ``fuse_fields``: (relative position, radius, age); relay entry: (relative position, velocity,
# radius, age), each as ``Obstacle`` holds it.
CameraFields = tuple[Vec3, float, float]
RelayFields = tuple[Vec3, Vec3, float, float]
# From this many camera-relay pairs on, the association gate is checked for all pairs at once with numpy (the same
# element-wise float operations in the same order, so the same figures to the last bit); below it a Python loop is
# cheaper than building the arrays. A 50-drone circle has some 14 of each within camera and relay range.
VECTOR_PAIRS = 48


def fuse_fields(
    camera: Sequence[CameraFields],
    relay: Sequence[RelayFields],
    own_vel_ned_mps: Vec3,
    config: AvoidanceConfig,
    *,
    vector_pairs: int = VECTOR_PAIRS,
) -> list[Obstacle]:
    """``fuse`` on the obstacles' fields rather than on ``Obstacle`` records: collision prevention builds its inputs
    at the avoidance rate for every neighbour, and a record per input that fusion only takes apart again cost more
    than fusion itself in a crowd. ``vector_pairs`` is exposed so tests can hold both association paths to one
    result."""
    own_vx, own_vy, own_vz = own_vel_ned_mps if _within3(own_vel_ned_mps, MAX_SPEED_MPS) else _ZERO3
    max_age = config.relay_max_age_s
    relays: list[Obstacle] = []
    for pos, vel, radius, age in relay:
        if not (age <= max_age and _within3(pos, MAX_REL_POS_M) and _within3(vel, MAX_SPEED_MPS)):
            continue
        age = max(0.0, age)
        (px, py, pz), (vx, vy, vz) = pos, vel
        relays.append(
            new_obstacle(
                rel_pos_ned_m=(px + vx * age, py + vy * age, pz + vz * age),
                vel_ned_mps=vel,
                vel_known=True,
                radius_m=radius,
                source="relay",
                age_s=age,
            )
        )
    cams = [c for c in camera if _within3(c[0], MAX_REL_POS_M) and c[2] <= MAX_AGE_S]

    cam_match: dict[int, int] = {}
    if cams and relays:
        relay_positions = [r.rel_pos_ned_m for r in relays]
        # Each detection where it is now on the static guess (the relay velocity also moves it once matched), and
        # the square of its gate.
        moved: list[tuple[float, float, float, float]] = []
        gate_m, gate_frac = config.gate_m, config.gate_range_frac
        for (cx, cy, cz), _radius, age in cams:
            age = max(0.0, age)
            cx, cy, cz = cx - own_vx * age, cy - own_vy * age, cz - own_vz * age
            gate = gate_m + gate_frac * math.sqrt(cx * cx + cy * cy + cz * cz)
            moved.append((cx, cy, cz, gate * gate))
        if len(cams) * len(relays) >= vector_pairs:
            candidates = _gate_pairs_numpy(moved, relay_positions)  # sorted
        else:
            candidates = []
            for ci, (cx, cy, cz, gate_sq) in enumerate(moved):
                for ri, (rx, ry, rz) in enumerate(relay_positions):
                    dx, dy, dz = rx - cx, ry - cy, rz - cz
                    d_sq = dx * dx + dy * dy + dz * dz
                    if d_sq <= gate_sq:  # a square root only for the few within the gate
                        candidates.append((math.sqrt(d_sq), ci, ri))
            candidates.sort()
        used_relay: set[int] = set()
        pairs = min(len(cams), len(relays))
        for _, ci, ri in candidates:
            if ci not in cam_match and ri not in used_relay:
                cam_match[ci] = ri
                used_relay.add(ri)
                if len(cam_match) == pairs:
                    break  # every detection or every entry is taken: no later pair can be

    out: list[Obstacle] = []
    for ci, c in enumerate(cams):
        age = max(0.0, c[2])
        ri_match = cam_match.get(ci)
        if ri_match is None:
            cx, cy, cz = c[0]
            out.append(
                new_obstacle(
                    rel_pos_ned_m=(cx - own_vx * age, cy - own_vy * age, cz - own_vz * age),
                    radius_m=c[1],
                    source="camera",
                    age_s=age,
                )
            )
            continue
        out.append(_fuse_pair(c[0], c[1], relays[ri_match], age, (own_vx, own_vy, own_vz), config))
    if cam_match:
        matched = set(cam_match.values())
        out.extend(r for ri, r in enumerate(relays) if ri not in matched)
    else:
        out.extend(relays)
    return out


def _gate_pairs_numpy(
    moved: list[tuple[float, float, float, float]], relay_positions: list[Vec3]
) -> list[tuple[float, int, int]]:
    """(distance, camera index, relay index) of every pair within the camera's gate, sorted as the tuples sort: the
    loop of ``fuse_fields`` as array operations (a difference, three products and two sums per pair, each rounded as
    the loop rounds it, and a correctly rounded square root)."""
    cam = np.array(moved)
    rel = np.array(relay_positions)
    dx = rel[:, 0] - cam[:, 0:1]
    dy = rel[:, 1] - cam[:, 1:2]
    dz = rel[:, 2] - cam[:, 2:3]
    d_sq = dx * dx + dy * dy + dz * dz
    ci, ri = np.nonzero(d_sq <= cam[:, 3:4])
    dist = np.sqrt(d_sq[ci, ri])  # correctly rounded, as math.sqrt
    order = np.lexsort((ri, ci, dist))  # the order of sorted (distance, camera, relay) tuples
    return list(zip(dist[order].tolist(), ci[order].tolist(), ri[order].tolist(), strict=True))


def _fuse_pair(cam_pos: Vec3, cam_radius_m: float, rel: Obstacle, cam_age_s: float, own_vel: Vec3,
               config: AvoidanceConfig) -> Obstacle:  # fmt: skip
    """Camera bearing with the inverse-variance mean of camera and relay range, relay velocity."""
    vx, vy, vz = rel.vel_ned_mps
    cx, cy, cz = cam_pos
    cx += (vx - own_vel[0]) * cam_age_s
    cy += (vy - own_vel[1]) * cam_age_s
    cz += (vz - own_vel[2]) * cam_age_s
    cam_range = math.sqrt(cx * cx + cy * cy + cz * cz)
    rx, ry, rz = rel.rel_pos_ned_m
    relay_range = math.sqrt(rx * rx + ry * ry + rz * rz)
    if cam_range < _EPS:
        pos = rel.rel_pos_ned_m
    else:
        var_cam = max(config.camera_range_sigma_frac * cam_range, 0.01) ** 2
        var_relay = max(config.relay_pos_sigma_m + config.relay_age_sigma_mps * rel.age_s, 0.01) ** 2
        rng = (cam_range / var_cam + relay_range / var_relay) / (1.0 / var_cam + 1.0 / var_relay)
        k = rng / cam_range
        pos = (cx * k, cy * k, cz * k)
    return new_obstacle(
        rel_pos_ned_m=pos,
        vel_ned_mps=rel.vel_ned_mps,
        vel_known=True,
        radius_m=max(cam_radius_m, rel.radius_m),
        source="fused",
        age_s=cam_age_s,
    )


# ---------------------------------------------------------------------------------------------------------------------
# ORCA linear programs (after RVO2's Agent.cpp). A line is (point x, point y, direction x, direction y); the permitted
# half-plane lies to the left of the direction, i.e. det(direction, point - v) <= 0.


def _lp1(
    lines: list[tuple[float, float, float, float]],
    n: int,
    radius: float,
    opt_x: float,
    opt_y: float,
    direction_opt: bool,
) -> tuple[float, float] | None:
    """Best point on line n within the disk and lines 0..n-1, or None when there is none."""
    px, py, dx, dy = lines[n]
    dot = px * dx + py * dy
    disc = dot * dot + radius * radius - (px * px + py * py)
    if disc < 0.0:
        return None
    sq = math.sqrt(disc)
    t_left = -dot - sq
    t_right = -dot + sq
    for i in range(n):
        qx, qy, ex, ey = lines[i]
        denom = dx * ey - dy * ex
        numer = ex * (py - qy) - ey * (px - qx)
        if abs(denom) <= 1e-6:
            if numer < 0.0:
                return None
            continue
        t = numer / denom
        if denom >= 0.0:
            t_right = min(t_right, t)
        else:
            t_left = max(t_left, t)
        if t_left > t_right:
            return None
    if direction_opt:
        t = t_right if opt_x * dx + opt_y * dy > 0.0 else t_left
    else:
        t = dx * (opt_x - px) + dy * (opt_y - py)
        t = t_left if t < t_left else (t_right if t > t_right else t)
    return px + t * dx, py + t * dy


def _lp2(
    lines: list[tuple[float, float, float, float]],
    radius: float,
    opt_x: float,
    opt_y: float,
    direction_opt: bool,
) -> tuple[int, float, float]:
    """(index of the first line that cannot be met or len(lines), result x, result y)."""
    if direction_opt:
        rx, ry = opt_x * radius, opt_y * radius
    else:
        norm_sq = opt_x * opt_x + opt_y * opt_y
        if norm_sq > radius * radius:
            s = radius / math.sqrt(norm_sq)
            rx, ry = opt_x * s, opt_y * s
        else:
            rx, ry = opt_x, opt_y
    for i, (px, py, dx, dy) in enumerate(lines):
        if dx * (py - ry) - dy * (px - rx) > 0.0:
            res = _lp1(lines, i, radius, opt_x, opt_y, direction_opt)
            if res is None:
                return i, rx, ry
            rx, ry = res
    return len(lines), rx, ry


def _lp3(
    lines: list[tuple[float, float, float, float]], begin: int, radius: float, rx: float, ry: float
) -> tuple[float, float]:
    """The velocity that minimises the largest violation of any line (all lines are soft: no static polygons)."""
    distance = 0.0
    for i in range(begin, len(lines)):
        px, py, dx, dy = lines[i]
        if dx * (py - ry) - dy * (px - rx) <= distance:
            continue
        proj: list[tuple[float, float, float, float]] = []
        for j in range(i):
            qx, qy, ex, ey = lines[j]
            determinant = dx * ey - dy * ex
            if abs(determinant) <= 1e-6:
                if dx * ex + dy * ey > 0.0:
                    continue
                lx, ly = 0.5 * (px + qx), 0.5 * (py + qy)
            else:
                s = (ex * (py - qy) - ey * (px - qx)) / determinant
                lx, ly = px + s * dx, py + s * dy
            nx, ny = ex - dx, ey - dy
            norm = math.sqrt(nx * nx + ny * ny)
            if norm < _EPS:
                continue
            proj.append((lx, ly, nx / norm, ny / norm))
        fail, tx, ty = _lp2(proj, radius, -dy, dx, True)
        if fail >= len(proj):
            rx, ry = tx, ty
        distance = dx * (py - ry) - dy * (px - rx)
    return rx, ry


# ---------------------------------------------------------------------------------------------------------------------
# Avoidance


def required_separation_m(radius_m: float, config: AvoidanceConfig) -> float:
    """Centre distance to keep from a body of this radius: min_distance for our own size, the same gap otherwise."""
    return max(config.own_radius_m + radius_m, config.min_distance_m + radius_m - config.own_radius_m)


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

    Responsibility: an obstacle with a known velocity that is not camera-only is taken to be a neighbour running
    this same algorithm and gets the reciprocal half of each manoeuvre; anything else (unknown velocity, or a
    camera track) is avoided in full, as if it would not move out of the way.
    """
    return avoid_prepared(own_vel_ned_mps, desired_vel_ned_mps, prepare(obstacles, config), config)


@dataclass(frozen=True, slots=True)
class Prepared:
    """What ``avoid`` works out of its obstacles whatever the velocities: the closest centre distance, and each
    usable obstacle with its figures (``prepare``). Collision prevention asks ``avoid`` twice about the same
    obstacles (the position loop's demand, then the mission's pace), and prepares them once."""

    closest_m: float
    # (obstacle, rel z, obstacle vz, separation to keep, horizontal distance squared, gap, obstacle horizontal speed)
    usable: list[tuple[Obstacle, float, float, float, float, float, float]]


def prepare(obstacles: Sequence[Obstacle], config: AvoidanceConfig) -> Prepared:
    """The closest distance and the usable obstacles (those within physical sense) with the figures ``avoid`` needs of
    each, in input order."""
    closest = math.inf
    usable: list[tuple[Obstacle, float, float, float, float, float, float]] = []
    for ob in obstacles:
        p = ob.rel_pos_ned_m
        if _finite3(p):
            closest = min(closest, math.sqrt(p[0] * p[0] + p[1] * p[1] + p[2] * p[2]))
        if not _within3(p, MAX_REL_POS_M):
            continue
        if ob.vel_known and not _within3(ob.vel_ned_mps, MAX_SPEED_MPS):
            continue
        px, py, pz = p
        bvx, bvy, bvz = ob.vel_ned_mps if ob.vel_known else _ZERO3
        radius = min(ob.radius_m, MAX_REL_POS_M) if ob.radius_m > 0.0 else 0.0  # NaN compares false: 0
        r = required_separation_m(radius, config)
        dist_sq = px * px + py * py
        usable.append((ob, pz, bvz, r, dist_sq, math.sqrt(dist_sq) - r, math.sqrt(bvx * bvx + bvy * bvy)))
    return Prepared(closest_m=closest, usable=usable)


def avoid_prepared(
    own_vel_ned_mps: Vec3, desired_vel_ned_mps: Vec3, prepared: Prepared, config: AvoidanceConfig
) -> AvoidanceResult:
    """``avoid`` on obstacles already through ``prepare`` (with the same config)."""
    closest = prepared.closest_m
    dvx, dvy, dvz = desired_vel_ned_mps
    if not (config.enabled and math.isfinite(dvx) and math.isfinite(dvy)):
        return AvoidanceResult(vel_ned_mps=desired_vel_ned_mps, active=False, closest_m=closest, constraining=0)

    vmax = max(0.0, config.max_speed_mps)
    cap = max(0.0, config.max_correction_mps)
    des_speed = math.hypot(dvx, dvy)
    if des_speed > vmax:
        dvx, dvy = dvx / des_speed * vmax, dvy / des_speed * vmax
        des_speed = vmax
    ovx, ovy, ovz = own_vel_ned_mps
    if not (-MAX_SPEED_MPS <= ovx <= MAX_SPEED_MPS and -MAX_SPEED_MPS <= ovy <= MAX_SPEED_MPS):
        ovx, ovy = dvx, dvy
    if not -MAX_SPEED_MPS <= ovz <= MAX_SPEED_MPS:
        ovz = dvz if -MAX_SPEED_MPS <= dvz <= MAX_SPEED_MPS else 0.0

    tau = max(config.horizon_s, 1e-3)
    inv_tau = 1.0 / tau
    inv_rec = 1.0 / max(config.recovery_time_s, 1e-3)
    tie = config.pass_right_tie_sin
    cos_r, sin_r = math.cos(config.pass_right_tilt_rad), math.sin(config.pass_right_tilt_rad)
    reach_speed = des_speed + cap

    lines: list[tuple[float, float, float, float]] = []
    # (nx, ny, distance, required separation, obstacle vx, vy, responsibility) for the safety layer.
    near: list[tuple[float, float, float, float, float, float, float]] = []
    constraining = 0
    for ob, r, dist_sq in _in_reach(prepared, ovz, tau, reach_speed, config):
        px, py, _pz = ob.rel_pos_ned_m
        bvx, bvy, _bvz = ob.vel_ned_mps if ob.vel_known else _ZERO3
        dist = math.sqrt(dist_sq)
        resp = 0.5 if (ob.vel_known and ob.source != "camera") else 1.0
        if dist < 1e-6:
            # Coincident centres: no bearing to go by; take the obstacle as straight ahead of the desired heading
            # (or north when hovering), so the drone backs off deterministically.
            ux, uy = (dvx / des_speed, dvy / des_speed) if des_speed > _EPS else (1.0, 0.0)
            px, py, dist, dist_sq = ux * 1e-6, uy * 1e-6, 1e-6, 1e-12
        rvx, rvy = ovx - bvx, ovy - bvy  # our velocity relative to the obstacle
        r_sq = r * r
        if dist_sq > r_sq:
            wx, wy = rvx - inv_tau * px, rvy - inv_tau * py
            w_len_sq = wx * wx + wy * wy
            dot1 = wx * px + wy * py
            if dot1 < 0.0 and dot1 * dot1 > r_sq * w_len_sq:
                # Closest boundary point is on the cut-off circle (the horizon end of the cone).
                w_len = math.sqrt(w_len_sq)
                uwx, uwy = wx / w_len, wy / w_len
                ldx, ldy = uwy, -uwx
                k = r * inv_tau - w_len
                ux, uy = k * uwx, k * uwy
            else:
                leg = math.sqrt(dist_sq - r_sq)
                det_pw = px * wy - py * wx
                # det > 0: relative velocity right of the bearing (NED), pass with the obstacle on our left.
                if det_pw > -tie * dist * math.sqrt(w_len_sq):
                    ldx, ldy = (px * leg - py * r) / dist_sq, (px * r + py * leg) / dist_sq
                else:
                    ldx, ldy = -(px * leg + py * r) / dist_sq, -(-px * r + py * leg) / dist_sq
                dot2 = rvx * ldx + rvy * ldy
                ux, uy = dot2 * ldx - rvx, dot2 * ldy - rvy
        else:
            # Already too close: the cut-off circle of the recovery time, i.e. separation restored within it.
            wx, wy = rvx - inv_rec * px, rvy - inv_rec * py
            w_len = math.sqrt(wx * wx + wy * wy)
            if w_len < _EPS:
                uwx, uwy = -px / dist, -py / dist
                w_len = 0.0
            else:
                uwx, uwy = wx / w_len, wy / w_len
            ldx, ldy = uwy, -uwx
            k = r * inv_rec - w_len
            ux, uy = k * uwx, k * uwy
        lpx, lpy = ovx + resp * ux - dvx, ovy + resp * uy - dvy  # line point relative to the desired velocity
        # Tilt the half-plane about its point, from north towards west: passing right of the obstacle gets cheaper.
        ldx, ldy = ldx * cos_r + ldy * sin_r, ldy * cos_r - ldx * sin_r
        lines.append((lpx, lpy, ldx, ldy))
        if ldx * lpy - ldy * lpx > 1e-9:
            constraining += 1
        near.append((px / dist, py / dist, dist, r, bvx, bvy, resp))

    if not lines:
        out = (dvx, dvy, desired_vel_ned_mps[2])
        return AvoidanceResult(vel_ned_mps=out, active=False, closest_m=closest, constraining=0)

    # Linear program in coordinates centred on the desired velocity, over the disk of the correction cap.
    fail, cx, cy = _lp2(lines, cap, 0.0, 0.0, False)
    if fail < len(lines):
        cx, cy = _lp3(lines, fail, cap, cx, cy)
    vx, vy = dvx + cx, dvy + cy

    vx, vy, braked = _safety_layer(vx, vy, near, config)
    constraining = max(constraining, braked)
    vx, vy = _limit(dvx, dvy, vx, vy, cap, vmax)
    active = (vx - dvx) ** 2 + (vy - dvy) ** 2 > 1e-12
    return AvoidanceResult(
        vel_ned_mps=(vx, vy, desired_vel_ned_mps[2]), active=active, closest_m=closest, constraining=constraining
    )


def _in_reach(
    prepared: Prepared, own_vz: float, tau: float, reach_speed: float, config: AvoidanceConfig
) -> list[tuple[Obstacle, float, float]]:
    """(obstacle, separation to keep, horizontal distance squared) of every usable obstacle that can be reached
    within the horizon, at most ``config.max_obstacles`` of them, the nearest by gap; in input order."""
    band = config.vertical_band_m
    found: list[tuple[float, int, Obstacle, float, float]] = []
    for ob, pz, bvz, r, dist_sq, gap, b_speed in prepared.usable:
        if abs(pz) > band:
            pz_end = pz + (bvz - own_vz) * tau
            if pz * pz_end > 0.0 and abs(pz_end) > band:
                continue
        if gap > tau * (reach_speed + b_speed):
            continue  # out of reach within the horizon whatever either does
        found.append((gap, len(found), ob, r, dist_sq))
    if 0 < config.max_obstacles < len(found):
        found = sorted(heapq.nsmallest(config.max_obstacles, found), key=lambda item: item[1])
    return [(ob, r, dist_sq) for _, _, ob, r, dist_sq in found]


def _safety_layer(
    vx: float, vy: float, near: list[tuple[float, float, float, float, float, float, float]], config: AvoidanceConfig
) -> tuple[float, float, int]:
    """Hard limit on the speed of approach to each obstacle, whatever the linear program had to give up.

    Outside the separation r the closing speed (relative to the obstacle) may not exceed what braking at
    ``max_accel_mps2`` cancels before r (a reciprocal neighbour brakes too, so its share doubles the distance); inside
    r the drone must open the distance at its share of (r - d) / recovery time. The excess over each limit is removed
    along that obstacle's direction, all computed from the same input and summed, so two obstacles pulling opposite
    ways (a drone squeezed between two) cancel rather than the last one winning.
    """
    acc = max(config.max_accel_mps2, 0.0)
    inv_rec = 1.0 / max(config.recovery_time_s, 1e-3)
    push_x = push_y = 0.0
    touched = 0
    for nx, ny, dist, r, bvx, bvy, resp in near:
        gap = dist - r
        limit = math.sqrt(2.0 * acc * gap / resp) if gap >= 0.0 else resp * gap * inv_rec
        excess = (vx - bvx) * nx + (vy - bvy) * ny - limit
        if excess > 1e-9:
            push_x -= excess * nx
            push_y -= excess * ny
            touched += 1
    return vx + push_x, vy + push_y, touched


def _limit(dvx: float, dvy: float, vx: float, vy: float, cap: float, vmax: float) -> tuple[float, float]:
    """Pull v back towards the (speed-limited) desired velocity until it is inside both the cap and speed disks.

    Both disks contain the desired velocity and are convex, so the largest fraction of the way from desired to v
    that stays in both is inside their intersection.
    """
    ex, ey = vx - dvx, vy - dvy
    e_sq = ex * ex + ey * ey
    if e_sq <= 0.0:
        return vx, vy
    t = 1.0
    if e_sq > cap * cap:
        t = cap / math.sqrt(e_sq)
    # |d + t e| = vmax: the positive root of e^2 t^2 + 2 (d.e) t + d^2 - vmax^2 = 0.
    wx, wy = dvx + t * ex, dvy + t * ey
    if wx * wx + wy * wy > vmax * vmax:
        de = dvx * ex + dvy * ey
        c = min(dvx * dvx + dvy * dvy - vmax * vmax, 0.0)  # desired is inside (or, by rounding, on) the circle
        t = min(t, max(0.0, (-de + math.sqrt(de * de - e_sq * c)) / e_sq))
    out_x, out_y = dvx + t * ex, dvy + t * ey
    # Rounding can leave the speed a hair above the limit; never report more than promised.
    sp_sq = out_x * out_x + out_y * out_y
    if sp_sq > vmax * vmax:
        s = vmax / math.sqrt(sp_sq)
        out_x, out_y = out_x * s, out_y * s
    return out_x, out_y
