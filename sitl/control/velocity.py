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

import math
from dataclasses import dataclass

from sitl.control import Vec3f
from sitl.mathutil import GRAVITY_MPS2

_NAN = math.nan


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
    """Velocity PID in NED. ``update`` takes setpoints that may hold NaN ("not set") fields.

    The body is written out per axis rather than looped over three indices: it runs at the physics rate for every
    drone, and the unrolled form does the same arithmetic in about half the interpreter time.
    """

    def __init__(self, config: VelocityConfig) -> None:
        self.config = config
        self.reset()

    def reset(self) -> None:
        self.integral_ned_mps2: list[float] = [0.0, 0.0, 0.0]
        self._vel_deriv: Vec3f = (0.0, 0.0, 0.0)
        self._prev_vel: Vec3f | None = None
        self._trig_config: VelocityConfig | None = None  # the config the cached tilt-limit cosine/sine belong to
        self._cos_tilt_max = 1.0
        self._sin_tilt_max = 0.0

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
        cfg = self.config
        integ = self.integral_ned_mps2
        vx, vy, vz = vel_ned_mps

        # Low-passed derivative of the measured velocity (the D term acts on the measurement).
        dx, dy, dz = self._vel_deriv
        prev = self._prev_vel
        self._prev_vel = vel_ned_mps
        if prev is not None and dt_s > 0.0:
            cutoff = cfg.vel_deriv_cutoff_hz
            alpha = 1.0 if cutoff <= 0.0 else dt_s / (dt_s + 1.0 / (2.0 * math.pi * cutoff))
            dx += alpha * ((vx - prev[0]) / dt_s - dx)
            dy += alpha * ((vy - prev[1]) / dt_s - dy)
            dz += alpha * ((vz - prev[2]) / dt_s - dz)
            self._vel_deriv = (dx, dy, dz)

        # PID per axis. A NaN velocity setpoint with an acceleration set is acceleration control (the PID stays
        # out); with neither set the axis brakes to zero velocity.
        sp_x, sp_y, sp_z = vel_sp_ned_mps
        ff_x, ff_y, ff_z = acc_ff_ned_mps2
        p_xy = cfg.xy_p_per_s
        d_xy = cfg.xy_d
        if sp_x == sp_x or ff_x != ff_x:
            err_x = (sp_x if sp_x == sp_x else 0.0) - vx
            acc_x = p_xy * err_x + integ[0] - d_xy * dx
            if ff_x == ff_x:
                acc_x = acc_x + ff_x
        else:
            err_x = _NAN
            acc_x = ff_x
        if sp_y == sp_y or ff_y != ff_y:
            err_y = (sp_y if sp_y == sp_y else 0.0) - vy
            acc_y = p_xy * err_y + integ[1] - d_xy * dy
            if ff_y == ff_y:
                acc_y = acc_y + ff_y
        else:
            err_y = _NAN
            acc_y = ff_y
        if sp_z == sp_z or ff_z != ff_z:
            err_z = (sp_z if sp_z == sp_z else 0.0) - vz
            acc_z = cfg.z_p_per_s * err_z + integ[2] - cfg.z_d * dz
            if ff_z == ff_z:
                acc_z = acc_z + ff_z
        else:
            err_z = _NAN
            acc_z = ff_z

        # Thrust direction (body z axis, pointing down through the vehicle) from a_sp - g, tilt-limited. A
        # demand to fall faster than gravity cannot be met by rotors: it is flown level-ish at minimum thrust.
        up_component = GRAVITY_MPS2 - acc_z
        if up_component < 0.0:
            up_component = 0.0
        norm = math.sqrt(acc_x * acc_x + acc_y * acc_y + up_component * up_component)
        if norm < 1e-9:
            bz_x, bz_y, bz_z = 0.0, 0.0, 1.0
        else:
            bz_x, bz_y, bz_z = -acc_x / norm, -acc_y / norm, up_component / norm
            if self._trig_config is not cfg:
                self._trig_config = cfg
                self._cos_tilt_max = math.cos(cfg.tilt_max_rad)
                self._sin_tilt_max = math.sin(cfg.tilt_max_rad)
            cos_max = self._cos_tilt_max
            if bz_z < cos_max:
                horiz = math.hypot(bz_x, bz_y)
                sin_max = self._sin_tilt_max
                if horiz < 1e-9:
                    bz_x, bz_y = sin_max, 0.0
                else:
                    bz_x, bz_y = bz_x / horiz * sin_max, bz_y / horiz * sin_max
                bz_z = cos_max

        # The collective keeps the demanded vertical force through the tilt limit (PX4 projects it the same way).
        mass = cfg.mass_kg
        thrust_min = cfg.thrust_min_n
        collective = mass * (GRAVITY_MPS2 - acc_z) / bz_z
        if collective < thrust_min:
            collective = thrust_min
        thr_x = -bz_x * collective
        thr_y = -bz_y * collective
        thr_z = -bz_z * collective

        # Vertical anti-windup: no integration further into a saturated collective.
        thrust_max = cfg.thrust_max_n
        if (-thr_z <= thrust_min and err_z >= 0.0) or (-thr_z >= thrust_max and err_z <= 0.0):
            err_z = 0.0

        # Vertical priority with a horizontal margin, then the horizontal part gets what remains.
        thr_xy = math.hypot(thr_x, thr_y)
        margin = cfg.thrust_xy_margin_n
        allocated_xy = margin if margin < thr_xy else thr_xy  # min(thr_xy, margin)
        thr_up_max_sq = thrust_max * thrust_max - allocated_xy * allocated_xy
        thr_up_max = math.sqrt(thr_up_max_sq) if thr_up_max_sq > 0.0 else 0.0
        if -thr_z > thr_up_max:
            thr_z = -thr_up_max
        thr_xy_max_sq = thrust_max * thrust_max - thr_z * thr_z
        thr_xy_max = math.sqrt(thr_xy_max_sq) if thr_xy_max_sq > 0.0 else 0.0
        if thr_xy > thr_xy_max:
            scale = thr_xy_max / thr_xy
            thr_x *= scale
            thr_y *= scale

        if not freeze_integrator and dt_s > 0.0:
            # Horizontal tracking anti-reset-windup (Rundqwist 1990, as PX4): while the produced horizontal
            # acceleration falls short of the demand, the shortfall is fed back against the integrator.
            if p_xy > 0.0 and err_x == err_x and err_y == err_y:
                prod_x = thr_x / mass
                prod_y = thr_y / mass
                if acc_x * acc_x + acc_y * acc_y > prod_x * prod_x + prod_y * prod_y:
                    arw_gain = 2.0 / p_xy
                    err_x -= arw_gain * (acc_x - prod_x)
                    err_y -= arw_gain * (acc_y - prod_y)
            i_xy = cfg.xy_i_per_s2
            if err_x == err_x:
                integ[0] += i_xy * err_x * dt_s
            if err_y == err_y:
                integ[1] += i_xy * err_y * dt_s
            if err_z == err_z:
                integ[2] += cfg.z_i_per_s2 * err_z * dt_s
            # The vertical integrator never needs to cancel more than gravity.
            if integ[2] > GRAVITY_MPS2:
                integ[2] = GRAVITY_MPS2
            elif integ[2] < -GRAVITY_MPS2:
                integ[2] = -GRAVITY_MPS2

        return (acc_x, acc_y, acc_z), (thr_x, thr_y, thr_z)
