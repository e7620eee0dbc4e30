"""State estimator: attitude, position and velocity from noisy sensors, so the controller never sees truth.

Two classic, cheap filters, both fixed-gain so that one update costs a few microseconds at the physics rate:

- Attitude: a Mahony complementary filter (gyro integration corrected by the accelerometer's gravity direction and
  the magnetometer's heading, with gyro-bias estimation). A multirotor's accelerometer mostly measures thrust, so
  the gravity reference is compensated by the vehicle's own acceleration estimated from GPS velocity, as PX4's
  former attitude_estimator_q did; without that, every horizontal acceleration would tilt the estimate.
- Position/velocity: per-axis third-order complementary filters (position, velocity, accelerometer bias) driven by
  the IMU in NED and corrected by GPS position and velocity (10 Hz) and barometric altitude (50 Hz), with gains
  from one time constant per axis (k1 = 3/tau, k2 = 3/tau^2, k3 = 1/tau^3, the critically-damped choice used by
  ArduPilot's original inertial navigation).

GPS faults are handled as PX4's EKF2 handles them, kept simple: a fix whose horizontal position disagrees with the
prediction by more than ``gps_pos_gate_m`` is not fused (its velocity still is), and when no GPS position has been
fused for ``gps_timeout_s`` (the receiver lost its fix, or a glitch kept every fix outside the gate) the horizontal
position is declared invalid (``Estimate.position_valid`` False). A fix that arrives after the receiver was silent
that long resets the position to it, as EKF2 resets on regaining GPS; a glitch that clears is fused again at once.

The local frame is anchored at the estimator's origin: the first GPS fix horizontally and the first barometer
reading (ground level at boot) vertically, as PX4's EKF2 does. The caller decides what that origin means (home).

The per-step arithmetic runs on plain Python floats (vectors as x, y, z locals, the attitude as a (w, x, y, z)
tuple): on 3-element arrays numpy's per-call overhead is far larger than the arithmetic itself. Only the published
``Estimate`` carries numpy arrays, built once per update.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sitl.mathutil import GRAVITY_MPS2, Quat, Vec3, dcm_to_quat, fast_constructor, mat_mul
from sitl.sensors.models import SensorReadings

_Floats3 = tuple[float, float, float]
_Floats4 = tuple[float, float, float, float]


@dataclass(frozen=True, slots=True, kw_only=True)
class EstimatorConfig:
    att_kp_acc: float = 0.15  # rad/s per unit of gravity-direction error
    att_kp_mag: float = 0.3  # rad/s per rad of heading error
    att_ki: float = 0.02  # gyro bias learning rate
    tau_xy_s: float = 0.8
    tau_z_s: float = 0.6
    gps_vel_gain: float = 0.35  # fraction of GPS velocity innovation applied per fix
    acc_lpf_tau_s: float = 0.05  # low-pass on the GPS-derived acceleration used for tilt compensation
    acc_gate_mps2: float = 1.0  # gravity correction weight halves at this manoeuvring acceleration
    converge_s: float = 1.0  # attitude settling time after the first heading measurement
    gps_converge_s: float = 2.5  # position settling after the first fix (~3 tau_xy): before it, not valid
    # Without GPS position fusion for this long the horizontal position is invalid (PX4's EKF2_NOAID_TOUT, 5 s).
    gps_timeout_s: float = 5.0
    # Horizontal innovation gate: PX4 gates GPS position at EKF2_GPS_P_GATE = 5 standard deviations, which with its
    # 0.5 m GPS noise and a settled filter is a few metres; our fixes' noise is 0.04 m + 0.03 m drift.
    gps_pos_gate_m: float = 5.0


@dataclass(frozen=True, slots=True, kw_only=True)
class Estimate:
    time_s: float
    pos_ned_m: Vec3
    vel_ned_mps: Vec3
    att_q_frd_to_ned: Quat
    rates_frd_radps: Vec3  # bias-corrected gyro
    roll_rad: float
    pitch_rad: float
    yaw_rad: float
    attitude_valid: bool
    position_valid: bool  # horizontal position and velocity from a GPS fix
    altitude_valid: bool


_new_estimate = fast_constructor(Estimate)


def _gains(tau_s: float) -> _Floats3:
    """Third-order complementary filter gains (position, velocity, accelerometer bias) for one time constant."""
    return 3.0 / tau_s, 3.0 / tau_s**2, 1.0 / tau_s**3


class Estimator:
    def __init__(self, config: EstimatorConfig, origin_alt_amsl_m: float) -> None:
        """``origin_alt_amsl_m`` is the altitude of the local frame's origin (down = 0), i.e. the ground at home."""
        self.config = config
        self._origin_alt_amsl_m = origin_alt_amsl_m
        self._k_xy = _gains(config.tau_xy_s)
        self._k_z = _gains(config.tau_z_s)
        self._gate_sq = config.acc_gate_mps2**2
        self._q: _Floats4 = (1.0, 0.0, 0.0, 0.0)
        self._gyro_bias: _Floats3 = (0.0, 0.0, 0.0)
        self._pos: _Floats3 = (0.0, 0.0, 0.0)
        self._vel: _Floats3 = (0.0, 0.0, 0.0)
        self._acc_bias: _Floats3 = (0.0, 0.0, 0.0)
        self._acc_ned_lpf: _Floats3 = (0.0, 0.0, 0.0)
        self._last_gps_vel: _Floats3 | None = None
        self._last_gps_time_s = 0.0
        self._last_pos_fused_s = -math.inf  # last GPS position fused (the innovation passed the gate)
        self._last_baro_time_s: float | None = None
        self._att_initialised = False
        self._att_since_s = math.inf
        self._have_gps = False
        self._gps_since_s = math.inf
        self._have_baro = False
        self._mag_ref_heading_rad = 0.0  # direction of the reference field's horizontal part (the declination)
        self._rates: _Floats3 = (0.0, 0.0, 0.0)

    def set_mag_reference(self, field_ned_gauss: Vec3) -> None:
        self._mag_ref_heading_rad = math.atan2(float(field_ned_gauss[1]), float(field_ned_gauss[0]))

    # -- attitude -------------------------------------------------------------------------------------------------
    def _init_attitude(self, accel_frd: Vec3, mag_frd: Vec3) -> None:
        """Level from gravity, heading from the magnetometer (TRIAD)."""
        accel = np.asarray(accel_frd, dtype=np.float64)
        down = -accel / max(math.hypot(*accel), 1e-6)  # body-frame direction of NED down
        east = np.cross(down, np.asarray(mag_frd, dtype=np.float64))
        east /= max(math.hypot(*east), 1e-9)
        north = np.cross(east, down)
        body_to_ned_meas = np.vstack((north, east, down))  # rows: NED axes in body coordinates
        # Correct for the magnetic declination: the reference field's horizontal direction is not true north.
        decl = self._mag_ref_heading_rad
        c, s = math.cos(decl), math.sin(decl)
        rz = np.array(((c, -s, 0.0), (s, c, 0.0), (0.0, 0.0, 1.0)))
        w, x, y, z = dcm_to_quat(mat_mul(rz, body_to_ned_meas)).tolist()
        self._q = (w, x, y, z)
        self._att_initialised = True

    def _update_attitude(self, gyro: _Floats3, accel: _Floats3, mag: _Floats3 | None, dt_s: float) -> None:
        cfg = self.config
        w, x, y, z = self._q
        # Body->NED rotation matrix of the current attitude, row by row (as sitl.mathutil.quat_to_dcm).
        xx, yy, zz, xy, xz, yz, wx, wy, wz = x * x, y * y, z * z, x * y, x * z, y * z, w * x, w * y, w * z
        r00, r01, r02 = 1 - 2 * (yy + zz), 2 * (xy - wz), 2 * (xz + wy)
        r10, r11, r12 = 2 * (xy + wz), 1 - 2 * (xx + zz), 2 * (yz - wx)
        r20, r21, r22 = 2 * (xz - wy), 2 * (yz + wx), 1 - 2 * (xx + yy)
        cx = cy = cz = 0.0
        # Gravity direction, compensated by the vehicle's own acceleration where GPS gives one.
        an, ae, ad = self._acc_ned_lpf
        fd = ad - GRAVITY_MPS2
        px = r00 * an + r10 * ae + r20 * fd  # predicted specific force in body axes: R^T (a - g)
        py = r01 * an + r11 * ae + r21 * fd
        pz = r02 * an + r12 * ae + r22 * fd
        mx, my, mz = accel
        n_meas = math.sqrt(mx * mx + my * my + mz * mz)
        n_pred = math.sqrt(px * px + py * py + pz * pz)
        if n_meas > 1e-3 and n_pred > 1e-3:
            # The compensation lags the true acceleration (10 Hz GPS), so trust gravity less while manoeuvring.
            weight = 1.0 / (1.0 + (an * an + ae * ae + ad * ad) / self._gate_sq)
            k = cfg.att_kp_acc * weight
            ux, uy, uz = mx / n_meas, my / n_meas, mz / n_meas
            vx, vy, vz = px / n_pred, py / n_pred, pz / n_pred
            cx = k * (uy * vz - uz * vy)
            cy = k * (uz * vx - ux * vz)
            cz = k * (ux * vy - uy * vx)
        if mag is not None:
            bx, by, bz = mag
            m_n = r00 * bx + r01 * by + r02 * bz
            m_e = r10 * bx + r11 * by + r12 * bz
            heading_err = math.atan2(m_e, m_n) - self._mag_ref_heading_rad
            heading_err = (heading_err + math.pi) % (2 * math.pi) - math.pi
            yaw_corr = -cfg.att_kp_mag * heading_err  # about NED down, rotated into body axes: R^T (0, 0, c)
            cx += r20 * yaw_corr
            cy += r21 * yaw_corr
            cz += r22 * yaw_corr
        ki = cfg.att_ki
        bgx, bgy, bgz = self._gyro_bias
        bgx -= ki * cx * dt_s
        bgy -= ki * cy * dt_s
        bgz -= ki * cz * dt_s
        self._gyro_bias = (bgx, bgy, bgz)
        gx, gy, gz = gyro
        rx, ry, rz = gx - bgx, gy - bgy, gz - bgz
        self._rates = (rx, ry, rz)
        half = 0.5 * dt_s
        ox, oy, oz = (rx + cx) * half, (ry + cy) * half, (rz + cz) * half
        # q * (1, omega dt / 2), renormalised.
        qw = w - x * ox - y * oy - z * oz
        qx = w * ox + x + y * oz - z * oy
        qy = w * oy - x * oz + y + z * ox
        qz = w * oz + x * oy - y * ox + z
        norm = math.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
        self._q = (qw / norm, qx / norm, qy / norm, qz / norm)

    # -- position -------------------------------------------------------------------------------------------------
    def update(self, readings: SensorReadings, time_s: float, dt_s: float) -> Estimate:
        cfg = self.config
        imu = readings.imu
        ax, ay, az = imu.accel_frd_mps2.tolist()
        mag = readings.mag
        if not self._att_initialised:
            if mag is not None:
                self._init_attitude(imu.accel_frd_mps2, mag.field_frd_gauss)
                self._att_since_s = time_s
        else:
            mag_frd = mag.field_frd_gauss.tolist() if mag is not None else None
            self._update_attitude(imu.gyro_frd_radps.tolist(), (ax, ay, az), mag_frd, dt_s)
        # Inertial prediction in NED: R(q) accel + g - accelerometer bias.
        w, x, y, z = self._q
        xx, yy, zz, xy, xz, yz, wx, wy, wz = x * x, y * y, z * z, x * y, x * z, y * z, w * x, w * y, w * z
        r00, r01, r02 = 1 - 2 * (yy + zz), 2 * (xy - wz), 2 * (xz + wy)
        r10, r11, r12 = 2 * (xy + wz), 1 - 2 * (xx + zz), 2 * (yz - wx)
        r20, r21, r22 = 2 * (xz - wy), 2 * (yz + wx), 1 - 2 * (xx + yy)
        bn, be, bd = self._acc_bias
        acc_n = r00 * ax + r01 * ay + r02 * az - bn
        acc_e = r10 * ax + r11 * ay + r12 * az - be
        acc_d = r20 * ax + r21 * ay + r22 * az + GRAVITY_MPS2 - bd
        pn, pe, pd = self._pos
        vn, ve, vd = self._vel
        pn += vn * dt_s + 0.5 * acc_n * dt_s * dt_s
        pe += ve * dt_s + 0.5 * acc_e * dt_s * dt_s
        pd += vd * dt_s + 0.5 * acc_d * dt_s * dt_s
        vn += acc_n * dt_s
        ve += acc_e * dt_s
        vd += acc_d * dt_s

        gps = readings.gps
        if gps is not None and gps.fix_type >= 3:
            gpn, gpe, _ = gps.pos_ned_m.tolist()
            gvn, gve, gvd = gps.vel_ned_mps.tolist()
            if not self._have_gps or gps.time_s - self._last_gps_time_s > cfg.gps_timeout_s:
                # First fix, or the first after the receiver was lost: start from it.
                pn, pe = gpn, gpe
                vn, ve, vd = gvn, gve, gvd
                if not self._have_gps:
                    self._gps_since_s = gps.time_s
                self._have_gps = True
                self._last_pos_fused_s = gps.time_s
            else:
                gps_dt = gps.time_s - self._last_gps_time_s
                err_n, err_e = gpn - pn, gpe - pe
                if err_n * err_n + err_e * err_e <= cfg.gps_pos_gate_m * cfg.gps_pos_gate_m:
                    k1, k2, k3 = self._k_xy
                    k1, k2, k3 = k1 * gps_dt, k2 * gps_dt, k3 * gps_dt
                    pn += k1 * err_n
                    pe += k1 * err_e
                    vn += k2 * err_n
                    ve += k2 * err_e
                    bn -= k3 * err_n
                    be -= k3 * err_e
                    self._last_pos_fused_s = gps.time_s
                gain = cfg.gps_vel_gain
                vn += gain * (gvn - vn)
                ve += gain * (gve - ve)
                vd += gain * (gvd - vd)
                last = self._last_gps_vel
                if last is not None and gps_dt > 0:
                    alpha = gps_dt / (cfg.acc_lpf_tau_s + gps_dt)
                    ln, le, ld = self._acc_ned_lpf
                    ln += alpha * ((gvn - last[0]) / gps_dt - ln)
                    le += alpha * ((gve - last[1]) / gps_dt - le)
                    ld += alpha * ((gvd - last[2]) / gps_dt - ld)
                    self._acc_ned_lpf = (ln, le, ld)
            self._last_gps_vel = (gvn, gve, gvd)
            self._last_gps_time_s = gps.time_s

        baro = readings.baro
        if baro is not None:
            down_meas = self._origin_alt_amsl_m - baro.alt_amsl_m
            if not self._have_baro:
                pd = down_meas
                self._have_baro = True
            elif self._last_baro_time_s is not None:
                baro_dt = time_s - self._last_baro_time_s
                k1, k2, k3 = self._k_z
                err_d = down_meas - pd
                pd += k1 * baro_dt * err_d
                vd += k2 * baro_dt * err_d
                bd -= k3 * baro_dt * err_d
            self._last_baro_time_s = time_s

        self._pos = (pn, pe, pd)
        self._vel = (vn, ve, vd)
        self._acc_bias = (bn, be, bd)
        # ZYX Euler angles from the same rotation matrix (as sitl.mathutil.quat_to_euler).
        sin_pitch = -r20
        sin_pitch = sin_pitch if sin_pitch < 1.0 else 1.0  # min(1, .) and max(-1, .) without the calls
        sin_pitch = sin_pitch if sin_pitch > -1.0 else -1.0
        roll = math.atan2(r21, r22)
        pitch = math.asin(sin_pitch)
        yaw = math.atan2(r10, r00)
        return _new_estimate(
            time_s=time_s,
            pos_ned_m=np.array((pn, pe, pd)),
            vel_ned_mps=np.array((vn, ve, vd)),
            att_q_frd_to_ned=np.array((w, x, y, z)),
            rates_frd_radps=np.array(self._rates),
            roll_rad=roll,
            pitch_rad=pitch,
            yaw_rad=yaw,
            attitude_valid=self._att_initialised and time_s - self._att_since_s >= cfg.converge_s,
            position_valid=time_s - self._gps_since_s >= cfg.gps_converge_s
            and time_s - self._last_pos_fused_s <= cfg.gps_timeout_s,
            altitude_valid=self._have_baro,
        )
