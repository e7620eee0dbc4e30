"""Crossing moves: straight lines at a cruise speed, trapezoidal profile, antipodal goals."""

from __future__ import annotations

import math

import pytest

from gcs.flight.crossing import CrossingError, CrossingMove, antipodal_goals


def _circle(n: int, radius_m: float) -> dict[int, tuple[float, float, float]]:
    return {i: (radius_m * math.cos(2 * math.pi * i / n), radius_m * math.sin(2 * math.pi * i / n), -3.0)
            for i in range(n)}  # fmt: skip


def test_antipodal_goals_mirror_through_the_centroid_and_keep_altitude() -> None:
    goals = antipodal_goals(_circle(8, 6.0))
    for i, g in goals.items():
        opposite = _circle(8, 6.0)[(i + 4) % 8]
        assert math.dist(g, opposite) < 1e-9


def test_every_drone_flies_its_straight_line_at_cruise_speed_and_stops_at_the_goal() -> None:
    starts = _circle(8, 6.0)
    move = CrossingMove(starts, antipodal_goals(starts), 10.0, speed_mps=2.0, accel_mps2=1.0)
    # 12 m at 2 m/s with 1 m/s^2 ramps: 2 s up, 4 s cruise, 2 s down
    assert move.duration_s() == pytest.approx(8.0)
    mid = move.setpoints(14.0)
    for i, sp in mid.items():
        assert math.hypot(*sp.vel_ned_mps[:2]) == pytest.approx(2.0)
        # on the line through start and goal: perpendicular offset zero
        s = starts[i]
        cross = s[0] * sp.pos_ned_m[1] - s[1] * sp.pos_ned_m[0]
        assert abs(cross) < 1e-9
        assert math.cos(sp.yaw_rad - math.atan2(-s[1], -s[0])) > 1 - 1e-9  # facing the way it flies
    # every drone is at the centre at the same instant: paths really cross
    assert all(math.hypot(*sp.pos_ned_m[:2]) < 1e-9 for sp in move.setpoints(14.0).values())
    end = move.setpoints(18.5)
    assert all(math.dist(sp.pos_ned_m, g) < 1e-9 and tuple(sp.vel_ned_mps) == (0.0, 0.0, 0.0)
               for sp, g in zip(end.values(), antipodal_goals(starts).values(), strict=True))  # fmt: skip
    assert move.done(18.0) and not move.done(17.9)


def test_a_short_move_never_reaches_cruise_speed() -> None:
    move = CrossingMove({1: (0.0, 0.0, 0.0)}, {1: (1.0, 0.0, 0.0)}, 0.0, speed_mps=5.0, accel_mps2=1.0)
    assert move.duration_s() == pytest.approx(2.0)
    assert move.setpoints(1.0)[1].vel_ned_mps[0] == pytest.approx(1.0)


def test_bad_moves_are_refused() -> None:
    with pytest.raises(CrossingError):
        CrossingMove({1: (0, 0, 0)}, {2: (1, 0, 0)}, 0.0, speed_mps=1.0)
    with pytest.raises(CrossingError):
        CrossingMove({1: (0, 0, 0)}, {1: (1, 0, 0)}, 0.0, speed_mps=0.0)
    with pytest.raises(CrossingError):
        antipodal_goals({})
