"""StraightLineTrajectory.advance (floats) and update (arrays) are the same reference, step for step."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sitl.autopilot.guidance import MotionLimits, StraightLineTrajectory

pytestmark = pytest.mark.timeout(30)

DT_S = 1.0 / 400.0
LIMITS = MotionLimits(speed_xy_mps=5.0, speed_up_mps=3.0, speed_down_mps=1.5, accel_xy_mps2=3.0, accel_z_mps2=3.0)
# Legs that reach cruise, turn while moving, retarget mid-leg, arrive and rest, and climb.
LEGS = [((20.0, 0.0, -3.0), 3.0), ((5.0, 12.0, -8.0), 4.0), ((5.0, 12.0, -8.0), 3.0), ((0.0, 0.0, -1.0), 6.0)]


def test_advance_gives_exactly_what_update_gives() -> None:
    by_arrays = StraightLineTrajectory(np.array((0.0, 0.0, -1.0)))
    by_floats = StraightLineTrajectory((0.0, 0.0, -1.0))
    steps = 0
    for target, duration_s in LEGS:
        goal = np.array(target)
        for _ in range(round(duration_s / DT_S)):
            ref = by_arrays.update(goal, LIMITS, DT_S, max_speed_mps=4.0)
            pos, vel, acc = by_floats.advance(target, LIMITS, DT_S, max_speed_mps=4.0)
            assert tuple(ref.pos_ned_m.tolist()) == pos
            assert tuple(ref.vel_ned_mps.tolist()) == vel
            assert tuple(ref.acc_ned_mps2.tolist()) == acc
            steps += 1
    assert np.array_equal(by_arrays.position, by_floats.position)
    assert by_floats.position.tolist() == [0.0, 0.0, -1.0]  # arrived and at rest
    assert steps == round(sum(d for _, d in LEGS) / DT_S)
    assert not any(math.isnan(v) for v in pos + vel + acc)
