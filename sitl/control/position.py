"""Position stage: a proportional position loop that turns a position error into a velocity setpoint.

Follows PX4's ``PositionControl::_positionControl``. Each axis is controlled independently and a NaN field
means "not set" (MAVLink ``type_mask``): with no position on an axis the velocity setpoint passes straight
through (velocity control), with both a position and a velocity the velocity is a feed-forward. The horizontal
speed limit is applied to the horizontal vector (never per axis, which would bend the flight path), and gives
the position correction priority over the feed-forward, as PX4's ``ControlMath::constrainXY`` does.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sitl.control import Vec3f
from sitl.kernels import cascade as ck


@dataclass(frozen=True, slots=True, kw_only=True)
class PositionConfig:
    xy_p_per_s: float  # MPC_XY_P
    z_p_per_s: float  # MPC_Z_P
    xy_vel_max_mps: float  # MPC_XY_VEL_MAX
    z_vel_max_up_mps: float  # MPC_Z_VEL_MAX_UP
    z_vel_max_dn_mps: float  # MPC_Z_VEL_MAX_DN


class PositionController:
    """Stateless P loop; ``update`` returns the NED velocity setpoint, NaN on axes left to acceleration
    control. The arithmetic is the kernel ``position_velocity_sp`` (sitl/kernels/cascade.py), with PX4's
    ``constrainXY`` giving the position correction priority over the feed-forward."""

    def __init__(self, config: PositionConfig) -> None:
        self.config = config

    @property
    def config(self) -> PositionConfig:
        return self._config

    @config.setter
    def config(self, config: PositionConfig) -> None:
        self._config = config
        row = np.empty(ck.POSITION_SIZE)
        row[ck.P_XY_P] = config.xy_p_per_s
        row[ck.P_Z_P] = config.z_p_per_s
        row[ck.P_XY_VEL_MAX] = config.xy_vel_max_mps
        row[ck.P_Z_VEL_MAX_UP] = config.z_vel_max_up_mps
        row[ck.P_Z_VEL_MAX_DN] = config.z_vel_max_dn_mps
        self.row = row  # the configuration as the kernels take it

    def reset(self) -> None:
        """Nothing to forget: the position loop has no memory."""

    def update(self, pos_ned_m: Vec3f, pos_sp_ned_m: Vec3f, vel_ff_ned_mps: Vec3f) -> Vec3f:
        pos_x, pos_y, pos_z = pos_ned_m
        sp_x, sp_y, sp_z = pos_sp_ned_m
        ff_x, ff_y, ff_z = vel_ff_ned_mps
        return ck.position_velocity_sp(self.row, pos_x, pos_y, pos_z, sp_x, sp_y, sp_z, ff_x, ff_y, ff_z)
