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

from dataclasses import dataclass

import numpy as np

from sitl.control import Vec3f
from sitl.kernels import cascade as ck

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
    """Rate PID; ``update`` returns the FRD torque setpoint (N m). The arithmetic is the kernel ``rate_torque``
    (sitl/kernels/cascade.py) on the controller's state row (integrator, filtered angular acceleration, previous
    rates, and the allocation's saturation report that the cascade's ``inner`` kernel writes into it)."""

    def __init__(self, config: RateConfig) -> None:
        self.config = config
        self.state = np.zeros(ck.RATE_STATE_SIZE)

    @property
    def config(self) -> RateConfig:
        return self._config

    @config.setter
    def config(self, config: RateConfig) -> None:
        self._config = config
        row = np.empty(ck.RATE_CONFIG_SIZE)
        row[ck.R_P : ck.R_P + 3] = config.p_per_s
        row[ck.R_I : ck.R_I + 3] = config.i_per_s2
        row[ck.R_D : ck.R_D + 3] = config.d
        row[ck.R_INT_LIM : ck.R_INT_LIM + 3] = config.int_lim_radps2
        row[ck.R_INERTIA : ck.R_INERTIA + 3] = config.inertia_kg_m2
        row[ck.R_CUTOFF] = config.deriv_cutoff_hz
        self.row = row  # the configuration as the kernels take it

    @property
    def integral_radps2(self) -> list[float]:
        """The integrator, rad/s^2 per axis."""
        return self.state[ck.S_INTEGRAL : ck.S_INTEGRAL + 3].tolist()

    def reset(self) -> None:
        self.state.fill(0.0)

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
        state = self.state
        state[ck.S_SAT_POS : ck.S_SAT_POS + 3] = saturated_pos
        state[ck.S_SAT_NEG : ck.S_SAT_NEG + 3] = saturated_neg
        wx, wy, wz = rates_frd_radps
        spx, spy, spz = rates_sp_frd_radps
        return ck.rate_torque(state, self.row, wx, wy, wz, spx, spy, spz, dt_s, freeze_integrator)
