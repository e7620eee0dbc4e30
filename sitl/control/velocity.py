"""Velocity stage: velocity PID to an acceleration setpoint, then to a thrust vector in newtons.

Follows PX4's ``PositionControl::_velocityControl`` and ``_accelerationControl`` with physical units: the PID
gains are PX4's ``MPC_*_VEL_*_ACC`` (m/s^2 of demand per m/s of error), and where PX4 scales acceleration by a
hover thrust estimate this stage multiplies by the airframe mass, ``F = m (a_sp - g)``; the integrator absorbs
any mismatch (payload, battery sag, a different real mass).

Limits, in PX4's order: tilt (the thrust direction stays within ``MPC_TILTMAX_AIR`` of vertical, keeping the
vertical force), minimum collective thrust, then maximum thrust with vertical priority: the vertical component
may use everything but a horizontal margin (``MPC_THR_XY_MARG``), the horizontal component gets what is left.
Anti-windup: the vertical integrator stops integrating towards a saturated thrust and is bounded by +-g, the
horizontal integrator uses PX4's tracking anti-reset-windup (the unachieved acceleration bleeds it).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sitl.control import Vec3f
from sitl.kernels import cascade as ck


@dataclass(frozen=True, slots=True, kw_only=True)
class VelocityConfig:
    xy_p_per_s: float  # MPC_XY_VEL_P_ACC
    xy_i_per_s2: float  # MPC_XY_VEL_I_ACC
    xy_d: float  # MPC_XY_VEL_D_ACC
    z_p_per_s: float  # MPC_Z_VEL_P_ACC
    z_i_per_s2: float  # MPC_Z_VEL_I_ACC
    z_d: float  # MPC_Z_VEL_D_ACC
    vel_deriv_cutoff_hz: float  # MPC_VELD_LP, low-pass on the measured-velocity derivative (D term)
    tilt_max_rad: float  # MPC_TILTMAX_AIR
    thrust_min_n: float  # MPC_THR_MIN * maximum collective thrust
    thrust_max_n: float  # MPC_THR_MAX * maximum collective thrust
    thrust_xy_margin_n: float  # MPC_THR_XY_MARG * maximum collective thrust
    mass_kg: float  # airframe mass: the hover model


@dataclass(frozen=True, slots=True, kw_only=True)
class VelocityOutput:
    acc_sp_ned_mps2: Vec3f  # the PID demand plus feed-forward, before any thrust limit
    thrust_sp_ned_n: Vec3f  # the force the rotors should produce, after tilt and thrust limits


class VelocityController:
    """Velocity PID in NED. ``update`` takes setpoints that may hold NaN ("not set") fields. The arithmetic is the
    kernel ``velocity_thrust`` (sitl/kernels/cascade.py) on the controller's state row."""

    def __init__(self, config: VelocityConfig) -> None:
        self.config = config
        self.state = np.zeros(ck.VELOCITY_STATE_SIZE)

    @property
    def config(self) -> VelocityConfig:
        return self._config

    @config.setter
    def config(self, config: VelocityConfig) -> None:
        self._config = config
        row = np.empty(ck.VELOCITY_SIZE)
        row[ck.V_XY_P] = config.xy_p_per_s
        row[ck.V_XY_I] = config.xy_i_per_s2
        row[ck.V_XY_D] = config.xy_d
        row[ck.V_Z_P] = config.z_p_per_s
        row[ck.V_Z_I] = config.z_i_per_s2
        row[ck.V_Z_D] = config.z_d
        row[ck.V_CUTOFF] = config.vel_deriv_cutoff_hz
        row[ck.V_TILT_MAX] = config.tilt_max_rad
        row[ck.V_THRUST_MIN] = config.thrust_min_n
        row[ck.V_THRUST_MAX] = config.thrust_max_n
        row[ck.V_XY_MARGIN] = config.thrust_xy_margin_n
        row[ck.V_MASS] = config.mass_kg
        self.row = row  # the configuration as the kernels take it

    @property
    def integral_ned_mps2(self) -> list[float]:
        """The integrator, m/s^2 per NED axis."""
        return self.state[ck.VS_INTEGRAL : ck.VS_INTEGRAL + 3].tolist()

    def reset(self) -> None:
        self.state.fill(0.0)

    def update(
        self,
        vel_ned_mps: Vec3f,
        vel_sp_ned_mps: Vec3f,
        acc_ff_ned_mps2: Vec3f,
        dt_s: float,
        *,
        freeze_integrator: bool = False,
    ) -> VelocityOutput:
        """One control step; an axis with neither velocity nor acceleration setpoint holds zero velocity."""
        acc, thrust = self.thrust_setpoint(vel_ned_mps, vel_sp_ned_mps, acc_ff_ned_mps2, dt_s, freeze_integrator)
        return VelocityOutput(acc_sp_ned_mps2=acc, thrust_sp_ned_n=thrust)

    def thrust_setpoint(
        self,
        vel_ned_mps: Vec3f,
        vel_sp_ned_mps: Vec3f,
        acc_ff_ned_mps2: Vec3f,
        dt_s: float,
        freeze_integrator: bool = False,
    ) -> tuple[Vec3f, Vec3f]:
        """``update`` without the result object: (acceleration setpoint, thrust setpoint), for the cascade."""
        vx, vy, vz = vel_ned_mps
        sp_x, sp_y, sp_z = vel_sp_ned_mps
        ff_x, ff_y, ff_z = acc_ff_ned_mps2
        ax, ay, az, tx, ty, tz = ck.velocity_thrust(self.state, self.row, vx, vy, vz, sp_x, sp_y, sp_z, ff_x, ff_y,
                                                    ff_z, dt_s, freeze_integrator)  # fmt: skip
        return (ax, ay, az), (tx, ty, tz)
