"""Control allocation: body torque and collective thrust to motor commands, from the airframe geometry.

The effectiveness matrix B maps rotor thrusts T_i (N) to [roll, pitch, yaw torque (N m, FRD), collective
thrust (N)]: a rotor at (x_i, y_i) pushing up (-z) gives roll -y_i T_i and pitch x_i T_i, its drag torque is
spin_dir_i (k_q / k_t) T_i about +z, and the thrusts add up. It is computed from the airframe file, never
typed in, and inverted once with a pseudo-inverse (exact for a quad, least-squares for more rotors).

Rotors only push, and only so hard, so a demand may not fit in [0, T_max] per rotor. A demand that fits is
reproduced exactly. Otherwise, priorities as a multicopter needs them to stay upright:
  (a) roll/pitch that fit with no yaw share at all (judged alone, as PX4 does) are scaled down together,
      which keeps the axis of the correction;
  (b) the collective moves (along the pseudo-inverse's thrust column, which changes no torque) to the value
      nearest the demand at which roll/pitch fit with some share of the yaw demand;
  (c) yaw gets the largest share in [0, 1] that fits at that collective.
(b) and (c) form a two-variable linear programme (collective k, yaw share g) with one pair of bounds per
rotor, solved exactly, so the output moves continuously with the demand (no motor-command jumps when a limit
is reached). The result reports which torque axes were cut and in which direction, which the rate controller
uses to stop its integrator winding up against a limit.

Motor commands are ``u = sqrt(T / T_max)``: the flight model commands rotor speed ``u * omega_max`` and thrust
goes with speed squared.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sitl.control import Vec3f
from sitl.dynamics.airframe import Airframe
from sitl.kernels import cascade as ck
from sitl.mathutil import fast_constructor

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


_new_result = fast_constructor(AllocationResult)


def effectiveness_matrix(airframe: Airframe) -> np.ndarray:
    """B (4 x n): rotor thrusts (N) -> [roll, pitch, yaw torque (N m, FRD), collective thrust (N)]."""
    yaw_per_thrust_m = airframe.torque_coeff_nm_per_radps2 / airframe.thrust_coeff_n_per_radps2
    columns = [
        (-rotor.pos_frd_m[1], rotor.pos_frd_m[0], rotor.spin_dir * yaw_per_thrust_m, 1.0) for rotor in airframe.rotors
    ]
    return np.array(columns, dtype=np.float64).T


def pseudo_inverse(b: np.ndarray) -> np.ndarray | None:
    """B+ = B^T (B B^T)^-1 of a 4 x n effectiveness matrix, or None when B's rank is below 4 (some axis cannot be
    controlled). Worked out in plain floats by Gauss-Jordan elimination with partial pivoting rather than with
    LAPACK, whose result depends in its last bits on the CPU (sitl/mathutil.py): every step's motor commands
    come from it."""
    rows = b.tolist()
    gram = [[math.fsum(x * y for x, y in zip(ri, rj, strict=True)) for rj in rows] for ri in rows]
    size = len(gram)
    inverse = [[float(i == j) for j in range(size)] for i in range(size)]
    scale = max(abs(v) for row in gram for v in row)
    for col in range(size):
        pivot = max(range(col, size), key=lambda r: abs(gram[r][col]))
        if abs(gram[pivot][col]) <= 1e-12 * scale:
            return None
        gram[col], gram[pivot] = gram[pivot], gram[col]
        inverse[col], inverse[pivot] = inverse[pivot], inverse[col]
        head = gram[col][col]
        gram[col] = [v / head for v in gram[col]]
        inverse[col] = [v / head for v in inverse[col]]
        for r in range(size):
            if r != col and gram[r][col] != 0.0:
                factor = gram[r][col]
                gram[r] = [v - factor * w for v, w in zip(gram[r], gram[col], strict=True)]
                inverse[r] = [v - factor * w for v, w in zip(inverse[r], inverse[col], strict=True)]
    columns = list(zip(*rows, strict=True))  # B^T, one row per rotor
    return np.array([[math.fsum(c * inverse[k][j] for k, c in enumerate(column)) for j in range(size)]
                     for column in columns], dtype=np.float64)  # fmt: skip


class ControlAllocator:
    """Pseudo-inverse allocation with roll/pitch > collective > yaw priority under saturation."""

    def __init__(self, airframe: Airframe) -> None:
        self.effectiveness = effectiveness_matrix(airframe)
        mix = pseudo_inverse(self.effectiveness)  # n x 4: columns roll, pitch, yaw, collective
        if mix is None:
            raise ValueError(f"airframe {airframe.name}: rotor layout cannot control roll, pitch, yaw and thrust")
        self.rotor_count = len(airframe.rotors)
        self.thrust_max_n = airframe.max_thrust_per_rotor_n
        if mix[:, 3].min() <= 0.0:
            raise ValueError(f"airframe {airframe.name}: some rotor does not add to the collective thrust")
        # Per rotor i, everything in units of its collective share c_i (so that a collective k adds k to every
        # rotor): roll, pitch and yaw coefficients divided by c_i, c_i itself, and T_max / c_i.
        self.rows = np.array(
            [(r / c, p / c, y / c, c, self.thrust_max_n / c) for r, p, y, c in mix.tolist()], dtype=np.float64
        )  # the kernels' allocation rows (sitl/kernels/cascade.py: L_ROLL ... L_HI_MAX)

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
        """Rotor commands for a torque (N m, FRD) and collective thrust (N) demand, saturating by priority (the
        kernel ``allocate``)."""
        n = self.rotor_count
        cmds, thrusts, flags = np.empty(n), np.empty(n), np.empty(ck.FLAGS_SIZE)
        roll_t, pitch_t, yaw_t = torque_frd_nm
        ck.allocate(self.rows, self.thrust_max_n, roll_t, pitch_t, yaw_t, thrust_n, cmds, thrusts, flags)
        return result_from(cmds.tolist(), thrusts.tolist(), flags.tolist())


def result_from(cmds: list[float], thrusts: list[float], flags: list[float]) -> AllocationResult:
    """The record of the allocation kernel's output."""
    sp = ck.F_SAT_POS
    sn = ck.F_SAT_NEG
    return _new_result(
        motor_cmds=tuple(cmds),
        rotor_thrusts_n=tuple(thrusts),
        saturated_pos=(flags[sp] != 0.0, flags[sp + 1] != 0.0, flags[sp + 2] != 0.0),
        saturated_neg=(flags[sn] != 0.0, flags[sn + 1] != 0.0, flags[sn + 2] != 0.0),
        thrust_saturation=int(flags[ck.F_THRUST_SAT]),
    )
