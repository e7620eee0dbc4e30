"""Position stage: a proportional position loop that turns a position error into a velocity setpoint.

Follows PX4's ``PositionControl::_positionControl``. Each axis is controlled independently and a NaN field
means "not set" (MAVLink ``type_mask``): with no position on an axis the velocity setpoint passes straight
through (velocity control), with both a position and a velocity the velocity is a feed-forward. The horizontal
speed limit is applied to the horizontal vector (never per axis, which would bend the flight path), and gives
the position correction priority over the feed-forward, as PX4's ``ControlMath::constrainXY`` does.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from sitl.control import Vec3f

_NAN = math.nan


@dataclass(frozen=True, slots=True, kw_only=True)
class PositionConfig:
    xy_p_per_s: float  # MPC_XY_P
    z_p_per_s: float  # MPC_Z_P
    xy_vel_max_mps: float  # MPC_XY_VEL_MAX
    z_vel_max_up_mps: float  # MPC_Z_VEL_MAX_UP
    z_vel_max_dn_mps: float  # MPC_Z_VEL_MAX_DN


def constrain_xy(prio_x: float, prio_y: float, extra_x: float, extra_y: float, max_norm: float) -> tuple[float, float]:
    """Limit |prio + extra| to max_norm, keeping as much of the priority vector as fits (PX4 constrainXY)."""
    sum_x = prio_x + extra_x
    sum_y = prio_y + extra_y
    if sum_x * sum_x + sum_y * sum_y <= max_norm * max_norm:
        return sum_x, sum_y
    prio_norm = math.hypot(prio_x, prio_y)
    if prio_norm >= max_norm or math.hypot(extra_x - prio_x, extra_y - prio_y) < 1e-3:
        scale = max_norm / prio_norm if prio_norm > 0.0 else 0.0
        return prio_x * scale, prio_y * scale
    extra_norm = math.hypot(extra_x, extra_y)
    if prio_norm < 1e-3:
        scale = max_norm / extra_norm
        return extra_x * scale, extra_y * scale
    # Walk from the priority vector along the extra vector's direction until the circle of radius max_norm:
    # |prio + s * unit_extra| = max_norm, the positive root of a quadratic in s.
    ux = extra_x / extra_norm
    uy = extra_y / extra_norm
    m = ux * prio_x + uy * prio_y
    c = prio_x * prio_x + prio_y * prio_y - max_norm * max_norm
    s = -m + math.sqrt(m * m - c)
    return prio_x + ux * s, prio_y + uy * s


class PositionController:
    """Stateless P loop; ``update`` returns the NED velocity setpoint, NaN on axes left to acceleration
    control."""

    def __init__(self, config: PositionConfig) -> None:
        self.config = config

    def reset(self) -> None:
        """Nothing to forget: the position loop has no memory."""

    def update(self, pos_ned_m: Vec3f, pos_sp_ned_m: Vec3f, vel_ff_ned_mps: Vec3f) -> Vec3f:
        cfg = self.config
        pos_x, pos_y, pos_z = pos_ned_m
        sp_x, sp_y, sp_z = pos_sp_ned_m
        ff_x, ff_y, ff_z = vel_ff_ned_mps
        # Per axis, written out (this runs every control step): P on the position error plus the velocity
        # feed-forward; a NaN position leaves the feed-forward alone, a NaN feed-forward contributes nothing.
        if sp_x == sp_x:
            pos_part_x = cfg.xy_p_per_s * (sp_x - pos_x)
            vel_x = pos_part_x + ff_x if ff_x == ff_x else pos_part_x
        else:
            vel_x, pos_part_x = ff_x, 0.0
        if sp_y == sp_y:
            pos_part_y = cfg.xy_p_per_s * (sp_y - pos_y)
            vel_y = pos_part_y + ff_y if ff_y == ff_y else pos_part_y
        else:
            vel_y, pos_part_y = ff_y, 0.0
        if sp_z == sp_z:
            vel_z = cfg.z_p_per_s * (sp_z - pos_z)
            if ff_z == ff_z:
                vel_z = vel_z + ff_z
        else:
            vel_z = ff_z

        nan_x = vel_x != vel_x
        nan_y = vel_y != vel_y
        if not (nan_x and nan_y):
            lim_x, lim_y = constrain_xy(
                pos_part_x,
                pos_part_y,
                0.0 if nan_x else vel_x - pos_part_x,
                0.0 if nan_y else vel_y - pos_part_y,
                cfg.xy_vel_max_mps,
            )
            vel_x = _NAN if nan_x else lim_x
            vel_y = _NAN if nan_y else lim_y

        if vel_z < -cfg.z_vel_max_up_mps:
            vel_z = -cfg.z_vel_max_up_mps
        elif vel_z > cfg.z_vel_max_dn_mps:
            vel_z = cfg.z_vel_max_dn_mps
        return vel_x, vel_y, vel_z
