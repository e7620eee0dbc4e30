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
    """Velocity PID in NED. ``update`` takes setpoints that may hold NaN ("not set") fields."""

    def __init__(self, config: VelocityConfig) -> None:
        self.config = config
        self.reset()

    def reset(self) -> None:
        self.integral_ned_mps2: list[float] = [0.0, 0.0, 0.0]
        self._vel_deriv = [0.0, 0.0, 0.0]
        self._prev_vel: Vec3f | None = None

    def _velocity_derivative(self, vel: Vec3f, dt_s: float) -> list[float]:
        deriv = self._vel_deriv
        prev = self._prev_vel
        self._prev_vel = vel
        if prev is None or dt_s <= 0.0:
            return deriv
        cutoff = self.config.vel_deriv_cutoff_hz
        alpha = 1.0 if cutoff <= 0.0 else dt_s / (dt_s + 1.0 / (2.0 * math.pi * cutoff))
        for i in range(3):
            raw = (vel[i] - prev[i]) / dt_s
            deriv[i] += alpha * (raw - deriv[i])
        return deriv

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
        cfg = self.config
        integ = self.integral_ned_mps2
        deriv = self._velocity_derivative(vel_ned_mps, dt_s)
        gains_p = (cfg.xy_p_per_s, cfg.xy_p_per_s, cfg.z_p_per_s)
        gains_d = (cfg.xy_d, cfg.xy_d, cfg.z_d)

        err = [0.0, 0.0, 0.0]
        acc = [0.0, 0.0, 0.0]
        for i in range(3):
            vel_sp = vel_sp_ned_mps[i]
            acc_ff = acc_ff_ned_mps2[i]
            if vel_sp != vel_sp:
                if acc_ff == acc_ff:  # acceleration control on this axis: the PID stays out
                    err[i] = _NAN
                    acc[i] = acc_ff
                    continue
                vel_sp = 0.0
            e = vel_sp - vel_ned_mps[i]
            err[i] = e
            pid = gains_p[i] * e + integ[i] - gains_d[i] * deriv[i]
            acc[i] = pid + acc_ff if acc_ff == acc_ff else pid
        acc_x, acc_y, acc_z = acc

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
            cos_max = math.cos(cfg.tilt_max_rad)
            if bz_z < cos_max:
                horiz = math.hypot(bz_x, bz_y)
                sin_max = math.sin(cfg.tilt_max_rad)
                if horiz < 1e-9:
                    bz_x, bz_y = sin_max, 0.0
                else:
                    bz_x, bz_y = bz_x / horiz * sin_max, bz_y / horiz * sin_max
                bz_z = cos_max

        # The collective keeps the demanded vertical force through the tilt limit (PX4 projects it the same way).
        collective = cfg.mass_kg * (GRAVITY_MPS2 - acc_z) / bz_z
        if collective < cfg.thrust_min_n:
            collective = cfg.thrust_min_n
        thr_x = -bz_x * collective
        thr_y = -bz_y * collective
        thr_z = -bz_z * collective

        # Vertical anti-windup: no integration further into a saturated collective.
        err_z = err[2]
        thrust_max = cfg.thrust_max_n
        if (-thr_z <= cfg.thrust_min_n and err_z >= 0.0) or (-thr_z >= thrust_max and err_z <= 0.0):
            err[2] = 0.0

        # Vertical priority with a horizontal margin, then the horizontal part gets what remains.
        thr_xy = math.hypot(thr_x, thr_y)
        allocated_xy = min(thr_xy, cfg.thrust_xy_margin_n)
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
            if cfg.xy_p_per_s > 0.0 and err[0] == err[0] and err[1] == err[1]:
                prod_x = thr_x / cfg.mass_kg
                prod_y = thr_y / cfg.mass_kg
                if acc_x * acc_x + acc_y * acc_y > prod_x * prod_x + prod_y * prod_y:
                    arw_gain = 2.0 / cfg.xy_p_per_s
                    err[0] -= arw_gain * (acc_x - prod_x)
                    err[1] -= arw_gain * (acc_y - prod_y)
            gains_i = (cfg.xy_i_per_s2, cfg.xy_i_per_s2, cfg.z_i_per_s2)
            for i in range(3):
                e = err[i]
                if e == e:
                    integ[i] += gains_i[i] * e * dt_s
            # The vertical integrator never needs to cancel more than gravity.
            if integ[2] > GRAVITY_MPS2:
                integ[2] = GRAVITY_MPS2
            elif integ[2] < -GRAVITY_MPS2:
                integ[2] = -GRAVITY_MPS2

        return VelocityOutput(acc_sp_ned_mps2=(acc_x, acc_y, acc_z), thrust_sp_ned_n=(thr_x, thr_y, thr_z))
