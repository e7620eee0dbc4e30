"""The estimator's step as a kernel (sitl/estimation/estimator.py is its shell: configuration, first attitude, the
record).

One drone's filter state is a row of ``STATE_SIZE`` float64 (flags as 0.0/1.0, "never" as -inf or inf); its
configuration a row of ``CONFIG_SIZE``. The step is the Mahony attitude update followed by the inertial prediction and
the GPS and barometer corrections, in exactly the order and form of the Python it replaced, so it gives the same bits.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from sitl.kernels import kernel
from sitl.mathutil import GRAVITY_MPS2

# State row: attitude quaternion (w, x, y, z), gyro bias, bias-corrected rates, low-passed GPS acceleration (NED),
# position, velocity, accelerometer bias (NED), the last GPS velocity, and the filter's clocks and flags.
Q = 0
GYRO_BIAS = 4
RATES = 7
ACC_LPF = 10
POS = 13
VEL = 16
ACC_BIAS = 19
LAST_GPS_VEL = 22
HAVE_LAST_GPS_VEL = 25
LAST_GPS_TIME = 26
LAST_POS_FUSED = 27
LAST_BARO_TIME = 28
HAVE_LAST_BARO_TIME = 29
ATT_INITIALISED = 30
ATT_SINCE = 31
HAVE_GPS = 32
GPS_SINCE = 33
HAVE_BARO = 34
MAG_REF_HEADING = 35
STATE_SIZE = 36

# Configuration row (sitl.estimation.estimator.EstimatorConfig, with the derived gains).
C_KP_ACC = 0
C_KP_MAG = 1
C_KI = 2
C_GATE_SQ = 3
C_K_XY = 4  # three gains: position, velocity, accelerometer bias
C_K_Z = 7
C_GPS_VEL_GAIN = 10
C_ACC_LPF_TAU = 11
C_CONVERGE = 12
C_GPS_CONVERGE = 13
C_GPS_TIMEOUT = 14
C_GPS_POS_GATE = 15
C_ORIGIN_ALT = 16
CONFIG_SIZE = 17

# Inputs: GPS row (time, fix type, north, east, velocity north, east, down).
G_TIME = 0
G_FIX = 1
G_POS = 2
G_VEL = 4
GPS_SIZE = 7

# Output row: position, velocity, attitude quaternion, rates, roll, pitch, yaw, and the three validity flags.
O_POS = 0
O_VEL = 3
O_Q = 6
O_RATES = 10
O_ROLL = 13
O_PITCH = 14
O_YAW = 15
O_ATT_VALID = 16
O_POS_VALID = 17
O_ALT_VALID = 18
OUT_SIZE = 19


def new_state() -> npt.NDArray[np.float64]:
    """A filter that has seen nothing: level, at the origin, no sensor yet."""
    s = np.zeros(STATE_SIZE)
    s[Q] = 1.0
    s[LAST_POS_FUSED] = -math.inf
    s[ATT_SINCE] = math.inf
    s[GPS_SINCE] = math.inf
    return s


@kernel(
    "void(float64[::1], float64[::1], float64[::1], float64[::1], boolean, float64[::1], boolean, float64[::1],"
    " boolean, float64, float64, float64, boolean, float64[::1])"
)
def step(
    s: npt.NDArray[np.float64],
    cfg: npt.NDArray[np.float64],
    gyro: npt.NDArray[np.float64],
    accel: npt.NDArray[np.float64],
    have_mag: bool,
    mag: npt.NDArray[np.float64],
    have_gps: bool,
    gps: npt.NDArray[np.float64],
    have_baro: bool,
    baro_alt_amsl_m: float,
    time_s: float,
    dt_s: float,
    update_attitude: bool,
    out: npt.NDArray[np.float64],
) -> None:
    """One estimator update: ``s`` advanced in place, the estimate written to ``out``."""
    ax = accel[0]
    ay = accel[1]
    az = accel[2]
    w = s[Q]
    x = s[Q + 1]
    y = s[Q + 2]
    z = s[Q + 3]
    if update_attitude:
        # Body->NED rotation matrix of the current attitude, row by row (as sitl.mathutil.quat_to_dcm).
        xx, yy, zz, xy, xz, yz, wx, wy, wz = x * x, y * y, z * z, x * y, x * z, y * z, w * x, w * y, w * z
        r00, r01, r02 = 1 - 2 * (yy + zz), 2 * (xy - wz), 2 * (xz + wy)
        r10, r11, r12 = 2 * (xy + wz), 1 - 2 * (xx + zz), 2 * (yz - wx)
        r20, r21, r22 = 2 * (xz - wy), 2 * (yz + wx), 1 - 2 * (xx + yy)
        cx = cy = cz = 0.0
        # Gravity direction, compensated by the vehicle's own acceleration where GPS gives one.
        an = s[ACC_LPF]
        ae = s[ACC_LPF + 1]
        ad = s[ACC_LPF + 2]
        fd = ad - GRAVITY_MPS2
        px = r00 * an + r10 * ae + r20 * fd  # predicted specific force in body axes: R^T (a - g)
        py = r01 * an + r11 * ae + r21 * fd
        pz = r02 * an + r12 * ae + r22 * fd
        n_meas = math.sqrt(ax * ax + ay * ay + az * az)
        n_pred = math.sqrt(px * px + py * py + pz * pz)
        if n_meas > 1e-3 and n_pred > 1e-3:
            # The compensation lags the true acceleration (10 Hz GPS), so trust gravity less while manoeuvring.
            weight = 1.0 / (1.0 + (an * an + ae * ae + ad * ad) / cfg[C_GATE_SQ])
            k = cfg[C_KP_ACC] * weight
            ux, uy, uz = ax / n_meas, ay / n_meas, az / n_meas
            vx, vy, vz = px / n_pred, py / n_pred, pz / n_pred
            cx = k * (uy * vz - uz * vy)
            cy = k * (uz * vx - ux * vz)
            cz = k * (ux * vy - uy * vx)
        if have_mag:
            bx = mag[0]
            by = mag[1]
            bz = mag[2]
            m_n = r00 * bx + r01 * by + r02 * bz
            m_e = r10 * bx + r11 * by + r12 * bz
            heading_err = math.atan2(m_e, m_n) - s[MAG_REF_HEADING]
            heading_err = (heading_err + math.pi) % (2 * math.pi) - math.pi
            yaw_corr = -cfg[C_KP_MAG] * heading_err  # about NED down, rotated into body axes: R^T (0, 0, c)
            cx += r20 * yaw_corr
            cy += r21 * yaw_corr
            cz += r22 * yaw_corr
        ki = cfg[C_KI]
        bgx = s[GYRO_BIAS] - ki * cx * dt_s
        bgy = s[GYRO_BIAS + 1] - ki * cy * dt_s
        bgz = s[GYRO_BIAS + 2] - ki * cz * dt_s
        s[GYRO_BIAS] = bgx
        s[GYRO_BIAS + 1] = bgy
        s[GYRO_BIAS + 2] = bgz
        rx, ry, rz = gyro[0] - bgx, gyro[1] - bgy, gyro[2] - bgz
        s[RATES] = rx
        s[RATES + 1] = ry
        s[RATES + 2] = rz
        half = 0.5 * dt_s
        ox, oy, oz = (rx + cx) * half, (ry + cy) * half, (rz + cz) * half
        # q * (1, omega dt / 2), renormalised.
        qw = w - x * ox - y * oy - z * oz
        qx = w * ox + x + y * oz - z * oy
        qy = w * oy - x * oz + y + z * ox
        qz = w * oz + x * oy - y * ox + z
        norm = math.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
        w, x, y, z = qw / norm, qx / norm, qy / norm, qz / norm
        s[Q] = w
        s[Q + 1] = x
        s[Q + 2] = y
        s[Q + 3] = z
    # Inertial prediction in NED: R(q) accel + g - accelerometer bias.
    xx, yy, zz, xy, xz, yz, wx, wy, wz = x * x, y * y, z * z, x * y, x * z, y * z, w * x, w * y, w * z
    r00, r01, r02 = 1 - 2 * (yy + zz), 2 * (xy - wz), 2 * (xz + wy)
    r10, r11, r12 = 2 * (xy + wz), 1 - 2 * (xx + zz), 2 * (yz - wx)
    r20, r21, r22 = 2 * (xz - wy), 2 * (yz + wx), 1 - 2 * (xx + yy)
    bn = s[ACC_BIAS]
    be = s[ACC_BIAS + 1]
    bd = s[ACC_BIAS + 2]
    acc_n = r00 * ax + r01 * ay + r02 * az - bn
    acc_e = r10 * ax + r11 * ay + r12 * az - be
    acc_d = r20 * ax + r21 * ay + r22 * az + GRAVITY_MPS2 - bd
    pn = s[POS]
    pe = s[POS + 1]
    pd = s[POS + 2]
    vn = s[VEL]
    ve = s[VEL + 1]
    vd = s[VEL + 2]
    pn += vn * dt_s + 0.5 * acc_n * dt_s * dt_s
    pe += ve * dt_s + 0.5 * acc_e * dt_s * dt_s
    pd += vd * dt_s + 0.5 * acc_d * dt_s * dt_s
    vn += acc_n * dt_s
    ve += acc_e * dt_s
    vd += acc_d * dt_s

    if have_gps and gps[G_FIX] >= 3.0:
        gps_time_s = gps[G_TIME]
        gpn = gps[G_POS]
        gpe = gps[G_POS + 1]
        gvn = gps[G_VEL]
        gve = gps[G_VEL + 1]
        gvd = gps[G_VEL + 2]
        if s[HAVE_GPS] == 0.0 or gps_time_s - s[LAST_GPS_TIME] > cfg[C_GPS_TIMEOUT]:
            # First fix, or the first after the receiver was lost: start from it.
            pn, pe = gpn, gpe
            vn, ve, vd = gvn, gve, gvd
            if s[HAVE_GPS] == 0.0:
                s[GPS_SINCE] = gps_time_s
            s[HAVE_GPS] = 1.0
            s[LAST_POS_FUSED] = gps_time_s
        else:
            gps_dt = gps_time_s - s[LAST_GPS_TIME]
            err_n, err_e = gpn - pn, gpe - pe
            gate = cfg[C_GPS_POS_GATE]
            if err_n * err_n + err_e * err_e <= gate * gate:
                k1 = cfg[C_K_XY] * gps_dt
                k2 = cfg[C_K_XY + 1] * gps_dt
                k3 = cfg[C_K_XY + 2] * gps_dt
                pn += k1 * err_n
                pe += k1 * err_e
                vn += k2 * err_n
                ve += k2 * err_e
                bn -= k3 * err_n
                be -= k3 * err_e
                s[LAST_POS_FUSED] = gps_time_s
            gain = cfg[C_GPS_VEL_GAIN]
            vn += gain * (gvn - vn)
            ve += gain * (gve - ve)
            vd += gain * (gvd - vd)
            if s[HAVE_LAST_GPS_VEL] != 0.0 and gps_dt > 0:
                alpha = gps_dt / (cfg[C_ACC_LPF_TAU] + gps_dt)
                ln = s[ACC_LPF]
                le = s[ACC_LPF + 1]
                ld = s[ACC_LPF + 2]
                ln += alpha * ((gvn - s[LAST_GPS_VEL]) / gps_dt - ln)
                le += alpha * ((gve - s[LAST_GPS_VEL + 1]) / gps_dt - le)
                ld += alpha * ((gvd - s[LAST_GPS_VEL + 2]) / gps_dt - ld)
                s[ACC_LPF] = ln
                s[ACC_LPF + 1] = le
                s[ACC_LPF + 2] = ld
        s[LAST_GPS_VEL] = gvn
        s[LAST_GPS_VEL + 1] = gve
        s[LAST_GPS_VEL + 2] = gvd
        s[HAVE_LAST_GPS_VEL] = 1.0
        s[LAST_GPS_TIME] = gps_time_s

    if have_baro:
        down_meas = cfg[C_ORIGIN_ALT] - baro_alt_amsl_m
        if s[HAVE_BARO] == 0.0:
            pd = down_meas
            s[HAVE_BARO] = 1.0
        elif s[HAVE_LAST_BARO_TIME] != 0.0:
            baro_dt = time_s - s[LAST_BARO_TIME]
            err_d = down_meas - pd
            pd += cfg[C_K_Z] * baro_dt * err_d
            vd += cfg[C_K_Z + 1] * baro_dt * err_d
            bd -= cfg[C_K_Z + 2] * baro_dt * err_d
        s[LAST_BARO_TIME] = time_s
        s[HAVE_LAST_BARO_TIME] = 1.0

    s[POS] = pn
    s[POS + 1] = pe
    s[POS + 2] = pd
    s[VEL] = vn
    s[VEL + 1] = ve
    s[VEL + 2] = vd
    s[ACC_BIAS] = bn
    s[ACC_BIAS + 1] = be
    s[ACC_BIAS + 2] = bd
    # ZYX Euler angles from the same rotation matrix (as sitl.mathutil.quat_to_euler).
    sin_pitch = -r20
    sin_pitch = sin_pitch if sin_pitch < 1.0 else 1.0
    sin_pitch = sin_pitch if sin_pitch > -1.0 else -1.0
    out[O_POS] = pn
    out[O_POS + 1] = pe
    out[O_POS + 2] = pd
    out[O_VEL] = vn
    out[O_VEL + 1] = ve
    out[O_VEL + 2] = vd
    out[O_Q] = w
    out[O_Q + 1] = x
    out[O_Q + 2] = y
    out[O_Q + 3] = z
    out[O_RATES] = s[RATES]
    out[O_RATES + 1] = s[RATES + 1]
    out[O_RATES + 2] = s[RATES + 2]
    out[O_ROLL] = math.atan2(r21, r22)
    out[O_PITCH] = math.asin(sin_pitch)
    out[O_YAW] = math.atan2(r10, r00)
    out[O_ATT_VALID] = 1.0 if s[ATT_INITIALISED] != 0.0 and time_s - s[ATT_SINCE] >= cfg[C_CONVERGE] else 0.0
    position_valid = time_s - s[GPS_SINCE] >= cfg[C_GPS_CONVERGE] and time_s - s[LAST_POS_FUSED] <= cfg[C_GPS_TIMEOUT]
    out[O_POS_VALID] = 1.0 if position_valid else 0.0
    out[O_ALT_VALID] = s[HAVE_BARO]
