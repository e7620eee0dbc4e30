"""Swarm behaviours besides fixed formations: leader-follower and Reynolds flocking (pure: time and state come in).

Both are laws run by the ground station each tick (gcs/command/streamer.py calls them at 20 Hz and does the MAVLink).
They read only what the drones *report*: each drone's telemetry as the fleet view holds it, mapped into the swarm frame
(``SwarmState``), never simulation truth. So they see what they would see with real vehicles: position reports at
10 Hz, up to a report period old, with the estimator's noise. Outputs are ``gcs.flight.formation.Setpoint`` in the swarm
frame; a NaN component is not commanded (the streamer sets the matching SET_POSITION_TARGET_LOCAL_NED ignore bit).

Leader-follower (``LeaderFollower``)
    The leader flies a reference path (``LeaderPath``) from where it is through waypoints at a cruise speed, corners
    rounded so that its course turns continuously. Each follower holds a fixed offset (forward, right) in the
    leader's *heading frame*: its slot is the leader's reported position plus the offset rotated by the heading,
    with the leader's reported velocity (plus the slot's rotation) as velocity feed-forward. The heading follows the
    course of the leader's reported velocity through a first-order filter whose rate is limited (``turn_towards``):
    the course of a hovering or braking drone is noise, and a turn of the whole formation moves a slot ``r`` metres
    from the leader at ``r`` times the turn rate. Rotating all offsets about the leader is a rigid motion, so no two
    slots come closer than the offsets are. Before the leader leaves, the followers join their slots on a
    synchronised transition of the formation engine (gcs/flight/formation.py), so nobody jumps at a slot metres away.

Flocking (``Flock``)
    Reynolds' steering behaviours: each drone's steering acceleration is a weighted sum of separation (away from
    neighbours closer than the separation radius, growing without bound as the distance shrinks), alignment
    (towards the mean velocity of its neighbours), cohesion (towards their centroid) and migration (the local
    centroid towards the current migration point). Separation comes first in the acceleration budget: the other
    terms get what it leaves, and once it asks for the whole budget (closer than 2/3 of the separation radius with
    the default weights) it gets all of it. A pair closing in is seen closer by what it would close in a look-ahead
    time, so that it starts braking while there is room (the velocity loop lags too). The commanded velocity
    integrates the steering acceleration and is limited to the maximum speed; horizontal motion is commanded by that
    velocity (with the acceleration as feed-forward), altitude by a position setpoint. Neighbours are the drones
    within the neighbour radius (horizontal distance: the flock flies at one altitude).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Final, Protocol

import numpy as np
import numpy.typing as npt

from gcs.flight.arrays import mat_mul
from gcs.flight.assignment import assign_min_squared_distance
from gcs.flight.formation import (
    FormationEngine,
    FormationError,
    Setpoint,
    SpecFieldError,
    TransitionLimits,
    VSpec,
    check_finite,
    check_positive,
    not_a_sysid,
)
from gcs.flight.frames import Vec3
from gcs.flight.geodesy import wrap_pi

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]

NAN3: Final = (math.nan, math.nan, math.nan)
MAX_TICK_S: Final = 0.5  # a longer gap between ticks (a stalled loop) is integrated as this long, not as a jump
COURSE_MIN_SPEED_MPS: Final = 0.3  # below this the leader's course is estimator noise: the heading is held
HEADING_TIME_CONSTANT_S: Final = 0.5  # the followers' heading frame follows the leader's course with this lag
JOIN_CLEARANCE_M: Final = 1.5  # followers joining their slots keep at least this far from the hovering leader
JOIN_SETTLE_S: Final = 1.0  # the leader leaves this long after the followers reached their slots
ARRIVAL_TOLERANCE_M: Final = 0.5  # the leader has reached its last waypoint when its report is this close
_PATH_STEP_M: Final = 0.05  # arc-length sampling of the leader's path (chord error on a 3 m arc: 0.1 mm)
_MIN_LEG_M: Final = 0.01  # waypoints closer than this to the previous point are dropped
_STRAIGHT_RAD: Final = 1e-3  # corners flatter than this get no arc
_JOIN_SAMPLE_S: Final = 0.1


class Behaviour(Protocol):
    """A swarm law the streamer runs each tick in place of the formation engine."""

    def setpoints(self, now_s: float, state: SwarmState) -> dict[int, Setpoint]:
        """Every commanded drone's setpoint at ``now_s``, from the drones' reported state."""
        ...

    def targets(self) -> dict[int, Vec3]:
        """Each drone's slot as of the last ``setpoints`` call (empty for a behaviour without slots)."""
        ...


@dataclass(frozen=True, slots=True, kw_only=True, eq=False)
class SwarmState:
    """The drones' reported positions and velocities in the swarm frame, one row per sysid (in ``sysids`` order)."""

    sysids: tuple[int, ...]
    pos_ned_m: FloatArray  # (n, 3)
    vel_ned_mps: FloatArray  # (n, 3)
    _rows: dict[int, int] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        n = len(self.sysids)
        if self.pos_ned_m.shape != (n, 3) or self.vel_ned_mps.shape != (n, 3):
            raise FormationError(f"SwarmState needs ({n}, 3) positions and velocities")
        object.__setattr__(self, "_rows", {sysid: k for k, sysid in enumerate(self.sysids)})

    @classmethod
    def from_mappings(cls, pos_ned_m: Mapping[int, Vec3], vel_ned_mps: Mapping[int, Vec3]) -> SwarmState:
        """Drones with both a position and a velocity, in sysid order."""
        ids = tuple(sorted(set(pos_ned_m) & set(vel_ned_mps)))
        pos = np.array([pos_ned_m[i] for i in ids], dtype=np.float64).reshape(-1, 3)
        vel = np.array([vel_ned_mps[i] for i in ids], dtype=np.float64).reshape(-1, 3)
        return cls(sysids=ids, pos_ned_m=pos, vel_ned_mps=vel)

    def row(self, sysid: int) -> int | None:
        """The row of ``sysid``, None if it has no report."""
        return self._rows.get(sysid)


def _check_points(owner: object, name: str, points: Sequence[tuple[float, float]]) -> None:
    for point in points:
        if len(point) != 2 or not all(math.isfinite(v) for v in point):
            raise SpecFieldError(owner, name, f"must hold (north, east) pairs, got {point}")


def limit_norm(vectors: FloatArray, max_norm: float) -> FloatArray:
    """Rows of ``vectors`` scaled down to at most ``max_norm`` (direction kept)."""
    norm = np.linalg.norm(vectors, axis=-1, keepdims=True)
    scale = np.minimum(1.0, max_norm / np.maximum(norm, 1e-12))
    return np.asarray(vectors * scale, dtype=np.float64)


def priority_sum(priority: FloatArray, extra: FloatArray, max_norm: float) -> FloatArray:
    """``priority + s * extra`` per row with the largest s in [0, 1] that keeps the norm within ``max_norm``.

    A priority vector longer than ``max_norm`` is scaled down to it and the extra dropped: whatever the extra
    terms want, they never eat into the priority term (PX4's ``constrainXY`` gives the position error priority
    over feed-forward the same way).
    """
    p2 = np.einsum("ij,ij->i", priority, priority)
    e2 = np.einsum("ij,ij->i", extra, extra)
    pe = np.einsum("ij,ij->i", priority, extra)
    m2 = max_norm * max_norm
    # |p + s e|^2 = m^2: the positive root (p2 < m2 makes the constant term negative, so the root is real)
    disc = np.maximum(pe * pe - e2 * (p2 - m2), 0.0)
    s = np.divide(-pe + np.sqrt(disc), e2, out=np.ones_like(e2), where=e2 > 1e-18)
    s = np.where(p2 >= m2, 0.0, np.clip(s, 0.0, 1.0))
    return limit_norm(priority + s[:, None] * extra, max_norm)


# ------------------------------------------------------------------------------------------------------- flocking


@dataclass(frozen=True, slots=True, kw_only=True)
class FlockSpec:
    """Reynolds flocking at a fixed altitude, towards migration points visited in turn.

    The flock moves on to the next migration point when its centroid is within ``arrival_radius_m`` of the current
    one, and stays at the last. Within that radius of the current point the migration speed tapers linearly to
    zero, so the flock comes to rest at the last point instead of orbiting it. No migration point: the flock only
    keeps together (and aligns).
    """

    alt_m: float
    migration_ne_m: tuple[tuple[float, float], ...] = ()
    max_speed_mps: float = 1.5
    max_accel_mps2: float = 1.5
    neighbour_radius_m: float = 6.0
    separation_radius_m: float = 2.5
    separation_weight_mps2: float = 3.0  # acceleration per unit of (radius / distance - 1), summed over neighbours
    separation_lookahead_s: float = 1.0  # distances shrink by this much of the closing speed (see separation_term)
    alignment_weight_per_s: float = 1.0  # acceleration per m/s of difference from the neighbours' mean velocity
    cohesion_weight_per_s2: float = 0.05  # acceleration per metre to the neighbours' centroid
    migration_weight_per_s: float = 0.8  # acceleration per m/s of difference from the migration velocity
    arrival_radius_m: float = 3.0

    def __post_init__(self) -> None:
        check_finite(
            self,
            alt_m=self.alt_m,
            max_speed_mps=self.max_speed_mps,
            max_accel_mps2=self.max_accel_mps2,
            neighbour_radius_m=self.neighbour_radius_m,
            separation_radius_m=self.separation_radius_m,
            separation_weight_mps2=self.separation_weight_mps2,
            separation_lookahead_s=self.separation_lookahead_s,
            alignment_weight_per_s=self.alignment_weight_per_s,
            cohesion_weight_per_s2=self.cohesion_weight_per_s2,
            migration_weight_per_s=self.migration_weight_per_s,
            arrival_radius_m=self.arrival_radius_m,
        )
        check_positive(
            self,
            alt_m=self.alt_m,
            max_speed_mps=self.max_speed_mps,
            max_accel_mps2=self.max_accel_mps2,
            neighbour_radius_m=self.neighbour_radius_m,
            separation_radius_m=self.separation_radius_m,
            separation_weight_mps2=self.separation_weight_mps2,
            arrival_radius_m=self.arrival_radius_m,
        )
        for name in (
            "separation_lookahead_s",
            "alignment_weight_per_s",
            "cohesion_weight_per_s2",
            "migration_weight_per_s",
        ):
            if getattr(self, name) < 0.0:
                raise SpecFieldError(self, name, f"must not be negative, got {getattr(self, name)}")
        if self.separation_radius_m > self.neighbour_radius_m:
            raise SpecFieldError(
                self,
                "separation_radius_m",
                f"({self.separation_radius_m:g}) must not exceed the "
                f"neighbour radius ({self.neighbour_radius_m:g}): a drone only sees its neighbours",
            )
        _check_points(self, "migration_ne_m", self.migration_ne_m)


def pairwise_offsets(pos_ne_m: FloatArray) -> tuple[FloatArray, FloatArray]:
    """``diff[i, j] = p_i - p_j`` (n, n, 2) and the distances (n, n), self-distance +inf (never a neighbour)."""
    diff = pos_ne_m[:, None, :] - pos_ne_m[None, :, :]
    dist = np.linalg.norm(diff, axis=-1)
    np.fill_diagonal(dist, np.inf)
    return diff, dist


def neighbours(pos_ne_m: FloatArray, radius_m: float) -> BoolArray:
    """``mask[i, j]``: drone j is a neighbour of drone i (closer than ``radius_m``, not itself)."""
    _, dist = pairwise_offsets(pos_ne_m)
    return np.asarray(dist < radius_m)


def separation_term(
    pos_ne_m: FloatArray, vel_ne_mps: FloatArray, radius_m: float, lookahead_s: float = 0.0
) -> FloatArray:
    """Sum over close neighbours of the unit vector away from them times ``radius / d_eff - 1``.

    ``d_eff`` is the distance less what the pair closes in ``lookahead_s`` at its current closing speed (reported
    velocities; a pair moving apart gets no credit): drones flying at each other feel each other early enough to
    brake within the acceleration limit and the velocity loop's lag, while the flock's own drones, moving alike,
    see their plain distance. The term is zero at ``d_eff = radius``, 1 at half of it and unbounded towards contact:
    times the weight (m/s^2) it is the acceleration away. Two drones at the same point push apart along a fixed
    direction (east for the higher row).
    """
    diff, dist = pairwise_offsets(pos_ne_m)
    safe = np.maximum(dist, 1e-6)
    unit = diff / safe[..., None]
    closing = -np.einsum("ijk,ijk->ij", unit, vel_ne_mps[:, None, :] - vel_ne_mps[None, :, :])
    effective = dist - lookahead_s * np.maximum(closing, 0.0)
    close = effective < radius_m
    strength = np.where(close, radius_m / np.maximum(effective, 1e-6) - 1.0, 0.0)
    coincident = close & (dist < 1e-6)
    if np.any(coincident):
        i, j = np.nonzero(coincident)
        unit[i, j] = np.stack([np.zeros(i.size), np.where(i < j, -1.0, 1.0)], axis=-1)
    return np.asarray(np.einsum("ij,ijk->ik", strength, unit), dtype=np.float64)


def alignment_term(vel_ne_mps: FloatArray, own_vel_ne_mps: FloatArray, mask: BoolArray) -> FloatArray:
    """Mean reported velocity of each drone's neighbours minus its own velocity (m/s); zero without neighbours."""
    count = mask.sum(axis=1)
    mean = np.divide(
        mat_mul(mask, vel_ne_mps), count[:, None], out=np.zeros_like(own_vel_ne_mps), where=count[:, None] > 0
    )
    return np.where(count[:, None] > 0, mean - own_vel_ne_mps, 0.0)


def cohesion_term(pos_ne_m: FloatArray, mask: BoolArray) -> FloatArray:
    """From each drone to the centroid of its neighbours (m); zero without neighbours."""
    count = mask.sum(axis=1)
    centroid = np.divide(mat_mul(mask, pos_ne_m), count[:, None], out=np.zeros_like(pos_ne_m), where=count[:, None] > 0)
    return np.where(count[:, None] > 0, centroid - pos_ne_m, 0.0)


def migration_term(
    pos_ne_m: FloatArray,
    own_vel_ne_mps: FloatArray,
    mask: BoolArray,
    goal_ne_m: FloatArray,
    speed_mps: float,
    slowing_radius_m: float,
) -> FloatArray:
    """Steering (m/s) towards the velocity that takes each drone's local centroid (itself and its neighbours) to the
    goal: ``speed`` towards it, tapering linearly within ``slowing_radius_m``.

    The local centroid, not the drone itself: every drone heading for the goal point would squeeze the flock into a
    ball around it (leaving spacing to the separation term alone); steering the centroid moves the flock as a body.
    """
    with_self = mask | np.eye(mask.shape[0], dtype=bool)
    centroid = mat_mul(with_self, pos_ne_m) / with_self.sum(axis=1)[:, None]
    to_goal = goal_ne_m[None, :] - centroid
    distance = np.linalg.norm(to_goal, axis=1, keepdims=True)
    desired = speed_mps * to_goal / np.maximum(distance, slowing_radius_m)
    return np.asarray(desired - own_vel_ne_mps, dtype=np.float64)


def flock_acceleration(
    pos_ne_m: FloatArray,
    vel_ne_mps: FloatArray,
    own_vel_ne_mps: FloatArray,
    goal_ne_m: FloatArray | None,
    spec: FlockSpec,
) -> FloatArray:
    """Each drone's steering acceleration (n, 2): the weighted terms, separation first, within the limit.

    ``pos_ne_m`` and ``vel_ne_mps`` are the reported horizontal states (neighbours are seen through them);
    ``own_vel_ne_mps`` is each drone's commanded velocity, the state the steering acts on.
    """
    mask = neighbours(pos_ne_m, spec.neighbour_radius_m)
    separation = spec.separation_weight_mps2 * separation_term(
        pos_ne_m, vel_ne_mps, spec.separation_radius_m, spec.separation_lookahead_s
    )
    rest = spec.alignment_weight_per_s * alignment_term(vel_ne_mps, own_vel_ne_mps, mask)
    rest += spec.cohesion_weight_per_s2 * cohesion_term(pos_ne_m, mask)
    if goal_ne_m is not None:
        rest += spec.migration_weight_per_s * migration_term(
            pos_ne_m, own_vel_ne_mps, mask, goal_ne_m, spec.max_speed_mps, spec.arrival_radius_m
        )
    return priority_sum(separation, rest, spec.max_accel_mps2)


class Flock:
    """Flocking of the drones present at the command; each keeps a commanded velocity the steering integrates."""

    def __init__(self, spec: FlockSpec, now_s: float, state: SwarmState) -> None:
        if not state.sysids:
            raise FormationError("no drones to flock")
        self.spec = spec
        self.sysids = state.sysids
        self._row = {sysid: k for k, sysid in enumerate(self.sysids)}
        self._vel_cmd = limit_norm(state.vel_ned_mps[:, :2].copy(), spec.max_speed_mps)  # start as they move
        self._last_s = now_s
        self._goals = np.array(spec.migration_ne_m, dtype=np.float64).reshape(-1, 2)
        self.goal_index = 0

    @property
    def goal_ne_m(self) -> tuple[float, float] | None:
        if self.goal_index >= self._goals.shape[0]:
            return None
        return (float(self._goals[self.goal_index, 0]), float(self._goals[self.goal_index, 1]))

    def setpoints(self, now_s: float, state: SwarmState) -> dict[int, Setpoint]:
        dt = min(max(now_s - self._last_s, 0.0), MAX_TICK_S)
        self._last_s = now_s
        rows = [k for k, sysid in enumerate(state.sysids) if sysid in self._row]
        if not rows:
            return {}
        ids = [state.sysids[k] for k in rows]
        mine = [self._row[s] for s in ids]
        pos = state.pos_ned_m[rows, :2]
        vel = state.vel_ned_mps[rows, :2]
        own = self._vel_cmd[mine]
        goals = self._goals
        centroid = pos.mean(axis=0)
        while self.goal_index < goals.shape[0] - 1 and (
            math.hypot(*(centroid - goals[self.goal_index])) <= self.spec.arrival_radius_m
        ):
            self.goal_index += 1
        goal = goals[self.goal_index] if goals.shape[0] else None
        acc = flock_acceleration(pos, vel, own, goal, self.spec)
        new = limit_norm(own + acc * dt, self.spec.max_speed_mps)
        if dt > 0.0:
            acc = (new - own) / dt  # what the commanded velocity actually does (the speed limit may cut it)
        self._vel_cmd[mine] = new
        down = -self.spec.alt_m
        return {
            sysid: Setpoint(
                pos_ned_m=(math.nan, math.nan, down),
                vel_ned_mps=(float(new[k, 0]), float(new[k, 1]), math.nan),
                acc_ned_mps2=(float(acc[k, 0]), float(acc[k, 1]), math.nan),
                yaw_rad=math.nan,
            )
            for k, sysid in enumerate(ids)
        }

    def targets(self) -> dict[int, Vec3]:
        return {}


# ------------------------------------------------------------------------------------------------ leader's path


class LeaderPath:
    """The leader's reference: from ``start`` through the waypoints, at rest at both ends, corners rounded.

    Every corner becomes a circular arc of ``turn_radius_m`` tangent to both legs (smaller where the legs are too
    short to hold it: each arc takes at most half of each leg), so the course turns continuously instead of
    jumping; the path then passes inside the corner, ``R (1 / cos(theta / 2) - 1)`` from it for a turn of theta.
    A reversal (a turn of nearly 180 deg) is flown as a stop and go. The speed along the path is the largest that
    stays within ``speed_mps``, within ``max_accel_mps2`` along the path and, on arcs, within ``max_accel_mps2``
    across it (v^2 / R); it is computed on arc-length samples (v^2 rising at most 2 a per metre both ways), and
    time follows exactly from constant acceleration between samples.
    """

    def __init__(
        self,
        start_ned_m: Sequence[float],
        waypoints_ned_m: Sequence[Sequence[float]],
        *,
        speed_mps: float,
        max_accel_mps2: float,
        turn_radius_m: float,
    ) -> None:
        points = [np.asarray(start_ned_m, dtype=np.float64).reshape(3)]
        for wp in waypoints_ned_m:
            p = np.asarray(wp, dtype=np.float64).reshape(3)
            if math.hypot(*(p - points[-1])) >= _MIN_LEG_M:
                points.append(p)
        if not all(np.all(np.isfinite(p)) for p in points):
            raise FormationError("path points must be finite")
        self.end_ned_m = points[-1]
        pos, tangent, curvature, limit = _sample_path(points, speed_mps, max_accel_mps2, turn_radius_m)
        self._s = _arc_lengths(pos)
        self._pos, self._tangent, self._curvature = pos, tangent, curvature
        self._v = _speed_profile(self._s, limit, max_accel_mps2)
        steps = np.diff(self._s)
        mean_speed = 0.5 * (self._v[:-1] + self._v[1:])
        dt = np.divide(steps, mean_speed, out=np.zeros_like(steps), where=mean_speed > 0)
        self._t = np.concatenate([[0.0], np.cumsum(dt)])
        self._a = np.divide(np.diff(self._v), dt, out=np.zeros_like(dt), where=dt > 0)

    @property
    def duration_s(self) -> float:
        return float(self._t[-1])

    @property
    def length_m(self) -> float:
        return float(self._s[-1])

    def sample(self, t_s: float) -> tuple[Vec3, Vec3, Vec3]:
        """Position, velocity and acceleration (NED) ``t_s`` after the start; at rest before and after."""
        if self._s.size < 2 or t_s <= 0.0 or t_s >= self._t[-1]:
            p = self._pos[0] if (self._s.size < 2 or t_s <= 0.0) else self._pos[-1]
            return _vec(p), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0)
        i = int(np.searchsorted(self._t, t_s, side="right")) - 1
        i = min(max(i, 0), self._t.size - 2)
        tau = t_s - self._t[i]
        a = float(self._a[i])
        v = float(self._v[i]) + a * tau
        s = float(self._s[i]) + float(self._v[i]) * tau + 0.5 * a * tau * tau
        ds = float(self._s[i + 1] - self._s[i])
        f = min(max((s - float(self._s[i])) / ds, 0.0), 1.0) if ds > 0 else 0.0
        pos = self._pos[i] + f * (self._pos[i + 1] - self._pos[i])
        tangent = self._tangent[i] + f * (self._tangent[i + 1] - self._tangent[i])
        tangent = tangent / max(math.hypot(*tangent), 1e-12)
        curvature = self._curvature[i] + f * (self._curvature[i + 1] - self._curvature[i])
        return _vec(pos), _vec(v * tangent), _vec(a * tangent + v * v * curvature)

    def remaining_waypoints(
        self, waypoints_ne_m: Sequence[tuple[float, float]], t_s: float
    ) -> tuple[tuple[float, float], ...]:
        """The waypoints the reference has not passed ``t_s`` after the start (each passed where the path comes
        nearest to it); the last one always remains, so a new leader still ends where the flight was to end."""
        remaining = []
        for north, east in waypoints_ne_m:
            nearest = int(np.argmin(np.linalg.norm(self._pos[:, :2] - np.array([north, east]), axis=1)))
            if float(self._t[nearest]) > t_s:
                remaining.append((north, east))
        return tuple(remaining) if remaining else (tuple(waypoints_ne_m[-1]),)  # type: ignore[return-value]

    def speed_profile(self) -> tuple[FloatArray, FloatArray]:
        """(time, speed) at every arc-length sample, for checks and plots."""
        return self._t.copy(), self._v.copy()


def _vec(values: FloatArray) -> Vec3:
    return (float(values[0]), float(values[1]), float(values[2]))


def _unit(v: FloatArray) -> FloatArray:
    return np.asarray(v / math.hypot(*v), dtype=np.float64)


def _arc_lengths(pos: FloatArray) -> FloatArray:
    return np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(pos, axis=0), axis=1))])


def _line(a: FloatArray, b: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Samples of the segment from a to b, a included, b excluded, and the tangent."""
    length = math.hypot(*(b - a))
    if length < 1e-9:  # two arcs meeting mid-leg leave no straight part
        return np.zeros((0, 3)), np.zeros((0, 3))
    count = max(1, math.ceil(length / _PATH_STEP_M))
    f = np.arange(count)[:, None] / count
    return a + f * (b - a), np.tile(_unit(b - a), (count, 1))


def _sample_path(
    points: list[FloatArray], speed_mps: float, accel_mps2: float, turn_radius_m: float
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """Arc-length samples of the rounded polyline: position, unit tangent, curvature vector (1/m), speed limit."""
    if len(points) < 2:
        p = points[0][None]
        return p, np.zeros((1, 3)), np.zeros((1, 3)), np.zeros(1)
    pos: list[FloatArray] = []
    tan: list[FloatArray] = []
    cur: list[FloatArray] = []
    lim: list[FloatArray] = []
    leg_start = points[0]
    for k in range(1, len(points)):
        corner = points[k]
        if k == len(points) - 1:
            leg_end, arc = corner, None
        else:
            u_in, u_out = _unit(corner - points[k - 1]), _unit(points[k + 1] - corner)
            theta = math.acos(min(1.0, max(-1.0, float((u_in * u_out).sum()))))
            half_legs = 0.5 * min(math.hypot(*(corner - points[k - 1])), math.hypot(*(points[k + 1] - corner)))
            if theta < _STRAIGHT_RAD:
                leg_end, arc = corner, None
            elif theta > math.pi - _STRAIGHT_RAD:
                leg_end, arc = corner, (0.0, u_in, u_out, theta)  # a reversal: stop at the corner
            else:
                tangent_m = min(turn_radius_m * math.tan(theta / 2.0), half_legs)
                radius = tangent_m / math.tan(theta / 2.0)
                leg_end, arc = corner - tangent_m * u_in, (radius, u_in, u_out, theta)
        p, t = _line(leg_start, leg_end)
        pos.append(p)
        tan.append(t)
        cur.append(np.zeros_like(p))
        lim.append(np.full(p.shape[0], speed_mps))
        if arc is None:
            leg_start = leg_end
            continue
        radius, u_in, u_out, theta = arc
        if radius <= 0.0:
            pos.append(corner[None])
            tan.append(u_in[None])
            cur.append(np.zeros((1, 3)))
            lim.append(np.zeros(1))
            leg_start = corner
            continue
        normal = _unit(u_out - float((u_in * u_out).sum()) * u_in)  # towards the arc's centre, in the plane of the legs
        centre = leg_end + radius * normal
        count = max(1, math.ceil(radius * theta / _PATH_STEP_M))
        phi = (np.arange(count) / count * theta)[:, None]
        pos.append(centre - radius * np.cos(phi) * normal + radius * np.sin(phi) * u_in)
        tan.append(np.sin(phi) * normal + np.cos(phi) * u_in)
        cur.append((np.cos(phi) * normal - np.sin(phi) * u_in) / radius)
        lim.append(np.full(count, min(speed_mps, math.sqrt(accel_mps2 * radius))))
        leg_start = centre - radius * math.cos(theta) * normal + radius * math.sin(theta) * u_in
    pos.append(points[-1][None])
    tan.append(tan[-1][-1:])
    cur.append(np.zeros((1, 3)))
    lim.append(np.zeros(1))
    return np.concatenate(pos), np.concatenate(tan), np.concatenate(cur), np.concatenate(lim)


def _speed_profile(s_m: FloatArray, limit_mps: FloatArray, accel_mps2: float) -> FloatArray:
    """The fastest speed at each sample within the limits, from rest to rest, |dv/dt| <= accel.

    v^2 may rise by at most 2 a per metre travelled: ``v_i^2 <= min_j<=i (limit_j^2 + 2 a (s_i - s_j))``, a running
    minimum, and the same backwards for braking.
    """
    limit_sq = limit_mps**2
    limit_sq[0] = 0.0
    limit_sq[-1] = 0.0
    two_a = 2.0 * accel_mps2
    forward = two_a * s_m + np.minimum.accumulate(limit_sq - two_a * s_m)
    backward = -two_a * s_m + np.minimum.accumulate((limit_sq + two_a * s_m)[::-1])[::-1]
    return np.sqrt(np.maximum(np.minimum(forward, backward), 0.0))


# --------------------------------------------------------------------------------------------- leader-follower


@dataclass(frozen=True, slots=True, kw_only=True)
class FollowSpec:
    """The leader flies ``waypoints_ne_m`` at ``alt_m``; followers hold offsets in its heading frame.

    ``offsets_fr_m`` are (forward, right) metres from the leader, one per follower at least; followers are
    assigned to them by minimum total squared distance (as formation slots are). Without offsets the followers
    form a V behind the leader (``spacing_m`` along each arm, ``angle_rad`` between the arms, like ``VSpec``).
    ``leader_sysid`` None: the lowest sysid leads.
    """

    waypoints_ne_m: tuple[tuple[float, float], ...]
    alt_m: float
    speed_mps: float = 1.5
    leader_sysid: int | None = None
    offsets_fr_m: tuple[tuple[float, float], ...] | None = None
    spacing_m: float = 2.5
    angle_rad: float = math.pi / 2.0
    turn_radius_m: float = 3.0
    max_accel_mps2: float = 1.0
    max_turn_rate_radps: float = 0.3

    def __post_init__(self) -> None:
        if not self.waypoints_ne_m:
            raise SpecFieldError(self, "waypoints_ne_m", "needs at least one waypoint")
        _check_points(self, "waypoints_ne_m", self.waypoints_ne_m)
        if self.offsets_fr_m is not None:
            for offset in self.offsets_fr_m:
                if len(offset) != 2 or not all(math.isfinite(v) for v in offset):
                    raise SpecFieldError(self, "offsets_fr_m", f"must hold (forward, right) pairs, got {offset}")
                if math.hypot(*offset) < 0.5:
                    raise SpecFieldError(self, "offsets_fr_m", f"{offset} puts a follower on the leader", joint=": ")
        values = {
            "alt_m": self.alt_m,
            "speed_mps": self.speed_mps,
            "spacing_m": self.spacing_m,
            "turn_radius_m": self.turn_radius_m,
            "max_accel_mps2": self.max_accel_mps2,
            "max_turn_rate_radps": self.max_turn_rate_radps,
        }
        check_finite(self, angle_rad=self.angle_rad, **values)
        check_positive(self, **values)
        _check_v_angle(self)
        _check_leader(self)

    def offsets(self, follower_count: int) -> FloatArray:
        """(forward, right) offsets (m, 2), m >= follower_count; FormationError if too few are given."""
        return follower_offsets(self.offsets_fr_m, follower_count, self.spacing_m, self.angle_rad)


def _check_leader(spec: FollowSpec | FollowAttachedSpec) -> None:
    """A leader named by its sysid (None: chosen when flown)."""
    problem = None if spec.leader_sysid is None else not_a_sysid(spec.leader_sysid)
    if problem is not None:
        raise SpecFieldError(spec, "leader_sysid", problem)


def _check_v_angle(spec: FollowSpec | FollowAttachedSpec) -> None:
    """The opening of the followers' V, (0, pi]."""
    if not 0.0 < spec.angle_rad <= math.pi:
        raise SpecFieldError(spec, "angle_rad", f"must be in (0, pi], got {spec.angle_rad}")


def follower_offsets(given_fr_m: Sequence[tuple[float, float]] | None, follower_count: int, spacing_m: float,
                     angle_rad: float) -> FloatArray:  # fmt: skip
    """The (forward, right) offsets given, one per follower at least (FormationError if too few), or without them a
    V behind the leader (``default_offsets``)."""
    if given_fr_m is None:
        return default_offsets(follower_count, spacing_m, angle_rad)
    if len(given_fr_m) < follower_count:
        raise FormationError(f"{len(given_fr_m)} follower offsets for {follower_count} followers: give one each")
    return np.array(given_fr_m, dtype=np.float64).reshape(-1, 2)


def default_offsets(follower_count: int, spacing_m: float, angle_rad: float = math.pi / 2.0) -> FloatArray:
    """A V behind the leader: the slots of ``VSpec`` after its apex, relative to the apex (forward, right)."""
    if follower_count == 0:
        return np.zeros((0, 2))
    v = VSpec(spacing_m=spacing_m, alt_m=1.0, angle_rad=angle_rad)
    slots = v.slots_ned_m(np.zeros(1), follower_count + 1)[0]
    return np.asarray(slots[1:, :2] - slots[0, :2], dtype=np.float64)


def rotate_ne(vectors: FloatArray, yaw_rad: float) -> FloatArray:
    """(forward, right) rows rotated by a heading into (north, east) (yaw positive from north towards east)."""
    c, s = math.cos(yaw_rad), math.sin(yaw_rad)
    out = np.empty_like(vectors)
    out[:, 0] = c * vectors[:, 0] - s * vectors[:, 1]
    out[:, 1] = s * vectors[:, 0] + c * vectors[:, 1]
    return out


def turn_towards(
    heading_rad: float, course_rad: float, dt_s: float, *, time_constant_s: float, max_rate_radps: float
) -> tuple[float, float]:
    """One step of the heading filter: (new heading, its rate). First order towards the course, rate-limited,
    the short way round, never past the course."""
    error = wrap_pi(course_rad - heading_rad)
    rate = max(-max_rate_radps, min(max_rate_radps, error / time_constant_s))
    step = rate * dt_s
    if abs(step) > abs(error):
        step = error
    return wrap_pi(heading_rad + step), rate


def course_of(vel_ne_mps: npt.ArrayLike, min_speed_mps: float = COURSE_MIN_SPEED_MPS) -> float | None:
    """Direction of travel (rad from north towards east), None when too slow for the direction to mean anything."""
    v = np.asarray(vel_ne_mps, dtype=np.float64)
    north, east = float(v[0]), float(v[1])
    if math.hypot(north, east) < min_speed_mps:
        return None
    return math.atan2(east, north)


def follower_slots(
    leader_ned_m: npt.ArrayLike,
    leader_vel_ned_mps: npt.ArrayLike,
    heading_rad: float,
    heading_rate_radps: float,
    offsets_fr_m: FloatArray,
    alt_m: float,
) -> tuple[FloatArray, FloatArray]:
    """Slots (k, 3) and their velocities (k, 3): the leader's position plus each offset rotated by the heading, at
    ``alt_m``; velocity = the leader's horizontal velocity plus the slot's motion as the heading turns."""
    k = offsets_fr_m.shape[0]
    leader = np.asarray(leader_ned_m, dtype=np.float64)
    leader_vel = np.asarray(leader_vel_ned_mps, dtype=np.float64)
    arm = rotate_ne(offsets_fr_m, heading_rad)
    pos = np.empty((k, 3))
    pos[:, 0] = float(leader[0]) + arm[:, 0]
    pos[:, 1] = float(leader[1]) + arm[:, 1]
    pos[:, 2] = -alt_m
    vel = np.zeros((k, 3))
    vel[:, 0] = float(leader_vel[0]) - heading_rate_radps * arm[:, 1]
    vel[:, 1] = float(leader_vel[1]) + heading_rate_radps * arm[:, 0]
    return pos, vel


@dataclass(frozen=True, slots=True, eq=False)
class _FixedSlots:
    """A still formation of given slots (the followers' places for the join), facing ``yaw_rad``."""

    slots: FloatArray  # (m, 3)
    centre: FloatArray  # (3,)
    yaw_rad: float

    def slots_ned_m(self, times_s: FloatArray, drone_count: int) -> FloatArray:
        if not 1 <= drone_count <= self.slots.shape[0]:
            raise FormationError(f"{self.slots.shape[0]} follower slots cannot hold {drone_count} followers")
        k = np.asarray(times_s).shape[0]
        return np.asarray(np.broadcast_to(self.slots, (k, *self.slots.shape)), dtype=np.float64)

    def frame(self, times_s: FloatArray) -> tuple[FloatArray, FloatArray]:
        k = np.asarray(times_s).shape[0]
        return np.tile(self.centre, (k, 1)), np.full(k, self.yaw_rad)


class LeaderFollower:
    """Leader-follower flight of the drones present at the command (see the module docstring).

    Phases: the followers join their slots around the hovering leader (a formation-engine transition); once there
    and ``JOIN_SETTLE_S`` later the leader leaves on its path and the followers track their slots from its reports.
    The join faces the first leg if the followers' paths keep ``JOIN_CLEARANCE_M`` from the leader that way; if not,
    the first of a few turned headings that does (the formation then turns to the course once the leader moves).
    """

    def __init__(self, spec: FollowSpec, now_s: float, state: SwarmState, limits: TransitionLimits) -> None:
        if not state.sysids:
            raise FormationError("no drones to fly leader-follower")
        leader = spec.leader_sysid if spec.leader_sysid is not None else min(state.sysids)
        row = state.row(leader)
        if row is None:
            raise FormationError(f"leader sysid {leader} is not in the swarm (sysids {list(state.sysids)})")
        self.spec = spec
        self.leader = leader
        self.followers = tuple(s for s in state.sysids if s != leader)
        self._offsets = spec.offsets(len(self.followers))
        self._hold = state.pos_ned_m[row].copy()
        down = -spec.alt_m
        waypoints = [(n, e, down) for n, e in spec.waypoints_ne_m]
        self.path = LeaderPath(
            self._hold,
            waypoints,
            speed_mps=spec.speed_mps,
            max_accel_mps2=spec.max_accel_mps2,
            turn_radius_m=spec.turn_radius_m,
        )
        self._leader_pos = self._hold.copy()
        self._leader_vel = np.zeros(3)
        self._slot_of: dict[int, int] = {}
        self._targets: dict[int, Vec3] = {}
        self._join: FormationEngine | None = None
        self.join_clearance_m = math.inf
        self.heading_rad = self._first_course(spec.waypoints_ne_m)
        self.heading_rate_radps = 0.0
        self._last_s = now_s
        self.depart_s = now_s
        if self.followers:
            self._plan_join(now_s, state, limits)

    @property
    def finish_s(self) -> float:
        """When the leader's reference reaches the last waypoint."""
        return self.depart_s + self.path.duration_s

    def _first_course(self, waypoints: Sequence[tuple[float, float]]) -> float:
        for north, east in waypoints:
            dn, de = north - float(self._hold[0]), east - float(self._hold[1])
            if math.hypot(dn, de) > ARRIVAL_TOLERANCE_M:
                return math.atan2(de, dn)
        return 0.0

    def _plan_join(self, now_s: float, state: SwarmState, limits: TransitionLimits) -> None:
        start = {s: state.pos_ned_m[state._rows[s]] for s in self.followers}
        centre = np.array([self._hold[0], self._hold[1], -self.spec.alt_m])
        best: tuple[float, FormationEngine, float] | None = None
        for turn in (0, 1, -1, 2, -2, 3, -3, 4):
            heading = wrap_pi(self.heading_rad + turn * math.pi / 4.0)
            slots = np.empty((self._offsets.shape[0], 3))
            slots[:, :2] = centre[:2] + rotate_ne(self._offsets, heading)
            slots[:, 2] = centre[2]
            engine = FormationEngine(limits)
            transition = engine.command(_FixedSlots(slots, centre, heading), now_s, start)
            times = np.arange(now_s, transition.arrival_s + _JOIN_SAMPLE_S, _JOIN_SAMPLE_S)
            clearance = float(np.min(np.linalg.norm(engine.sample_ned_m(times) - self._hold, axis=-1)))
            if best is None or clearance > best[0]:
                best = (clearance, engine, heading)
            if clearance >= JOIN_CLEARANCE_M:
                break
        assert best is not None
        self.join_clearance_m, self._join, self.heading_rad = best
        assert self._join.transition is not None
        self._slot_of = dict(self._join.transition.slot_of_drone)
        self.depart_s = self._join.transition.arrival_s + JOIN_SETTLE_S

    def setpoints(self, now_s: float, state: SwarmState) -> dict[int, Setpoint]:
        dt = min(max(now_s - self._last_s, 0.0), MAX_TICK_S)
        self._last_s = now_s
        row = state.row(self.leader)
        if row is not None:  # a silent leader: keep its last report
            self._leader_pos = state.pos_ned_m[row].copy()
            self._leader_vel = state.vel_ned_mps[row].copy()
        out: dict[int, Setpoint] = {}
        pos, vel, acc = self.path.sample(now_s - self.depart_s)
        out[self.leader] = Setpoint(pos_ned_m=pos, vel_ned_mps=vel, acc_ned_mps2=acc, yaw_rad=math.nan)
        self._targets = {self.leader: pos}
        if not self.followers:
            return out
        if now_s < self.depart_s and self._join is not None:  # (a follower lost while joining is left out)
            out.update({s: sp for s, sp in self._join.setpoints(now_s).items() if s in self.followers})
            self._targets.update({s: p for s, p in self._join.targets(now_s).items() if s in self.followers})
            return out
        course = course_of(self._leader_vel)
        if course is not None:
            self.heading_rad, self.heading_rate_radps = turn_towards(
                self.heading_rad,
                course,
                dt,
                time_constant_s=HEADING_TIME_CONSTANT_S,
                max_rate_radps=self.spec.max_turn_rate_radps,
            )
        else:
            self.heading_rate_radps = 0.0
        offsets = self._offsets[[self._slot_of.get(s, k) for k, s in enumerate(self.followers)]]
        slots, slot_vel = follower_slots(
            self._leader_pos, self._leader_vel, self.heading_rad, self.heading_rate_radps, offsets, self.spec.alt_m
        )
        for k, sysid in enumerate(self.followers):
            target = _vec(slots[k])
            self._targets[sysid] = target
            out[sysid] = Setpoint(
                pos_ned_m=target,
                vel_ned_mps=(float(slot_vel[k, 0]), float(slot_vel[k, 1]), 0.0),
                acc_ned_mps2=NAN3,
                yaw_rad=math.nan,
            )
        return out

    def targets(self) -> dict[int, Vec3]:
        return dict(self._targets)

    def without(self, lost: int, now_s: float, state: SwarmState, limits: TransitionLimits) -> LeaderFollower:
        """The same flight without drone ``lost``. A lost follower leaves its slot empty; a lost leader hands over
        to the next follower, which hovers while the others join their slots around it (the join of a new
        command: synchronised and collision-aware) and then flies on through the waypoints not yet reached.
        ``state`` holds the survivors only."""
        if lost != self.leader:
            self.followers = tuple(s for s in self.followers if s != lost)
            self._targets.pop(lost, None)
            return self
        if not self.followers:
            raise FormationError("no follower left to take the lead")
        waypoints = self.path.remaining_waypoints(self.spec.waypoints_ne_m, now_s - self.depart_s)
        spec = dataclasses.replace(self.spec, leader_sysid=self.followers[0], waypoints_ne_m=waypoints)
        return LeaderFollower(spec, now_s, state, limits)

    def done(self, now_s: float) -> bool:
        """The leader's reference is at the last waypoint and so is the leader, by its last report."""
        if now_s < self.finish_s:
            return False
        return math.hypot(*(self._leader_pos - self.path.end_ned_m)) <= ARRIVAL_TOLERANCE_M


@dataclass(frozen=True, slots=True, kw_only=True)
class LeaderReport:
    """Where a leader the ground station does not command said it was, carried on to now (swarm frame)."""

    pos_ned_m: Vec3
    vel_ned_mps: Vec3


@dataclass(frozen=True, slots=True, kw_only=True)
class FollowAttachedSpec:
    """Every simulated drone holds a (forward, right) offset from a leader that flies itself: a vehicle attached to
    the swarm as ``leader`` (docs/external.md), in the frame of its course, at ``alt_m``, for ``duration_s``.
    ``leader_sysid`` None: the one attached leader. Offsets as ``FollowSpec``'s (a V behind it without them)."""

    alt_m: float
    duration_s: float
    leader_sysid: int | None = None
    offsets_fr_m: tuple[tuple[float, float], ...] | None = None
    spacing_m: float = 2.5
    angle_rad: float = math.pi / 2.0
    max_turn_rate_radps: float = 0.3

    def __post_init__(self) -> None:
        values = {"alt_m": self.alt_m, "duration_s": self.duration_s, "spacing_m": self.spacing_m,
                  "max_turn_rate_radps": self.max_turn_rate_radps}  # fmt: skip
        check_finite(self, angle_rad=self.angle_rad, **values)
        check_positive(self, **values)
        _check_v_angle(self)
        _check_leader(self)

    def offsets(self, follower_count: int) -> FloatArray:
        """(forward, right) offsets (m, 2), m >= follower_count; FormationError if too few are given."""
        return follower_offsets(self.offsets_fr_m, follower_count, self.spacing_m, self.angle_rad)


class FollowAttached:
    """Followers of a leader the ground station does not command, from its reports alone (``leader()``: its
    latest, or None while it has said nothing or has gone silent). Each follower is given the offset nearest to it
    once, at the start; the offsets turn with the leader's course (held while it hovers); with no report the
    followers hold their last slots. Each follower keeps its own distance from the leader by its avoidance, which
    takes the leader for traffic."""

    def __init__(self, spec: FollowAttachedSpec, leader: Callable[[], LeaderReport | None], now_s: float,
                 state: SwarmState) -> None:  # fmt: skip
        report = leader()
        if report is None:
            raise FormationError("the attached leader has not said where it is yet")
        if not state.sysids:
            raise FormationError("no drones to follow the leader")
        self.spec = spec
        self.leader = leader
        self.followers = state.sysids
        self.heading_rad = course_of(np.asarray(report.vel_ned_mps)[:2]) or 0.0
        self.heading_rate_radps = 0.0
        offsets = spec.offsets(len(self.followers))
        slots, _ = follower_slots(report.pos_ned_m, report.vel_ned_mps, self.heading_rad, 0.0, offsets, spec.alt_m)
        chosen = assign_min_squared_distance(state.pos_ned_m, slots)
        self._offsets = offsets[list(chosen)]
        self._last_s = now_s
        self._targets: dict[int, Vec3] = {}

    def setpoints(self, now_s: float, state: SwarmState) -> dict[int, Setpoint]:
        dt, self._last_s = max(0.0, now_s - self._last_s), now_s
        report = self.leader()
        if report is None:  # silent: hold where the slots were
            return {s: Setpoint(pos_ned_m=p, vel_ned_mps=(0.0, 0.0, 0.0), acc_ned_mps2=NAN3, yaw_rad=math.nan)
                    for s, p in self._targets.items()}  # fmt: skip
        course = course_of(np.asarray(report.vel_ned_mps)[:2])
        if course is not None:
            self.heading_rad, self.heading_rate_radps = turn_towards(
                self.heading_rad, course, dt, time_constant_s=HEADING_TIME_CONSTANT_S,
                max_rate_radps=self.spec.max_turn_rate_radps,
            )  # fmt: skip
        else:
            self.heading_rate_radps = 0.0
        slots, slot_vel = follower_slots(report.pos_ned_m, report.vel_ned_mps, self.heading_rad,
                                         self.heading_rate_radps, self._offsets, self.spec.alt_m)  # fmt: skip
        out = {}
        for k, sysid in enumerate(self.followers):
            self._targets[sysid] = target = _vec(slots[k])
            out[sysid] = Setpoint(pos_ned_m=target, vel_ned_mps=(float(slot_vel[k, 0]), float(slot_vel[k, 1]), 0.0),
                                  acc_ned_mps2=NAN3, yaw_rad=math.nan)  # fmt: skip
        return out

    def targets(self) -> dict[int, Vec3]:
        return dict(self._targets)
