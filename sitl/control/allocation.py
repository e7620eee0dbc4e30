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

from sitl.airframe import Airframe
from sitl.control import Vec3f
from sitl.mathutil import fast_constructor

Bool3 = tuple[bool, bool, bool]

# Rounding slack (N, in collective units) when testing whether a demand fits: bounds are compared in thrust
# units, never after dividing by a possibly tiny yaw coefficient.
_TOL = 1e-9

_NOT_CUT: Bool3 = (False, False, False)


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


# In the helpers below, rotor i must satisfy lo_i <= k + g * yaw_i <= hi_i: k the collective, g the yaw share.


def _shares_at(lo: list[float], hi: list[float], yaw: list[float], k: float) -> tuple[float, float]:
    """Interval of yaw shares in [0, 1] that fit at collective k (empty when first > second)."""
    g_lo = 0.0
    g_hi = 1.0
    for lo_i, hi_i, y in zip(lo, hi, yaw, strict=True):
        if y > 0.0:
            bound_lo = (lo_i - _TOL - k) / y
            bound_hi = (hi_i + _TOL - k) / y
        elif y < 0.0:
            bound_lo = (hi_i + _TOL - k) / y
            bound_hi = (lo_i - _TOL - k) / y
        elif lo_i - _TOL <= k <= hi_i + _TOL:
            continue
        else:
            return 1.0, 0.0
        if bound_lo > g_lo:
            g_lo = bound_lo
        if bound_hi < g_hi:
            g_hi = bound_hi
    return g_lo, g_hi


def _feasible_shares(lo: list[float], hi: list[float], yaw: list[float]) -> tuple[float, float]:
    """Interval of yaw shares in [0, 1] that fit at some collective: g (yaw_j - yaw_i) <= hi_j - lo_i."""
    g_start = 0.0
    g_end = 1.0
    for lo_i, y_i in zip(lo, yaw, strict=True):
        for hi_j, y_j in zip(hi, yaw, strict=True):
            room = hi_j - lo_i + _TOL
            slope = y_j - y_i
            if slope > 0.0:
                if room < g_end * slope:
                    g_end = room / slope
            elif slope < 0.0:
                if room < g_start * slope:  # i.e. room / slope > g_start, slope being negative
                    g_start = room / slope
            elif room < 0.0:
                return 1.0, 0.0
    return g_start, g_end


def _max_collective(hi: list[float], yaw: list[float], g_start: float, g_end: float) -> float:
    """Largest k that fits with some share in [g_start, g_end]: the maximum of min_i(hi_i - g * yaw_i).

    That function is concave and piecewise linear in g, so its maximum is at an end of the interval or where a
    falling bound (yaw_i > 0) crosses a rising one (yaw_j < 0).
    """
    candidates = [g_start, g_end]
    for hi_i, y_i in zip(hi, yaw, strict=True):
        if y_i > 0.0:
            for hi_j, y_j in zip(hi, yaw, strict=True):
                if y_j < 0.0:
                    g = (hi_i - hi_j) / (y_i - y_j)
                    if g_start < g < g_end:
                        candidates.append(g)
    return max(min(h - g * y for h, y in zip(hi, yaw, strict=True)) for g in candidates)


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
        self._rows: tuple[tuple[float, float, float, float, float], ...] = tuple(
            (r / c, p / c, y / c, c, self.thrust_max_n / c) for r, p, y, c in mix.tolist()
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
        """Rotor commands for a torque (N m, FRD) and collective thrust (N) demand, saturating by priority."""
        t_max = self.thrust_max_n
        roll_t, pitch_t, yaw_t = torque_frd_nm
        rows = self._rows

        # The common case first, in one pass: every rotor fits as demanded (the same per-rotor arithmetic as the
        # general path below with the full yaw share and the demanded collective).
        thrusts: list[float] = []
        cmds: list[float] = []
        for r, p, y_coef, c, hi_max in rows:
            a = r * roll_t + p * pitch_t
            y = y_coef * yaw_t
            if not -a - _TOL <= thrust_n + y <= hi_max - a + _TOL:
                break
            t = c * (a + thrust_n + y)
            t = 0.0 if t < 0.0 else (t_max if t > t_max else t)
            thrusts.append(t)
            cmds.append(math.sqrt(t / t_max))
        else:
            return _new_result(
                motor_cmds=tuple(cmds),
                rotor_thrusts_n=tuple(thrusts),
                saturated_pos=_NOT_CUT,
                saturated_neg=_NOT_CUT,
                thrust_saturation=0,
            )
        return self._allocate_saturated(roll_t, pitch_t, yaw_t, thrust_n)

    def _allocate_saturated(self, roll_t: float, pitch_t: float, yaw_t: float, thrust_n: float) -> AllocationResult:
        """The general case: some rotor would leave [0, T_max], so cut by priority (see the module docstring)."""
        t_max = self.thrust_max_n
        rows = self._rows

        # Rotor i takes c_i * (rp_i + k + g * yaw_i): rp_i and yaw_i are its roll/pitch and yaw parts in
        # collective units, k the collective, g the yaw share. Staying inside [0, T_max] means
        # lo_i = -rp_i <= k + g * yaw_i <= T_max / c_i - rp_i = hi_i.
        rp = [r * roll_t + p * pitch_t for r, p, _, _, _ in rows]
        yaw = [row[2] * yaw_t for row in rows]
        lo = [-a for a in rp]
        hi = [row[4] - a for a, row in zip(rp, rows, strict=True)]
        collective = thrust_n
        rp_scale = 1.0
        thrust_saturation = 0
        # The demanded collective with a reduced yaw share (roll/pitch then fit too)?
        g_lo, g_hi = _shares_at(lo, hi, yaw, collective)
        if g_lo > g_hi:
            g_start, g_end = _feasible_shares(lo, hi, yaw)
            if g_start > g_end:
                # (a) Scale roll/pitch by the largest s with s * (rp_j - rp_i) <= T_max / c_j for all i, j.
                for a_j, row_j in zip(rp, rows, strict=True):
                    for a_i in rp:
                        if a_j > a_i:
                            rp_scale = min(rp_scale, row_j[4] / (a_j - a_i))
                rp = [a * rp_scale for a in rp]
                lo = [-a for a in rp]
                hi = [row[4] - a for a, row in zip(rp, rows, strict=True)]
                g_start, g_end = 0.0, max(0.0, _feasible_shares(lo, hi, yaw)[1])
            # (b) The collective nearest to the demand at which roll/pitch fit with some yaw share.
            g_lo, g_hi = _shares_at(lo, hi, yaw, collective)
            if g_lo > g_hi:
                if collective > min(h - g_start * y for h, y in zip(hi, yaw, strict=True)):
                    collective = _max_collective(hi, yaw, g_start, g_end)
                    thrust_saturation = 1
                else:  # the mirror image: the smallest collective, via negated bounds
                    neg_lo = [-v for v in lo]
                    collective = -_max_collective(neg_lo, [-y for y in yaw], g_start, g_end)
                    thrust_saturation = -1
                g_hi = _shares_at(lo, hi, yaw, collective)[1]
        # (c) The largest yaw share at that collective.
        yaw_share = min(max(g_hi, 0.0), 1.0)

        thrusts = []
        cmds = []
        for a, y, row in zip(rp, yaw, rows, strict=True):
            t = row[3] * (a + collective + yaw_share * y)
            t = 0.0 if t < 0.0 else (t_max if t > t_max else t)
            thrusts.append(t)
            cmds.append(math.sqrt(t / t_max))

        rp_cut = rp_scale < 1.0 - _TOL
        yaw_cut = yaw_share < 1.0 - _TOL
        return _new_result(
            motor_cmds=tuple(cmds),
            rotor_thrusts_n=tuple(thrusts),
            saturated_pos=(rp_cut and roll_t > 0.0, rp_cut and pitch_t > 0.0, yaw_cut and yaw_t > 0.0),
            saturated_neg=(rp_cut and roll_t < 0.0, rp_cut and pitch_t < 0.0, yaw_cut and yaw_t < 0.0),
            thrust_saturation=thrust_saturation,
        )
