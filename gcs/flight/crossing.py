"""Straight-line moves that are allowed to cross: the stress test for onboard collision avoidance.

The formation engine plans transitions whose paths keep the drones apart (assignment plus a separation check), which
is what a mission wants and exactly what an avoidance test must not have. A ``CrossingMove`` sends every drone
straight to its own goal at a fixed cruise speed with a trapezoidal speed profile, whatever lies in between - e.g.
the classic antipodal swap, every drone on a circle to the opposite point, all paths through the centre at once. It
is up to the drones to stay apart. Pure: positions and time in, setpoints out.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

from gcs.flight.behaviours import SwarmState
from gcs.flight.formation import Setpoint

Vec3f = tuple[float, float, float]


class CrossingError(ValueError):
    """A move that cannot be flown (one line for the user)."""


def antipodal_goals(positions: Mapping[int, Sequence[float]], centre_ne_m: tuple[float, float] | None = None
                    ) -> dict[int, Vec3f]:  # fmt: skip
    """Each drone's point mirrored through the centre (default: the drones' centroid), at its own altitude."""
    if not positions:
        raise CrossingError("no drones to move")
    if centre_ne_m is None:
        centre_ne_m = (
            sum(p[0] for p in positions.values()) / len(positions),
            sum(p[1] for p in positions.values()) / len(positions),
        )
    cn, ce = centre_ne_m
    return {i: (2.0 * cn - p[0], 2.0 * ce - p[1], float(p[2])) for i, p in positions.items()}


@dataclass(frozen=True, slots=True)
class _Line:
    start: Vec3f
    unit: Vec3f
    length_m: float
    yaw_rad: float


class CrossingMove:
    """Every drone from where it is to its goal along a straight line, cruise ``speed_mps``, ramps at ``accel_mps2``."""

    def __init__(self, starts: Mapping[int, Sequence[float]], goals: Mapping[int, Sequence[float]], start_s: float,
                 *, speed_mps: float, accel_mps2: float = 1.0) -> None:  # fmt: skip
        if set(starts) != set(goals):
            raise CrossingError("every drone needs a start and a goal")
        if not (math.isfinite(speed_mps) and speed_mps > 0 and math.isfinite(accel_mps2) and accel_mps2 > 0):
            raise CrossingError(f"speed and acceleration must be positive, got {speed_mps}, {accel_mps2}")
        self.start_s = start_s
        self.goals = {i: (float(g[0]), float(g[1]), float(g[2])) for i, g in goals.items()}
        self.speed_mps = speed_mps
        self.accel_mps2 = accel_mps2
        self._lines: dict[int, _Line] = {}
        for i, p0 in starts.items():
            p1 = goals[i]
            d = (float(p1[0]) - float(p0[0]), float(p1[1]) - float(p0[1]), float(p1[2]) - float(p0[2]))
            length = math.sqrt(d[0] ** 2 + d[1] ** 2 + d[2] ** 2)
            if not math.isfinite(length):
                raise CrossingError(f"drone {i}: start and goal must be finite")
            unit = (d[0] / length, d[1] / length, d[2] / length) if length > 1e-9 else (0.0, 0.0, 0.0)
            yaw = math.atan2(unit[1], unit[0]) if math.hypot(unit[0], unit[1]) > 1e-9 else math.nan
            start = (float(p0[0]), float(p0[1]), float(p0[2]))
            self._lines[i] = _Line(start=start, unit=unit, length_m=length, yaw_rad=yaw)

    def _profile(self, length_m: float, t_s: float) -> tuple[float, float, float]:
        """(distance along the line, speed, acceleration) of a trapezoidal (or triangular) profile at time t."""
        a, v = self.accel_mps2, self.speed_mps
        if length_m < v * v / a:  # never reaches cruise speed
            v = math.sqrt(length_m * a)
        t_ramp = v / a
        t_cruise = max(0.0, (length_m - v * t_ramp) / v)
        if t_s <= 0.0:
            return 0.0, 0.0, 0.0
        if t_s < t_ramp:
            return 0.5 * a * t_s * t_s, a * t_s, a
        if t_s < t_ramp + t_cruise:
            return 0.5 * a * t_ramp * t_ramp + v * (t_s - t_ramp), v, 0.0
        t_dec = t_s - t_ramp - t_cruise
        if t_dec < t_ramp:
            return length_m - 0.5 * a * (t_ramp - t_dec) ** 2, v - a * t_dec, -a
        return length_m, 0.0, 0.0

    def duration_s(self) -> float:
        longest = max((line.length_m for line in self._lines.values()), default=0.0)
        v = min(self.speed_mps, math.sqrt(longest * self.accel_mps2)) if longest > 0 else 0.0
        return 0.0 if v == 0 else v / self.accel_mps2 + longest / v

    def setpoints(self, now_s: float, state: SwarmState | None = None) -> dict[int, Setpoint]:
        """Each drone's point on its line (a ``Behaviour`` for the streamer; the drones' state is not needed).

        The yaw faces along the line, so a forward camera looks where the drone is going."""
        out = {}
        for i, line in self._lines.items():
            s, v, a = self._profile(line.length_m, now_s - self.start_s)
            u, p = line.unit, line.start
            out[i] = Setpoint(
                pos_ned_m=(p[0] + u[0] * s, p[1] + u[1] * s, p[2] + u[2] * s),
                vel_ned_mps=(u[0] * v, u[1] * v, u[2] * v),
                acc_ned_mps2=(u[0] * a, u[1] * a, u[2] * a),
                yaw_rad=line.yaw_rad,
            )
        return out

    def targets(self) -> dict[int, Vec3f]:
        """The goals (the streamer reports them as the drones' slots)."""
        return dict(self.goals)

    def done(self, now_s: float) -> bool:
        return now_s - self.start_s >= self.duration_s()
