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
    """Rate PID; ``update`` returns the FRD torque setpoint (N m)."""

    def __init__(self, config: RateConfig) -> None:
        self.config = config
        self.reset()

    def reset(self) -> None:
        self.integral_radps2: list[float] = [0.0, 0.0, 0.0]
        self._ang_acc = [0.0, 0.0, 0.0]
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
        cfg = self.config
        ang_acc = self._ang_acc
        prev = self._prev_rates
        self._prev_rates = rates_frd_radps
        if prev is not None and dt_s > 0.0:
            cutoff = cfg.deriv_cutoff_hz
            alpha = 1.0 if cutoff <= 0.0 else dt_s / (dt_s + 1.0 / (2.0 * math.pi * cutoff))
            for i in range(3):
                raw = (rates_frd_radps[i] - prev[i]) / dt_s
                ang_acc[i] += alpha * (raw - ang_acc[i])

        integ = self.integral_radps2
        p, i_gain, d = cfg.p_per_s, cfg.i_per_s2, cfg.d
        demand = [0.0, 0.0, 0.0]
        for i in range(3):
            err = rates_sp_frd_radps[i] - rates_frd_radps[i]
            demand[i] = p[i] * err + integ[i] - d[i] * ang_acc[i]
            if freeze_integrator or dt_s <= 0.0:
                continue
            if (saturated_pos[i] and err > 0.0) or (saturated_neg[i] and err < 0.0):
                err = 0.0
            factor = err / _I_ATTENUATION_RATE_RADPS
            factor = 1.0 - factor * factor
            if factor > 0.0:
                value = integ[i] + factor * i_gain[i] * err * dt_s
                lim = cfg.int_lim_radps2[i]
                integ[i] = -lim if value < -lim else (lim if value > lim else value)

        jx, jy, jz = cfg.inertia_kg_m2
        wx, wy, wz = rates_frd_radps
        # Euler's equation: J dw/dt = tau - w x (J w), so the torque that yields the demanded acceleration
        # adds the gyroscopic term back.
        return (
            jx * demand[0] + (jz - jy) * wy * wz,
            jy * demand[1] + (jx - jz) * wz * wx,
            jz * demand[2] + (jy - jx) * wx * wy,
        )
