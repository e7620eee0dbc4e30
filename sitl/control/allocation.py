"""Control allocation: body torque and collective thrust to motor commands, from the airframe geometry.

The effectiveness matrix B maps rotor thrusts T_i (N) to [roll, pitch, yaw torque (N m, FRD), collective
thrust (N)]: a rotor at (x_i, y_i) pushing up (-z) gives roll -y_i T_i and pitch x_i T_i, its drag torque is
spin_dir_i (k_q / k_t) T_i about +z, and the thrusts add up. It is computed from the airframe file, never
typed in, and inverted once with a pseudo-inverse (exact for a quad, least-squares for more rotors).

Rotors only push, and only so hard, so a demand may not fit in [0, T_max] per rotor. Priorities, as a
multicopter needs them to stay upright:
  (a) roll/pitch alone wider than the rotors' range -> scale roll and pitch down together (keeps the axis of
      the correction);
  (b) shift the collective (along the pseudo-inverse's thrust column, which changes no torque) to the value
      nearest the demand at which roll/pitch fit;
  (c) add yaw with the largest factor in [0, 1] that still fits.
The result reports which torque axes were cut and in which direction, which the rate controller uses to stop
its integrator winding up against a limit it cannot push.

Motor commands are ``u = sqrt(T / T_max)``: the flight model commands rotor speed ``u * omega_max`` and thrust
goes with speed squared.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sitl.airframe import Airframe
from sitl.control import Vec3f

Bool3 = tuple[bool, bool, bool]


@dataclass(frozen=True, slots=True, kw_only=True)
class AllocationResult:
    motor_cmds: tuple[float, ...]  # in [0, 1], rotor order of the airframe file
    rotor_thrusts_n: tuple[float, ...]
    # Per torque axis (roll, pitch, yaw): True if the delivered torque is below the demand (saturated_pos) or
    # above it (saturated_neg), i.e. the allocation could not go further in that direction.
    saturated_pos: Bool3
    saturated_neg: Bool3
    # +1: less collective than demanded (at the top), -1: more than demanded (roll/pitch needed it), 0: exact.
    thrust_saturation: int


def effectiveness_matrix(airframe: Airframe) -> np.ndarray:
    """B (4 x n): rotor thrusts (N) -> [roll, pitch, yaw torque (N m, FRD), collective thrust (N)]."""
    yaw_per_thrust_m = airframe.torque_coeff_nm_per_radps2 / airframe.thrust_coeff_n_per_radps2
    columns = [
        (-rotor.pos_frd_m[1], rotor.pos_frd_m[0], rotor.spin_dir * yaw_per_thrust_m, 1.0)
        for rotor in airframe.rotors
    ]
    return np.array(columns, dtype=np.float64).T


class ControlAllocator:
    """Pseudo-inverse allocation with roll/pitch > collective > yaw priority under saturation."""

    def __init__(self, airframe: Airframe) -> None:
        self.effectiveness = effectiveness_matrix(airframe)
        if np.linalg.matrix_rank(self.effectiveness) < 4:
            raise ValueError(
                f"airframe {airframe.name}: rotor layout cannot control roll, pitch, yaw and thrust"
            )
        mix = np.linalg.pinv(self.effectiveness)  # n x 4
        self.rotor_count = len(airframe.rotors)
        self.thrust_max_n = airframe.max_thrust_per_rotor_n
        self._roll: tuple[float, ...] = tuple(mix[:, 0].tolist())
        self._pitch: tuple[float, ...] = tuple(mix[:, 1].tolist())
        self._yaw: tuple[float, ...] = tuple(mix[:, 2].tolist())
        self._collective: tuple[float, ...] = tuple(mix[:, 3].tolist())
        if min(self._collective) <= 0.0:
            raise ValueError(f"airframe {airframe.name}: some rotor does not add to the collective thrust")

    @property
    def collective_max_n(self) -> float:
        return self.thrust_max_n * self.rotor_count

    def reset(self) -> None:
        """Nothing to forget: allocation has no memory."""

    def achieved(self, rotor_thrusts_n: tuple[float, ...] | list[float]) -> tuple[float, float, float, float]:
        """[roll, pitch, yaw torque, collective thrust] that the given rotor thrusts produce (B @ T)."""
        out = self.effectiveness @ np.asarray(rotor_thrusts_n, dtype=np.float64)
        return float(out[0]), float(out[1]), float(out[2]), float(out[3])

    def allocate(self, torque_frd_nm: Vec3f, thrust_n: float) -> AllocationResult:
        t_max = self.thrust_max_n
        roll_t, pitch_t, yaw_t = torque_frd_nm
        mix_r, mix_p, mix_y, mix_c = self._roll, self._pitch, self._yaw, self._collective
        idx = range(self.rotor_count)

        # Roll/pitch part per rotor, measured in units of the collective direction (a_i = rp_i / c_i): the
        # collective k fits roll/pitch iff max(-a_i) <= k <= min(T_max / c_i - a_i).
        ratio = [(mix_r[i] * roll_t + mix_p[i] * pitch_t) / mix_c[i] for i in idx]
        k_lo = max(-a for a in ratio)
        k_hi = min(t_max / mix_c[i] - ratio[i] for i in idx)
        rp_scale = 1.0
        if k_lo > k_hi:
            # (a) Scale roll/pitch by the largest s with s (a_j - a_i) <= T_max / c_j for every pair i, j.
            for j in idx:
                for i in idx:
                    spread = ratio[j] - ratio[i]
                    if spread > 0.0:
                        rp_scale = min(rp_scale, t_max / (mix_c[j] * spread))
            ratio = [a * rp_scale for a in ratio]
            k_lo = max(-a for a in ratio)
            k_hi = min(t_max / mix_c[i] - ratio[i] for i in idx)
            k_hi = max(k_hi, k_lo)  # rounding
        # (b) Collective nearest to the demand that keeps roll/pitch inside the rotor range.
        collective = thrust_n
        thrust_saturation = 0
        if collective < k_lo:
            collective = k_lo
            thrust_saturation = -1
        elif collective > k_hi:
            collective = k_hi
            thrust_saturation = 1
        base = [(ratio[i] + collective) * mix_c[i] for i in idx]
        # (c) Yaw: the largest share in [0, 1] that keeps every rotor inside [0, T_max].
        yaw_scale = 1.0
        for i in idx:
            y = mix_y[i] * yaw_t
            if y > 0.0:
                room = (t_max - base[i]) / y
            elif y < 0.0:
                room = -base[i] / y
            else:
                continue
            if room < yaw_scale:
                yaw_scale = room
        if yaw_scale < 0.0:
            yaw_scale = 0.0
        thrusts = []
        cmds = []
        for i in idx:
            t = base[i] + yaw_scale * mix_y[i] * yaw_t
            t = 0.0 if t < 0.0 else (t_max if t > t_max else t)
            thrusts.append(t)
            cmds.append(math.sqrt(t / t_max))

        rp_cut = rp_scale < 1.0
        yaw_cut = yaw_scale < 1.0
        return AllocationResult(
            motor_cmds=tuple(cmds),
            rotor_thrusts_n=tuple(thrusts),
            saturated_pos=(rp_cut and roll_t > 0.0, rp_cut and pitch_t > 0.0, yaw_cut and yaw_t > 0.0),
            saturated_neg=(rp_cut and roll_t < 0.0, rp_cut and pitch_t < 0.0, yaw_cut and yaw_t < 0.0),
            thrust_saturation=thrust_saturation,
        )
