"""Leader-follower as an onboard behaviour: the leader flies its waypoints itself, each follower keeps its own
offset from the leader as the leader's position reports (relay or mesh) say where it is.

Every drone runs the same class; ``LF_LEADER`` (a sysid) says who leads:

- **The leader** hovers ``LF_WAIT`` seconds (the followers join their slots meanwhile), then flies its waypoints
  (``LF_WP_CNT``, ``LF_WP1_N``, ``LF_WP1_E``, ...; its own local frame) at ``LF_ALT`` above its home: a reference
  point moves along the path, each corner rounded by an arc of ``LF_TURN_R``, at up to ``LF_SPEED``, accelerating
  and braking within ``LF_AMAX`` (along the path, and across it on arcs: v^2 / R), at rest at the last waypoint;
  the drone tracks it (position plus velocity feed-forward), as PX4 tracks a mission.
- **A follower** holds ``(LF_FWD, LF_RIGHT)`` metres (forward, right) in the leader's *heading frame*: its slot is
  the leader's reported position plus the offset rotated by the heading, at ``LF_ALT``, with the leader's reported
  velocity (and the slot's turn) as velocity feed-forward. The heading starts at ``LF_HDG0`` (degrees, the first
  leg's course) and follows the course of the leader's reported velocity through a first-order, rate-limited
  filter (time constant 0.5 s, at most ``LF_TURN_RATE`` rad/s, held while the leader moves slower than 0.3 m/s):
  the ground station's law (gcs/flight/behaviours.py ``LeaderFollower``). Until the leader is heard a follower holds
  where it is; it joins its slot by a point moving towards it at ``LF_SPEED``, so nobody jumps at a slot metres away.
  Collision prevention stays under it all.

What differs from the ground station's leader-follower: the join is each follower's straight line to its slot rather
than a synchronised, collision-checked transition (``LF_WAIT`` stands for the join's duration), and a lost leader is
not replaced (the followers hold where they are).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import ClassVar, Final

from sitl.mathutil import wrap_pi
from sitl.onboard.behaviours.points import Vec2, add, norm, point_params, read_points, scale, sub
from sitl.onboard.interface import NeighbourReport, OnboardSetpoint, OnboardState

WAYPOINTS: Final = "LF_WP"
COURSE_MIN_SPEED_MPS: Final = 0.3  # below this the leader's course is estimator noise: the heading is held
HEADING_TIME_CONSTANT_S: Final = 0.5
MAX_STEP_S: Final = 0.5  # a longer gap between steps is integrated as this long, not as a jump
MIN_LEG_M: Final = 0.01  # waypoints closer than this to the previous point are dropped
STRAIGHT_RAD: Final = 1e-3  # corners flatter than this get no arc


def rotate(forward_right: Vec2, heading_rad: float) -> Vec2:
    """(forward, right) in the frame of ``heading_rad`` as (north, east)."""
    c, s = math.cos(heading_rad), math.sin(heading_rad)
    return (c * forward_right[0] - s * forward_right[1], s * forward_right[0] + c * forward_right[1])


@dataclass(frozen=True, slots=True)
class Segment:
    """A straight leg (``radius_m`` 0 and no turn) or a circular arc tangent to the legs on both sides of a corner."""

    start_ne_m: Vec2
    tangent: Vec2  # unit, at the start
    length_m: float
    radius_m: float = 0.0
    turn_rad: float = 0.0  # signed: positive turns right (north towards east)
    max_speed_mps: float = math.inf  # v^2 / R within the acceleration limit on an arc; 0 at a reversal

    def at(self, s_m: float) -> tuple[Vec2, Vec2]:
        """Position and unit tangent ``s_m`` into the segment."""
        if self.radius_m <= 0.0:
            return add(self.start_ne_m, scale(self.tangent, s_m)), self.tangent
        side = 1.0 if self.turn_rad > 0 else -1.0
        to_centre = (-self.tangent[1] * side, self.tangent[0] * side)
        centre = add(self.start_ne_m, scale(to_centre, self.radius_m))
        phi = s_m / self.radius_m * side  # the turn so far, positive from north towards east
        radius = rotate(scale(to_centre, -self.radius_m), phi)
        return add(centre, radius), rotate(self.tangent, phi)


class Path:
    """The leader's path from where it was at the start through its waypoints, each corner rounded by an arc of
    ``turn_radius_m`` (smaller where the legs are short: an arc takes at most half of each) so that the course turns
    continuously, as the ground station's leader path (gcs/flight/behaviours.py ``LeaderPath``); a reversal is a
    stop."""

    def __init__(self, start: Vec2, waypoints: tuple[Vec2, ...], turn_radius_m: float, max_accel_mps2: float) -> None:
        points = [start]
        for point in waypoints:
            if norm(sub(point, points[-1])) >= MIN_LEG_M:
                points.append(point)
        self.end_ne_m = points[-1]
        self.segments: list[Segment] = []
        leg_start = points[0]
        for k in range(1, len(points)):
            corner = points[k]
            u_in = scale(sub(corner, points[k - 1]), 1.0 / norm(sub(corner, points[k - 1])))
            if k == len(points) - 1:
                self._line(leg_start, corner, u_in)
                break
            u_out = scale(sub(points[k + 1], corner), 1.0 / norm(sub(points[k + 1], corner)))
            cross = u_in[0] * u_out[1] - u_in[1] * u_out[0]
            theta = math.acos(min(1.0, max(-1.0, u_in[0] * u_out[0] + u_in[1] * u_out[1])))
            if theta < STRAIGHT_RAD:
                self._line(leg_start, corner, u_in)
                leg_start = corner
                continue
            if theta > math.pi - STRAIGHT_RAD:  # a reversal: stop at the corner
                self._line(leg_start, corner, u_in, end_speed_mps=0.0)
                leg_start = corner
                continue
            half = 0.5 * min(norm(sub(corner, points[k - 1])), norm(sub(points[k + 1], corner)))
            cut = min(turn_radius_m * math.tan(theta / 2.0), half)
            radius = cut / math.tan(theta / 2.0)
            arc_start = sub(corner, scale(u_in, cut))
            self._line(leg_start, arc_start, u_in)
            self.segments.append(Segment(arc_start, u_in, radius * theta, radius, math.copysign(theta, cross),
                                         math.sqrt(max_accel_mps2 * radius)))  # fmt: skip
            leg_start = add(corner, scale(u_out, cut))
        self.length_m = sum(seg.length_m for seg in self.segments)

    def _line(self, a: Vec2, b: Vec2, tangent: Vec2, end_speed_mps: float = math.inf) -> None:
        self.segments.append(Segment(a, tangent, norm(sub(b, a))))
        if end_speed_mps < math.inf:  # a zero-length stop the speed profile must meet
            self.segments.append(Segment(b, tangent, 0.0, max_speed_mps=end_speed_mps))

    def at(self, s_m: float) -> tuple[Vec2, Vec2]:
        """Position and unit tangent ``s_m`` along the path (clamped to its ends)."""
        for seg in self.segments:
            if s_m <= seg.length_m and seg.length_m > 0.0:
                return seg.at(max(s_m, 0.0))
            s_m -= seg.length_m
        return self.end_ne_m, (0.0, 0.0)

    def speed_limit(self, s_m: float, max_accel_mps2: float) -> float:
        """The largest speed at ``s_m`` from which every later limit (arcs, stops, the end at rest) can still be
        met braking within ``max_accel_mps2``."""
        limit, start = math.inf, 0.0
        for seg in self.segments:
            end = start + seg.length_m
            if seg.max_speed_mps < math.inf and end >= s_m:
                ahead = max(start - s_m, 0.0)
                limit = min(limit, math.sqrt(seg.max_speed_mps**2 + 2.0 * max_accel_mps2 * ahead))
            start = end
        return min(limit, math.sqrt(2.0 * max_accel_mps2 * max(self.length_m - s_m, 0.0)))


class LeaderFollower:
    """Leader or follower, by ``LF_LEADER`` (module docstring); the parameters mirror ``FollowSpec``."""

    RATE_HZ: ClassVar[float] = 20.0
    PARAMS: ClassVar[dict[str, tuple[float, float, float]]] = {
        "LF_LEADER": (1.0, 1.0, 255.0),  # the leader's sysid
        "LF_FWD": (-2.0, -100.0, 100.0),  # m, this follower's offset ahead of the leader
        "LF_RIGHT": (0.0, -100.0, 100.0),  # m, to the leader's right
        "LF_ALT": (3.0, 0.5, 100.0),  # m above home
        "LF_SPEED": (1.5, 0.1, 20.0),  # m/s
        "LF_AMAX": (1.0, 0.1, 10.0),  # m/s^2, along the leader's path and across it on arcs
        "LF_TURN_R": (3.0, 0.1, 100.0),  # m, the leader's path rounds each corner with an arc of this radius
        "LF_TURN_RATE": (0.3, 0.01, 3.0),  # rad/s, the followers' heading frame at most
        "LF_HDG0": (0.0, -180.0, 180.0),  # deg, the heading frame before the leader moves
        "LF_WAIT": (5.0, 0.0, 600.0),  # s, the leader hovers this long before it leaves
        **point_params(WAYPOINTS),
    }

    def __init__(self) -> None:
        self.start_s = math.nan
        self.last_s = math.nan
        self.path: Path | None = None  # the leader's
        self.along_m = 0.0
        self.speed_mps = 0.0
        self.heading_rad = math.nan  # a follower's heading frame
        self.join_ne_m: Vec2 | None = None  # a follower's point moving towards its slot

    def step(self, state: OnboardState) -> OnboardSetpoint | None:
        p = state.params
        if math.isnan(self.start_s):
            self.start_s = self.last_s = state.time_s
        dt = min(max(state.time_s - self.last_s, 0.0), MAX_STEP_S)
        self.last_s = state.time_s
        if state.sysid == int(p["LF_LEADER"]):
            return self._lead(state, p, dt)
        leader = next((n for n in state.neighbours if n.sysid == int(p["LF_LEADER"])), None)
        if leader is None:
            return None  # not heard yet (or lost): hold where it is
        return self._follow(state, leader, p, dt)

    def _lead(self, state: OnboardState, p: Mapping[str, float], dt: float) -> OnboardSetpoint:
        if self.path is None:
            self.path = Path((state.pos_ned_m[0], state.pos_ned_m[1]), read_points(p, WAYPOINTS), p["LF_TURN_R"],
                             p["LF_AMAX"])  # fmt: skip
        down = -p["LF_ALT"]
        if state.time_s - self.start_s >= p["LF_WAIT"]:
            target = min(p["LF_SPEED"], self.path.speed_limit(self.along_m, p["LF_AMAX"]))
            change = p["LF_AMAX"] * dt
            self.speed_mps = min(max(target, self.speed_mps - change), self.speed_mps + change)
            self.along_m = min(self.along_m + self.speed_mps * dt, self.path.length_m)
        pos, tangent = self.path.at(self.along_m)
        vel = scale(tangent, self.speed_mps)
        return OnboardSetpoint(pos_ned_m=(pos[0], pos[1], down), vel_ned_mps=(vel[0], vel[1], 0.0))

    def _follow(self, state: OnboardState, leader: NeighbourReport, p: Mapping[str, float],
                dt: float) -> OnboardSetpoint:  # fmt: skip
        leader_vel: Vec2 = (leader.vel_ned_mps[0], leader.vel_ned_mps[1])
        leader_pos: Vec2 = (leader.pos_ned_m[0], leader.pos_ned_m[1])
        if math.isnan(self.heading_rad):
            self.heading_rad = math.radians(p["LF_HDG0"])
        rate = 0.0
        if norm(leader_vel) >= COURSE_MIN_SPEED_MPS:
            error = wrap_pi(math.atan2(leader_vel[1], leader_vel[0]) - self.heading_rad)
            rate = max(-p["LF_TURN_RATE"], min(p["LF_TURN_RATE"], error / HEADING_TIME_CONSTANT_S))
            turn = rate * dt if abs(rate * dt) <= abs(error) else error
            self.heading_rad = wrap_pi(self.heading_rad + turn)
        arm = rotate((p["LF_FWD"], p["LF_RIGHT"]), self.heading_rad)
        slot = add(leader_pos, arm)
        slot_vel = (leader_vel[0] - rate * arm[1], leader_vel[1] + rate * arm[0])
        if self.join_ne_m is None:
            self.join_ne_m = (state.pos_ned_m[0], state.pos_ned_m[1])
        gap = sub(slot, self.join_ne_m)
        if norm(gap) > 1e-3:  # joining: a point moves towards the slot at LF_SPEED relative to it
            self.join_ne_m = add(self.join_ne_m, scale(slot_vel, dt))
            gap = sub(slot, self.join_ne_m)
            move = min(norm(gap), p["LF_SPEED"] * dt)
            self.join_ne_m = add(self.join_ne_m, scale(gap, move / max(norm(gap), 1e-12)))
            return OnboardSetpoint(pos_ned_m=(self.join_ne_m[0], self.join_ne_m[1], -p["LF_ALT"]),
                                   vel_ned_mps=(slot_vel[0], slot_vel[1], 0.0))  # fmt: skip
        self.join_ne_m = slot
        return OnboardSetpoint(pos_ned_m=(slot[0], slot[1], -p["LF_ALT"]), vel_ned_mps=(slot_vel[0], slot_vel[1], 0.0))
