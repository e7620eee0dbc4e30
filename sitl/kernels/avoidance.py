"""Collision prevention's numeric core as kernels: fusion of camera and relay, the obstacles' figures, and ORCA's
linear programs with the safety layer (sitl/avoidance/algorithm.py is the shell: configuration, records, the documented
functions; docs/avoidance.md has the algorithm).

An obstacle is a row of ``OBSTACLE_SIZE`` float64 (relative position, velocity, whether the velocity is known, radius,
source, age, and the sysid the relay named it by: 0 for a body only the camera knows); a prepared obstacle adds the
figures ``avoid`` needs whatever the velocities. Python's ``min``/``max`` are spelled out (``pymath.pmin``/``pmax``: the
first argument unless the second is strictly beyond it), and every sum is in the Python's order, so the kernels give the
bits the Python form gave.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from sitl.kernels import cascade as ck
from sitl.kernels import kernel
from sitl.kernels.pymath import hypot2, pmax, pmin, py_square

EPS = 1e-9
# Bounds of physical sense for inputs (a relative position beyond 1000 km, a speed beyond 1 km/s, an age beyond
# 1000 s is corrupt data, not an obstacle); they keep every intermediate product finite.
MAX_REL_POS_M = 1e6
MAX_SPEED_MPS = 1e3
MAX_AGE_S = 1e3

# Obstacle row.
O_POS = 0
O_VEL = 3
O_VEL_KNOWN = 6
O_RADIUS = 7
O_SOURCE = 8
O_AGE = 9
O_SYSID = 10  # read by no arithmetic: it names the body a correction was for
OBSTACLE_SIZE = 11
SOURCE_CAMERA = 0.0
SOURCE_RELAY = 1.0
SOURCE_FUSED = 2.0
# Traffic: a relayed body that does not avoid in turn (an intruder, reported as ADSB_VEHICLE), alone or fused with
# a camera detection. Avoided in full, as a camera track is, but with its velocity known.
SOURCE_TRAFFIC = 3.0
SOURCE_FUSED_TRAFFIC = 4.0
# A prepared obstacle: its row, then the separation to keep, horizontal distance squared, gap, horizontal speed.
U_SEPARATION = OBSTACLE_SIZE
U_DIST_SQ = OBSTACLE_SIZE + 1
U_GAP = OBSTACLE_SIZE + 2
U_SPEED = OBSTACLE_SIZE + 3
USABLE_SIZE = OBSTACLE_SIZE + 4
# Fusion's inputs: a camera detection (relative position, radius, age) and a relay entry (relative position,
# velocity, radius, age, 1 when the body avoids in turn: a swarm neighbour, 0 for traffic; and its sysid).
CAMERA_SIZE = 5
RELAY_SIZE = 10
R_COOPERATIVE = 8
R_SYSID = 9

# A relayed neighbour as collision prevention holds it, in this drone's local frame (sitl/drone/awareness.py converts
# each report once): position, velocity, when the position was true, how old the sender's own knowledge of it was
# (traffic's tslc), 1 for a swarm neighbour (0 for traffic), and its sysid. ``relay_inputs`` turns these into
# fusion's relay entries at the avoidance rate.
N_POS = 0
N_VEL = 3
N_RECEIVED = 6
N_STALE = 7
N_COOPERATIVE = 8
N_SYSID = 9
NEIGHBOUR_SIZE = 10

# Configuration row (sitl.avoidance.algorithm.AvoidanceConfig).
K_ENABLED = 0
K_OWN_RADIUS = 1
K_MIN_DIST = 2
K_HORIZON = 3
K_RECOVERY = 4
K_MAX_CORR = 5
K_MAX_SPEED = 6
K_MAX_ACCEL = 7
K_BAND = 8
K_TILT = 9
K_TIE = 10
K_MAX_OBSTACLES = 11
K_RELAY_MAX_AGE = 12
K_GATE = 13
K_GATE_FRAC = 14
K_CAM_SIGMA_FRAC = 15
K_RELAY_SIGMA = 16
K_RELAY_AGE_SIGMA = 17
CONFIG_SIZE = 18


@kernel("boolean(float64, float64, float64, float64)")
def within3(x: float, y: float, z: float, limit: float) -> bool:
    """All three components in [-limit, limit] (false for NaN)."""
    return -limit <= x <= limit and -limit <= y <= limit and -limit <= z <= limit


@kernel("float64(float64, float64[::1])")
def separation_m(radius_m: float, cfg: npt.NDArray[np.float64]) -> float:
    """Centre distance to keep from a body of this radius: min_distance for our own size, the same gap otherwise."""
    own = cfg[K_OWN_RADIUS]
    return pmax(own + radius_m, cfg[K_MIN_DIST] + radius_m - own)


@kernel("void(float64[::1], float64[::1], float64, float64, float64, float64, float64[::1], float64[::1])")
def _fuse_pair(
    cam: npt.NDArray[np.float64],
    rel: npt.NDArray[np.float64],
    cam_age_s: float,
    own_vx: float,
    own_vy: float,
    own_vz: float,
    cfg: npt.NDArray[np.float64],
    out: npt.NDArray[np.float64],
) -> None:
    """Camera bearing with the inverse-variance mean of camera and relay range, relay velocity."""
    vx, vy, vz = rel[O_VEL], rel[O_VEL + 1], rel[O_VEL + 2]
    cx, cy, cz = cam[0], cam[1], cam[2]
    cx += (vx - own_vx) * cam_age_s
    cy += (vy - own_vy) * cam_age_s
    cz += (vz - own_vz) * cam_age_s
    cam_range = math.sqrt(cx * cx + cy * cy + cz * cz)
    rx, ry, rz = rel[O_POS], rel[O_POS + 1], rel[O_POS + 2]
    relay_range = math.sqrt(rx * rx + ry * ry + rz * rz)
    if cam_range < EPS:
        out[O_POS], out[O_POS + 1], out[O_POS + 2] = rx, ry, rz
    else:
        var_cam = py_square(pmax(cfg[K_CAM_SIGMA_FRAC] * cam_range, 0.01))
        var_relay = py_square(pmax(cfg[K_RELAY_SIGMA] + cfg[K_RELAY_AGE_SIGMA] * rel[O_AGE], 0.01))
        rng = (cam_range / var_cam + relay_range / var_relay) / (1.0 / var_cam + 1.0 / var_relay)
        k = rng / cam_range
        out[O_POS], out[O_POS + 1], out[O_POS + 2] = cx * k, cy * k, cz * k
    out[O_VEL], out[O_VEL + 1], out[O_VEL + 2] = vx, vy, vz
    out[O_VEL_KNOWN] = 1.0
    out[O_RADIUS] = pmax(cam[3], rel[O_RADIUS])
    out[O_SOURCE] = SOURCE_FUSED if rel[O_SOURCE] == SOURCE_RELAY else SOURCE_FUSED_TRAFFIC
    out[O_AGE] = cam_age_s
    out[O_SYSID] = rel[O_SYSID]


@kernel("int64(float64[:, ::1], float64, float64, float64, float64, float64, float64, float64, int64, float64[:, ::1])")
def relay_inputs(
    neighbours: npt.NDArray[np.float64],
    x: float,
    y: float,
    z: float,
    now_s: float,
    radius_m: float,
    stale_rate_mps: float,
    stale_max_m: float,
    keep: int,
    out: npt.NDArray[np.float64],
) -> int:
    """Fusion's relay entries (``RELAY_SIZE`` rows, written to ``out``) from neighbour rows (``NEIGHBOUR_SIZE``), for
    a drone at (x, y, z) at ``now_s``; returns how many. With more than ``keep`` neighbours (``keep`` > 0) only the
    ``keep`` nearest by reported position are kept, nearest first and in their given order on a tie, as
    ``heapq.nsmallest`` keeps them; otherwise all, in their given order. A report's age is how long ago its position
    was true (never negative); a body known only from a stale report (``N_STALE`` > 0) is given a radius grown by
    ``stale_rate_mps`` for every second its knowledge is old, at most ``stale_max_m`` more."""
    n = neighbours.shape[0]
    order = np.arange(n)
    if 0 < keep < n:
        key = np.empty(n)
        for i in range(n):
            key[i] = (
                py_square(neighbours[i, N_POS] - x)
                + py_square(neighbours[i, N_POS + 1] - y)
                + py_square(neighbours[i, N_POS + 2] - z)
            )
        order = np.argsort(key, kind="mergesort")[:keep]
    for j in range(order.shape[0]):
        nb = neighbours[order[j]]
        row = out[j]
        age = pmax(0.0, now_s - nb[N_RECEIVED])
        stale = nb[N_STALE]
        row[0], row[1], row[2] = nb[N_POS] - x, nb[N_POS + 1] - y, nb[N_POS + 2] - z
        row[3], row[4], row[5] = nb[N_VEL], nb[N_VEL + 1], nb[N_VEL + 2]
        row[6] = radius_m if stale <= 0.0 else radius_m + pmin(stale_rate_mps * (stale + age), stale_max_m)
        row[7] = age
        row[R_COOPERATIVE] = nb[N_COOPERATIVE]
        row[R_SYSID] = nb[N_SYSID]
    return order.shape[0]


@kernel("int64(float64[:, ::1], float64[:, ::1], float64[::1], float64[::1], float64[:, ::1])")
def fuse(
    camera: npt.NDArray[np.float64],
    relay: npt.NDArray[np.float64],
    own_vel: npt.NDArray[np.float64],
    cfg: npt.NDArray[np.float64],
    out: npt.NDArray[np.float64],
) -> int:
    """One obstacle list from camera detections and relayed neighbours, all brought up to now, written to ``out``
    (room for every input); returns how many rows it wrote. See ``sitl.avoidance.algorithm.fuse`` for the rules."""
    if within3(own_vel[0], own_vel[1], own_vel[2], MAX_SPEED_MPS):
        own_vx, own_vy, own_vz = own_vel[0], own_vel[1], own_vel[2]
    else:
        own_vx, own_vy, own_vz = 0.0, 0.0, 0.0
    max_age = cfg[K_RELAY_MAX_AGE]
    relays = np.empty((relay.shape[0], OBSTACLE_SIZE))
    n_rel = 0
    for i in range(relay.shape[0]):
        px, py, pz = relay[i, 0], relay[i, 1], relay[i, 2]
        vx, vy, vz = relay[i, 3], relay[i, 4], relay[i, 5]
        age = relay[i, 7]
        if not (age <= max_age and within3(px, py, pz, MAX_REL_POS_M) and within3(vx, vy, vz, MAX_SPEED_MPS)):
            continue
        age = pmax(0.0, age)
        row = relays[n_rel]
        row[O_POS], row[O_POS + 1], row[O_POS + 2] = px + vx * age, py + vy * age, pz + vz * age
        row[O_VEL], row[O_VEL + 1], row[O_VEL + 2] = vx, vy, vz
        row[O_VEL_KNOWN] = 1.0
        row[O_RADIUS] = relay[i, 6]
        row[O_SOURCE] = SOURCE_RELAY if relay[i, R_COOPERATIVE] != 0.0 else SOURCE_TRAFFIC
        row[O_AGE] = age
        row[O_SYSID] = relay[i, R_SYSID]
        n_rel += 1
    cams = np.empty(camera.shape[0], np.int64)
    n_cam = 0
    for i in range(camera.shape[0]):
        if within3(camera[i, 0], camera[i, 1], camera[i, 2], MAX_REL_POS_M) and camera[i, 4] <= MAX_AGE_S:
            cams[n_cam] = i
            n_cam += 1

    cam_match = np.full(n_cam, -1, np.int64)
    matches = 0
    if n_cam > 0 and n_rel > 0:
        # Each detection where it is now on the static guess (the relay velocity also moves it once matched), and the
        # square of its gate; then every pair within its gate, nearest first (ties in camera, then relay order, as
        # sorted tuples of (distance, camera, relay) would go), matched greedily.
        gate_m, gate_frac = cfg[K_GATE], cfg[K_GATE_FRAC]
        dist = np.empty(n_cam * n_rel)
        pair_cam = np.empty(n_cam * n_rel, np.int64)
        pair_rel = np.empty(n_cam * n_rel, np.int64)
        n_pairs = 0
        for ci in range(n_cam):
            c = camera[cams[ci]]
            age = pmax(0.0, c[4])
            cx, cy, cz = c[0] - own_vx * age, c[1] - own_vy * age, c[2] - own_vz * age
            gate = gate_m + gate_frac * math.sqrt(cx * cx + cy * cy + cz * cz)
            gate_sq = gate * gate
            for ri in range(n_rel):
                dx, dy, dz = relays[ri, 0] - cx, relays[ri, 1] - cy, relays[ri, 2] - cz
                d_sq = dx * dx + dy * dy + dz * dz
                if d_sq <= gate_sq:
                    dist[n_pairs] = math.sqrt(d_sq)
                    pair_cam[n_pairs] = ci
                    pair_rel[n_pairs] = ri
                    n_pairs += 1
        order = np.argsort(dist[:n_pairs], kind="mergesort")
        used_relay = np.zeros(n_rel, np.bool_)
        pairs = min(n_cam, n_rel)
        for k in range(n_pairs):
            ci, ri = pair_cam[order[k]], pair_rel[order[k]]
            if cam_match[ci] < 0 and not used_relay[ri]:
                cam_match[ci] = ri
                used_relay[ri] = True
                matches += 1
                if matches == pairs:
                    break

    n_out = 0
    for ci in range(n_cam):
        c = camera[cams[ci]]
        age = pmax(0.0, c[4])
        row = out[n_out]
        ri = cam_match[ci]
        if ri < 0:
            row[O_POS], row[O_POS + 1], row[O_POS + 2] = c[0] - own_vx * age, c[1] - own_vy * age, c[2] - own_vz * age
            row[O_VEL], row[O_VEL + 1], row[O_VEL + 2] = 0.0, 0.0, 0.0
            row[O_VEL_KNOWN] = 0.0
            row[O_RADIUS] = c[3]
            row[O_SOURCE] = SOURCE_CAMERA
            row[O_AGE] = age
            row[O_SYSID] = 0.0
        else:
            _fuse_pair(c, relays[ri], age, own_vx, own_vy, own_vz, cfg, row)
        n_out += 1
    for ri in range(n_rel):
        matched = False
        for ci in range(n_cam):
            if cam_match[ci] == ri:
                matched = True
                break
        if not matched:
            out[n_out, :] = relays[ri]
            n_out += 1
    return n_out


@kernel("float64(float64[:, ::1], float64[::1], float64[:, ::1], int64[::1])")
def prepare(
    obstacles: npt.NDArray[np.float64],
    cfg: npt.NDArray[np.float64],
    usable: npt.NDArray[np.float64],
    count: npt.NDArray[np.int64],
) -> float:
    """The closest centre distance of the obstacles (inf with none); the usable ones (within physical sense) with the
    figures ``avoid`` needs, in input order, in ``usable`` (``count[0]`` of them)."""
    closest = math.inf
    n = 0
    for i in range(obstacles.shape[0]):
        ob = obstacles[i]
        px, py, pz = ob[O_POS], ob[O_POS + 1], ob[O_POS + 2]
        if math.isfinite(px) and math.isfinite(py) and math.isfinite(pz):
            closest = pmin(closest, math.sqrt(px * px + py * py + pz * pz))
        if not within3(px, py, pz, MAX_REL_POS_M):
            continue
        known = ob[O_VEL_KNOWN] != 0.0
        if known and not within3(ob[O_VEL], ob[O_VEL + 1], ob[O_VEL + 2], MAX_SPEED_MPS):
            continue
        if known:
            bvx, bvy = ob[O_VEL], ob[O_VEL + 1]
        else:
            bvx, bvy = 0.0, 0.0
        radius = pmin(ob[O_RADIUS], MAX_REL_POS_M) if ob[O_RADIUS] > 0.0 else 0.0  # NaN compares false: 0
        r = separation_m(radius, cfg)
        dist_sq = px * px + py * py
        row = usable[n]
        row[:OBSTACLE_SIZE] = ob
        row[U_SEPARATION] = r
        row[U_DIST_SQ] = dist_sq
        row[U_GAP] = math.sqrt(dist_sq) - r
        row[U_SPEED] = math.sqrt(bvx * bvx + bvy * bvy)
        n += 1
    count[0] = n
    return closest


@kernel("boolean(float64[::1], float64, float64, float64)")
def _apart_vertically(u: npt.NDArray[np.float64], own_vz: float, tau: float, band: float) -> bool:
    """A usable obstacle outside the vertical band that does not converge into it within the horizon."""
    pz = u[O_POS + 2]
    if abs(pz) <= band:
        return False
    bvz = u[O_VEL + 2] if u[O_VEL_KNOWN] != 0.0 else 0.0
    pz_end = pz + (bvz - own_vz) * tau
    return pz * pz_end > 0.0 and abs(pz_end) > band


@kernel("UniTuple(float64, 3)(float64, float64, float64, float64, float64, float64)")
def _own_velocity(
    own_vx: float, own_vy: float, own_vz: float, dvx: float, dvy: float, dvz: float
) -> tuple[float, float, float]:
    """This drone's velocity as avoidance takes it: beyond physical sense, the desired one horizontally, and
    vertically the desired one (or 0 if that too is beyond sense)."""
    ovx, ovy, ovz = own_vx, own_vy, own_vz
    if not (-MAX_SPEED_MPS <= ovx <= MAX_SPEED_MPS and -MAX_SPEED_MPS <= ovy <= MAX_SPEED_MPS):
        ovx, ovy = dvx, dvy
    if not -MAX_SPEED_MPS <= ovz <= MAX_SPEED_MPS:
        ovz = dvz if -MAX_SPEED_MPS <= dvz <= MAX_SPEED_MPS else 0.0
    return ovx, ovy, ovz


@kernel("int64(float64[:, ::1], int64, float64, float64, float64, float64, float64, float64[::1], float64[::1])")
def conflict(
    usable: npt.NDArray[np.float64],
    count: int,
    own_vx: float,
    own_vy: float,
    own_vz: float,
    dvx: float,
    dvy: float,
    cfg: npt.NDArray[np.float64],
    found: npt.NDArray[np.float64],
) -> int:
    """The usable obstacle most in conflict, or -1 with none: an obstacle (within the vertical band, or converging into
    it) in conflict is closer than its separation now, or comes closer within the horizon if it keeps its velocity
    (none when unknown) and this drone flies its current or its desired horizontal velocity. The one whose predicted
    closest approach is smallest (the first on a tie); ``found`` gets that distance (horizontal, centre to centre) and
    the time until it (0: now). The own velocity is taken as ``avoid`` takes it (the desired one beyond sense)."""
    own_vx, own_vy, own_vz = _own_velocity(own_vx, own_vy, own_vz, dvx, dvy, 0.0)
    tau = pmax(cfg[K_HORIZON], 1e-3)
    band = cfg[K_BAND]
    best = -1
    best_d_sq = math.inf
    best_t = 0.0
    for i in range(count):
        u = usable[i]
        if _apart_vertically(u, own_vz, tau, band):
            continue
        px, py = u[O_POS], u[O_POS + 1]
        known = u[O_VEL_KNOWN] != 0.0
        bvx = u[O_VEL] if known else 0.0
        bvy = u[O_VEL + 1] if known else 0.0
        r_sq = u[U_SEPARATION] * u[U_SEPARATION]
        if u[U_DIST_SQ] <= r_sq and u[U_DIST_SQ] < best_d_sq:
            best, best_d_sq, best_t = i, u[U_DIST_SQ], 0.0
        for k in range(2):
            vx = own_vx if k == 0 else dvx
            vy = own_vy if k == 0 else dvy
            wx, wy = vx - bvx, vy - bvy
            ww = wx * wx + wy * wy
            if ww > 0.0:
                t = (px * wx + py * wy) / ww
                t = 0.0 if t < 0.0 else (tau if t > tau else t)
                ex, ey = px - wx * t, py - wy * t
                e_sq = ex * ex + ey * ey
                if e_sq < r_sq and e_sq < best_d_sq:
                    best, best_d_sq, best_t = i, e_sq, t
    if best >= 0:
        found[0] = math.sqrt(best_d_sq)
        found[1] = best_t
    return best


# ORCA linear programs (after RVO2's Agent.cpp). A line is a row (point x, point y, direction x, direction y); the
# permitted half-plane lies to the left of the direction, i.e. det(direction, point - v) <= 0.


@kernel("Tuple((boolean, float64, float64))(float64[:, ::1], int64, float64, float64, float64, boolean)")
def _lp1(
    lines: npt.NDArray[np.float64], n: int, radius: float, opt_x: float, opt_y: float, direction_opt: bool
) -> tuple[bool, float, float]:
    """Best point on line n within the disk and lines 0..n-1, or (False, ...) when there is none."""
    px, py, dx, dy = lines[n, 0], lines[n, 1], lines[n, 2], lines[n, 3]
    dot = px * dx + py * dy
    disc = dot * dot + radius * radius - (px * px + py * py)
    if disc < 0.0:
        return False, 0.0, 0.0
    sq = math.sqrt(disc)
    t_left = -dot - sq
    t_right = -dot + sq
    for i in range(n):
        qx, qy, ex, ey = lines[i, 0], lines[i, 1], lines[i, 2], lines[i, 3]
        denom = dx * ey - dy * ex
        numer = ex * (py - qy) - ey * (px - qx)
        if abs(denom) <= 1e-6:
            if numer < 0.0:
                return False, 0.0, 0.0
            continue
        t = numer / denom
        if denom >= 0.0:
            t_right = pmin(t_right, t)
        else:
            t_left = pmax(t_left, t)
        if t_left > t_right:
            return False, 0.0, 0.0
    if direction_opt:
        t = t_right if opt_x * dx + opt_y * dy > 0.0 else t_left
    else:
        t = dx * (opt_x - px) + dy * (opt_y - py)
        t = t_left if t < t_left else (t_right if t > t_right else t)
    return True, px + t * dx, py + t * dy


@kernel("Tuple((int64, float64, float64))(float64[:, ::1], int64, float64, float64, float64, boolean)")
def _lp2(
    lines: npt.NDArray[np.float64], count: int, radius: float, opt_x: float, opt_y: float, direction_opt: bool
) -> tuple[int, float, float]:
    """(index of the first of the first ``count`` lines that cannot be met, or ``count``; result x, result y)."""
    if direction_opt:
        rx, ry = opt_x * radius, opt_y * radius
    else:
        norm_sq = opt_x * opt_x + opt_y * opt_y
        if norm_sq > radius * radius:
            s = radius / math.sqrt(norm_sq)
            rx, ry = opt_x * s, opt_y * s
        else:
            rx, ry = opt_x, opt_y
    for i in range(count):
        px, py, dx, dy = lines[i, 0], lines[i, 1], lines[i, 2], lines[i, 3]
        if dx * (py - ry) - dy * (px - rx) > 0.0:
            ok, tx, ty = _lp1(lines, i, radius, opt_x, opt_y, direction_opt)
            if not ok:
                return i, rx, ry
            rx, ry = tx, ty
    return count, rx, ry


@kernel("UniTuple(float64, 2)(float64[:, ::1], int64, int64, float64, float64, float64)")
def _lp3(
    lines: npt.NDArray[np.float64], count: int, begin: int, radius: float, rx: float, ry: float
) -> tuple[float, float]:
    """The velocity that minimises the largest violation of any line (all lines are soft: no static polygons)."""
    distance = 0.0
    proj = np.empty((count, 4))
    for i in range(begin, count):
        px, py, dx, dy = lines[i, 0], lines[i, 1], lines[i, 2], lines[i, 3]
        if dx * (py - ry) - dy * (px - rx) <= distance:
            continue
        n_proj = 0
        for j in range(i):
            qx, qy, ex, ey = lines[j, 0], lines[j, 1], lines[j, 2], lines[j, 3]
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
            if norm < EPS:
                continue
            proj[n_proj, 0], proj[n_proj, 1], proj[n_proj, 2], proj[n_proj, 3] = lx, ly, nx / norm, ny / norm
            n_proj += 1
        fail, tx, ty = _lp2(proj, n_proj, radius, -dy, dx, True)
        if fail >= n_proj:
            rx, ry = tx, ty
        distance = dx * (py - ry) - dy * (px - rx)
    return rx, ry


@kernel("int64(float64[:, ::1], int64, float64, float64, float64, float64[::1], int64[::1])")
def _in_reach(
    usable: npt.NDArray[np.float64],
    count: int,
    own_vz: float,
    tau: float,
    reach_speed: float,
    cfg: npt.NDArray[np.float64],
    chosen: npt.NDArray[np.int64],
) -> int:
    """Indices (into ``usable``) of every usable obstacle that can be reached within the horizon, at most
    ``K_MAX_OBSTACLES`` of them, the nearest by gap (ties: the earlier), in input order; returns how many."""
    band = cfg[K_BAND]
    gaps = np.empty(count)
    n = 0
    for i in range(count):
        u = usable[i]
        if _apart_vertically(u, own_vz, tau, band):
            continue
        if u[U_GAP] > tau * (reach_speed + u[U_SPEED]):
            continue  # out of reach within the horizon whatever either does
        chosen[n] = i
        gaps[n] = u[U_GAP]
        n += 1
    limit = int(cfg[K_MAX_OBSTACLES])
    if 0 < limit < n:
        nearest = np.sort(np.argsort(gaps[:n], kind="mergesort")[:limit])
        kept = chosen[:n][nearest]
        chosen[:limit] = kept
        n = limit
    return n


@kernel("Tuple((float64, float64, int64))(float64, float64, float64[:, ::1], int64, float64[::1])")
def _safety_layer(
    vx: float, vy: float, near: npt.NDArray[np.float64], count: int, cfg: npt.NDArray[np.float64]
) -> tuple[float, float, int]:
    """Hard limit on the speed of approach to each obstacle, whatever the linear program had to give up (rows of
    ``near``: bearing x, y, distance, separation, obstacle vx, vy, responsibility); see ``sitl.avoidance.algorithm``."""
    acc = pmax(cfg[K_MAX_ACCEL], 0.0)
    inv_rec = 1.0 / pmax(cfg[K_RECOVERY], 1e-3)
    push_x = 0.0
    push_y = 0.0
    touched = 0
    for i in range(count):
        nx, ny, dist, r = near[i, 0], near[i, 1], near[i, 2], near[i, 3]
        bvx, bvy, resp = near[i, 4], near[i, 5], near[i, 6]
        gap = dist - r
        limit = math.sqrt(2.0 * acc * gap / resp) if gap >= 0.0 else resp * gap * inv_rec
        excess = (vx - bvx) * nx + (vy - bvy) * ny - limit
        if excess > 1e-9:
            push_x -= excess * nx
            push_y -= excess * ny
            touched += 1
    return vx + push_x, vy + push_y, touched


@kernel("UniTuple(float64, 2)(float64, float64, float64, float64, float64, float64)")
def _limit(dvx: float, dvy: float, vx: float, vy: float, cap: float, vmax: float) -> tuple[float, float]:
    """Pull v back towards the (speed-limited) desired velocity until it is inside both the cap and speed disks."""
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
        c = pmin(dvx * dvx + dvy * dvy - vmax * vmax, 0.0)  # desired is inside (or, by rounding, on) the circle
        t = pmin(t, pmax(0.0, (-de + math.sqrt(de * de - e_sq * c)) / e_sq))
    out_x, out_y = dvx + t * ex, dvy + t * ey
    # Rounding can leave the speed a hair above the limit; never report more than promised.
    sp_sq = out_x * out_x + out_y * out_y
    if sp_sq > vmax * vmax:
        s = vmax / math.sqrt(sp_sq)
        out_x, out_y = out_x * s, out_y * s
    return out_x, out_y


@kernel(
    "Tuple((float64, float64, boolean, int64))"
    "(float64[:, ::1], int64, float64, float64, float64, float64, float64, float64, float64[::1])"
)
def avoid(
    usable: npt.NDArray[np.float64],
    count: int,
    own_vx: float,
    own_vy: float,
    own_vz: float,
    dvx: float,
    dvy: float,
    dvz: float,
    cfg: npt.NDArray[np.float64],
) -> tuple[float, float, bool, int]:
    """ORCA on prepared obstacles for a finite desired horizontal velocity (avoidance enabled): the horizontal
    velocity to fly, whether it differs from the desired one, and how many obstacles forced a change. See
    ``sitl.avoidance.algorithm.avoid`` for the guarantees and the responsibility rule."""
    vmax = pmax(0.0, cfg[K_MAX_SPEED])
    cap = pmax(0.0, cfg[K_MAX_CORR])
    des_speed = hypot2(dvx, dvy)
    if des_speed > vmax:
        dvx, dvy = dvx / des_speed * vmax, dvy / des_speed * vmax
        des_speed = vmax
    ovx, ovy, ovz = _own_velocity(own_vx, own_vy, own_vz, dvx, dvy, dvz)

    tau = pmax(cfg[K_HORIZON], 1e-3)
    inv_tau = 1.0 / tau
    inv_rec = 1.0 / pmax(cfg[K_RECOVERY], 1e-3)
    tie = cfg[K_TIE]
    cos_r, sin_r = math.cos(cfg[K_TILT]), math.sin(cfg[K_TILT])
    reach_speed = des_speed + cap

    chosen = np.empty(count, np.int64)
    n = _in_reach(usable, count, ovz, tau, reach_speed, cfg, chosen)
    lines = np.empty((n, 4))
    near = np.empty((n, 7))
    constraining = 0
    for k in range(n):
        ob = usable[chosen[k]]
        r = ob[U_SEPARATION]
        dist_sq = ob[U_DIST_SQ]
        px, py = ob[O_POS], ob[O_POS + 1]
        known = ob[O_VEL_KNOWN] != 0.0
        if known:
            bvx, bvy = ob[O_VEL], ob[O_VEL + 1]
        else:
            bvx, bvy = 0.0, 0.0
        dist = math.sqrt(dist_sq)
        source = ob[O_SOURCE]
        resp = 0.5 if (known and (source == SOURCE_RELAY or source == SOURCE_FUSED)) else 1.0  # noqa: SIM109
        if dist < 1e-6:
            # Coincident centres: no bearing to go by; take the obstacle as straight ahead of the desired heading
            # (or north when hovering), so the drone backs off deterministically.
            if des_speed > EPS:
                ux, uy = dvx / des_speed, dvy / des_speed
            else:
                ux, uy = 1.0, 0.0
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
                kk = r * inv_tau - w_len
                ux, uy = kk * uwx, kk * uwy
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
            if w_len < EPS:
                uwx, uwy = -px / dist, -py / dist
                w_len = 0.0
            else:
                uwx, uwy = wx / w_len, wy / w_len
            ldx, ldy = uwy, -uwx
            kk = r * inv_rec - w_len
            ux, uy = kk * uwx, kk * uwy
        lpx, lpy = ovx + resp * ux - dvx, ovy + resp * uy - dvy  # line point relative to the desired velocity
        # Tilt the half-plane about its point, from north towards west: passing right of the obstacle gets cheaper.
        ldx, ldy = ldx * cos_r + ldy * sin_r, ldy * cos_r - ldx * sin_r
        lines[k, 0], lines[k, 1], lines[k, 2], lines[k, 3] = lpx, lpy, ldx, ldy
        if ldx * lpy - ldy * lpx > 1e-9:
            constraining += 1
        near[k, 0], near[k, 1], near[k, 2], near[k, 3] = px / dist, py / dist, dist, r
        near[k, 4], near[k, 5], near[k, 6] = bvx, bvy, resp

    if n == 0:
        return dvx, dvy, False, 0

    # Linear program in coordinates centred on the desired velocity, over the disk of the correction cap.
    fail, cx, cy = _lp2(lines, n, cap, 0.0, 0.0, False)
    if fail < n:
        cx, cy = _lp3(lines, n, fail, cap, cx, cy)
    vx, vy = dvx + cx, dvy + cy

    vx, vy, braked = _safety_layer(vx, vy, near, n, cfg)
    constraining = max(constraining, braked)
    vx, vy = _limit(dvx, dvy, vx, vy, cap, vmax)
    active = py_square(vx - dvx) + py_square(vy - dvy) > 1e-12
    return vx, vy, active, constraining


# What ``run`` writes: whether a correction applies, the horizontal velocity to fly, the closest centre distance of all
# obstacles, and, when it found the conflict that starts a correction, that body (``conflict``'s figures).
RUN_ACTIVE = 0
RUN_VEL = 1
RUN_CLOSEST = 3
RUN_CONFLICT = 4  # 1.0: ``RUN_SYSID``..``RUN_SEPARATION`` describe it
RUN_SYSID = 5
RUN_SOURCE = 6
RUN_PREDICTED = 7
RUN_IN_S = 8
RUN_SEPARATION = 9
RUN_SIZE = 10

# The slowest pace a correction aims for (``run``: the position loop's demand capped at the setpoint's own speed).
MIN_PREFERRED_SPEED_MPS = 1.0


@kernel(
    "int64(float64, float64, float64, float64, float64, float64, float64[:, ::1], float64, float64[:, ::1], float64,"
    " float64, float64, float64, int64, float64[::1], float64[:, ::1])"
)
def obstacles(
    x: float,
    y: float,
    z: float,
    own_vx: float,
    own_vy: float,
    own_vz: float,
    camera: npt.NDArray[np.float64],
    camera_age_s: float,
    neighbours: npt.NDArray[np.float64],
    now_s: float,
    radius_m: float,
    stale_rate_mps: float,
    stale_max_m: float,
    keep: int,
    cfg: npt.NDArray[np.float64],
    out: npt.NDArray[np.float64],
) -> int:
    """The obstacles of a drone at (x, y, z) flying (own_vx, own_vy, own_vz) at ``now_s``, written to ``out`` (room for
    every camera row and neighbour): the camera rows, each aged by ``camera_age_s`` more, fused with the relayed
    neighbours (``relay_inputs``, then ``fuse``); returns how many."""
    aged = camera.copy()
    for i in range(aged.shape[0]):
        aged[i, 4] += camera_age_s
    relay = np.empty((neighbours.shape[0], RELAY_SIZE))
    n_relay = relay_inputs(neighbours, x, y, z, now_s, radius_m, stale_rate_mps, stale_max_m, keep, relay)
    own = np.empty(3)
    own[0], own[1], own[2] = own_vx, own_vy, own_vz
    return fuse(aged, relay[:n_relay], own, cfg, out)


@kernel(
    "void(float64, float64, float64, float64, float64, float64, float64, float64, float64, float64, float64, float64,"
    " float64[::1], float64[:, ::1], float64, float64[:, ::1], float64, float64, float64, float64, int64,"
    " float64[::1], boolean, float64[::1])"
)
def run(
    x: float,
    y: float,
    z: float,
    own_vx: float,
    own_vy: float,
    own_vz: float,
    sp_x: float,
    sp_y: float,
    sp_z: float,
    ff_x: float,
    ff_y: float,
    ff_z: float,
    position_cfg: npt.NDArray[np.float64],
    camera: npt.NDArray[np.float64],
    camera_age_s: float,
    neighbours: npt.NDArray[np.float64],
    now_s: float,
    radius_m: float,
    stale_rate_mps: float,
    stale_max_m: float,
    keep: int,
    cfg: npt.NDArray[np.float64],
    correcting: bool,
    out: npt.NDArray[np.float64],
) -> None:
    """One run of collision prevention (sitl/avoidance/collision_prevention.py ``CollisionPrevention``) for a drone at
    (x, y, z) flying (own_vx, own_vy, own_vz) towards a setpoint's position ``sp_*`` and velocity ``ff_*``, written to
    ``out`` (``RUN_*``). The velocity the position loop would ask for; the obstacles (``obstacles``, ``prepare``); ORCA
    on that demand
    (``avoid``). A correction starts only for a conflict (``conflict``, looked for when not ``correcting``); once it
    applies, ORCA is asked again for the demand capped at the setpoint's own horizontal speed (at least
    ``MIN_PREFERRED_SPEED_MPS``): a drone fallen behind a moving setpoint asks for the mission's pace, not a sprint
    into the crowd."""
    dvx, dvy, dvz = ck.position_velocity_sp(position_cfg, x, y, z, sp_x, sp_y, sp_z, ff_x, ff_y, ff_z)
    found_obstacles = np.empty((camera.shape[0] + neighbours.shape[0], OBSTACLE_SIZE))
    n = obstacles(x, y, z, own_vx, own_vy, own_vz, camera, camera_age_s, neighbours, now_s, radius_m, stale_rate_mps,
                  stale_max_m, keep, cfg, found_obstacles)  # fmt: skip
    usable = np.empty((n, USABLE_SIZE))
    count = np.zeros(1, np.int64)
    closest = prepare(found_obstacles[:n], cfg, usable, count)
    out[RUN_CLOSEST] = closest
    out[RUN_ACTIVE] = 0.0
    out[RUN_CONFLICT] = 0.0
    enabled = cfg[K_ENABLED] != 0.0
    if not (enabled and math.isfinite(dvx) and math.isfinite(dvy)):
        return
    k = count[0]
    vx, vy, active, _ = avoid(usable, k, own_vx, own_vy, own_vz, dvx, dvy, dvz, cfg)
    if active and not correcting:
        found = np.zeros(2)
        index = conflict(usable, k, own_vx, own_vy, own_vz, dvx, dvy, cfg, found)
        if index < 0:
            return
        row = usable[index]
        out[RUN_CONFLICT] = 1.0
        out[RUN_SYSID] = row[O_SYSID]
        out[RUN_SOURCE] = row[O_SOURCE]
        out[RUN_PREDICTED] = found[0]
        out[RUN_IN_S] = found[1]
        out[RUN_SEPARATION] = row[U_SEPARATION]
    if not active:
        return
    # The pace to aim for: the demand, no faster horizontally than the setpoint moves (finite: checked above).
    ff_speed = hypot2(ff_x, ff_y) if math.isfinite(ff_x) and math.isfinite(ff_y) else 0.0
    cap = pmax(ff_speed, MIN_PREFERRED_SPEED_MPS)
    speed = hypot2(dvx, dvy)
    if speed > cap:
        px, py = dvx * cap / speed, dvy * cap / speed
        if px != dvx or py != dvy:
            vx, vy, _, _ = avoid(usable, k, own_vx, own_vy, own_vz, px, py, dvz, cfg)
    out[RUN_ACTIVE] = 1.0
    out[RUN_VEL], out[RUN_VEL + 1] = vx, vy
