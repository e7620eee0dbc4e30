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
        mix = np.linalg.pinv(self.effectiveness)  # n x 4: columns roll, pitch, yaw, collective
        self.rotor_count = len(airframe.rotors)
        self.thrust_max_n = airframe.max_thrust_per_rotor_n
        if mix[:, 3].min() <= 0.0:
            raise ValueError(f"airframe {airframe.name}: some rotor does not add to the collective thrust")
        # Per rotor i, everything measured in units of its collective share c_i: roll and pitch coefficients
        # divided by c_i, the yaw coefficient, c_i, and T_max / c_i (the most collective this rotor allows).
        self._rows: tuple[tuple[float, float, float, float, float], ...] = tuple(
            (r / c, p / c, y, c, self.thrust_max_n / c) for r, p, y, c in mix.tolist()
        )

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
        rows = self._rows

        # Roll/pitch part of rotor i in collective units, a_i = rp_i / c_i: a collective k fits roll/pitch iff
        # max(-a_i) <= k <= min(T_max / c_i - a_i).
        ratio = [r * roll_t + p * pitch_t for r, p, _, _, _ in rows]
        k_lo, k_hi = self._collective_range(ratio)
        rp_scale = 1.0
        if k_lo > k_hi:
            # (a) Scale roll/pitch by the largest s with s (a_j - a_i) <= T_max / c_j for every pair i, j.
            for a_j, row_j in zip(ratio, rows, strict=True):
                for a_i in ratio:
                    if a_j > a_i:
                        rp_scale = min(rp_scale, row_j[4] / (a_j - a_i))
            ratio = [a * rp_scale for a in ratio]
            k_lo, k_hi = self._collective_range(ratio)
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
        # (c) Yaw: the largest share in [0, 1] that keeps every rotor inside [0, T_max].
        base = []
        yaw_scale = 1.0
        for a, (_, _, y_coef, c, _) in zip(ratio, rows, strict=True):
            b = (a + collective) * c
            base.append(b)
            y = y_coef * yaw_t
            if y > 0.0:
                room = (t_max - b) / y
            elif y < 0.0:
                room = -b / y
            else:
                continue
            if room < yaw_scale:
                yaw_scale = room
        if yaw_scale < 0.0:
            yaw_scale = 0.0
        thrusts = []
        cmds = []
        yaw_part = yaw_scale * yaw_t
        for b, row in zip(base, rows, strict=True):
            t = b + yaw_part * row[2]
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

    def _collective_range(self, ratio: list[float]) -> tuple[float, float]:
        k_lo = -math.inf
        k_hi = math.inf
        for a, row in zip(ratio, self._rows, strict=True):
            if -a > k_lo:
                k_lo = -a
            if row[4] - a < k_hi:
                k_hi = row[4] - a
        return k_lo, k_hi
