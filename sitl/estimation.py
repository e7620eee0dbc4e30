"""State estimator: attitude, position and velocity from noisy sensors, so the controller never sees truth.

Two classic, cheap filters, both fixed-gain so that one update costs a few microseconds at 400 Hz:

- Attitude: a Mahony complementary filter (gyro integration corrected by the accelerometer's gravity direction and
  the magnetometer's heading, with gyro-bias estimation). A multirotor's accelerometer mostly measures thrust, so
  the gravity reference is compensated by the vehicle's own acceleration estimated from GPS velocity, as PX4's
  former attitude_estimator_q did; without that, every horizontal acceleration would tilt the estimate.
- Position/velocity: per-axis third-order complementary filters (position, velocity, accelerometer bias) driven by
  the IMU in NED and corrected by GPS position and velocity (10 Hz) and barometric altitude (50 Hz), with gains
  from one time constant per axis (k1 = 3/tau, k2 = 3/tau^2, k3 = 1/tau^3, the critically-damped choice used by
  ArduPilot's original inertial navigation).

The local frame is anchored at the estimator's origin: the first GPS fix horizontally and the first barometer
reading (ground level at boot) vertically, as PX4's EKF2 does. The caller decides what that origin means (home).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sitl.mathutil import GRAVITY_MPS2, Quat, Vec3, dcm_to_quat, quat_mul, quat_to_dcm, quat_to_euler, vec3
from sitl.sensors.models import SensorReadings

_G_NED = vec3(0.0, 0.0, GRAVITY_MPS2)


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


class Estimator:
    def __init__(self, config: EstimatorConfig, origin_alt_amsl_m: float) -> None:
        """``origin_alt_amsl_m`` is the altitude of the local frame's origin (down = 0), i.e. the ground at home."""
        self.config = config
        self._origin_alt_amsl_m = origin_alt_amsl_m
        self._q: Quat = np.array((1.0, 0.0, 0.0, 0.0))
        self._gyro_bias = np.zeros(3)
        self._pos = np.zeros(3)
        self._vel = np.zeros(3)
        self._acc_bias = np.zeros(3)
        self._acc_ned_lpf = np.zeros(3)
        self._last_gps_vel: Vec3 | None = None
        self._last_gps_time_s = 0.0
        self._last_baro_time_s: float | None = None
        self._att_initialised = False
        self._att_since_s = math.inf
        self._have_gps = False
        self._gps_since_s = math.inf
        self._have_baro = False
        self._mag_ref_ned = np.array((1.0, 0.0, 0.0))
        self._rates = np.zeros(3)
        self._time_s = 0.0

    def set_mag_reference(self, field_ned_gauss: Vec3) -> None:
        self._mag_ref_ned = np.asarray(field_ned_gauss, dtype=np.float64)

    # -- attitude -------------------------------------------------------------------------------------------------
    def _init_attitude(self, accel_frd: Vec3, mag_frd: Vec3) -> None:
        """Level from gravity, heading from the magnetometer (TRIAD)."""
        down = -accel_frd / max(float(np.linalg.norm(accel_frd)), 1e-6)  # body-frame direction of NED down
        east = np.cross(down, mag_frd)
        east /= max(float(np.linalg.norm(east)), 1e-9)
        north = np.cross(east, down)
        body_to_ned_meas = np.vstack((north, east, down))  # rows: NED axes in body coordinates
        # Correct for the magnetic declination: the reference field's horizontal direction is not true north.
        decl = math.atan2(self._mag_ref_ned[1], self._mag_ref_ned[0])
        c, s = math.cos(decl), math.sin(decl)
        rz = np.array(((c, -s, 0.0), (s, c, 0.0), (0.0, 0.0, 1.0)))
        self._q = dcm_to_quat(rz @ body_to_ned_meas)
        self._att_initialised = True

    def _update_attitude(self, gyro: Vec3, accel: Vec3, mag: Vec3 | None, dt_s: float) -> None:
        cfg = self.config
        r = quat_to_dcm(self._q)
        correction = np.zeros(3)
        # Gravity direction, compensated by the vehicle's own acceleration where GPS gives one.
        f_pred_ned = self._acc_ned_lpf - _G_NED
        f_pred = r.T @ f_pred_ned
        n_meas, n_pred = np.linalg.norm(accel), np.linalg.norm(f_pred)
        if n_meas > 1e-3 and n_pred > 1e-3:
            # The compensation lags the true acceleration (10 Hz GPS), so trust gravity less while manoeuvring.
            acc = self._acc_ned_lpf
            weight = 1.0 / (1.0 + (acc[0] * acc[0] + acc[1] * acc[1] + acc[2] * acc[2]) / cfg.acc_gate_mps2**2)
            correction += cfg.att_kp_acc * weight * np.cross(accel / n_meas, f_pred / n_pred)
        if mag is not None:
            m_ned = r @ mag
            heading_err = math.atan2(m_ned[1], m_ned[0]) - math.atan2(self._mag_ref_ned[1], self._mag_ref_ned[0])
            heading_err = (heading_err + math.pi) % (2 * math.pi) - math.pi
            correction += r.T @ vec3(0.0, 0.0, -cfg.att_kp_mag * heading_err)
        self._gyro_bias -= cfg.att_ki * correction * dt_s
        omega = gyro - self._gyro_bias + correction
        self._rates = gyro - self._gyro_bias
        half = 0.5 * dt_s
        dq = np.array((1.0, omega[0] * half, omega[1] * half, omega[2] * half))
        q = quat_mul(self._q, dq)
        self._q = q / math.sqrt(q @ q)

    # -- position -------------------------------------------------------------------------------------------------
    def _correct(self, axes: slice, err: Vec3, tau_s: float, dt_s: float) -> None:
        k1, k2, k3 = 3.0 / tau_s, 3.0 / tau_s**2, 1.0 / tau_s**3
        self._pos[axes] += k1 * dt_s * err
        self._vel[axes] += k2 * dt_s * err
        self._acc_bias[axes] -= k3 * dt_s * err

    def update(self, readings: SensorReadings, time_s: float, dt_s: float) -> Estimate:
        cfg = self.config
        imu = readings.imu
        if not self._att_initialised:
            if readings.mag is not None:
                self._init_attitude(imu.accel_frd_mps2, readings.mag.field_frd_gauss)
                self._att_since_s = time_s
        else:
            mag = readings.mag.field_frd_gauss if readings.mag is not None else None
            self._update_attitude(imu.gyro_frd_radps, imu.accel_frd_mps2, mag, dt_s)
        # Inertial prediction in NED.
        acc_ned = quat_to_dcm(self._q) @ imu.accel_frd_mps2 + _G_NED - self._acc_bias
        self._pos += self._vel * dt_s + 0.5 * acc_ned * dt_s * dt_s
        self._vel += acc_ned * dt_s

        gps = readings.gps
        if gps is not None and gps.fix_type >= 3:
            if not self._have_gps:
                self._pos[:2] = gps.pos_ned_m[:2]
                self._vel[:] = gps.vel_ned_mps
                self._have_gps = True
                self._gps_since_s = gps.time_s
            else:
                gps_dt = gps.time_s - self._last_gps_time_s
                self._correct(slice(0, 2), gps.pos_ned_m[:2] - self._pos[:2], cfg.tau_xy_s, gps_dt)
                self._vel += cfg.gps_vel_gain * (gps.vel_ned_mps - self._vel)
                if self._last_gps_vel is not None and gps_dt > 0:
                    acc_gps = (gps.vel_ned_mps - self._last_gps_vel) / gps_dt
                    alpha = gps_dt / (cfg.acc_lpf_tau_s + gps_dt)
                    self._acc_ned_lpf += alpha * (acc_gps - self._acc_ned_lpf)
            self._last_gps_vel = gps.vel_ned_mps
            self._last_gps_time_s = gps.time_s

        baro = readings.baro
        if baro is not None:
            down_meas = self._origin_alt_amsl_m - baro.alt_amsl_m
            if not self._have_baro:
                self._pos[2] = down_meas
                self._have_baro = True
            elif self._last_baro_time_s is not None:
                baro_dt = time_s - self._last_baro_time_s
                self._correct(slice(2, 3), np.array((down_meas - self._pos[2],)), cfg.tau_z_s, baro_dt)
            self._last_baro_time_s = time_s

        self._time_s = time_s
        roll, pitch, yaw = quat_to_euler(self._q)
        return Estimate(
            time_s=time_s,
            pos_ned_m=self._pos.copy(),
            vel_ned_mps=self._vel.copy(),
            att_q_frd_to_ned=self._q.copy(),
            rates_frd_radps=self._rates.copy(),
            roll_rad=roll,
            pitch_rad=pitch,
            yaw_rad=yaw,
            attitude_valid=self._att_initialised and time_s - self._att_since_s >= cfg.converge_s,
            position_valid=time_s - self._gps_since_s >= cfg.gps_converge_s,
            altitude_valid=self._have_baro,
        )
