"""The state estimator alone, fed synthetic sensor readings of a rigid body whose true state is known exactly.

Pins the behaviour of the Mahony attitude filter (TRIAD initialisation, gravity and heading corrections, gyro-bias
learning, GPS-derived acceleration compensation), the third-order position/velocity/bias complementary filters and
the validity flags, so that a rewrite of the estimator's arithmetic can be checked against them.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import pytest

from sitl.estimation.estimator import Estimate, Estimator, EstimatorConfig
from sitl.mathutil import GRAVITY_MPS2, quat_from_euler, quat_to_dcm, wrap_pi
from sitl.sensors.models import BaroSample, GpsSample, ImuSample, MagSample, SensorConfig, SensorReadings

pytestmark = pytest.mark.timeout(60)

RATE_HZ = 400.0
DT_S = 1.0 / RATE_HZ
GPS_EVERY = 40  # 10 Hz
BARO_MAG_EVERY = 8  # 50 Hz
ORIGIN_ALT_M = 488.0
FIELD_NED = SensorConfig().mag_field_ned_gauss  # Zurich: 2.8 deg east declination
CONFIG = EstimatorConfig()
G_NED = np.array((0.0, 0.0, GRAVITY_MPS2))


class SyntheticSensors:
    """Readings of a rigid body at a fixed attitude, moving from ``pos0``/``vel0`` with a constant NED acceleration
    that starts at ``accel_from_s``.

    IMU every step, barometer and magnetometer at 50 Hz, GPS at 10 Hz (no fix before ``gps_fix_s``). Readings are
    exact unless ``noise_seed`` is given, then they carry white noise of the default sensor configuration's size.
    ``gps_offset_ned_m`` is added to the GPS position only (a jump of the fix, the inertial sensors do not see it).
    """

    def __init__(
        self,
        *,
        roll_rad: float = 0.0,
        pitch_rad: float = 0.0,
        yaw_rad: float = 0.0,
        acc_ned_mps2: tuple[float, float, float] = (0.0, 0.0, 0.0),
        vel0_ned_mps: tuple[float, float, float] = (0.0, 0.0, 0.0),
        pos0_ned_m: tuple[float, float, float] = (0.0, 0.0, 0.0),
        gyro_bias_radps: tuple[float, float, float] = (0.0, 0.0, 0.0),
        accel_bias_mps2: tuple[float, float, float] = (0.0, 0.0, 0.0),
        accel_from_s: float = 0.0,
        gps_fix_s: float = 0.0,
        noise_seed: int | None = None,
    ) -> None:
        self.r_body_to_ned = quat_to_dcm(quat_from_euler(roll_rad, pitch_rad, yaw_rad))
        self.acc_ned = np.array(acc_ned_mps2)
        self.vel0 = np.array(vel0_ned_mps)
        self.pos0 = np.array(pos0_ned_m)
        self.gyro_bias = np.array(gyro_bias_radps)
        self.accel_bias = np.array(accel_bias_mps2)
        self.accel_from_s = accel_from_s
        self.gps_fix_s = gps_fix_s
        self.gps_offset_ned_m = np.zeros(3)
        self._rng = np.random.default_rng(noise_seed) if noise_seed is not None else None
        self._cfg = SensorConfig()

    def _noise(self, sigma: float, n: int = 3) -> np.ndarray:
        return sigma * self._rng.standard_normal(n) if self._rng is not None else np.zeros(n)

    def acc(self, t: float) -> np.ndarray:
        return self.acc_ned if t >= self.accel_from_s else np.zeros(3)

    def pos(self, t: float) -> np.ndarray:
        ta = max(0.0, t - self.accel_from_s)
        return self.pos0 + self.vel0 * t + 0.5 * self.acc_ned * ta * ta

    def vel(self, t: float) -> np.ndarray:
        return self.vel0 + self.acc_ned * max(0.0, t - self.accel_from_s)

    def readings(self, step: int) -> SensorReadings:
        t = step * DT_S
        cfg = self._cfg
        r_t = self.r_body_to_ned.T
        imu = ImuSample(
            gyro_frd_radps=self.gyro_bias + self._noise(cfg.gyro_noise_radps),
            accel_frd_mps2=r_t @ (self.acc(t) - G_NED) + self.accel_bias + self._noise(cfg.accel_noise_mps2),
        )
        gps = baro = mag = None
        if step % GPS_EVERY == 0:
            fixed = t >= self.gps_fix_s - 1e-9
            pos = self.pos(t) + self.gps_offset_ned_m + self._noise(cfg.gps_pos_noise_h_m)
            vel = self.vel(t) + self._noise(cfg.gps_vel_noise_mps)
            gps = GpsSample(
                time_s=t,
                fix_type=3 if fixed else 1,
                satellites=12 if fixed else 3,
                lat_deg=math.nan,  # the estimator works in the local frame only
                lon_deg=math.nan,
                alt_amsl_m=ORIGIN_ALT_M - pos[2],
                pos_ned_m=pos if fixed else np.full(3, math.nan),
                vel_ned_mps=vel if fixed else np.full(3, math.nan),
                eph_m=0.3,
                epv_m=0.4,
            )
        if step % BARO_MAG_EVERY == 0:
            alt = ORIGIN_ALT_M - self.pos(t)[2] + self._noise(cfg.baro_noise_m, 1)[0]
            baro = BaroSample(alt_amsl_m=alt, pressure_hpa=1013.25, temperature_c=15.0)
            mag = MagSample(field_frd_gauss=r_t @ np.array(FIELD_NED) + self._noise(cfg.mag_noise_gauss))
        return SensorReadings(imu=imu, gps=gps, baro=baro, mag=mag)


def make_estimator(config: EstimatorConfig = CONFIG) -> Estimator:
    est = Estimator(config, origin_alt_amsl_m=ORIGIN_ALT_M)
    est.set_mag_reference(np.array(FIELD_NED))
    return est


def run(
    est: Estimator,
    sensors: SyntheticSensors,
    duration_s: float,
    first_step: int = 0,
    on_step: Callable[[int, Estimate], None] | None = None,
) -> tuple[int, Estimate]:
    """Feed ``duration_s`` of readings from ``first_step`` on; returns the next step and the last estimate."""
    steps = round(duration_s * RATE_HZ)
    estimate = None
    for step in range(first_step, first_step + steps):
        estimate = est.update(sensors.readings(step), step * DT_S, DT_S)
        if on_step is not None:
            on_step(step, estimate)
    assert estimate is not None
    return first_step + steps, estimate


def attitude_error_deg(estimate: Estimate, roll: float, pitch: float, yaw: float) -> float:
    errs = (estimate.roll_rad - roll, estimate.pitch_rad - pitch, wrap_pi(estimate.yaw_rad - yaw))
    return math.degrees(max(abs(e) for e in errs))


# ---- attitude -------------------------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("roll_deg", "pitch_deg", "yaw_deg"),
    [(0.0, 0.0, 0.0), (0.0, 0.0, 135.0), (20.0, -10.0, 120.0), (-25.0, 15.0, -60.0)],
)
def test_triad_initialisation_gives_the_true_attitude_from_the_first_readings(
    roll_deg: float, pitch_deg: float, yaw_deg: float
) -> None:
    # GIVEN exact accelerometer and magnetometer readings of a vehicle at rest at some attitude
    roll, pitch, yaw = (math.radians(a) for a in (roll_deg, pitch_deg, yaw_deg))
    sensors = SyntheticSensors(roll_rad=roll, pitch_rad=pitch, yaw_rad=yaw)
    # WHEN the estimator sees its first sample
    estimate = make_estimator().update(sensors.readings(0), 0.0, DT_S)
    # THEN its attitude is the true one, heading relative to true north (the declination is taken out)
    assert attitude_error_deg(estimate, roll, pitch, yaw) < 1e-6
    assert float(np.dot(estimate.att_q_frd_to_ned, estimate.att_q_frd_to_ned)) == pytest.approx(1.0)
    # ... but it is not trusted yet
    assert not estimate.attitude_valid


@pytest.mark.parametrize(("roll_deg", "pitch_deg", "yaw_deg"), [(0.0, 0.0, 30.0), (20.0, -10.0, 120.0)])
def test_attitude_stays_on_the_truth_with_noisy_sensors(roll_deg: float, pitch_deg: float, yaw_deg: float) -> None:
    # GIVEN a vehicle at rest at a level or tilted attitude, with noisy sensors (seeded)
    roll, pitch, yaw = (math.radians(a) for a in (roll_deg, pitch_deg, yaw_deg))
    sensors = SyntheticSensors(roll_rad=roll, pitch_rad=pitch, yaw_rad=yaw, noise_seed=1)
    est = make_estimator()
    # WHEN it runs for 10 s
    errors: list[float] = []
    run(est, sensors, 10.0, on_step=lambda _s, e: errors.append(attitude_error_deg(e, roll, pitch, yaw)))
    # THEN the TRIAD initialisation from one noisy sample is within a degree, and the filter only improves on it
    assert max(errors) < 0.75, f"worst attitude error {max(errors):.3f} deg"
    assert errors[-1] < 0.6
    assert errors[-1] <= errors[0]


@pytest.mark.parametrize(("roll_deg", "pitch_deg", "yaw_deg"), [(0.0, 0.0, 30.0), (20.0, -10.0, 120.0)])
def test_attitude_converges_after_a_disturbed_initialisation(roll_deg: float, pitch_deg: float, yaw_deg: float) -> None:
    # GIVEN an estimator initialised from a first sample taken 5 deg off in roll, 4 deg in pitch and 10 deg in yaw
    roll, pitch, yaw = (math.radians(a) for a in (roll_deg, pitch_deg, yaw_deg))
    off = SyntheticSensors(
        roll_rad=roll + math.radians(5.0), pitch_rad=pitch - math.radians(4.0), yaw_rad=yaw + math.radians(10.0)
    )
    est = make_estimator()
    first = est.update(off.readings(0), 0.0, DT_S)
    assert attitude_error_deg(first, roll, pitch, yaw) == pytest.approx(10.0, abs=0.01)
    # WHEN it then sees exact readings of the true, level or tilted, attitude
    sensors = SyntheticSensors(roll_rad=roll, pitch_rad=pitch, yaw_rad=yaw)
    step, after_10s = run(est, sensors, 10.0, first_step=1)
    _, after_40s = run(est, sensors, 30.0, first_step=step)
    # THEN the tilt error has mostly gone after 10 s (gravity gain), the heading follows more slowly, and after
    # 40 s every axis is within a degree (the gyro-bias integrator, wound up by the error, settles last)
    assert abs(after_10s.roll_rad - roll) < math.radians(1.25)
    assert abs(after_10s.pitch_rad - pitch) < math.radians(1.0)
    assert abs(wrap_pi(after_10s.yaw_rad - yaw)) < math.radians(9.5)
    assert attitude_error_deg(after_40s, roll, pitch, yaw) < 1.0


def test_gyro_bias_is_learned_at_rest() -> None:
    # GIVEN a vehicle at rest whose gyro reads a constant bias on every axis
    bias = np.array((0.01, -0.008, 0.006))
    sensors = SyntheticSensors(roll_rad=math.radians(5.0), yaw_rad=math.radians(-40.0), gyro_bias_radps=tuple(bias))
    est = make_estimator()
    # WHEN it has run for 20 s, and for 3 minutes
    step, early = run(est, sensors, 20.0)
    _, late = run(est, sensors, 160.0, first_step=step)
    # THEN the bias-corrected rates go to zero as the bias estimate converges (slowest mode ~45 s for these gains)
    assert np.all(np.abs(early.rates_frd_radps) > 0.5 * np.abs(bias))
    assert np.all(np.abs(late.rates_frd_radps) < 0.06 * np.abs(bias)), late.rates_frd_radps / bias
    # ... and the attitude error it caused on the way (several degrees) is mostly gone
    assert attitude_error_deg(late, math.radians(5.0), 0.0, math.radians(-40.0)) < 0.5


def test_gps_acceleration_keeps_the_tilt_of_an_accelerating_vehicle() -> None:
    # GIVEN a vehicle pitched 15 deg nose down, at rest for 2 s, then accelerating north at g tan(15 deg) as its
    # thrust alone makes it (the accelerometer then reads along the body z axis, as if level)
    pitch = math.radians(-15.0)
    acc_n = GRAVITY_MPS2 * math.tan(-pitch)
    sensors = SyntheticSensors(pitch_rad=pitch, acc_ned_mps2=(acc_n, 0.0, 0.0), accel_from_s=2.0)
    est = make_estimator()
    # WHEN it flies like that for 8 s with the GPS velocity showing the acceleration
    errors: list[float] = []
    _, estimate = run(est, sensors, 10.0, on_step=lambda _s, e: errors.append(attitude_error_deg(e, 0.0, pitch, 0.0)))
    # THEN the gravity reference is compensated by the GPS-derived acceleration: the attitude keeps the true tilt
    # (a quarter of a degree lost while the 10 Hz compensation catches up) instead of being pulled towards level
    assert max(errors) < 0.4, f"worst attitude error {max(errors):.3f} deg"
    # ... and the velocity and position follow the accelerating truth
    t = 10.0 - DT_S
    np.testing.assert_allclose(estimate.vel_ned_mps, sensors.vel(t), atol=0.01)
    np.testing.assert_allclose(estimate.pos_ned_m, sensors.pos(t), atol=0.005)


# ---- position, velocity, altitude ---------------------------------------------------------------------------------
def test_position_and_velocity_start_at_the_first_gps_fix() -> None:
    # GIVEN a vehicle moving at 2 m/s north-east, 12 m north and 5 m west of the origin, at 3 m altitude
    sensors = SyntheticSensors(pos0_ned_m=(12.0, -5.0, -3.0), vel0_ned_mps=(2.0, 2.0, 0.0))
    # WHEN the estimator sees its first readings (GPS, barometer and magnetometer all due)
    estimate = make_estimator().update(sensors.readings(0), 0.0, DT_S)
    # THEN the horizontal position and the velocity are the fix's, the altitude the barometer's
    np.testing.assert_allclose(estimate.pos_ned_m, (12.0, -5.0, -3.0), atol=1e-9)
    np.testing.assert_allclose(estimate.vel_ned_mps, (2.0, 2.0, 0.0), atol=1e-9)


def test_constant_velocity_motion_is_tracked_without_lag() -> None:
    # GIVEN a vehicle cruising at 3 m/s north and 1 m/s up with exact sensors
    sensors = SyntheticSensors(vel0_ned_mps=(3.0, 0.0, -1.0), yaw_rad=math.radians(10.0))
    est = make_estimator()
    # WHEN it has flown for 10 s
    _, estimate = run(est, sensors, 10.0)
    # THEN position and velocity are on the truth
    t = 10.0 - DT_S
    np.testing.assert_allclose(estimate.pos_ned_m, sensors.pos(t), atol=1e-3)
    np.testing.assert_allclose(estimate.vel_ned_mps, sensors.vel(t), atol=1e-3)


def test_horizontal_position_follows_a_gps_jump_with_the_configured_time_constant() -> None:
    # GIVEN a vehicle at rest whose estimate has settled on the GPS fix
    sensors = SyntheticSensors()
    est = make_estimator()
    step, _ = run(est, sensors, 5.0)
    # WHEN the fix jumps 1 m north (the inertial sensors see no motion), at a GPS sample
    assert step % GPS_EVERY == 0
    sensors.gps_offset_ned_m = np.array((1.0, 0.0, 0.0))
    t0 = step * DT_S
    north: dict[float, float] = {}
    worst_down = 0.0

    def record(s: int, estimate: Estimate) -> None:
        nonlocal worst_down
        north[round(s * DT_S - t0, 6)] = float(estimate.pos_ned_m[0])
        worst_down = max(worst_down, abs(float(estimate.pos_ned_m[2])))

    run(est, sensors, 6.0, first_step=step, on_step=record)
    tau = CONFIG.tau_xy_s
    # THEN the first fix moves it by k1 dt = 3 dt / tau_xy of the jump, it is within 5 % of the new fix after
    # tau_xy, overshoots by less than 5 % and is within 2 cm after 6 tau_xy
    assert north[0.0] == pytest.approx(3.0 * GPS_EVERY * DT_S / tau, abs=1e-9)
    assert abs(north[round(tau, 6)] - 1.0) < 0.05
    assert max(north.values()) < 1.05
    assert abs(north[round(6 * tau, 6)] - 1.0) < 0.02
    # ... and the altitude does not move
    assert worst_down < 1e-6


def test_vertical_accelerometer_bias_is_learned_from_the_barometer() -> None:
    # GIVEN a hovering vehicle whose accelerometer reads 0.3 m/s^2 too much along the body z axis
    sensors = SyntheticSensors(pos0_ned_m=(0.0, 0.0, -3.0), accel_bias_mps2=(0.0, 0.0, 0.3))
    est = make_estimator()
    # WHEN it has run for 1 s, and for 20 s
    step, early = run(est, sensors, 1.0)
    _, late = run(est, sensors, 19.0, first_step=step)
    # THEN the bias shows at first (the vehicle seems to sink) and is then learned: on the truth within millimetres
    assert early.vel_ned_mps[2] > 0.03
    assert late.pos_ned_m[2] == pytest.approx(-3.0, abs=0.002)
    assert late.vel_ned_mps[2] == pytest.approx(0.0, abs=0.005)


def test_altitude_is_relative_to_the_origin_altitude_given_at_construction() -> None:
    # GIVEN an estimator whose origin is the ground at 488 m AMSL, and a barometer reading 490.5 m
    sensors = SyntheticSensors(pos0_ned_m=(0.0, 0.0, -2.5))
    est = make_estimator()
    assert sensors.readings(0).baro is not None
    # WHEN it sees the first barometer sample
    estimate = est.update(sensors.readings(0), 0.0, DT_S)
    # THEN the vehicle is 2.5 m above the origin, and the altitude is valid from then on
    assert estimate.pos_ned_m[2] == pytest.approx(-2.5, abs=1e-9)
    assert estimate.altitude_valid


# ---- validity flags -----------------------------------------------------------------------------------------------
def test_nothing_is_valid_before_the_first_heading_barometer_and_gps_samples() -> None:
    # GIVEN readings with only the IMU (step 1 is off the barometer, magnetometer and GPS schedules)
    sensors = SyntheticSensors()
    readings = sensors.readings(1)
    assert readings.mag is None and readings.baro is None and readings.gps is None
    # WHEN the estimator sees them
    estimate = make_estimator().update(readings, DT_S, DT_S)
    # THEN no part of the estimate is valid, and the attitude is still the identity
    assert not (estimate.attitude_valid or estimate.position_valid or estimate.altitude_valid)
    np.testing.assert_array_equal(estimate.att_q_frd_to_ned, (1.0, 0.0, 0.0, 0.0))


def test_attitude_becomes_valid_converge_s_after_the_first_magnetometer_sample() -> None:
    # GIVEN an estimator whose first magnetometer sample arrives at step 8 (20 ms)
    sensors = SyntheticSensors()
    est = make_estimator()
    flags: dict[int, bool] = {}
    # WHEN it runs from step 1 on (IMU only until the first magnetometer sample)
    run(est, sensors, 2.0, first_step=1, on_step=lambda s, e: flags.__setitem__(s, e.attitude_valid))
    # THEN the attitude becomes valid exactly converge_s after that sample, and stays valid
    first_valid = min(s for s, ok in flags.items() if ok)
    assert first_valid * DT_S == pytest.approx(BARO_MAG_EVERY * DT_S + CONFIG.converge_s, abs=1.01 * DT_S)
    assert all(ok for s, ok in flags.items() if s >= first_valid)


def test_position_becomes_valid_gps_converge_s_after_the_first_3d_fix() -> None:
    # GIVEN a receiver that reports "no fix" for the first 1.5 s, then 3D fixes at 10 Hz
    sensors = SyntheticSensors(pos0_ned_m=(4.0, 3.0, 0.0), gps_fix_s=1.5)
    est = make_estimator()
    flags: dict[int, Estimate] = {}
    # WHEN the estimator runs for 6 s
    run(est, sensors, 6.0, on_step=flags.__setitem__)
    # THEN the no-fix reports are ignored (the position stays at the origin) ...
    assert not flags[round(1.4 * RATE_HZ)].position_valid
    np.testing.assert_allclose(flags[round(1.4 * RATE_HZ)].pos_ned_m[:2], (0.0, 0.0), atol=1e-9)
    # ... the first 3D fix sets the position, which becomes valid gps_converge_s later and stays valid
    np.testing.assert_allclose(flags[round(1.5 * RATE_HZ)].pos_ned_m[:2], (4.0, 3.0), atol=1e-9)
    first_valid = min(s for s, e in flags.items() if e.position_valid)
    assert first_valid * DT_S == pytest.approx(1.5 + CONFIG.gps_converge_s, abs=1.01 * DT_S)
    assert all(e.position_valid for s, e in flags.items() if s >= first_valid)
    # ... while the attitude and altitude were valid independently of the fix
    assert flags[round(1.4 * RATE_HZ)].attitude_valid
    assert flags[round(1.4 * RATE_HZ)].altitude_valid


# ---- outputs ------------------------------------------------------------------------------------------------------
def test_estimate_arrays_are_fresh_float_arrays_each_update() -> None:
    # GIVEN an estimator that has produced an estimate
    sensors = SyntheticSensors(roll_rad=0.1, gyro_bias_radps=(0.01, 0.0, 0.0))
    est = make_estimator()
    first = est.update(sensors.readings(0), 0.0, DT_S)
    # WHEN the caller scribbles over the arrays of that estimate
    arrays = (first.pos_ned_m, first.vel_ned_mps, first.att_q_frd_to_ned, first.rates_frd_radps)
    for a in arrays:
        assert isinstance(a, np.ndarray) and a.dtype == np.float64
        a[:] = 1e6
    # THEN the next estimate is unaffected
    second = est.update(sensors.readings(1), DT_S, DT_S)
    assert second.pos_ned_m.shape == (3,) and second.att_q_frd_to_ned.shape == (4,)
    assert np.all(np.abs(second.pos_ned_m) < 1.0)
    assert attitude_error_deg(second, 0.1, 0.0, 0.0) < 0.01
    np.testing.assert_allclose(second.rates_frd_radps, (0.01, 0.0, 0.0), atol=1e-3)


def test_same_readings_give_identical_estimates() -> None:
    # GIVEN two estimators fed the same noisy readings
    a, b = make_estimator(), make_estimator()
    sa, sb = SyntheticSensors(roll_rad=0.2, noise_seed=7), SyntheticSensors(roll_rad=0.2, noise_seed=7)
    # WHEN both run for 3 s
    _, ea = run(a, sa, 3.0)
    _, eb = run(b, sb, 3.0)
    # THEN their estimates are bit-identical
    for f in ("pos_ned_m", "vel_ned_mps", "att_q_frd_to_ned", "rates_frd_radps"):
        np.testing.assert_array_equal(getattr(ea, f), getattr(eb, f))
    assert (ea.roll_rad, ea.pitch_rad, ea.yaw_rad) == (eb.roll_rad, eb.pitch_rad, eb.yaw_rad)


def test_a_published_estimate_builds_its_vectors_from_the_row_of_its_own_step() -> None:
    """``published`` (the estimate of a step taken in a kernel) copies the output row at once and builds its vectors
    on first read: read late, replaced or pickled, it is the estimate ``update`` returned for that step."""
    import dataclasses
    import pickle

    est, sensors = make_estimator(), SyntheticSensors()
    kept = []
    for step in range(300):
        eager = est.update(sensors.readings(step), step * DT_S, DT_S)
        kept.append((eager, est.published(step * DT_S)))
    for eager, late in kept[::37]:
        for copy_ in (late, dataclasses.replace(late), pickle.loads(pickle.dumps(late))):
            for f in dataclasses.fields(Estimate):
                a, b = getattr(eager, f.name), getattr(copy_, f.name)
                assert type(a) is type(b)
                assert a.tobytes() == b.tobytes() if isinstance(a, np.ndarray) else a == b, f.name
        assert type(dataclasses.replace(late)) is Estimate
