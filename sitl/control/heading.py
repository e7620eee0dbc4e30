"""The heading a setpoint that leaves yaw free is flown at: held, or turned towards the direction of travel.

A multicopter can fly any way it faces, so a setpoint without a yaw (MAVLink's YAW_IGNORE, a goto or a mission item
with NaN heading) says nothing about where the nose points. PX4 holds the last heading in offboard and, in its auto
modes, follows MPC_YAW_MODE (3 = along the trajectory). Here the choice is one parameter, MPC_YAW_FOLLOW, for every
mode, because what the nose points at is what the forward camera sees: a drone of a rotating formation held at its
takeoff heading flies sideways or backwards to its camera, and does not see what it flies into (docs/avoidance.md).

Following the direction of travel turns the heading setpoint towards the horizontal velocity setpoint (the position
loop's output: where the drone is being sent, avoidance's correction included), at most MPC_YAWRAUTO_MAX, and only
when that velocity is above ``FOLLOW_MIN_SPEED_MPS``: a hovering drone's velocity demand is position-hold noise
whose direction means nothing, so below that the heading is kept, as ArduPilot keeps its look-ahead yaw below a
minimum speed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from sitl.mathutil import wrap_pi

# Well above a hovering drone's velocity demand (a few cm/s), below any cruise or formation speed worth looking
# ahead at (a circle of radius 4 m turning at 0.3 rad/s moves its slots at 1.2 m/s).
FOLLOW_MIN_SPEED_MPS = 0.5


@dataclass(frozen=True, slots=True, kw_only=True)
class HeadingConfig:
    follow_travel: bool  # MPC_YAW_FOLLOW
    follow_rate_max_radps: float  # MPC_YAWRAUTO_MAX


def follow_travel(yaw_sp_rad: float, vel_sp_n_mps: float, vel_sp_e_mps: float, elapsed_s: float,
                  config: HeadingConfig) -> float:  # fmt: skip
    """The next heading setpoint from the last one: turned towards the horizontal velocity setpoint at the rate
    limit, or unchanged while that velocity is slow (or not set)."""
    speed_sq = vel_sp_n_mps * vel_sp_n_mps + vel_sp_e_mps * vel_sp_e_mps
    if not config.follow_travel or not speed_sq > FOLLOW_MIN_SPEED_MPS * FOLLOW_MIN_SPEED_MPS:  # NaN: not set
        return yaw_sp_rad
    error = wrap_pi(math.atan2(vel_sp_e_mps, vel_sp_n_mps) - yaw_sp_rad)
    step = config.follow_rate_max_radps * elapsed_s
    return wrap_pi(yaw_sp_rad + max(-step, min(step, error)))
