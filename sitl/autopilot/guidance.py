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
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from sitl.mathutil import Vec3, fast_constructor


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


_new_reference = fast_constructor(Reference)


def _component_scale(horizontal: float, vertical: float, limit_xy: float, limit_up: float, limit_down: float) -> float:
    """Largest magnitude along a unit direction (given by its horizontal and down components) whose horizontal
    and vertical components stay within limits."""
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
    reference then reaches the target still moving (about 0.3 m/s at 5 m/s cruise and 400 Hz physics) and stops dead.
    """
    a_dt = accel_mps2 * dt_s
    discriminant = a_dt * a_dt + 8.0 * accel_mps2 * dist_m - 4.0 * accel_mps2 * previous_mps * dt_s
    if discriminant <= 0.0:
        return 0.0
    return max(0.0, 0.5 * (math.sqrt(discriminant) - a_dt))


Floats3 = tuple[float, float, float]
_ZERO3: Floats3 = (0.0, 0.0, 0.0)


def floats3(v: Vec3 | Sequence[float]) -> Floats3:
    """A 3-vector as three Python floats (an array's own values: ``tolist`` converts without rounding)."""
    if isinstance(v, np.ndarray):
        x, y, z = v.tolist()  # already Python floats
        return (x, y, z)
    return (float(v[0]), float(v[1]), float(v[2]))


class StraightLineTrajectory:
    """Moves a reference point toward a target along a straight line with bounded speed and acceleration.

    The state is kept in Python floats (numpy's per-call overhead on 3-vectors is larger than the arithmetic, and
    this runs every control step); only the returned ``Reference`` and ``position`` are arrays.
    """

    def __init__(self, start_ned_m: Vec3 | Sequence[float]) -> None:
        self._pos = floats3(start_ned_m)
        self._speed = 0.0
        self._dir = (0.0, 0.0, 0.0)

    @property
    def position(self) -> Vec3:
        return np.array(self._pos)

    @property
    def position_floats(self) -> Floats3:
        """``position`` as the floats it is kept in, without building an array (read on every commander tick)."""
        return self._pos

    def reset(self, pos_ned_m: Vec3 | Sequence[float]) -> None:
        self._pos = floats3(pos_ned_m)
        self._speed = 0.0

    def reset_moving(self, pos_ned_m: Vec3 | Sequence[float], vel_ned_mps: Vec3 | Sequence[float]) -> None:
        """Restart the reference at ``pos_ned_m`` already moving at ``vel_ned_mps`` (the vehicle's own state): a
        target ahead along that velocity is then reached by braking from it, not by stopping dead and starting
        again from rest."""
        self._pos = floats3(pos_ned_m)
        vx, vy, vz = floats3(vel_ned_mps)
        speed = math.sqrt(vx * vx + vy * vy + vz * vz)
        if speed < 1e-9:
            self._speed = 0.0
            return
        self._speed = speed
        self._dir = (vx / speed, vy / speed, vz / speed)

    def update(
        self, target_ned_m: Vec3 | Sequence[float], limits: MotionLimits, dt_s: float, max_speed_mps: float = math.inf
    ) -> Reference:
        """Advance the reference one step towards the target; position, velocity and acceleration as arrays."""
        pos, vel, acc = self.advance(target_ned_m, limits, dt_s, max_speed_mps)
        return _new_reference(pos_ned_m=np.array(pos), vel_ned_mps=np.array(vel), acc_ned_mps2=np.array(acc))

    def advance(
        self, target_ned_m: Vec3 | Sequence[float], limits: MotionLimits, dt_s: float, max_speed_mps: float = math.inf
    ) -> tuple[Floats3, Floats3, Floats3]:
        """``update`` with the reference as (position, velocity, acceleration) float tuples, for a caller that
        works in floats anyway (three arrays and a record less per control step)."""
        tx, ty, tz = floats3(target_ned_m)
        px, py, pz = self._pos
        dx = tx - px
        dy = ty - py
        dz = tz - pz
        dist = math.sqrt(dx * dx + dy * dy + dz * dz)
        if dist < 1e-4 and self._speed < 1e-3:
            self._pos = (tx, ty, tz)
            self._speed = 0.0
            return self._pos, _ZERO3, _ZERO3
        if dist > 1e-9:
            ux, uy, uz = dx / dist, dy / dist, dz / dist
        else:
            ux, uy, uz = self._dir
        horizontal = math.hypot(ux, uy)
        line_limit = _component_scale(horizontal, uz, limits.speed_xy_mps, limits.speed_up_mps, limits.speed_down_mps)
        # A new direction (target moved) carries over only the speed component along it, and no more than the new
        # line allows: 5 m/s of horizontal cruise turned 45 degrees downward would otherwise descend at 2.5 m/s.
        # (A lower speed limit on the same line is approached with the allowed deceleration instead.)
        if self._speed > 0.0:
            ox, oy, oz = self._dir
            cos_turn = ux * ox + uy * oy + uz * oz
            if cos_turn < 1.0 - 1e-9:
                self._speed = min(max(0.0, self._speed * cos_turn), line_limit)
        self._dir = (ux, uy, uz)
        v_max = min(max_speed_mps, line_limit)
        a_max = _component_scale(horizontal, uz, limits.accel_xy_mps2, limits.accel_z_mps2, limits.accel_z_mps2)
        previous = self._speed
        desired = min(v_max, _stoppable_speed(dist, previous, a_max, dt_s))
        speed = max(previous - a_max * dt_s, min(previous + a_max * dt_s, desired))
        self._speed = speed
        step = min(dist, 0.5 * (previous + speed) * dt_s)
        self._pos = (px + ux * step, py + uy * step, pz + uz * step)
        acc = (speed - previous) / dt_s
        return self._pos, (ux * speed, uy * speed, uz * speed), (ux * acc, uy * acc, uz * acc)
