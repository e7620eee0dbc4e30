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

The per-step arithmetic is a compiled kernel (sitl/kernels/estimator.py) on a row of float64 state: in Python it cost
some 10 us of interpreter work per update, at the physics rate. Only the published ``Estimate`` carries numpy arrays,
built once per update.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from sitl.kernels import estimator as ek
from sitl.mathutil import Quat, Vec3, dcm_to_quat, fast_constructor, mat_mul
from sitl.sensors.models import SensorReadings

_Floats3 = tuple[float, float, float]


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
    """The filter's shell: configuration, the first attitude (TRIAD, once), and the published ``Estimate``; every
    update runs the compiled step (sitl/kernels/estimator.py) on the filter's state row.

    ``state`` is the row to keep the filter in (a row of a host's array of its drones' estimators), or None for a row
    of its own."""

    def __init__(
        self, config: EstimatorConfig, origin_alt_amsl_m: float, state: npt.NDArray[np.float64] | None = None
    ) -> None:
        """``origin_alt_amsl_m`` is the altitude of the local frame's origin (down = 0), i.e. the ground at home."""
        self.config = config
        if state is None:
            state = np.empty(ek.STATE_SIZE)
        state[:] = ek.new_state()
        self._s = state
        k_xy, k_z = _gains(config.tau_xy_s), _gains(config.tau_z_s)
        cfg = np.empty(ek.CONFIG_SIZE)
        cfg[ek.C_KP_ACC] = config.att_kp_acc
        cfg[ek.C_KP_MAG] = config.att_kp_mag
        cfg[ek.C_KI] = config.att_ki
        cfg[ek.C_GATE_SQ] = config.acc_gate_mps2**2
        cfg[ek.C_K_XY : ek.C_K_XY + 3] = k_xy
        cfg[ek.C_K_Z : ek.C_K_Z + 3] = k_z
        cfg[ek.C_GPS_VEL_GAIN] = config.gps_vel_gain
        cfg[ek.C_ACC_LPF_TAU] = config.acc_lpf_tau_s
        cfg[ek.C_CONVERGE] = config.converge_s
        cfg[ek.C_GPS_CONVERGE] = config.gps_converge_s
        cfg[ek.C_GPS_TIMEOUT] = config.gps_timeout_s
        cfg[ek.C_GPS_POS_GATE] = config.gps_pos_gate_m
        cfg[ek.C_ORIGIN_ALT] = origin_alt_amsl_m
        self._cfg = cfg
        self._out = np.zeros(ek.OUT_SIZE)
        self._gps = np.zeros(ek.GPS_SIZE)
        self._no_vec = np.zeros(3)

    def set_mag_reference(self, field_ned_gauss: Vec3) -> None:
        """The direction of the reference field's horizontal part (the declination) that headings are held to."""
        self._s[ek.MAG_REF_HEADING] = math.atan2(float(field_ned_gauss[1]), float(field_ned_gauss[0]))

    def _init_attitude(self, accel_frd: Vec3, mag_frd: Vec3) -> None:
        """Level from gravity, heading from the magnetometer (TRIAD)."""
        accel = np.asarray(accel_frd, dtype=np.float64)
        down = -accel / max(math.hypot(*accel), 1e-6)  # body-frame direction of NED down
        east = np.cross(down, np.asarray(mag_frd, dtype=np.float64))
        east /= max(math.hypot(*east), 1e-9)
        north = np.cross(east, down)
        body_to_ned_meas = np.vstack((north, east, down))  # rows: NED axes in body coordinates
        # Correct for the magnetic declination: the reference field's horizontal direction is not true north.
        decl = float(self._s[ek.MAG_REF_HEADING])
        c, s = math.cos(decl), math.sin(decl)
        rz = np.array(((c, -s, 0.0), (s, c, 0.0), (0.0, 0.0, 1.0)))
        self._s[ek.Q : ek.Q + 4] = dcm_to_quat(mat_mul(rz, body_to_ned_meas))
        self._s[ek.ATT_INITIALISED] = 1.0

    @property
    def attitude_initialised(self) -> bool:
        """Has the filter its first attitude (from gravity and the magnetometer, ``_init_attitude``)?"""
        return bool(self._s[ek.ATT_INITIALISED] != 0.0)

    def kernel_rows(
        self,
    ) -> tuple[
        npt.NDArray[np.float64], npt.NDArray[np.float64], npt.NDArray[np.float64], npt.NDArray[np.float64],
        npt.NDArray[np.float64],
    ]:  # fmt: skip
        """The rows its kernel's ``step`` takes (state, configuration, GPS sample, an empty vector, output), for a
        kernel that steps the filter itself on an IMU sample alone (sitl/kernels/between_ticks.py); ``published``
        then gives the estimate."""
        return self._s, self._cfg, self._gps, self._no_vec, self._out

    def published(self, time_s: float) -> Estimate:
        """The estimate in the output row (of the step just taken at ``time_s``), its vectors built on first read
        (``_RowEstimate``): between the commander's ticks few readers look at them."""
        est = _new_row_estimate(_RowEstimate)
        out = self._out.tolist()
        _set_time(est, time_s)
        _set_roll(est, out[ek.O_ROLL])
        _set_pitch(est, out[ek.O_PITCH])
        _set_yaw(est, out[ek.O_YAW])
        _set_att_valid(est, out[ek.O_ATT_VALID] != 0.0)
        _set_pos_valid(est, out[ek.O_POS_VALID] != 0.0)
        _set_alt_valid(est, out[ek.O_ALT_VALID] != 0.0)
        _set_row(est, out)
        # None marks a vector not built yet (a test of an unset slot would raise, and raising costs a microsecond).
        _set_pos(est, None)
        _set_vel(est, None)
        _set_att(est, None)
        _set_rates(est, None)
        return est

    def update(self, readings: SensorReadings, time_s: float, dt_s: float) -> Estimate:
        imu = readings.imu
        mag = readings.mag
        update_attitude = self._s[ek.ATT_INITIALISED] != 0.0
        if not update_attitude and mag is not None:
            self._init_attitude(imu.accel_frd_mps2, mag.field_frd_gauss)
            self._s[ek.ATT_SINCE] = time_s
        gps = readings.gps
        if gps is not None:
            g = self._gps
            g[ek.G_TIME] = gps.time_s
            g[ek.G_FIX] = gps.fix_type
            g[ek.G_POS : ek.G_POS + 2] = gps.pos_ned_m[:2]
            g[ek.G_VEL : ek.G_VEL + 3] = gps.vel_ned_mps
        baro = readings.baro
        ek.step(
            self._s,
            self._cfg,
            imu.gyro_frd_radps,
            imu.accel_frd_mps2,
            mag is not None,
            mag.field_frd_gauss if mag is not None else self._no_vec,
            gps is not None,
            self._gps,
            baro is not None,
            baro.alt_amsl_m if baro is not None else 0.0,
            time_s,
            dt_s,
            update_attitude,
            self._out,
        )
        return self.published_whole(time_s)

    def published_whole(self, time_s: float) -> Estimate:
        """The estimate in the output row (of the step just taken at ``time_s``) with every vector built at once: for
        a reader that reads them all (the commander's tick), cheaper than ``published``'s first reads."""
        pn, pe, pd, vn, ve, vd, w, x, y, z, p, q, r, roll, pitch, yaw, att_valid, pos_valid, alt_valid = (
            self._out.tolist()
        )
        return _new_estimate(
            time_s=time_s,
            pos_ned_m=np.array((pn, pe, pd)),
            vel_ned_mps=np.array((vn, ve, vd)),
            att_q_frd_to_ned=np.array((w, x, y, z)),
            rates_frd_radps=np.array((p, q, r)),
            roll_rad=roll,
            pitch_rad=pitch,
            yaw_rad=yaw,
            attitude_valid=att_valid != 0.0,
            position_valid=pos_valid != 0.0,
            altitude_valid=alt_valid != 0.0,
        )


class _RowEstimate(Estimate):
    """An ``Estimate`` published from the filter's output row whose vectors are built on first read.

    Between the commander's ticks the estimate of a step goes to the commander and to ``ClosedLoop.estimate``, and
    most steps nobody reads its vectors (telemetry, the cameras and the tick read tens of times a second): four numpy
    vectors a step were most of ``published``. The row's values are copied at the step (so an estimate read later is
    the one of its own step), the scalars set as plain fields, and each vector built on its first read and kept in
    ``Estimate``'s own slot, which this class's property shadows. ``dataclasses.replace``, copies and pickles of it
    give a plain ``Estimate`` with the same fields."""

    __slots__ = ("_row",)
    _row: list[float]  # the output row at the step

    def __new__(cls, **fields: object) -> Estimate:  # type: ignore[misc]
        # Only ``dataclasses.replace`` calls the class: it gets the plain record (``published`` uses ``object``).
        return Estimate(**fields)  # type: ignore[arg-type]

    def __reduce__(self) -> tuple[object, tuple[object, ...]]:
        return _plain_estimate, (tuple(getattr(self, f.name) for f in dataclasses.fields(Estimate)),)

    def __eq__(self, other: object) -> bool:
        return _plain_estimate(tuple(getattr(self, f.name) for f in dataclasses.fields(Estimate))) == other

    __hash__ = None  # type: ignore[assignment]

    def _vector(self, name: str, start: int, size: int) -> Vec3:
        vector = np.array(self._row[start : start + size])
        _SLOTS[name].__set__(self, vector)
        return vector

    @property
    def pos_ned_m(self) -> Vec3:
        built = _get_pos(self)
        if built is not None:
            return built
        return self._vector("pos_ned_m", ek.O_POS, 3)

    @property
    def vel_ned_mps(self) -> Vec3:
        built = _get_vel(self)
        if built is not None:
            return built
        return self._vector("vel_ned_mps", ek.O_VEL, 3)

    @property
    def att_q_frd_to_ned(self) -> Quat:
        built = _get_att(self)
        if built is not None:
            return built
        return self._vector("att_q_frd_to_ned", ek.O_Q, 4)

    @property
    def rates_frd_radps(self) -> Vec3:
        built = _get_rates(self)
        if built is not None:
            return built
        return self._vector("rates_frd_radps", ek.O_RATES, 3)


def _plain_estimate(values: tuple[object, ...]) -> Estimate:
    """A plain ``Estimate`` from its fields' values in declaration order (copies and pickles of a row estimate)."""
    return Estimate(**{f.name: v for f, v in zip(dataclasses.fields(Estimate), values, strict=True)})  # type: ignore[arg-type]


_new_row_estimate = object.__new__
_set_time = Estimate.__dict__["time_s"].__set__
_set_roll = Estimate.__dict__["roll_rad"].__set__
_set_pitch = Estimate.__dict__["pitch_rad"].__set__
_set_yaw = Estimate.__dict__["yaw_rad"].__set__
_set_att_valid = Estimate.__dict__["attitude_valid"].__set__
_set_pos_valid = Estimate.__dict__["position_valid"].__set__
_set_alt_valid = Estimate.__dict__["altitude_valid"].__set__
_set_row = _RowEstimate.__dict__["_row"].__set__
# Estimate's own slots, shadowed by the row estimate's properties: where each vector is kept once built.
_SLOTS = {name: Estimate.__dict__[name] for name in ("pos_ned_m", "vel_ned_mps", "att_q_frd_to_ned", "rates_frd_radps")}
_get_pos = _SLOTS["pos_ned_m"].__get__
_get_vel = _SLOTS["vel_ned_mps"].__get__
_get_att = _SLOTS["att_q_frd_to_ned"].__get__
_get_rates = _SLOTS["rates_frd_radps"].__get__
_set_pos = _SLOTS["pos_ned_m"].__set__
_set_vel = _SLOTS["vel_ned_mps"].__set__
_set_att = _SLOTS["att_q_frd_to_ned"].__set__
_set_rates = _SLOTS["rates_frd_radps"].__set__
