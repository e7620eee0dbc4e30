"""The heading of a setpoint that leaves yaw free: held, or turned towards the direction of travel."""

from __future__ import annotations

import math

import pytest

from sitl.control.heading import FOLLOW_MIN_SPEED_MPS, HeadingConfig, follow_travel

FOLLOW = HeadingConfig(follow_travel=True, follow_rate_max_radps=math.radians(45.0))
HOLD = HeadingConfig(follow_travel=False, follow_rate_max_radps=math.radians(45.0))


def test_the_heading_turns_towards_the_velocity_at_the_rate_limit_and_then_follows_it() -> None:
    # GIVEN a heading north and a velocity setpoint east at 1 m/s
    yaw = 0.0
    # WHEN 1 s passes in 100 steps THEN it has turned 45 deg towards east, no more
    for _ in range(100):
        yaw = follow_travel(yaw, 0.0, 1.0, 0.01, FOLLOW)
    assert yaw == pytest.approx(math.radians(45.0))
    # AND after another second it points east and stays there
    for _ in range(200):
        yaw = follow_travel(yaw, 0.0, 1.0, 0.01, FOLLOW)
    assert yaw == pytest.approx(math.pi / 2)


def test_the_shorter_way_round_across_plus_minus_180_degrees() -> None:
    # GIVEN a heading of 170 deg and travel towards -169 deg (191 deg): 21 deg clockwise, 339 anticlockwise
    travel = math.radians(-169.0)
    # WHEN 0.1 s passes THEN it turned 4.5 deg clockwise, to 174.5 deg
    yaw = follow_travel(math.radians(170.0), math.cos(travel), math.sin(travel), 0.1, FOLLOW)
    assert math.degrees(yaw) == pytest.approx(174.5)
    # AND it reaches the travel direction through 180 deg, not the long way round
    for _ in range(10):
        yaw = follow_travel(yaw, math.cos(travel), math.sin(travel), 0.1, FOLLOW)
    assert math.degrees(yaw) == pytest.approx(-169.0)


def test_slow_unset_or_disabled_keeps_the_heading() -> None:
    slow = FOLLOW_MIN_SPEED_MPS * 0.9
    assert follow_travel(0.3, 0.0, slow, 0.01, FOLLOW) == 0.3  # hovering: position-hold noise has no direction
    assert follow_travel(0.3, math.nan, math.nan, 0.01, FOLLOW) == 0.3  # no velocity setpoint
    assert follow_travel(0.3, 0.0, 2.0, 0.01, HOLD) == 0.3  # MPC_YAW_FOLLOW = 0 (PX4 offboard)
