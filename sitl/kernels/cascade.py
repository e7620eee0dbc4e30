"""The cascade's inner loops as kernels: attitude P to body rates, the rate PID to a torque, and the allocation of
torque and collective thrust to motor commands (sitl/control/attitude.py, rate.py, allocation.py are their shells:
configuration from parameters, records for telemetry). ``inner`` runs all three at once, as the cascade does at
every physics step.

The same operations in the same order as the Python they replaced, with Python's ``min``/``max`` spelled out, so
motor commands keep their bits (the reference flight hashes every one of them).
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from sitl.kernels import kernel
from sitl.kernels.pymath import hypot2, pmax, pmin
from sitl.mathutil import GRAVITY_MPS2

# Attitude configuration row (sitl.control.attitude.AttitudeConfig).
A_ROLL_P = 0
A_PITCH_P = 1
A_YAW_P = 2
A_YAW_WEIGHT = 3
A_ROLL_MAX = 4
A_PITCH_MAX = 5
A_YAW_MAX = 6
ATTITUDE_SIZE = 7
# Rate configuration row (sitl.control.rate.RateConfig): per axis P, I, D, integrator limit, inertia; D cutoff.
R_P = 0
R_I = 3
R_D = 6
R_INT_LIM = 9
R_INERTIA = 12
R_CUTOFF = 15
RATE_CONFIG_SIZE = 16
# Rate state row: integrator, filtered angular acceleration, previous rates and whether there are any, and the
# allocation's saturation report of the last step (1.0 = saturated), positive then negative side per axis.
S_INTEGRAL = 0
S_ANG_ACC = 3
S_PREV = 6
S_HAVE_PREV = 9
S_SAT_POS = 10
S_SAT_NEG = 13
RATE_STATE_SIZE = 16
# Allocation rows (sitl.control.allocation.ControlAllocator): per rotor its roll, pitch and yaw coefficients in
# collective units, its collective share, and T_max over that share.
L_ROLL = 0
L_PITCH = 1
L_YAW = 2
L_SHARE = 3
L_HI_MAX = 4
# Allocation report: saturated_pos (3), saturated_neg (3), thrust saturation (+1, -1, 0).
F_SAT_POS = 0
F_SAT_NEG = 3
F_THRUST_SAT = 6
FLAGS_SIZE = 7

# Rounding slack (N, in collective units) when testing whether a demand fits: bounds are compared in thrust units,
# never after dividing by a possibly tiny yaw coefficient.
TOL = 1e-9
# PX4's I-term attenuation: the integration rate shrinks smoothly for large rate errors (flips, big steps), which
# otherwise wind the integrator up during the manoeuvre and make it bounce back afterwards.
I_ATTENUATION_RATE_RADPS = math.radians(400.0)


@kernel("UniTuple(float64, 4)(float64, float64, float64, float64, float64, float64)")
def quat_between(sx: float, sy: float, sz: float, dx: float, dy: float, dz: float) -> tuple[float, float, float, float]:
    """Shortest rotation taking unit vector src onto unit vector dst."""
    cx = sy * dz - sz * dy
    cy = sz * dx - sx * dz
    cz = sx * dy - sy * dx
    dot = sx * dx + sy * dy + sz * dz
    if cx * cx + cy * cy + cz * cz < 1e-10 and dot < 0.0:
        # Opposite vectors: rotate half a turn about any axis orthogonal to src (the least aligned base axis).
        ax_, ay_, az_ = abs(sx), abs(sy), abs(sz)
        if ax_ < ay_:
            b0, b1, b2 = (1.0, 0.0, 0.0) if ax_ < az_ else (0.0, 0.0, 1.0)
        else:
            b0, b1, b2 = (0.0, 1.0, 0.0) if ay_ < az_ else (0.0, 0.0, 1.0)
        cx = sy * b2 - sz * b1
        cy = sz * b0 - sx * b2
        cz = sx * b1 - sy * b0
        w = 0.0
    else:
        w = dot + 1.0
    n = math.sqrt(w * w + cx * cx + cy * cy + cz * cz)
    return w / n, cx / n, cy / n, cz / n


@kernel(
    "UniTuple(float64, 3)(float64, float64, float64, float64, float64, float64, float64, float64, float64,"
    " float64[::1])"
)
def attitude_rates(
    qw: float,
    qx: float,
    qy: float,
    qz: float,
    dw: float,
    dx: float,
    dy: float,
    dz: float,
    yawspeed_ff: float,
    cfg: npt.NDArray[np.float64],
) -> tuple[float, float, float]:
    """Body-rate setpoint (rad/s, FRD) steering attitude q to the setpoint d; NaN yaw-rate feed-forward = none."""
    # Body z axes (third DCM columns) of the current and desired attitude, in NED.
    ez0, ez1, ez2 = 2.0 * (qx * qz + qw * qy), 2.0 * (qy * qz - qw * qx), 1.0 - 2.0 * (qx * qx + qy * qy)
    ed0, ed1, ed2 = 2.0 * (dx * dz + dw * dy), 2.0 * (dy * dz - dw * dx), 1.0 - 2.0 * (dx * dx + dy * dy)
    # Reduced setpoint: the current attitude tilted (in the world frame) so that its thrust axis matches.
    tw, tx, ty, tz = quat_between(ez0, ez1, ez2, ed0, ed1, ed2)
    weight = cfg[A_YAW_WEIGHT]
    yaw_gain = cfg[A_YAW_P] / weight if weight > 1e-4 else cfg[A_YAW_P]
    if abs(tx) > 1.0 - 1e-5 or abs(ty) > 1.0 - 1e-5:
        # Thrust axes exactly opposed: no preferred tilt axis, so steer by the full attitude error (conj(q) q_sp).
        ew = qw * dw + qx * dx + qy * dy + qz * dz
        ex = qw * dx - qx * dw - qy * dz + qz * dy
        ey = qw * dy + qx * dz - qy * dw - qz * dx
        ez_ = qw * dz - qx * dy + qy * dx - qz * dw
        sign = 2.0 if ew >= 0.0 else -2.0
        rate_x = sign * ex * cfg[A_ROLL_P]
        rate_y = sign * ey * cfg[A_PITCH_P]
        rate_z = sign * ez_ * cfg[A_YAW_P]
    else:
        # reduced = tilt * q, then conj(q) * reduced and conj(reduced) * q_sp, with only the components used.
        rw = tw * qw - tx * qx - ty * qy - tz * qz
        rx = tw * qx + tx * qw + ty * qz - tz * qy
        ry = tw * qy - tx * qz + ty * qw + tz * qx
        rz = tw * qz + tx * qy - ty * qx + tz * qw
        # Tilt error in the body frame (its axis lies in the body x-y plane), as 2 sin(angle / 2) * axis.
        ex = qw * rx - qx * rw - qy * rz + qz * ry
        ey = qw * ry + qx * rz - qy * rw - qz * rx
        rate_x = 2.0 * ex * cfg[A_ROLL_P]
        rate_y = 2.0 * ey * cfg[A_PITCH_P]
        # Remaining heading error about the thrust axis, of which only the weighted share is used.
        mw = rw * dw + rx * dx + ry * dy + rz * dz
        mz = rw * dz - rx * dy + ry * dx - rz * dw
        if mw < 0.0:
            mz = -mz
        mz = mz if mz > -1.0 else -1.0
        mz = mz if mz < 1.0 else 1.0
        rate_z = 2.0 * math.sin(weight * math.asin(mz)) * yaw_gain
    if yawspeed_ff == yawspeed_ff:
        # NED down axis seen from the body: third row of the body->NED rotation matrix.
        rate_x += 2.0 * (qx * qz - qw * qy) * yawspeed_ff
        rate_y += 2.0 * (qy * qz + qw * qx) * yawspeed_ff
        rate_z += (1.0 - 2.0 * (qx * qx + qy * qy)) * yawspeed_ff
    lim = cfg[A_ROLL_MAX]
    rate_x = -lim if rate_x < -lim else (lim if rate_x > lim else rate_x)
    lim = cfg[A_PITCH_MAX]
    rate_y = -lim if rate_y < -lim else (lim if rate_y > lim else rate_y)
    lim = cfg[A_YAW_MAX]
    rate_z = -lim if rate_z < -lim else (lim if rate_z > lim else rate_z)
    return rate_x, rate_y, rate_z


@kernel(
    "UniTuple(float64, 3)(float64[::1], float64[::1], float64, float64, float64, float64, float64, float64, float64,"
    " boolean)"
)
def rate_torque(
    state: npt.NDArray[np.float64],
    cfg: npt.NDArray[np.float64],
    wx: float,
    wy: float,
    wz: float,
    spx: float,
    spy: float,
    spz: float,
    dt_s: float,
    freeze_integrator: bool,
) -> tuple[float, float, float]:
    """The torque setpoint (N m, FRD) of the rate PID, its ``state`` row advanced (the saturation report in the row is
    the allocation's of the last step)."""
    rates = (wx, wy, wz)
    rates_sp = (spx, spy, spz)
    acc = np.empty(3)
    for k in range(3):
        acc[k] = state[S_ANG_ACC + k]
    if state[S_HAVE_PREV] != 0.0 and dt_s > 0.0:
        cutoff = cfg[R_CUTOFF]
        alpha = 1.0 if cutoff <= 0.0 else dt_s / (dt_s + 1.0 / (2.0 * math.pi * cutoff))
        for k in range(3):
            acc[k] += alpha * ((rates[k] - state[S_PREV + k]) / dt_s - acc[k])
            state[S_ANG_ACC + k] = acc[k]
    for k in range(3):
        state[S_PREV + k] = rates[k]
    state[S_HAVE_PREV] = 1.0
    demand = np.empty(3)
    for k in range(3):
        err = rates_sp[k] - rates[k]
        demand[k] = cfg[R_P + k] * err + state[S_INTEGRAL + k] - cfg[R_D + k] * acc[k]
        if not freeze_integrator and dt_s > 0.0:
            # No integration towards a side the allocation reports saturated, an integration rate attenuated for
            # large errors, and a bound.
            if (state[S_SAT_POS + k] != 0.0 and err > 0.0) or (state[S_SAT_NEG + k] != 0.0 and err < 0.0):
                err = 0.0
            factor = err / I_ATTENUATION_RATE_RADPS
            factor = 1.0 - factor * factor
            if factor > 0.0:
                lim = cfg[R_INT_LIM + k]
                value = state[S_INTEGRAL + k] + factor * cfg[R_I + k] * err * dt_s
                state[S_INTEGRAL + k] = -lim if value < -lim else (lim if value > lim else value)
    jx, jy, jz = cfg[R_INERTIA], cfg[R_INERTIA + 1], cfg[R_INERTIA + 2]
    # Euler's equation: J dw/dt = tau - w x (J w), so the torque that yields the demanded acceleration adds the
    # gyroscopic term back.
    return (
        jx * demand[0] + (jz - jy) * wy * wz,
        jy * demand[1] + (jx - jz) * wz * wx,
        jz * demand[2] + (jy - jx) * wx * wy,
    )


# In the helpers below, rotor i must satisfy lo_i <= k + g * yaw_i <= hi_i: k the collective, g the yaw share.


@kernel("UniTuple(float64, 2)(float64[::1], float64[::1], float64[::1], float64)")
def _shares_at(
    lo: npt.NDArray[np.float64], hi: npt.NDArray[np.float64], yaw: npt.NDArray[np.float64], k: float
) -> tuple[float, float]:
    """Interval of yaw shares in [0, 1] that fit at collective k (empty when first > second)."""
    g_lo = 0.0
    g_hi = 1.0
    for i in range(lo.shape[0]):
        lo_i, hi_i, y = lo[i], hi[i], yaw[i]
        if y > 0.0:
            bound_lo = (lo_i - TOL - k) / y
            bound_hi = (hi_i + TOL - k) / y
        elif y < 0.0:
            bound_lo = (hi_i + TOL - k) / y
            bound_hi = (lo_i - TOL - k) / y
        elif lo_i - TOL <= k <= hi_i + TOL:
            continue
        else:
            return 1.0, 0.0
        if bound_lo > g_lo:
            g_lo = bound_lo
        if bound_hi < g_hi:
            g_hi = bound_hi
    return g_lo, g_hi


@kernel("UniTuple(float64, 2)(float64[::1], float64[::1], float64[::1])")
def _feasible_shares(
    lo: npt.NDArray[np.float64], hi: npt.NDArray[np.float64], yaw: npt.NDArray[np.float64]
) -> tuple[float, float]:
    """Interval of yaw shares in [0, 1] that fit at some collective: g (yaw_j - yaw_i) <= hi_j - lo_i."""
    g_start = 0.0
    g_end = 1.0
    n = lo.shape[0]
    for i in range(n):
        for j in range(n):
            room = hi[j] - lo[i] + TOL
            slope = yaw[j] - yaw[i]
            if slope > 0.0:
                if room < g_end * slope:
                    g_end = room / slope
            elif slope < 0.0:
                if room < g_start * slope:  # i.e. room / slope > g_start, slope being negative
                    g_start = room / slope
            elif room < 0.0:
                return 1.0, 0.0
    return g_start, g_end


@kernel("float64(float64[::1], float64[::1], float64)")
def _lowest_bound(hi: npt.NDArray[np.float64], yaw: npt.NDArray[np.float64], g: float) -> float:
    """min_i(hi_i - g * yaw_i), as Python's ``min`` over them in rotor order."""
    best = hi[0] - g * yaw[0]
    for i in range(1, hi.shape[0]):
        v = hi[i] - g * yaw[i]
        if v < best:
            best = v
    return best


@kernel("float64(float64[::1], float64[::1], float64, float64)")
def _max_collective(hi: npt.NDArray[np.float64], yaw: npt.NDArray[np.float64], g_start: float, g_end: float) -> float:
    """Largest k that fits with some share in [g_start, g_end]: the maximum of min_i(hi_i - g * yaw_i), which is
    concave and piecewise linear in g, so at an end of the interval or where a falling bound (yaw_i > 0) crosses a
    rising one (yaw_j < 0); candidates in the order the Python listed them, the first of equal maxima kept."""
    best = _lowest_bound(hi, yaw, g_start)
    v = _lowest_bound(hi, yaw, g_end)
    if v > best:
        best = v
    n = hi.shape[0]
    for i in range(n):
        if yaw[i] > 0.0:
            for j in range(n):
                if yaw[j] < 0.0:
                    g = (hi[i] - hi[j]) / (yaw[i] - yaw[j])
                    if g_start < g < g_end:
                        v = _lowest_bound(hi, yaw, g)
                        if v > best:
                            best = v
    return best


@kernel("void(float64[:, ::1], float64, float64, float64, float64, float64, float64[::1], float64[::1], float64[::1])")
def allocate(
    rows: npt.NDArray[np.float64],
    t_max: float,
    roll_t: float,
    pitch_t: float,
    yaw_t: float,
    thrust_n: float,
    cmds: npt.NDArray[np.float64],
    thrusts: npt.NDArray[np.float64],
    flags: npt.NDArray[np.float64],
) -> None:
    """Rotor commands and thrusts for a torque (N m, FRD) and collective thrust (N) demand, saturating by priority
    (sitl/control/allocation.py); which axes were cut and the thrust saturation in ``flags``."""
    n = rows.shape[0]
    for k in range(FLAGS_SIZE):
        flags[k] = 0.0
    # The common case first, in one pass: every rotor fits as demanded.
    fits = True
    for i in range(n):
        a = rows[i, L_ROLL] * roll_t + rows[i, L_PITCH] * pitch_t
        y = rows[i, L_YAW] * yaw_t
        if not -a - TOL <= thrust_n + y <= rows[i, L_HI_MAX] - a + TOL:
            fits = False
            break
        t = rows[i, L_SHARE] * (a + thrust_n + y)
        t = 0.0 if t < 0.0 else (t_max if t > t_max else t)
        thrusts[i] = t
        cmds[i] = math.sqrt(t / t_max)
    if fits:
        return
    # The general case: some rotor would leave [0, T_max], so cut by priority. Rotor i takes c_i * (rp_i + k + g *
    # yaw_i); staying inside [0, T_max] means lo_i = -rp_i <= k + g * yaw_i <= T_max / c_i - rp_i = hi_i.
    rp = np.empty(n)
    yaw = np.empty(n)
    lo = np.empty(n)
    hi = np.empty(n)
    for i in range(n):
        rp[i] = rows[i, L_ROLL] * roll_t + rows[i, L_PITCH] * pitch_t
        yaw[i] = rows[i, L_YAW] * yaw_t
        lo[i] = -rp[i]
        hi[i] = rows[i, L_HI_MAX] - rp[i]
    collective = thrust_n
    rp_scale = 1.0
    thrust_saturation = 0.0
    # The demanded collective with a reduced yaw share (roll/pitch then fit too)?
    g_lo, g_hi = _shares_at(lo, hi, yaw, collective)
    if g_lo > g_hi:
        g_start, g_end = _feasible_shares(lo, hi, yaw)
        if g_start > g_end:
            # (a) Scale roll/pitch by the largest s with s * (rp_j - rp_i) <= T_max / c_j for all i, j.
            for j in range(n):
                for i in range(n):
                    if rp[j] > rp[i]:
                        rp_scale = pmin(rp_scale, rows[j, L_HI_MAX] / (rp[j] - rp[i]))
            for i in range(n):
                rp[i] = rp[i] * rp_scale
                lo[i] = -rp[i]
                hi[i] = rows[i, L_HI_MAX] - rp[i]
            g_start, g_end = 0.0, pmax(0.0, _feasible_shares(lo, hi, yaw)[1])
        # (b) The collective nearest to the demand at which roll/pitch fit with some yaw share.
        g_lo, g_hi = _shares_at(lo, hi, yaw, collective)
        if g_lo > g_hi:
            if collective > _lowest_bound(hi, yaw, g_start):
                collective = _max_collective(hi, yaw, g_start, g_end)
                thrust_saturation = 1.0
            else:  # the mirror image: the smallest collective, via negated bounds
                neg_lo = np.empty(n)
                neg_yaw = np.empty(n)
                for i in range(n):
                    neg_lo[i] = -lo[i]
                    neg_yaw[i] = -yaw[i]
                collective = -_max_collective(neg_lo, neg_yaw, g_start, g_end)
                thrust_saturation = -1.0
            g_hi = _shares_at(lo, hi, yaw, collective)[1]
    # (c) The largest yaw share at that collective.
    yaw_share = pmin(pmax(g_hi, 0.0), 1.0)
    for i in range(n):
        t = rows[i, L_SHARE] * (rp[i] + collective + yaw_share * yaw[i])
        t = 0.0 if t < 0.0 else (t_max if t > t_max else t)
        thrusts[i] = t
        cmds[i] = math.sqrt(t / t_max)
    rp_cut = rp_scale < 1.0 - TOL
    yaw_cut = yaw_share < 1.0 - TOL
    flags[F_SAT_POS] = 1.0 if rp_cut and roll_t > 0.0 else 0.0
    flags[F_SAT_POS + 1] = 1.0 if rp_cut and pitch_t > 0.0 else 0.0
    flags[F_SAT_POS + 2] = 1.0 if yaw_cut and yaw_t > 0.0 else 0.0
    flags[F_SAT_NEG] = 1.0 if rp_cut and roll_t < 0.0 else 0.0
    flags[F_SAT_NEG + 1] = 1.0 if rp_cut and pitch_t < 0.0 else 0.0
    flags[F_SAT_NEG + 2] = 1.0 if yaw_cut and yaw_t < 0.0 else 0.0
    flags[F_THRUST_SAT] = thrust_saturation


# ``inner``'s output row: body-rate setpoint, torque setpoint, the allocation's report, then per rotor its command and
# its thrust.
O_RATES_SP = 0
O_TORQUE = 3
O_FLAGS = 6
O_ROTORS = O_FLAGS + FLAGS_SIZE


@kernel(
    "void(float64, float64, float64, float64, float64, float64, float64, float64, float64, boolean, float64, float64,"
    " float64, float64, float64, float64, float64, float64, boolean, float64[::1], float64[::1], float64[::1],"
    " float64[:, ::1], float64, float64[::1])"
)
def inner(
    qw: float,
    qx: float,
    qy: float,
    qz: float,
    dw: float,
    dx: float,
    dy: float,
    dz: float,
    yawspeed_ff: float,
    rates_given: bool,
    spx: float,
    spy: float,
    spz: float,
    wx: float,
    wy: float,
    wz: float,
    collective: float,
    dt_s: float,
    landed: bool,
    attitude_cfg: npt.NDArray[np.float64],
    rate_cfg: npt.NDArray[np.float64],
    rate_state: npt.NDArray[np.float64],
    alloc_rows: npt.NDArray[np.float64],
    t_max: float,
    out: npt.NDArray[np.float64],
) -> None:
    """The inner loops of one step: attitude (unless the body rates are given), rate and allocation; the
    allocation's saturation report goes into the rate state for the next step's integrator."""
    if not rates_given:
        spx, spy, spz = attitude_rates(qw, qx, qy, qz, dw, dx, dy, dz, yawspeed_ff, attitude_cfg)
    tx, ty, tz = rate_torque(rate_state, rate_cfg, wx, wy, wz, spx, spy, spz, dt_s, landed)
    n = alloc_rows.shape[0]
    flags = out[O_FLAGS : O_FLAGS + FLAGS_SIZE]
    allocate(alloc_rows, t_max, tx, ty, tz, collective, out[O_ROTORS : O_ROTORS + n],
             out[O_ROTORS + n : O_ROTORS + 2 * n], flags)  # fmt: skip
    for k in range(3):
        rate_state[S_SAT_POS + k] = flags[F_SAT_POS + k]
        rate_state[S_SAT_NEG + k] = flags[F_SAT_NEG + k]
    out[O_RATES_SP], out[O_RATES_SP + 1], out[O_RATES_SP + 2] = spx, spy, spz
    out[O_TORQUE], out[O_TORQUE + 1], out[O_TORQUE + 2] = tx, ty, tz


# ---------------------------------------------------------------------------------------------------------------------
# The outer loops (at MPC_LOOP_HZ): position P to a velocity setpoint, the velocity PID to an acceleration and a thrust
# vector, and the attitude that produces that thrust at the heading setpoint.

# Position configuration row (sitl.control.position.PositionConfig).
P_XY_P = 0
P_Z_P = 1
P_XY_VEL_MAX = 2
P_Z_VEL_MAX_UP = 3
P_Z_VEL_MAX_DN = 4
POSITION_SIZE = 5
# Velocity configuration row (sitl.control.velocity.VelocityConfig).
V_XY_P = 0
V_XY_I = 1
V_XY_D = 2
V_Z_P = 3
V_Z_I = 4
V_Z_D = 5
V_CUTOFF = 6
V_TILT_MAX = 7
V_THRUST_MIN = 8
V_THRUST_MAX = 9
V_XY_MARGIN = 10
V_MASS = 11
VELOCITY_SIZE = 12
# Velocity state row: integrator, filtered derivative of the measured velocity, the previous velocity and whether
# there is one.
VS_INTEGRAL = 0
VS_DERIV = 3
VS_PREV = 6
VS_HAVE_PREV = 9
VELOCITY_STATE_SIZE = 10
# Heading configuration row (sitl.control.heading.HeadingConfig): follow the direction of travel (1.0) or hold the
# heading, and the turn rate limit while following.
HD_FOLLOW = 0
HD_RATE_MAX = 1
HEADING_SIZE = 2
# A trajectory setpoint as the kernels take it (sitl.control.cascade.TrajectorySetpoint; NaN = not set).
SP_POS = 0
SP_VEL = 3
SP_ACC = 6
SP_YAW = 9
SP_YAWSPEED = 10
SETPOINT_SIZE = 11
# The outer loops' last output, held between their runs: the attitude setpoint, the heading-rate feed-forward and
# the collective thrust the inner loops fly towards (also between ticks, sitl/kernels/between_ticks.py), the velocity,
# acceleration and thrust setpoints, and the heading setpoint last flown (NaN: none yet).
U_ATT_SP = 0
U_YAWSPEED_FF = 4
U_COLLECTIVE = 5
U_VEL_SP = 6
U_ACC_SP = 9
U_THRUST = 12
U_YAW_PREV = 15
OUTER_SIZE = 16
# A heading setpoint follows the direction of travel only above this speed (sitl/control/heading.py says why).
FOLLOW_MIN_SPEED_MPS = 0.5


@kernel("UniTuple(float64, 2)(float64, float64, float64, float64, float64)")
def constrain_xy(prio_x: float, prio_y: float, extra_x: float, extra_y: float, max_norm: float) -> tuple[float, float]:
    """Limit |prio + extra| to max_norm, keeping as much of the priority vector as fits (PX4 constrainXY)."""
    sum_x = prio_x + extra_x
    sum_y = prio_y + extra_y
    if sum_x * sum_x + sum_y * sum_y <= max_norm * max_norm:
        return sum_x, sum_y
    prio_norm = hypot2(prio_x, prio_y)
    if prio_norm >= max_norm or hypot2(extra_x - prio_x, extra_y - prio_y) < 1e-3:
        scale = max_norm / prio_norm if prio_norm > 0.0 else 0.0
        return prio_x * scale, prio_y * scale
    extra_norm = hypot2(extra_x, extra_y)
    if prio_norm < 1e-3:
        scale = max_norm / extra_norm
        return extra_x * scale, extra_y * scale
    # Walk from the priority vector along the extra vector's direction until the circle of radius max_norm:
    # |prio + s * unit_extra| = max_norm, the positive root of a quadratic in s.
    ux = extra_x / extra_norm
    uy = extra_y / extra_norm
    m = ux * prio_x + uy * prio_y
    c = prio_x * prio_x + prio_y * prio_y - max_norm * max_norm
    s = -m + math.sqrt(m * m - c)
    return prio_x + ux * s, prio_y + uy * s


@kernel(
    "UniTuple(float64, 3)(float64[::1], float64, float64, float64, float64, float64, float64, float64, float64,"
    " float64)"
)
def position_velocity_sp(
    cfg: npt.NDArray[np.float64],
    pos_x: float,
    pos_y: float,
    pos_z: float,
    sp_x: float,
    sp_y: float,
    sp_z: float,
    ff_x: float,
    ff_y: float,
    ff_z: float,
) -> tuple[float, float, float]:
    """The NED velocity setpoint of the position P loop, NaN on axes left to acceleration control: P on the position
    error plus the velocity feed-forward; a NaN position leaves the feed-forward alone, a NaN feed-forward adds
    nothing."""
    if sp_x == sp_x:
        pos_part_x = cfg[P_XY_P] * (sp_x - pos_x)
        vel_x = pos_part_x + ff_x if ff_x == ff_x else pos_part_x
    else:
        vel_x, pos_part_x = ff_x, 0.0
    if sp_y == sp_y:
        pos_part_y = cfg[P_XY_P] * (sp_y - pos_y)
        vel_y = pos_part_y + ff_y if ff_y == ff_y else pos_part_y
    else:
        vel_y, pos_part_y = ff_y, 0.0
    if sp_z == sp_z:
        vel_z = cfg[P_Z_P] * (sp_z - pos_z)
        if ff_z == ff_z:
            vel_z = vel_z + ff_z
    else:
        vel_z = ff_z
    nan_x = vel_x != vel_x
    nan_y = vel_y != vel_y
    if not (nan_x and nan_y):
        lim_x, lim_y = constrain_xy(
            pos_part_x,
            pos_part_y,
            0.0 if nan_x else vel_x - pos_part_x,
            0.0 if nan_y else vel_y - pos_part_y,
            cfg[P_XY_VEL_MAX],
        )
        vel_x = math.nan if nan_x else lim_x
        vel_y = math.nan if nan_y else lim_y
    if vel_z < -cfg[P_Z_VEL_MAX_UP]:
        vel_z = -cfg[P_Z_VEL_MAX_UP]
    elif vel_z > cfg[P_Z_VEL_MAX_DN]:
        vel_z = cfg[P_Z_VEL_MAX_DN]
    return vel_x, vel_y, vel_z


@kernel(
    "UniTuple(float64, 6)(float64[::1], float64[::1], float64, float64, float64, float64, float64, float64, float64,"
    " float64, float64, float64, boolean)"
)
def velocity_thrust(
    state: npt.NDArray[np.float64],
    cfg: npt.NDArray[np.float64],
    vx: float,
    vy: float,
    vz: float,
    sp_x: float,
    sp_y: float,
    sp_z: float,
    ff_x: float,
    ff_y: float,
    ff_z: float,
    dt_s: float,
    freeze_integrator: bool,
) -> tuple[float, float, float, float, float, float]:
    """(acceleration setpoint, thrust setpoint) of the velocity PID (sitl/control/velocity.py), its ``state`` row
    advanced."""
    # Low-passed derivative of the measured velocity (the D term acts on the measurement).
    dx, dy, dz = state[VS_DERIV], state[VS_DERIV + 1], state[VS_DERIV + 2]
    if state[VS_HAVE_PREV] != 0.0 and dt_s > 0.0:
        cutoff = cfg[V_CUTOFF]
        alpha = 1.0 if cutoff <= 0.0 else dt_s / (dt_s + 1.0 / (2.0 * math.pi * cutoff))
        dx += alpha * ((vx - state[VS_PREV]) / dt_s - dx)
        dy += alpha * ((vy - state[VS_PREV + 1]) / dt_s - dy)
        dz += alpha * ((vz - state[VS_PREV + 2]) / dt_s - dz)
        state[VS_DERIV], state[VS_DERIV + 1], state[VS_DERIV + 2] = dx, dy, dz
    state[VS_PREV], state[VS_PREV + 1], state[VS_PREV + 2] = vx, vy, vz
    state[VS_HAVE_PREV] = 1.0

    # PID per axis. A NaN velocity setpoint with an acceleration set is acceleration control (the PID stays out);
    # with neither set the axis brakes to zero velocity.
    p_xy = cfg[V_XY_P]
    d_xy = cfg[V_XY_D]
    if sp_x == sp_x or ff_x != ff_x:
        err_x = (sp_x if sp_x == sp_x else 0.0) - vx
        acc_x = p_xy * err_x + state[VS_INTEGRAL] - d_xy * dx
        if ff_x == ff_x:
            acc_x = acc_x + ff_x
    else:
        err_x = math.nan
        acc_x = ff_x
    if sp_y == sp_y or ff_y != ff_y:
        err_y = (sp_y if sp_y == sp_y else 0.0) - vy
        acc_y = p_xy * err_y + state[VS_INTEGRAL + 1] - d_xy * dy
        if ff_y == ff_y:
            acc_y = acc_y + ff_y
    else:
        err_y = math.nan
        acc_y = ff_y
    if sp_z == sp_z or ff_z != ff_z:
        err_z = (sp_z if sp_z == sp_z else 0.0) - vz
        acc_z = cfg[V_Z_P] * err_z + state[VS_INTEGRAL + 2] - cfg[V_Z_D] * dz
        if ff_z == ff_z:
            acc_z = acc_z + ff_z
    else:
        err_z = math.nan
        acc_z = ff_z

    # Thrust direction (body z axis, pointing down through the vehicle) from a_sp - g, tilt-limited. A demand to
    # fall faster than gravity cannot be met by rotors: it is flown level-ish at minimum thrust.
    up_component = GRAVITY_MPS2 - acc_z
    if up_component < 0.0:
        up_component = 0.0
    norm = math.sqrt(acc_x * acc_x + acc_y * acc_y + up_component * up_component)
    if norm < 1e-9:
        bz_x, bz_y, bz_z = 0.0, 0.0, 1.0
    else:
        bz_x, bz_y, bz_z = -acc_x / norm, -acc_y / norm, up_component / norm
        cos_max = math.cos(cfg[V_TILT_MAX])
        if bz_z < cos_max:
            horiz = hypot2(bz_x, bz_y)
            sin_max = math.sin(cfg[V_TILT_MAX])
            if horiz < 1e-9:
                bz_x, bz_y = sin_max, 0.0
            else:
                bz_x, bz_y = bz_x / horiz * sin_max, bz_y / horiz * sin_max
            bz_z = cos_max

    # The collective keeps the demanded vertical force through the tilt limit (PX4 projects it the same way).
    mass = cfg[V_MASS]
    thrust_min = cfg[V_THRUST_MIN]
    collective = mass * (GRAVITY_MPS2 - acc_z) / bz_z
    if collective < thrust_min:
        collective = thrust_min
    thr_x = -bz_x * collective
    thr_y = -bz_y * collective
    thr_z = -bz_z * collective

    # Vertical anti-windup: no integration further into a saturated collective.
    thrust_max = cfg[V_THRUST_MAX]
    if (-thr_z <= thrust_min and err_z >= 0.0) or (-thr_z >= thrust_max and err_z <= 0.0):
        err_z = 0.0

    # Vertical priority with a horizontal margin, then the horizontal part gets what remains.
    thr_xy = hypot2(thr_x, thr_y)
    margin = cfg[V_XY_MARGIN]
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
        # Horizontal tracking anti-reset-windup (Rundqwist 1990, as PX4): while the produced horizontal acceleration
        # falls short of the demand, the shortfall is fed back against the integrator.
        if p_xy > 0.0 and err_x == err_x and err_y == err_y:
            prod_x = thr_x / mass
            prod_y = thr_y / mass
            if acc_x * acc_x + acc_y * acc_y > prod_x * prod_x + prod_y * prod_y:
                arw_gain = 2.0 / p_xy
                err_x -= arw_gain * (acc_x - prod_x)
                err_y -= arw_gain * (acc_y - prod_y)
        i_xy = cfg[V_XY_I]
        if err_x == err_x:
            state[VS_INTEGRAL] += i_xy * err_x * dt_s
        if err_y == err_y:
            state[VS_INTEGRAL + 1] += i_xy * err_y * dt_s
        if err_z == err_z:
            state[VS_INTEGRAL + 2] += cfg[V_Z_I] * err_z * dt_s
        # The vertical integrator never needs to cancel more than gravity.
        if state[VS_INTEGRAL + 2] > GRAVITY_MPS2:
            state[VS_INTEGRAL + 2] = GRAVITY_MPS2
        elif state[VS_INTEGRAL + 2] < -GRAVITY_MPS2:
            state[VS_INTEGRAL + 2] = -GRAVITY_MPS2
    return acc_x, acc_y, acc_z, thr_x, thr_y, thr_z


@kernel("UniTuple(float64, 4)(float64, float64, float64, float64, float64, float64, float64, float64, float64)")
def dcm_to_quat(
    r00: float, r01: float, r02: float, r10: float, r11: float, r12: float, r20: float, r21: float, r22: float
) -> tuple[float, float, float, float]:
    """Unit quaternion (w >= 0) of a rotation matrix, row by row (Shepperd's method)."""
    tr = r00 + r11 + r22
    if tr > 0.0:
        s = math.sqrt(tr + 1.0) * 2.0
        w, x, y, z = 0.25 * s, (r21 - r12) / s, (r02 - r20) / s, (r10 - r01) / s
    elif r00 > r11 and r00 > r22:
        s = math.sqrt(1.0 + r00 - r11 - r22) * 2.0
        w, x, y, z = (r21 - r12) / s, 0.25 * s, (r01 + r10) / s, (r02 + r20) / s
    elif r11 > r22:
        s = math.sqrt(1.0 + r11 - r00 - r22) * 2.0
        w, x, y, z = (r02 - r20) / s, (r01 + r10) / s, 0.25 * s, (r12 + r21) / s
    else:
        s = math.sqrt(1.0 + r22 - r00 - r11) * 2.0
        w, x, y, z = (r10 - r01) / s, (r02 + r20) / s, (r12 + r21) / s, 0.25 * s
    n = math.sqrt(w * w + x * x + y * y + z * z)
    if w < 0.0:
        n = -n
    return w / n, x / n, y / n, z / n


@kernel("UniTuple(float64, 4)(float64, float64, float64, float64)")
def thrust_to_attitude(tx: float, ty: float, tz: float, yaw_rad: float) -> tuple[float, float, float, float]:
    """Attitude whose body z axis opposes the thrust vector, with the heading closest to ``yaw_rad``."""
    norm = math.sqrt(tx * tx + ty * ty + tz * tz)
    if norm < 1e-9:
        bz_x, bz_y, bz_z = 0.0, 0.0, 1.0  # no thrust, no direction: level is the safe choice
    else:
        bz_x, bz_y, bz_z = -tx / norm, -ty / norm, -tz / norm
    sin_yaw = math.sin(yaw_rad)
    cos_yaw = math.cos(yaw_rad)
    # body x = (yaw direction rotated by 90 degrees) x body z, which lies in the plane of the yaw heading.
    bx_x = cos_yaw * bz_z
    bx_y = sin_yaw * bz_z
    bx_z = -sin_yaw * bz_y - cos_yaw * bz_x
    if bz_z < 0.0:  # upside down: keep the nose towards the heading
        bx_x, bx_y, bx_z = -bx_x, -bx_y, -bx_z
    if abs(bz_z) < 1e-6:  # thrust in the horizontal plane: heading undefined, any orthogonal x will do
        bx_x, bx_y, bx_z = 0.0, 0.0, 1.0
    n = math.sqrt(bx_x * bx_x + bx_y * bx_y + bx_z * bx_z)
    bx_x /= n
    bx_y /= n
    bx_z /= n
    by_x = bz_y * bx_z - bz_z * bx_y
    by_y = bz_z * bx_x - bz_x * bx_z
    by_z = bz_x * bx_y - bz_y * bx_x
    # The rotation matrix has columns body x, body y, body z.
    return dcm_to_quat(bx_x, by_x, bz_x, bx_y, by_y, bz_y, bx_z, by_z, bz_z)


@kernel("float64(float64)")
def wrap_pi(angle_rad: float) -> float:
    """An angle wrapped to [-pi, pi), as sitl.mathutil.wrap_pi (Python's float ``%``)."""
    return (angle_rad + math.pi) % (2 * math.pi) - math.pi


@kernel("float64(float64, float64, float64, float64, boolean, float64)")
def follow_travel(
    yaw_sp_rad: float, vel_sp_n_mps: float, vel_sp_e_mps: float, elapsed_s: float, follow: bool, rate_max_radps: float
) -> float:
    """The next heading setpoint from the last one: turned towards the horizontal velocity setpoint at the rate limit
    (``follow``, MPC_YAW_FOLLOW), or unchanged while that velocity is slow or not set (sitl/control/heading.py)."""
    speed_sq = vel_sp_n_mps * vel_sp_n_mps + vel_sp_e_mps * vel_sp_e_mps
    if not follow or not speed_sq > FOLLOW_MIN_SPEED_MPS * FOLLOW_MIN_SPEED_MPS:  # NaN: not set
        return yaw_sp_rad
    error = wrap_pi(math.atan2(vel_sp_e_mps, vel_sp_n_mps) - yaw_sp_rad)
    step = rate_max_radps * elapsed_s
    return wrap_pi(yaw_sp_rad + pmax(-step, pmin(step, error)))


@kernel(
    "void(float64[::1], float64[::1], float64[::1], float64[::1], float64, boolean, float64[::1], float64[::1],"
    " float64[::1], float64[::1], float64[::1])"
)
def outer(
    pos: npt.NDArray[np.float64],
    vel: npt.NDArray[np.float64],
    att_q: npt.NDArray[np.float64],
    sp: npt.NDArray[np.float64],
    elapsed_s: float,
    landed: bool,
    position_cfg: npt.NDArray[np.float64],
    velocity_cfg: npt.NDArray[np.float64],
    velocity_state: npt.NDArray[np.float64],
    heading_cfg: npt.NDArray[np.float64],
    held: npt.NDArray[np.float64],
) -> None:
    """The outer loops once, towards the setpoint row ``sp`` from the estimated position, velocity and attitude:
    the position P loop's velocity setpoint, the velocity PID's acceleration and thrust (integrating over
    ``elapsed_s``, frozen when ``landed``), the heading setpoint (the setpoint's yaw; or, left free, the current
    heading when a yaw rate is set or none was flown yet, else the last one held or turned towards the direction of
    travel) and the attitude of that thrust at that heading, all into ``held``."""
    vsx, vsy, vsz = position_velocity_sp(position_cfg, pos[0], pos[1], pos[2], sp[SP_POS], sp[SP_POS + 1],
                                         sp[SP_POS + 2], sp[SP_VEL], sp[SP_VEL + 1], sp[SP_VEL + 2])  # fmt: skip
    ax, ay, az, tx, ty, tz = velocity_thrust(velocity_state, velocity_cfg, vel[0], vel[1], vel[2], vsx, vsy, vsz,
                                             sp[SP_ACC], sp[SP_ACC + 1], sp[SP_ACC + 2], elapsed_s, landed)  # fmt: skip
    yaw_sp = sp[SP_YAW]
    if yaw_sp != yaw_sp:
        last = held[U_YAW_PREV]
        if sp[SP_YAWSPEED] == sp[SP_YAWSPEED] or last != last:
            # Rate-only heading control (or nothing to hold yet): the current heading, no yaw error.
            w, x, y, z = att_q[0], att_q[1], att_q[2], att_q[3]
            yaw_sp = math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
        else:
            yaw_sp = follow_travel(last, vsx, vsy, elapsed_s, heading_cfg[HD_FOLLOW] != 0.0, heading_cfg[HD_RATE_MAX])
    held[U_YAW_PREV] = yaw_sp
    qw, qx, qy, qz = thrust_to_attitude(tx, ty, tz, yaw_sp)
    held[U_ATT_SP], held[U_ATT_SP + 1], held[U_ATT_SP + 2], held[U_ATT_SP + 3] = qw, qx, qy, qz
    held[U_YAWSPEED_FF] = sp[SP_YAWSPEED]
    held[U_COLLECTIVE] = math.sqrt(tx * tx + ty * ty + tz * tz)
    held[U_VEL_SP], held[U_VEL_SP + 1], held[U_VEL_SP + 2] = vsx, vsy, vsz
    held[U_ACC_SP], held[U_ACC_SP + 1], held[U_ACC_SP + 2] = ax, ay, az
    held[U_THRUST], held[U_THRUST + 1], held[U_THRUST + 2] = tx, ty, tz


@kernel(
    "void(float64, float64, float64, float64, float64, float64, float64, float64[::1], float64, boolean, float64[::1],"
    " float64[::1], float64[::1], float64[:, ::1], float64, float64[::1])"
)
def inner_held(
    qw: float,
    qx: float,
    qy: float,
    qz: float,
    wx: float,
    wy: float,
    wz: float,
    held: npt.NDArray[np.float64],
    dt_s: float,
    landed: bool,
    attitude_cfg: npt.NDArray[np.float64],
    rate_cfg: npt.NDArray[np.float64],
    rate_state: npt.NDArray[np.float64],
    alloc_rows: npt.NDArray[np.float64],
    t_max: float,
    out: npt.NDArray[np.float64],
) -> None:
    """The inner loops (``inner``) from the estimated attitude ``qw``..``qz`` and body rates ``wx``..``wz`` towards
    what the outer loops hold (``held``: the attitude, the yaw-rate feed-forward, the collective): a tick's control
    step after ``outer``, and a step between ticks (sitl/kernels/between_ticks.py ``step``)."""
    a = U_ATT_SP
    inner(qw, qx, qy, qz, held[a], held[a + 1], held[a + 2], held[a + 3], held[U_YAWSPEED_FF], False, math.nan,
          math.nan, math.nan, wx, wy, wz, held[U_COLLECTIVE], dt_s, landed, attitude_cfg, rate_cfg, rate_state,
          alloc_rows, t_max, out)  # fmt: skip


@kernel(
    "void(float64[::1], float64[::1], float64[::1], float64[::1], float64[::1], boolean, float64, float64, boolean,"
    " float64[::1], float64[::1], float64[::1], float64[::1], float64[::1], float64[::1], float64[::1],"
    " float64[::1], float64[:, ::1], float64, float64[::1])"
)
def trajectory(
    pos: npt.NDArray[np.float64],
    vel: npt.NDArray[np.float64],
    att_q: npt.NDArray[np.float64],
    rates: npt.NDArray[np.float64],
    sp: npt.NDArray[np.float64],
    outer_due: bool,
    elapsed_s: float,
    dt_s: float,
    landed: bool,
    position_cfg: npt.NDArray[np.float64],
    velocity_cfg: npt.NDArray[np.float64],
    velocity_state: npt.NDArray[np.float64],
    heading_cfg: npt.NDArray[np.float64],
    held: npt.NDArray[np.float64],
    attitude_cfg: npt.NDArray[np.float64],
    rate_cfg: npt.NDArray[np.float64],
    rate_state: npt.NDArray[np.float64],
    alloc_rows: npt.NDArray[np.float64],
    t_max: float,
    out: npt.NDArray[np.float64],
) -> None:
    """One control step towards a trajectory setpoint: the outer loops when ``outer_due`` (``outer``), then the inner
    loops towards what they hold, on the estimated attitude and body rates."""
    if outer_due:
        outer(pos, vel, att_q, sp, elapsed_s, landed, position_cfg, velocity_cfg, velocity_state, heading_cfg, held)
    inner_held(att_q[0], att_q[1], att_q[2], att_q[3], rates[0], rates[1], rates[2], held, dt_s, landed, attitude_cfg,
               rate_cfg, rate_state, alloc_rows, t_max, out)  # fmt: skip
