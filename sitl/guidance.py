"""Smooth reference trajectories for the auto modes (takeoff, hold, goto, land, RTL, missions).

PX4 never hands a raw position jump to its position controller in auto modes: a trajectory generator turns a
target into a reference position, velocity and acceleration that respect speed and acceleration limits. This is
the same idea with a straight-line, acceleration-limited (trapezoidal-speed) profile: at every step the reference
speed along the line to the target is the largest that can still stop at the target with the allowed deceleration,
limited by the cruise speed and by how fast speed may change.

Horizontal and vertical limits differ (multirotors climb slower than they cruise); the line's speed limit is the
largest speed whose horizontal and vertical components both respect theirs.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sitl.mathutil import Vec3


@dataclass(frozen=True, slots=True, kw_only=True)
class MotionLimits:
    speed_xy_mps: float
    speed_up_mps: float
    speed_down_mps: float
    accel_xy_mps2: float
    accel_z_mps2: float


@dataclass(frozen=True, slots=True, kw_only=True)
class Reference:
    pos_ned_m: Vec3
    vel_ned_mps: Vec3
    acc_ned_mps2: Vec3


def _component_scale(direction: Vec3, limit_xy: float, limit_up: float, limit_down: float) -> float:
    """Largest magnitude along a unit direction whose horizontal and vertical components stay within limits."""
    horizontal = math.hypot(direction[0], direction[1])
    vertical = direction[2]
    scale = math.inf
    if horizontal > 1e-9:
        scale = limit_xy / horizontal
    if vertical < -1e-9:
        scale = min(scale, limit_up / -vertical)
    elif vertical > 1e-9:
        scale = min(scale, limit_down / vertical)
    return scale


def _stoppable_speed(dist_m: float, previous_mps: float, accel_mps2: float, dt_s: float) -> float:
    """Largest speed v for this step from which the vehicle can still stop at the target.

    The step moves (previous + v) / 2 * dt, and what is left must satisfy v^2 <= 2 a (distance left). Judging by the
    distance before the step instead lets the speed run one step ahead of the braking curve at every step, and the
    reference then reaches the target still moving (about 0.3 m/s at 5 m/s cruise and 400 Hz) and stops dead.
    """
    a_dt = accel_mps2 * dt_s
    discriminant = a_dt * a_dt + 8.0 * accel_mps2 * dist_m - 4.0 * accel_mps2 * previous_mps * dt_s
    if discriminant <= 0.0:
        return 0.0
    return max(0.0, 0.5 * (math.sqrt(discriminant) - a_dt))


class StraightLineTrajectory:
    """Moves a reference point toward a target along a straight line with bounded speed and acceleration."""

    def __init__(self, start_ned_m: Vec3) -> None:
        self._pos = np.array(start_ned_m, dtype=np.float64)
        self._speed = 0.0
        self._dir = np.zeros(3)

    @property
    def position(self) -> Vec3:
        return self._pos

    def reset(self, pos_ned_m: Vec3) -> None:
        self._pos = np.array(pos_ned_m, dtype=np.float64)
        self._speed = 0.0

    def update(
        self, target_ned_m: Vec3, limits: MotionLimits, dt_s: float, max_speed_mps: float = math.inf
    ) -> Reference:
        delta = target_ned_m - self._pos
        dist = float(np.linalg.norm(delta))
        if dist < 1e-4 and self._speed < 1e-3:
            self._pos = np.array(target_ned_m, dtype=np.float64)
            self._speed = 0.0
            return Reference(pos_ned_m=self._pos.copy(), vel_ned_mps=np.zeros(3), acc_ned_mps2=np.zeros(3))
        direction = delta / dist if dist > 1e-9 else self._dir
        line_limit = _component_scale(direction, limits.speed_xy_mps, limits.speed_up_mps, limits.speed_down_mps)
        # A new direction (target moved) carries over only the speed component along it, and no more than the new
        # line allows: 5 m/s of horizontal cruise turned 45 degrees downward would otherwise descend at 2.5 m/s.
        # (A lower speed limit on the same line is approached with the allowed deceleration instead.)
        if self._speed > 0.0:
            cos_turn = float(direction @ self._dir)
            if cos_turn < 1.0 - 1e-9:
                self._speed = min(max(0.0, self._speed * cos_turn), line_limit)
        self._dir = direction
        v_max = min(max_speed_mps, line_limit)
        a_max = _component_scale(direction, limits.accel_xy_mps2, limits.accel_z_mps2, limits.accel_z_mps2)
        previous = self._speed
        desired = min(v_max, _stoppable_speed(dist, previous, a_max, dt_s))
        self._speed = max(previous - a_max * dt_s, min(previous + a_max * dt_s, desired))
        step = min(dist, 0.5 * (previous + self._speed) * dt_s)
        self._pos = self._pos + direction * step
        acc = direction * ((self._speed - previous) / dt_s)
        return Reference(pos_ned_m=self._pos.copy(), vel_ned_mps=direction * self._speed, acc_ned_mps2=acc)
