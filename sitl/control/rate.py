"""Body-rate stage: a PID on the FRD body rates whose output is a physical torque in newton metres.

Follows PX4's ``RateControl`` (P and I on the error, D on the measured rate through a low-pass, integrator
bounds, and no integration towards an axis the control allocation reports saturated), with one deliberate
difference in units: the PID computes an angular-acceleration demand in rad/s^2 and the torque is
``J * alpha + w x (J w)`` (Euler's rigid-body equation, J the airframe's diagonal inertia). So
``MC_ROLLRATE_P`` here is (rad/s^2) per (rad/s), i.e. 1/s, ``MC_*RATE_I`` is 1/s^2, ``MC_*RATE_D`` is
dimensionless and ``MC_*_INT_LIM`` is rad/s^2: the same gains fit any vehicle size, unlike PX4's normalised
torque units, and PX4 values do not carry over.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from sitl.control import Vec3f

# PX4's I-term attenuation: the integration rate shrinks smoothly for large rate errors (flips, big steps),
# which otherwise wind the integrator up during the manoeuvre and make it bounce back afterwards.
_I_ATTENUATION_RATE_RADPS = math.radians(400.0)

NO_SATURATION: tuple[bool, bool, bool] = (False, False, False)


@dataclass(frozen=True, slots=True, kw_only=True)
class RateConfig:
    p_per_s: Vec3f  # MC_ROLLRATE_P, MC_PITCHRATE_P, MC_YAWRATE_P
    i_per_s2: Vec3f  # MC_ROLLRATE_I, MC_PITCHRATE_I, MC_YAWRATE_I
    d: Vec3f  # MC_ROLLRATE_D, MC_PITCHRATE_D, MC_YAWRATE_D
    int_lim_radps2: Vec3f  # MC_RR_INT_LIM, MC_PR_INT_LIM, MC_YR_INT_LIM
    deriv_cutoff_hz: float  # IMU_DGYRO_CUTOFF, low-pass on the rate derivative for the D term
    inertia_kg_m2: Vec3f  # airframe diagonal inertia


class RateController:
    """Rate PID; ``update`` returns the FRD torque setpoint (N m).

    Written out per axis rather than looped over three indices: it runs at the physics rate for every drone.
    """

    def __init__(self, config: RateConfig) -> None:
        self.config = config
        self.reset()

    def reset(self) -> None:
        self.integral_radps2: list[float] = [0.0, 0.0, 0.0]
        self._ang_acc: Vec3f = (0.0, 0.0, 0.0)
        self._prev_rates: Vec3f | None = None

    def update(
        self,
        rates_frd_radps: Vec3f,
        rates_sp_frd_radps: Vec3f,
        dt_s: float,
        *,
        saturated_pos: tuple[bool, bool, bool] = NO_SATURATION,
        saturated_neg: tuple[bool, bool, bool] = NO_SATURATION,
        freeze_integrator: bool = False,
    ) -> Vec3f:
        """One step. ``saturated_pos[i]``: the allocation could not deliver more positive torque on axis i."""
        return self.torque_setpoint(
            rates_frd_radps, rates_sp_frd_radps, dt_s, saturated_pos, saturated_neg, freeze_integrator
        )

    def torque_setpoint(
        self,
        rates_frd_radps: Vec3f,
        rates_sp_frd_radps: Vec3f,
        dt_s: float,
        saturated_pos: tuple[bool, bool, bool],
        saturated_neg: tuple[bool, bool, bool],
        freeze_integrator: bool,
    ) -> Vec3f:
        """``update`` with positional arguments (the cascade's per-step call)."""
        cfg = self.config
        wx, wy, wz = rates_frd_radps
        # Low-passed angular acceleration from the measured rates (the D term acts on the measurement).
        acc_x, acc_y, acc_z = self._ang_acc
        prev = self._prev_rates
        self._prev_rates = rates_frd_radps
        if prev is not None and dt_s > 0.0:
            cutoff = cfg.deriv_cutoff_hz
            alpha = 1.0 if cutoff <= 0.0 else dt_s / (dt_s + 1.0 / (2.0 * math.pi * cutoff))
            acc_x += alpha * ((wx - prev[0]) / dt_s - acc_x)
            acc_y += alpha * ((wy - prev[1]) / dt_s - acc_y)
            acc_z += alpha * ((wz - prev[2]) / dt_s - acc_z)
            self._ang_acc = (acc_x, acc_y, acc_z)

        integ = self.integral_radps2
        p_x, p_y, p_z = cfg.p_per_s
        d_x, d_y, d_z = cfg.d
        sp_x, sp_y, sp_z = rates_sp_frd_radps
        err_x = sp_x - wx
        err_y = sp_y - wy
        err_z = sp_z - wz
        demand_x = p_x * err_x + integ[0] - d_x * acc_x
        demand_y = p_y * err_y + integ[1] - d_y * acc_y
        demand_z = p_z * err_z + integ[2] - d_z * acc_z
        if not freeze_integrator and dt_s > 0.0:
            # Per axis: no integration towards a side the allocation reports saturated, an integration rate
            # attenuated for large errors, and a bound.
            i_x, i_y, i_z = cfg.i_per_s2
            lim_x, lim_y, lim_z = cfg.int_lim_radps2
            sat_x, sat_y, sat_z = saturated_pos
            neg_x, neg_y, neg_z = saturated_neg
            if (sat_x and err_x > 0.0) or (neg_x and err_x < 0.0):
                err_x = 0.0
            factor = err_x / _I_ATTENUATION_RATE_RADPS
            factor = 1.0 - factor * factor
            if factor > 0.0:
                value = integ[0] + factor * i_x * err_x * dt_s
                integ[0] = -lim_x if value < -lim_x else (lim_x if value > lim_x else value)
            if (sat_y and err_y > 0.0) or (neg_y and err_y < 0.0):
                err_y = 0.0
            factor = err_y / _I_ATTENUATION_RATE_RADPS
            factor = 1.0 - factor * factor
            if factor > 0.0:
                value = integ[1] + factor * i_y * err_y * dt_s
                integ[1] = -lim_y if value < -lim_y else (lim_y if value > lim_y else value)
            if (sat_z and err_z > 0.0) or (neg_z and err_z < 0.0):
                err_z = 0.0
            factor = err_z / _I_ATTENUATION_RATE_RADPS
            factor = 1.0 - factor * factor
            if factor > 0.0:
                value = integ[2] + factor * i_z * err_z * dt_s
                integ[2] = -lim_z if value < -lim_z else (lim_z if value > lim_z else value)

        jx, jy, jz = cfg.inertia_kg_m2
        # Euler's equation: J dw/dt = tau - w x (J w), so the torque that yields the demanded acceleration
        # adds the gyroscopic term back.
        return (
            jx * demand_x + (jz - jy) * wy * wz,
            jy * demand_y + (jx - jz) * wz * wx,
            jz * demand_z + (jy - jx) * wx * wy,
        )
