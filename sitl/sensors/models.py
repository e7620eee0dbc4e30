"""Sensor models: what the autopilot sees of the true state.

Each model is pure apart from its own seeded noise stream: ``sample(truth) -> reading or None`` when it has no new
sample this step (GPS and barometer run slower than the physics). Noise figures are typical of the parts on a
PX4-class flight controller (ICM-42688 IMU, MS5611 barometer, u-blox M8/M9 GPS) and of PX4 SITL's own sensor
plugins, chosen so that a well-tuned vehicle holds position to a few centimetres, as PX4 SITL does.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from sitl.dynamics.noise import NoiseSource
from sitl.dynamics.plant import PlantState
from sitl.faults.failures import GPS_GLITCH_OFFSET_NE_M, GpsFault
from sitl.kernels import between_ticks as bt
from sitl.mathutil import GRAVITY_MPS2, Vec3, fast_constructor, vec3


@dataclass(frozen=True, slots=True, kw_only=True)
class SensorConfig:
    gyro_noise_radps: float = 0.003  # per sample, 1 sigma
    gyro_bias_max_radps: float = 0.005  # initial bias drawn uniformly in +-this, per axis
    accel_noise_mps2: float = 0.03
    accel_bias_max_mps2: float = 0.05
    gps_rate_hz: float = 10.0
    gps_time_to_fix_s: float = 1.5  # from boot; pre-arm checks wait for it like on a real vehicle
    gps_pos_noise_h_m: float = 0.04
    gps_pos_noise_v_m: float = 0.08
    gps_pos_drift_h_m: float = 0.03  # 1 sigma of a slow Gauss-Markov wander (multipath, atmosphere)
    gps_drift_time_s: float = 60.0
    gps_vel_noise_mps: float = 0.04
    gps_satellites: int = 12
    baro_rate_hz: float = 50.0
    baro_noise_m: float = 0.05
    mag_noise_gauss: float = 0.005
    # Earth field at the default home (Zurich): 0.48 gauss total, inclination 63.5 deg, declination 2.8 deg.
    mag_field_ned_gauss: tuple[float, float, float] = (0.2137, 0.0104, 0.4296)


@dataclass(frozen=True, slots=True, kw_only=True)
class ImuSample:
    gyro_frd_radps: Vec3
    accel_frd_mps2: Vec3


@dataclass(frozen=True, slots=True, kw_only=True)
class GpsSample:
    time_s: float
    fix_type: int  # MAVLink GPS_FIX_TYPE: 0 no GPS, 1 no fix, 3 3D fix
    satellites: int
    lat_deg: float
    lon_deg: float
    alt_amsl_m: float
    pos_ned_m: Vec3  # the same fix expressed in the local frame around home
    vel_ned_mps: Vec3
    eph_m: float
    epv_m: float


@dataclass(frozen=True, slots=True, kw_only=True)
class BaroSample:
    alt_amsl_m: float
    pressure_hpa: float
    temperature_c: float


@dataclass(frozen=True, slots=True, kw_only=True)
class MagSample:
    field_frd_gauss: Vec3


# Built at the sensor rates (the IMU at every physics step): the cheap constructors of the frozen records.
_new_imu_sample = fast_constructor(ImuSample)
_new_gps_sample = fast_constructor(GpsSample)
_new_baro_sample = fast_constructor(BaroSample)
_new_mag_sample = fast_constructor(MagSample)


def _isa_pressure_hpa(alt_amsl_m: float) -> float:
    """ISA troposphere pressure at a geometric altitude (close enough to geopotential at these heights)."""
    return 1013.25 * (1.0 - 2.25577e-5 * alt_amsl_m) ** 5.25588


class Imu:
    def __init__(self, config: SensorConfig, rng: np.random.Generator) -> None:
        self._cfg = config
        gyro_bias = rng.uniform(-config.gyro_bias_max_radps, config.gyro_bias_max_radps, 3).tolist()
        accel_bias = rng.uniform(-config.accel_bias_max_mps2, config.accel_bias_max_mps2, 3).tolist()
        self._gyro_bias: tuple[float, float, float] = (gyro_bias[0], gyro_bias[1], gyro_bias[2])
        self._accel_bias: tuple[float, float, float] = (accel_bias[0], accel_bias[1], accel_bias[2])
        self.noise = NoiseSource(rng)  # a sample takes two rows: gyro, then accelerometer

    def biases(self) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
        """The gyro's and the accelerometer's bias, drawn at boot."""
        return self._gyro_bias, self._accel_bias

    def sample(self, truth: PlantState) -> ImuSample:
        # Scalar arithmetic on Python floats: at every physics step numpy's per-call overhead on 3-vectors dominates.
        noise = self.noise
        wx, wy, wz = truth.rates_frd_radps.tolist()
        bx, by, bz = self._gyro_bias
        nx, ny, nz = noise.floats3()
        k = self._cfg.gyro_noise_radps
        gyro = np.array((wx + bx + k * nx, wy + by + k * ny, wz + bz + k * nz))
        fx, fy, fz = truth.specific_force_frd_mps2.tolist()
        bx, by, bz = self._accel_bias
        nx, ny, nz = noise.floats3()
        k = self._cfg.accel_noise_mps2
        accel = np.array((fx + bx + k * nx, fy + by + k * ny, fz + bz + k * nz))
        return _new_imu_sample(gyro_frd_radps=gyro, accel_frd_mps2=accel)


class _Periodic:
    """Fires at a fixed rate in simulation time, aligned to multiples of the period."""

    __slots__ = ("_period_s", "next_s")

    def __init__(self, rate_hz: float) -> None:
        self._period_s = 1.0 / rate_hz
        self.next_s = 0.0  # the next sample is due at this time (less 1 ns of rounding slack)

    def due(self, time_s: float) -> bool:
        if time_s + 1e-9 < self.next_s:
            return False
        self.next_s += self._period_s * max(1, math.floor((time_s - self.next_s) / self._period_s) + 1)
        return True


class Gps:
    def __init__(self, config: SensorConfig, rng: np.random.Generator) -> None:
        self._cfg = config
        self._noise = NoiseSource(rng)
        self.clock = _Periodic(config.gps_rate_hz)
        self._drift_n_m = 0.0
        self._drift_e_m = 0.0
        self._alpha = math.exp(-1.0 / (config.gps_rate_hz * config.gps_drift_time_s))
        self._drift_gain = math.sqrt(1 - self._alpha**2) * config.gps_pos_drift_h_m
        # An injected fault (sitl/faults/failures.py): OFF reports no fix, GLITCH offsets every fix by
        # GPS_GLITCH_OFFSET_NE_M.
        self.fault = GpsFault.NONE

    def sample(self, truth: PlantState) -> GpsSample | None:
        if not self.clock.due(truth.time_s):
            return None
        cfg = self._cfg
        searching = truth.time_s < cfg.gps_time_to_fix_s
        if searching or self.fault is GpsFault.OFF:
            nan3 = vec3(math.nan, math.nan, math.nan)
            return _new_gps_sample(
                time_s=truth.time_s,
                fix_type=1,
                satellites=3 if searching else 0,
                lat_deg=math.nan,
                lon_deg=math.nan,
                alt_amsl_m=math.nan,
                pos_ned_m=nan3,
                vel_ned_mps=nan3,
                eph_m=99.0,
                epv_m=99.0,
            )
        noise = self._noise
        pos_x, pos_y, pos_z = noise.floats3()
        vel_x, vel_y, vel_z = noise.floats3()
        drift_x, drift_y, _ = noise.floats3()
        self._drift_n_m = self._alpha * self._drift_n_m + self._drift_gain * drift_x
        self._drift_e_m = self._alpha * self._drift_e_m + self._drift_gain * drift_y
        err_n = self._drift_n_m + cfg.gps_pos_noise_h_m * pos_x
        err_e = self._drift_e_m + cfg.gps_pos_noise_h_m * pos_y
        if self.fault is GpsFault.GLITCH:
            err_n += GPS_GLITCH_OFFSET_NE_M[0]
            err_e += GPS_GLITCH_OFFSET_NE_M[1]
        err_d = cfg.gps_pos_noise_v_m * pos_z
        tn, te, td = truth.pos_ned_m.tolist()
        vn, ve, vd = truth.vel_ned_mps.tolist()
        k_vel = cfg.gps_vel_noise_mps
        # Geodetic of the noisy fix: offset the true geodetic by the same error (metres to degrees, local scale).
        lat = truth.geo.lat_deg + math.degrees(err_n / 6378137.0)
        lon = truth.geo.lon_deg + math.degrees(err_e / (6378137.0 * math.cos(math.radians(truth.geo.lat_deg))))
        return _new_gps_sample(
            time_s=truth.time_s,
            fix_type=3,
            satellites=cfg.gps_satellites,
            lat_deg=lat,
            lon_deg=lon,
            alt_amsl_m=truth.geo.alt_amsl_m - err_d,
            pos_ned_m=vec3(tn + err_n, te + err_e, td + err_d),
            vel_ned_mps=vec3(vn + k_vel * vel_x, ve + k_vel * vel_y, vd + k_vel * vel_z),
            eph_m=max(0.3, 3 * cfg.gps_pos_noise_h_m),
            epv_m=max(0.4, 3 * cfg.gps_pos_noise_v_m),
        )


class Barometer:
    def __init__(self, config: SensorConfig, rng: np.random.Generator) -> None:
        self._cfg = config
        self.noise = NoiseSource(rng)  # a sample takes one row
        self.clock = _Periodic(config.baro_rate_hz)

    def sample(self, truth: PlantState) -> BaroSample | None:
        if not self.clock.due(truth.time_s):
            return None
        alt = truth.geo.alt_amsl_m + self._cfg.baro_noise_m * self.noise.scalar()
        return _new_baro_sample(alt_amsl_m=alt, pressure_hpa=_isa_pressure_hpa(alt), temperature_c=15.0 - 0.0065 * alt)


class Magnetometer:
    def __init__(self, config: SensorConfig, rng: np.random.Generator) -> None:
        self._cfg = config
        self.noise = NoiseSource(rng)  # a sample takes one row
        self._field_ned = tuple(float(c) for c in config.mag_field_ned_gauss)
        self.clock = _Periodic(config.baro_rate_hz)

    def sample(self, truth: PlantState) -> MagSample | None:
        if not self.clock.due(truth.time_s):
            return None
        w, x, y, z = truth.att_q_frd_to_ned.tolist()
        fn, fe, fd = self._field_ned
        nx, ny, nz = self.noise.floats3()
        k = self._cfg.mag_noise_gauss
        # R(q)^T field_ned, with R(q) the body->NED rotation matrix.
        bx = (1 - 2 * (y * y + z * z)) * fn + 2 * (x * y + w * z) * fe + 2 * (x * z - w * y) * fd
        by = 2 * (x * y - w * z) * fn + (1 - 2 * (x * x + z * z)) * fe + 2 * (y * z + w * x) * fd
        bz = 2 * (x * z + w * y) * fn + 2 * (y * z - w * x) * fe + (1 - 2 * (x * x + y * y)) * fd
        return _new_mag_sample(field_frd_gauss=vec3(bx + k * nx, by + k * ny, bz + k * nz))


@dataclass(frozen=True, slots=True, kw_only=True)
class SensorReadings:
    imu: ImuSample
    gps: GpsSample | None
    baro: BaroSample | None
    mag: MagSample | None


_new_readings = fast_constructor(SensorReadings)

# What a compiled step takes to sample the sensors itself (sitl/kernels/between_ticks.py ``sense``, after the plant's
# IMU inputs): the IMU's noise block and row, then for the barometer whether it is due, its noise block and row and
# the true altitude AMSL, then for the magnetometer whether it is due, its noise block and row and the true attitude
# quaternion (w, x, y, z).
KernelSample = tuple[
    npt.NDArray[np.float64], int, bool, npt.NDArray[np.float64], int, float, bool, npt.NDArray[np.float64], int,
    float, float, float, float,
]  # fmt: skip
_NOTHING = np.zeros((1, 3))  # the noise block of a sensor not due


class SensorSuite:
    """All sensors of one drone, each with an independent stream spawned from one seed."""

    def __init__(self, config: SensorConfig, seed: int) -> None:
        streams = [np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(4)]
        self.config = config
        self.imu = Imu(config, streams[0])
        self.gps = Gps(config, streams[1])
        self.baro = Barometer(config, streams[2])
        self.mag = Magnetometer(config, streams[3])
        # The constants as the compiled step takes them (sitl/kernels/between_ticks.py).
        gyro_bias, accel_bias = self.imu.biases()
        row = np.empty(bt.SENSORS_SIZE)
        row[bt.I_GYRO_BIAS : bt.I_GYRO_BIAS + 3] = gyro_bias
        row[bt.I_ACCEL_BIAS : bt.I_ACCEL_BIAS + 3] = accel_bias
        row[bt.I_GYRO_NOISE] = config.gyro_noise_radps
        row[bt.I_ACCEL_NOISE] = config.accel_noise_mps2
        row[bt.I_BARO_NOISE] = config.baro_noise_m
        row[bt.I_MAG_NOISE] = config.mag_noise_gauss
        row[bt.I_MAG_FIELD : bt.I_MAG_FIELD + 3] = [float(c) for c in config.mag_field_ned_gauss]
        self.row = row

    def take_kernel_sample(self, truth: PlantState, attitude_initialised: bool) -> KernelSample | None:
        """Hand a compiled step what it needs to take this step's sample itself, and consume it here as ``sample``
        would (each due sensor's clock advanced, its noise rows taken); None, having changed nothing, when the
        shells must sample: a GPS fix is due (its records, drift and faults stay Python), the magnetometer is due
        before the estimator has its first attitude (initialised from the readings in Python), or a noise block
        has fewer rows left than the sample takes (``sample`` refills it)."""
        time_s = truth.time_s
        due_s = time_s + 1e-9
        if due_s >= self.gps.clock.next_s:
            return None
        baro, mag = self.baro, self.mag
        baro_due = due_s >= baro.clock.next_s
        mag_due = due_s >= mag.clock.next_s
        if mag_due and not attitude_initialised:
            return None
        imu_noise = self.imu.noise
        if not (imu_noise.holds(2) and (not baro_due or baro.noise.holds(1)) and (not mag_due or mag.noise.holds(1))):
            return None
        imu_block, imu_row = imu_noise.take_rows(2)  # type: ignore[misc]  # holds(2) said it would
        baro_block, baro_row, alt_amsl_m = _NOTHING, 0, 0.0
        if baro_due:
            baro.clock.due(time_s)
            baro_block, baro_row = baro.noise.take_rows(1)  # type: ignore[misc]
            alt_amsl_m = truth.geo.alt_amsl_m
        mag_block, mag_row, qw, qx, qy, qz = _NOTHING, 0, 0.0, 0.0, 0.0, 0.0
        if mag_due:
            mag.clock.due(time_s)
            mag_block, mag_row = mag.noise.take_rows(1)  # type: ignore[misc]
            qw, qx, qy, qz = truth.att_q_frd_to_ned.tolist()
        return (imu_block, imu_row, baro_due, baro_block, baro_row, alt_amsl_m, mag_due, mag_block, mag_row,
                qw, qx, qy, qz)  # fmt: skip

    def sample(self, truth: PlantState) -> SensorReadings:
        # The slower sensors are asked only when due (the same test their clocks make): most physics steps carry
        # the IMU alone, and three calls that return None would cost more than the IMU sample itself.
        due_s = truth.time_s + 1e-9
        gps, baro, mag = self.gps, self.baro, self.mag
        return _new_readings(
            imu=self.imu.sample(truth),
            gps=gps.sample(truth) if due_s >= gps.clock.next_s else None,
            baro=baro.sample(truth) if due_s >= baro.clock.next_s else None,
            mag=mag.sample(truth) if due_s >= mag.clock.next_s else None,
        )


__all__ = ["GRAVITY_MPS2", "SensorConfig", "SensorReadings", "SensorSuite"]
