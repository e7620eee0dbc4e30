"""Flying the shipped onboard behaviours from the ground station: set each drone's parameters, turn them on, watch.

The ground station does what a real one would before handing over to the drones: it converts the step's spec into
each drone's MAVLink parameters (gcs/flight/onboard.py; points into that drone's own local frame, in which each drone
reports and flies), sets them, each confirmed by its echo, and sets BHV_EN = 1. Afterwards it only watches:

- ``leader_arrived`` says when the onboard leader has reported itself at its last waypoint;
- ``FollowObserver`` computes, from the leader's reports and with the ground law's own heading filter, where each
  follower's slot is, so that the flight report measures the formation error of the onboard flight exactly as the
  ground station's (the recorder's targets; nothing is sent).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Final

import numpy as np

from gcs.command.procedures import start_onboard_behaviours
from gcs.command.streamer import FormationStreamer
from gcs.fleet.errors import SwarmError
from gcs.fleet.swarm import Swarm
from gcs.flight.assignment import assign_min_squared_distance
from gcs.flight.behaviours import (
    ARRIVAL_TOLERANCE_M,
    COURSE_MIN_SPEED_MPS,
    HEADING_TIME_CONSTANT_S,
    FlockSpec,
    FollowSpec,
    follower_slots,
    rotate_ne,
    turn_towards,
)
from gcs.flight.frames import Vec3
from gcs.flight.onboard import flock_params, point_values

JOIN_SETTLE_S: Final = 2.0  # the onboard leader leaves this long after the farthest follower can have joined
FOLLOW_MARGIN_S: Final = 30.0  # the leader must report itself at its last waypoint this long after the earliest


def _local_points(streamer: FormationStreamer, sysid: int, points_ne_m: tuple[tuple[float, float], ...],
                  alt_m: float) -> tuple[tuple[tuple[float, float], ...], float]:  # fmt: skip
    """Swarm-frame points (north, east) and an altitude, in the drone's own local frame (height above its home)."""
    frame = streamer.picture.drone_frame(sysid)
    if frame is None:
        raise SwarmError(f"drone {sysid}: no home position yet")
    local = [frame.to_local((north, east, -alt_m)) for north, east in points_ne_m]
    height = -frame.to_local((0.0, 0.0, -alt_m))[2]
    return tuple((p[0], p[1]) for p in local), height


def set_each(swarm: Swarm, values: Mapping[int, Mapping[str, float]]) -> None:
    """Per drone (sysid -> name -> value), every parameter confirmed by its echo; SwarmError names the first failure."""
    names = sorted({name for own in values.values() for name in own})
    for name in names:
        wanted = {sysid: own[name] for sysid, own in values.items() if name in own}
        bad = [r.sysid for r in swarm.params.set_each(name, wanted) if not r.ok]
        if bad:
            raise SwarmError(f"{name} not set on sysid {bad} (does the drone carry the onboard behaviour?)")


def start_onboard_flock(swarm: Swarm, streamer: FormationStreamer, spec: FlockSpec) -> list[int]:
    """Every drone's flocking parameters (migration points in its frame), then the behaviour on; the sysids."""
    shared = flock_params(spec)
    values: dict[int, dict[str, float]] = {}
    for sysid in swarm.liveness.active_sysids:
        points, height = _local_points(streamer, sysid, spec.migration_ne_m, spec.alt_m)
        values[sysid] = {**shared, "FLK_ALT": height, **point_values("FLK_MIG", points)}
    set_each(swarm, values)
    return start_onboard_behaviours(swarm, streamer)


@dataclass(frozen=True, slots=True, kw_only=True)
class OnboardFollow:
    """What the ground station knows of an onboard leader-follower flight it started."""

    leader: int
    offsets_fr_m: dict[int, tuple[float, float]]  # follower sysid -> (forward, right)
    heading0_rad: float
    last_waypoint_ne_m: tuple[float, float]
    earliest_end_s: float  # the leader cannot be at its last waypoint before this (mission time)
    latest_end_s: float


def start_onboard_follow(swarm: Swarm, streamer: FormationStreamer, spec: FollowSpec, now_s: float) -> OnboardFollow:
    """Assign each follower an offset (minimum total squared distance to the slots around the hovering leader, as
    the ground law's join), set everyone's parameters and turn the behaviour on."""
    here = swarm.picture.positions(swarm.flown_sysids)
    sysids = [s for s in swarm.liveness.active_sysids if s in here]
    leader = spec.leader_sysid if spec.leader_sysid is not None else min(sysids)
    if leader not in here:
        raise SwarmError(f"leader sysid {leader} has no position report")
    followers = [s for s in sysids if s != leader]
    start = np.array(here[leader][:2])
    first = next(((n, e) for n, e in spec.waypoints_ne_m if math.dist((n, e), start) > ARRIVAL_TOLERANCE_M), None)
    heading = math.atan2(first[1] - start[1], first[0] - start[0]) if first is not None else 0.0
    offsets = spec.offsets(len(followers))
    slots = start + rotate_ne(offsets, heading)
    chosen = assign_min_squared_distance(np.array([here[s][:2] for s in followers]).reshape(-1, 2), slots)
    joins = [math.hypot(*(np.array(here[s][:2]) - slots[k])) for s, k in zip(followers, chosen, strict=True)]
    join_m = max(joins, default=0.0)
    wait_s = join_m / spec.speed_mps + JOIN_SETTLE_S
    shared = {"LF_LEADER": float(leader), "LF_SPEED": spec.speed_mps, "LF_AMAX": spec.max_accel_mps2,
              "LF_TURN_RATE": spec.max_turn_rate_radps, "LF_HDG0": math.degrees(heading),
              "LF_WAIT": wait_s}  # fmt: skip
    values: dict[int, dict[str, float]] = {}
    assigned: dict[int, tuple[float, float]] = {}
    for sysid in sysids:
        points, height = _local_points(streamer, sysid, spec.waypoints_ne_m, spec.alt_m)
        values[sysid] = {**shared, "LF_ALT": height}
        if sysid == leader:
            values[sysid].update(point_values("LF_WP", points))
        else:
            k = chosen[followers.index(sysid)]
            assigned[sysid] = (float(offsets[k, 0]), float(offsets[k, 1]))
            values[sysid].update({"LF_FWD": assigned[sysid][0], "LF_RIGHT": assigned[sysid][1]})
    set_each(swarm, values)
    start_onboard_behaviours(swarm, streamer)
    legs = [tuple(start), *spec.waypoints_ne_m]
    length = sum(math.dist(a, b) for a, b in itertools.pairwise(legs))
    earliest = now_s + wait_s + length / spec.speed_mps
    return OnboardFollow(leader=leader, offsets_fr_m=assigned, heading0_rad=heading,
                         last_waypoint_ne_m=spec.waypoints_ne_m[-1], earliest_end_s=earliest,
                         latest_end_s=earliest + spec.speed_mps / spec.max_accel_mps2 + FOLLOW_MARGIN_S)  # fmt: skip


def leader_arrived(follow: OnboardFollow, streamer: FormationStreamer, now_s: float) -> bool:
    """The leader reports itself at its last waypoint (not before it could have flown there)."""
    placed = streamer.picture.placed(follow.leader)
    where = placed.pos_ned_m if placed is not None else None
    return (now_s >= follow.earliest_end_s and where is not None
            and math.dist(where[:2], follow.last_waypoint_ne_m) <= ARRIVAL_TOLERANCE_M)  # fmt: skip


class FollowObserver:
    """Where each follower's slot is, from the leader's reports, by the ground law (for the flight report only:
    nothing is sent). Call with the mission time; it integrates the heading filter between calls."""

    def __init__(self, follow: OnboardFollow, streamer: FormationStreamer, spec: FollowSpec, now_s: float) -> None:
        self.follow = follow
        self.streamer = streamer
        self.spec = spec
        self.heading_rad = follow.heading0_rad
        self.last_s = now_s
        self.followers = tuple(follow.offsets_fr_m)
        self.offsets = np.array([follow.offsets_fr_m[s] for s in self.followers]).reshape(-1, 2)
        self._targets: dict[int, Vec3] = {}

    def __call__(self, now_s: float) -> dict[int, Vec3]:
        if now_s <= self.last_s and self._targets:
            return self._targets
        dt, self.last_s = max(now_s - self.last_s, 0.0), now_s
        state = self.streamer.picture.state(self.streamer.swarm.flown_sysids)
        row = state.row(self.follow.leader)
        if row is None or not self.followers:
            return self._targets
        vel = state.vel_ned_mps[row]
        rate = 0.0
        if math.hypot(float(vel[0]), float(vel[1])) >= COURSE_MIN_SPEED_MPS:
            course = math.atan2(float(vel[1]), float(vel[0]))
            self.heading_rad, rate = turn_towards(self.heading_rad, course, dt, time_constant_s=HEADING_TIME_CONSTANT_S,
                                                  max_rate_radps=self.spec.max_turn_rate_radps)  # fmt: skip
        slots, _ = follower_slots(state.pos_ned_m[row], vel, self.heading_rad, rate, self.offsets, self.spec.alt_m)
        self._targets = {s: (float(p[0]), float(p[1]), float(p[2])) for s, p in zip(self.followers, slots, strict=True)}
        return self._targets
