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

from dataclasses import dataclass

from sitl.kernels import cascade as ck

# Well above a hovering drone's velocity demand (a few cm/s), below any cruise or formation speed worth looking
# ahead at (a circle of radius 4 m turning at 0.3 rad/s moves its slots at 1.2 m/s). Defined with the kernel that
# reads it.
FOLLOW_MIN_SPEED_MPS = ck.FOLLOW_MIN_SPEED_MPS


@dataclass(frozen=True, slots=True, kw_only=True)
class HeadingConfig:
    follow_travel: bool  # MPC_YAW_FOLLOW
    follow_rate_max_radps: float  # MPC_YAWRAUTO_MAX


def follow_travel(yaw_sp_rad: float, vel_sp_n_mps: float, vel_sp_e_mps: float, elapsed_s: float,
                  config: HeadingConfig) -> float:  # fmt: skip
    """The next heading setpoint from the last one: turned towards the horizontal velocity setpoint at the rate
    limit, or unchanged while that velocity is slow (or not set). The arithmetic is the kernel ``follow_travel``
    (sitl/kernels/cascade.py), which the cascade's outer loops call themselves."""
    return ck.follow_travel(yaw_sp_rad, vel_sp_n_mps, vel_sp_e_mps, elapsed_s, config.follow_travel,
                            config.follow_rate_max_radps)  # fmt: skip
