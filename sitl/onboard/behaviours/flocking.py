"""Reynolds flocking as an onboard behaviour: each drone steers itself from its own estimate and its neighbour table.

The law is the ground station's (gcs/flight/behaviours.py, ``Flock``), for one drone: separation from every drone in the
table whose distance, shortened by what the pair closes in ``FLK_SEP_LOOK`` seconds, is inside ``FLK_SEP_R``;
alignment with, and cohesion towards, the drones within ``FLK_NBR_R`` (horizontal distance); migration of the local
centroid (itself and those neighbours) towards the current migration point. Separation comes first in the
acceleration budget ``FLK_AMAX``; the commanded velocity integrates the steering and is limited to ``FLK_VMAX``;
horizontal motion is that velocity (its change as acceleration feed-forward), altitude a position at ``FLK_ALT``
above the drone's home.

What differs from the ground station's flock, because nobody sees the whole flock:
- the neighbours are whatever the table holds (the ground station's relay, the mesh within radio range, or both),
  each as old as its report;
- a drone moves on to the next migration point when its *local* centroid is within ``FLK_ARR_R`` of the current
  one (the ground station uses the whole flock's centroid), so drones at the flock's edge may turn a little later.

Migration points are parameters in the drone's own local frame (``FLK_MIG_CNT``, ``FLK_MIG1_N``, ``FLK_MIG1_E``,
...: sitl/onboard/behaviours/points.py): a ground station sends each drone the same points, converted into its
frame, as a real one would.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import ClassVar, Final

from sitl.onboard.behaviours.points import (
    Vec2,
    add,
    limit_norm,
    norm,
    point_params,
    priority_sum,
    read_points,
    scale,
    sub,
)
from sitl.onboard.interface import NeighbourReport, OnboardSetpoint, OnboardState

MIGRATION: Final = "FLK_MIG"
MAX_STEP_S: Final = 0.5  # a longer gap between steps is integrated as this long, not as a jump


class Flocking:
    """One drone of a Reynolds flock (module docstring); the parameters are those of ``FlockSpec``."""

    RATE_HZ: ClassVar[float] = 20.0  # as the ground station's setpoint stream
    PARAMS: ClassVar[dict[str, tuple[float, float, float]]] = {
        "FLK_ALT": (4.0, 0.5, 100.0),  # m above home
        "FLK_VMAX": (1.5, 0.1, 20.0),  # m/s
        "FLK_AMAX": (1.5, 0.1, 10.0),  # m/s^2
        "FLK_NBR_R": (6.0, 0.5, 100.0),  # m
        "FLK_SEP_R": (2.5, 0.1, 50.0),  # m
        "FLK_SEP_W": (3.0, 0.0, 50.0),  # m/s^2 per unit of (radius / distance - 1)
        "FLK_SEP_LOOK": (1.0, 0.0, 10.0),  # s
        "FLK_ALI_W": (1.0, 0.0, 20.0),  # 1/s
        "FLK_COH_W": (0.05, 0.0, 10.0),  # 1/s^2
        "FLK_MIG_W": (0.8, 0.0, 20.0),  # 1/s
        "FLK_ARR_R": (3.0, 0.1, 100.0),  # m
        **point_params(MIGRATION),
    }

    def __init__(self) -> None:
        self.vel_cmd_ne_mps: Vec2 | None = None  # the commanded velocity the steering integrates
        self.last_s = math.nan
        self.goal_index = 0

    def step(self, state: OnboardState) -> OnboardSetpoint:
        p = state.params
        vmax = p["FLK_VMAX"]
        dt = 0.0 if math.isnan(self.last_s) else min(max(state.time_s - self.last_s, 0.0), MAX_STEP_S)
        self.last_s = state.time_s
        own_pos: Vec2 = (state.pos_ned_m[0], state.pos_ned_m[1])
        own_vel: Vec2 = (state.vel_ned_mps[0], state.vel_ned_mps[1])
        if self.vel_cmd_ne_mps is None:
            self.vel_cmd_ne_mps = limit_norm(own_vel, vmax)  # start as it moves
        cmd = self.vel_cmd_ne_mps
        goal = self._goal(own_pos, state.neighbours, p)
        acc = steering(own_pos, own_vel, cmd, state.sysid, state.neighbours, goal, p)
        new = limit_norm(add(cmd, scale(acc, dt)), vmax)
        if dt > 0.0:
            acc = scale(sub(new, cmd), 1.0 / dt)  # what the commanded velocity actually does
        self.vel_cmd_ne_mps = new
        return OnboardSetpoint(pos_ned_m=(math.nan, math.nan, -p["FLK_ALT"]), vel_ned_mps=(new[0], new[1], math.nan),
                               acc_ned_mps2=(acc[0], acc[1], math.nan))  # fmt: skip

    def _goal(self, own_pos: Vec2, table: tuple[NeighbourReport, ...], p: Mapping[str, float]) -> Vec2 | None:
        """The current migration point, moving on while the local centroid is within the arrival radius."""
        goals = read_points(p, MIGRATION)
        if not goals:
            return None
        self.goal_index = min(self.goal_index, len(goals) - 1)
        centroid = local_centroid(own_pos, table, p["FLK_NBR_R"])
        while self.goal_index < len(goals) - 1 and norm(sub(centroid, goals[self.goal_index])) <= p["FLK_ARR_R"]:
            self.goal_index += 1
        return goals[self.goal_index]


def horizontal(report: NeighbourReport) -> tuple[Vec2, Vec2]:
    return (report.pos_ned_m[0], report.pos_ned_m[1]), (report.vel_ned_mps[0], report.vel_ned_mps[1])


def local_centroid(own_pos: Vec2, table: tuple[NeighbourReport, ...], radius_m: float) -> Vec2:
    """The centroid of the drone and its neighbours within ``radius_m``."""
    north, east, count = own_pos[0], own_pos[1], 1
    for report in table:
        pos, _ = horizontal(report)
        if norm(sub(own_pos, pos)) < radius_m:
            north, east, count = north + pos[0], east + pos[1], count + 1
    return (north / count, east / count)


def steering(own_pos: Vec2, own_vel: Vec2, cmd_vel: Vec2, sysid: int, table: tuple[NeighbourReport, ...],
             goal: Vec2 | None, params: Mapping[str, float]) -> Vec2:  # fmt: skip
    """The drone's steering acceleration (north, east): separation first, the other terms within what it leaves.

    ``own_vel`` is the drone's estimate (closing speeds), ``cmd_vel`` its commanded velocity (what alignment and
    migration steer); ``params`` its parameters.
    """
    sep_r, look, nbr_r = params["FLK_SEP_R"], params["FLK_SEP_LOOK"], params["FLK_NBR_R"]
    separation: Vec2 = (0.0, 0.0)
    vel_sum: Vec2 = (0.0, 0.0)
    pos_sum: Vec2 = (0.0, 0.0)
    count = 0
    for report in table:
        pos, vel = horizontal(report)
        diff = sub(own_pos, pos)
        dist = norm(diff)
        unit = scale(diff, 1.0 / max(dist, 1e-6))
        rel = sub(own_vel, vel)
        closing = -(unit[0] * rel[0] + unit[1] * rel[1])
        effective = dist - look * max(closing, 0.0)
        if effective < sep_r:
            if dist < 1e-6:  # two drones at one point part along a fixed direction: east for the higher sysid
                unit = (0.0, -1.0 if sysid < report.sysid else 1.0)
            separation = add(separation, scale(unit, sep_r / max(effective, 1e-6) - 1.0))
        if dist < nbr_r:
            vel_sum, pos_sum, count = add(vel_sum, vel), add(pos_sum, pos), count + 1
    rest: Vec2 = (0.0, 0.0)
    if count:
        rest = scale(sub(scale(vel_sum, 1.0 / count), cmd_vel), params["FLK_ALI_W"])
        rest = add(rest, scale(sub(scale(pos_sum, 1.0 / count), own_pos), params["FLK_COH_W"]))
    if goal is not None:
        centroid = scale(add(pos_sum, own_pos), 1.0 / (count + 1))
        to_goal = sub(goal, centroid)
        desired = scale(to_goal, params["FLK_VMAX"] / max(norm(to_goal), params["FLK_ARR_R"]))
        rest = add(rest, scale(sub(desired, cmd_vel), params["FLK_MIG_W"]))
    return priority_sum(scale(separation, params["FLK_SEP_W"]), rest, params["FLK_AMAX"])
