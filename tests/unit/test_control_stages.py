"""The cascade stages one by one (limits, anti-windup, NaN fields, signs), then the whole cascade on a toy plant."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from sitl.control.attitude import AttitudeController, thrust_to_attitude
from sitl.control.cascade import AttitudeSetpoint, Cascade, TrajectorySetpoint
from sitl.control.configs import attitude_config, position_config, rate_config, velocity_config
from sitl.control.params import CONTROL_PARAMS
from sitl.control.position import PositionController
from sitl.control.rate import RateController
from sitl.control.velocity import VelocityController
from sitl.dynamics.airframe import load_airframe
from sitl.mathutil import GRAVITY_MPS2, quat_from_euler, quat_to_euler
from sitl.params import ParamStore
from tests.unit.toy_plant import CONTROL_DT_S, Flight, GustyWind, NoisyEstimate, ToyPlant, fly

AIRFRAME = load_airframe("quad_x_f450")
MASS = AIRFRAME.mass_kg
WEIGHT_N = MASS * GRAVITY_MPS2
COLLECTIVE_MAX_N = AIRFRAME.max_thrust_per_rotor_n * len(AIRFRAME.rotors)
NAN3 = (math.nan, math.nan, math.nan)
DT = CONTROL_DT_S


def _store(**overrides: float) -> ParamStore:
    store = ParamStore(CONTROL_PARAMS)
    for name, value in overrides.items():
        store.set(name, value)
    return store


def _q(roll_deg: float = 0.0, pitch_deg: float = 0.0, yaw_deg: float = 0.0) -> tuple[float, float, float, float]:
    w, x, y, z = quat_from_euler(math.radians(roll_deg), math.radians(pitch_deg), math.radians(yaw_deg)).tolist()
    return w, x, y, z


def _tilt_deg(thrust: tuple[float, float, float]) -> float:
    return math.degrees(math.atan2(math.hypot(thrust[0], thrust[1]), -thrust[2]))


# ---- parameters ----------------------------------------------------------------------------------------------------
def test_parameter_table_is_valid_and_unique() -> None:
    store = ParamStore(CONTROL_PARAMS)  # rejects duplicates, long names and defaults out of range
    assert len(store) == len(CONTROL_PARAMS)
    for definition in CONTROL_PARAMS:
        assert definition.description and definition.name.isupper()


# ---- position ------------------------------------------------------------------------------------------------------
def test_far_target_is_approached_at_max_horizontal_speed_along_its_direction() -> None:
    # GIVEN a position 300 m north and 400 m east
    ctl = PositionController(position_config(_store()))
    # WHEN the position loop runs
    vx, vy, vz = ctl.update((0.0, 0.0, -5.0), (300.0, 400.0, -5.0), NAN3)
    # THEN the horizontal speed is the limit, pointing at the target
    assert math.hypot(vx, vy) == pytest.approx(12.0)
    assert vy / vx == pytest.approx(400.0 / 300.0)
    assert vz == pytest.approx(0.0)


def test_vertical_speed_limits_differ_up_and_down() -> None:
    ctl = PositionController(position_config(_store()))
    assert ctl.update((0.0, 0.0, 0.0), (0.0, 0.0, -100.0), NAN3)[2] == pytest.approx(-3.0)  # climb
    assert ctl.update((0.0, 0.0, -100.0), (0.0, 0.0, 0.0), NAN3)[2] == pytest.approx(1.5)  # descend


def test_small_error_gives_proportional_velocity() -> None:
    ctl = PositionController(position_config(_store()))
    vx, vy, vz = ctl.update((1.0, 2.0, -3.0), (2.0, 1.0, -3.5), NAN3)
    assert (vx, vy, vz) == pytest.approx((0.95, -0.95, -0.5))


def test_nan_position_on_an_axis_means_velocity_control_there() -> None:
    # GIVEN a setpoint with north/east positions but only a vertical velocity (a landing descent)
    ctl = PositionController(position_config(_store()))
    vx, vy, vz = ctl.update((0.0, 0.0, -10.0), (1.0, 0.0, math.nan), (math.nan, math.nan, 0.7))
    # THEN the horizontal axes are position-controlled and the vertical velocity passes through
    assert (vx, vy, vz) == pytest.approx((0.95, 0.0, 0.7))


def test_velocity_is_feedforward_when_position_is_set_and_unset_axes_stay_nan() -> None:
    ctl = PositionController(position_config(_store()))
    vx, vy, vz = ctl.update((0.0, 0.0, -5.0), (0.0, math.nan, -5.0), (2.0, math.nan, math.nan))
    assert vx == pytest.approx(2.0)  # on target: the feed-forward alone
    assert math.isnan(vy)  # nothing set: left to the acceleration setpoint
    assert vz == pytest.approx(0.0)


def test_speed_limit_keeps_position_correction_before_feedforward() -> None:
    # GIVEN a 10 m/s feed-forward east while 20 m south of the target
    ctl = PositionController(position_config(_store(MPC_XY_VEL_MAX=5.0)))
    vx, vy, _ = ctl.update((0.0, 0.0, -5.0), (20.0, 0.0, -5.0), (0.0, 10.0, 0.0))
    # THEN the correction (0.95 * 20 = 19 m/s north) fills the whole 5 m/s limit; the feed-forward is dropped
    assert (vx, vy) == pytest.approx((5.0, 0.0))


# ---- velocity -> thrust --------------------------------------------------------------------------------------------
def _velocity(**overrides: float) -> VelocityController:
    return VelocityController(velocity_config(_store(**overrides), AIRFRAME))


def test_hover_demand_is_the_weight_upwards() -> None:
    out = _velocity().update((0.0, 0.0, 0.0), (0.0, 0.0, 0.0), NAN3, DT)
    assert out.thrust_sp_ned_n == pytest.approx((0.0, 0.0, -WEIGHT_N))


def test_acceleration_feedforward_becomes_force_through_the_mass() -> None:
    out = _velocity().update((0.0, 0.0, 0.0), (0.0, 0.0, 0.0), (1.0, 0.0, -2.0), DT)
    assert out.thrust_sp_ned_n == pytest.approx((MASS * 1.0, 0.0, -MASS * (GRAVITY_MPS2 + 2.0)))


def test_tilt_limit_keeps_the_vertical_force() -> None:
    # GIVEN a huge northward velocity error
    out = _velocity().update((0.0, 0.0, 0.0), (30.0, 0.0, 0.0), NAN3, DT)
    fx, fy, fz = out.thrust_sp_ned_n
    # THEN the thrust leans exactly MPC_TILTMAX_AIR towards north and still carries the weight
    assert _tilt_deg(out.thrust_sp_ned_n) == pytest.approx(45.0)
    assert fx > 0.0 and fy == pytest.approx(0.0)
    assert fz == pytest.approx(-WEIGHT_N)


def test_collective_never_drops_below_minimum_thrust() -> None:
    # GIVEN a demand to fall faster than gravity
    out = _velocity().update((0.0, 0.0, 0.0), (0.0, 0.0, 0.0), (0.0, 0.0, 20.0), DT)
    # THEN the rotors keep MPC_THR_MIN and the vehicle stays level
    assert out.thrust_sp_ned_n == pytest.approx((0.0, 0.0, -0.12 * COLLECTIVE_MAX_N))


def test_full_climb_keeps_a_horizontal_margin_and_the_maximum_thrust() -> None:
    # GIVEN demands for a violent climb and a sideways acceleration at once
    out = _velocity().update((0.0, 0.0, 0.0), (0.0, 0.0, 0.0), (20.0, 0.0, -40.0), DT)
    fx, _, fz = out.thrust_sp_ned_n
    # THEN the thrust stays within MPC_THR_MAX, and horizontal control keeps its MPC_THR_XY_MARG share
    assert math.hypot(fx, fz) == pytest.approx(COLLECTIVE_MAX_N)
    assert fx == pytest.approx(0.3 * COLLECTIVE_MAX_N)


def test_vertical_integrator_stops_winding_into_saturated_thrust() -> None:
    # GIVEN a climb demand far beyond the maximum thrust, held for a second
    ctl = _velocity(MPC_THR_MAX=0.5)
    for _ in range(400):
        ctl.update((0.0, 0.0, 0.0), (0.0, 0.0, -8.0), NAN3, DT)
    # THEN the vertical integrator did not wind up
    assert ctl.integral_ned_mps2[2] == pytest.approx(0.0)
    # AND it still integrates the other way (towards unsaturating)
    ctl.update((0.0, 0.0, -1.0), (0.0, 0.0, 0.0), NAN3, DT)
    assert ctl.integral_ned_mps2[2] > 0.0


def test_vertical_integrator_is_bounded_by_gravity() -> None:
    ctl = _velocity(MPC_Z_VEL_I_ACC=3.0)
    for _ in range(4000):
        ctl.update((0.0, 0.0, 0.5), (0.0, 0.0, 0.0), NAN3, DT)  # always sinking: integrate upwards
    assert ctl.integral_ned_mps2[2] == pytest.approx(-GRAVITY_MPS2)


def test_horizontal_integrator_is_bled_while_tilt_limited() -> None:
    # GIVEN a sustained horizontal error large enough to saturate the tilt
    saturated = _velocity()
    for _ in range(400):
        saturated.update((0.0, 0.0, 0.0), (20.0, 0.0, 0.0), NAN3, DT)
    # THEN the integrator does not accumulate the error (plainly it would hold 0.4 * 20 * 1 s = 8 m/s^2) but
    # tracks the saturation (PX4's tracking anti-windup settles it at a_produced - P * e / 2 = g - 30 m/s^2)
    integral = saturated.integral_ned_mps2[0]
    assert GRAVITY_MPS2 - 30.0 < integral < 0.0
    # AND the demand still leans fully towards the target
    out = saturated.update((0.0, 0.0, 0.0), (20.0, 0.0, 0.0), NAN3, DT)
    assert _tilt_deg(out.thrust_sp_ned_n) == pytest.approx(45.0)
    # AND without saturation it integrates normally
    free = _velocity()
    for _ in range(400):
        free.update((0.0, 0.0, 0.0), (0.5, 0.0, 0.0), NAN3, DT)
    assert free.integral_ned_mps2[0] == pytest.approx(0.4 * 0.5 * 1.0, rel=1e-6)


def test_acceleration_only_axis_flies_open_loop_and_leaves_its_integrator_alone() -> None:
    ctl = _velocity()
    out = ctl.update((3.0, 0.0, 0.0), (math.nan, 0.0, 0.0), (1.5, math.nan, math.nan), DT)
    assert out.acc_sp_ned_mps2[0] == pytest.approx(1.5)  # no velocity feedback on north
    assert ctl.integral_ned_mps2[0] == 0.0


def test_axis_with_nothing_set_brakes_to_zero_velocity() -> None:
    ctl = _velocity()
    out = ctl.update((2.0, 0.0, 0.0), NAN3, NAN3, DT)
    assert out.acc_sp_ned_mps2[0] == pytest.approx(-3.0 * 2.0)


def test_frozen_integrator_does_not_move() -> None:
    ctl = _velocity()
    ctl.update((0.0, 0.0, 0.0), (1.0, 1.0, -1.0), NAN3, DT, freeze_integrator=True)
    assert ctl.integral_ned_mps2 == [0.0, 0.0, 0.0]


# ---- attitude ------------------------------------------------------------------------------------------------------
def test_vertical_thrust_gives_level_attitude_with_the_yaw_setpoint() -> None:
    q = thrust_to_attitude((0.0, 0.0, -WEIGHT_N), math.radians(30.0))
    roll, pitch, yaw = quat_to_euler(np.array(q))
    assert (roll, pitch, yaw) == pytest.approx((0.0, 0.0, math.radians(30.0)), abs=1e-12)


def test_thrust_north_pitches_nose_down_and_thrust_east_rolls_right() -> None:
    roll, pitch, _ = quat_to_euler(np.array(thrust_to_attitude((5.0, 0.0, -WEIGHT_N), 0.0)))
    assert pitch == pytest.approx(-math.atan2(5.0, WEIGHT_N)) and roll == pytest.approx(0.0, abs=1e-12)
    roll, pitch, _ = quat_to_euler(np.array(thrust_to_attitude((0.0, 5.0, -WEIGHT_N), 0.0)))
    assert roll == pytest.approx(math.atan2(5.0, WEIGHT_N)) and pitch == pytest.approx(0.0, abs=1e-12)


def test_attitude_errors_command_rates_of_the_same_sign() -> None:
    ctl = AttitudeController(attitude_config(_store()))
    level = _q()
    # GIVEN small errors about each axis THEN the rate setpoint is about that axis, same sign, P times the error
    rx, ry, rz = ctl.update(level, _q(roll_deg=2.0))
    assert rx == pytest.approx(6.5 * math.radians(2.0), rel=1e-3) and abs(ry) < 1e-9 and abs(rz) < 1e-9
    rx, ry, rz = ctl.update(level, _q(pitch_deg=-2.0))
    assert ry == pytest.approx(-6.5 * math.radians(2.0), rel=1e-3) and abs(rx) < 1e-9 and abs(rz) < 1e-9
    rx, ry, rz = ctl.update(level, _q(yaw_deg=2.0))
    assert rz == pytest.approx(2.8 * math.radians(2.0), rel=1e-3) and abs(rx) < 1e-9 and abs(ry) < 1e-9
    assert ctl.update(_q(10.0, -5.0, 70.0), _q(10.0, -5.0, 70.0)) == pytest.approx((0.0, 0.0, 0.0), abs=1e-12)


def test_rate_setpoints_respect_the_rate_limits() -> None:
    ctl = AttitudeController(attitude_config(_store()))
    rx, ry, rz = ctl.update(_q(), _q(roll_deg=-170.0, pitch_deg=60.0, yaw_deg=170.0))
    assert abs(rx) <= math.radians(220.0) + 1e-12 and abs(ry) <= math.radians(220.0) + 1e-12
    assert abs(rz) <= math.radians(120.0) + 1e-12


def test_roll_pitch_come_first_when_yaw_error_is_large() -> None:
    # GIVEN a 10 degree tilt error together with a 150 degree heading error
    ctl = AttitudeController(attitude_config(_store(MC_ROLLRATE_MAX=1800.0, MC_YAWRATE_MAX=1800.0)))
    rx, ry, rz = ctl.update(_q(), _q(roll_deg=10.0, yaw_deg=150.0))
    # THEN the tilt is corrected as hard as if there were no heading error, about the shortest axis (the
    # setpoint's roll axis, 150 degrees round from the body's)
    assert math.hypot(rx, ry) == pytest.approx(6.5 * 2.0 * math.sin(math.radians(5.0)), rel=1e-9)
    assert math.atan2(ry, rx) == pytest.approx(math.radians(150.0), abs=1e-9)
    # AND the yaw command uses only MC_YAW_WEIGHT of the heading error
    assert rz == pytest.approx(2.8 / 0.4 * 2.0 * math.sin(0.4 * math.radians(75.0)), rel=1e-9)
    assert rz < 2.8 * math.radians(150.0)


def test_yaw_rate_feedforward_is_a_heading_rate() -> None:
    ctl = AttitudeController(attitude_config(_store()))
    # level: all of it about body z
    assert ctl.update(_q(), _q(), 0.5) == pytest.approx((0.0, 0.0, 0.5))
    # rolled 30 degrees right: the NED down axis seen from the body tilts towards body -y
    rx, ry, rz = ctl.update(_q(roll_deg=30.0), _q(roll_deg=30.0), 0.5)
    assert (rx, ry, rz) == pytest.approx((0.0, 0.5 * math.sin(math.radians(30.0)), 0.5 * math.cos(math.radians(30.0))))


# ---- rates ---------------------------------------------------------------------------------------------------------
def test_torque_is_inertia_times_angular_acceleration_demand() -> None:
    # GIVEN a roll-rate error of 1 rad/s on the reference airframe and on one twice as heavy in roll
    ctl = RateController(rate_config(_store(), AIRFRAME))
    heavy = dataclasses.replace(AIRFRAME, inertia_diag_kg_m2=(0.05825, 0.029125, 0.055225))
    ctl_heavy = RateController(rate_config(_store(), heavy))
    tx = ctl.update((0.0, 0.0, 0.0), (1.0, 0.0, 0.0), DT)[0]
    tx_heavy = ctl_heavy.update((0.0, 0.0, 0.0), (1.0, 0.0, 0.0), DT)[0]
    # THEN the torque is J * P * error: the same gains fit both
    assert tx == pytest.approx(0.029125 * 25.0)
    assert tx_heavy == pytest.approx(2.0 * tx)


def test_derivative_acts_on_the_measurement_not_the_setpoint() -> None:
    ctl = RateController(rate_config(_store(MC_ROLLRATE_I=0.0), AIRFRAME))
    ctl.update((0.0, 0.0, 0.0), (0.0, 0.0, 0.0), DT)
    # A setpoint step gives no derivative kick...
    assert ctl.update((0.0, 0.0, 0.0), (2.0, 0.0, 0.0), DT)[0] == pytest.approx(0.029125 * 25.0 * 2.0)
    # ...while a measured rate change is damped (opposite torque beyond the P term).
    damped = ctl.update((0.1, 0.0, 0.0), (2.0, 0.0, 0.0), DT)[0]
    assert damped < 0.029125 * 25.0 * 1.9


def test_rate_integrator_is_limited() -> None:
    ctl = RateController(rate_config(_store(), AIRFRAME))
    for _ in range(4000):
        ctl.update((0.0, 0.0, 0.0), (1.0, -1.0, 1.0), DT)
    assert ctl.integral_radps2 == pytest.approx([30.0, -30.0, 5.0])


def test_rate_integrator_does_not_push_into_reported_saturation() -> None:
    ctl = RateController(rate_config(_store(), AIRFRAME))
    sat = (True, False, False)
    for _ in range(100):
        ctl.update((0.0, 0.0, 0.0), (1.0, 0.0, 0.0), DT, saturated_pos=sat)
    assert ctl.integral_radps2[0] == 0.0
    ctl.update((0.0, 0.0, 0.0), (-1.0, 0.0, 0.0), DT, saturated_pos=sat)  # unsaturating direction: allowed
    assert ctl.integral_radps2[0] < 0.0


def test_gyroscopic_coupling_is_compensated() -> None:
    # Spinning about pitch and yaw at once needs a roll torque (Iz - Iy) * q * r just to keep the rates.
    ctl = RateController(rate_config(_store(), AIRFRAME))
    tx, _, _ = ctl.update((0.0, 1.0, 2.0), (0.0, 1.0, 2.0), DT)
    assert tx == pytest.approx((0.055225 - 0.029125) * 1.0 * 2.0)


# ---- the cascade ---------------------------------------------------------------------------------------------------
@dataclasses.dataclass(frozen=True)
class _State:
    pos_ned_m: tuple[float, float, float] = (0.0, 0.0, -5.0)
    vel_ned_mps: tuple[float, float, float] = (0.0, 0.0, 0.0)
    att_q_frd_to_ned: tuple[float, float, float, float] = (1.0, 0.0, 0.0, 0.0)
    rates_frd_radps: tuple[float, float, float] = (0.0, 0.0, 0.0)


def test_setpoint_fields_default_to_not_set() -> None:
    sp = TrajectorySetpoint()
    assert all(math.isnan(v) for v in (*sp.pos_ned_m, *sp.vel_ned_mps, *sp.acc_ned_mps2, sp.yaw_rad))


def test_hover_at_the_setpoint_gives_hover_motor_commands() -> None:
    out = Cascade(AIRFRAME, _store()).update(_State(), TrajectorySetpoint(pos_ned_m=(0.0, 0.0, -5.0)), DT)
    assert out.motor_cmds == pytest.approx((math.sqrt(AIRFRAME.hover_thrust_fraction),) * 4)
    assert out.collective_sp_n == pytest.approx(WEIGHT_N)


def test_parameter_change_takes_effect_at_the_next_step() -> None:
    store = _store()
    cascade = Cascade(AIRFRAME, store)
    sp = TrajectorySetpoint(pos_ned_m=(1.0, 0.0, -5.0))
    assert cascade.update(_State(), sp, DT).vel_sp_ned_mps[0] == pytest.approx(0.95)
    store.set("MPC_XY_P", 0.5)
    assert cascade.update(_State(), sp, DT).vel_sp_ned_mps[0] == pytest.approx(0.5)


def test_unset_heading_holds_the_last_heading_setpoint() -> None:
    cascade = Cascade(AIRFRAME, _store())
    cascade.update(_State(), TrajectorySetpoint(pos_ned_m=(0.0, 0.0, -5.0), yaw_rad=1.0), DT)
    out = cascade.update(_State(), TrajectorySetpoint(pos_ned_m=(0.0, 0.0, -5.0)), DT)
    assert quat_to_euler(np.array(out.att_sp_q))[2] == pytest.approx(1.0)
    # with a yaw rate and no heading, the heading follows the vehicle and the rate is fed forward
    out = cascade.update(_State(), TrajectorySetpoint(pos_ned_m=(0.0, 0.0, -5.0), yawspeed_radps=0.3), DT)
    assert quat_to_euler(np.array(out.att_sp_q))[2] == pytest.approx(0.0)
    assert out.rates_sp_frd_radps[2] == pytest.approx(0.3)


def test_landed_freezes_the_integrators() -> None:
    cascade = Cascade(AIRFRAME, _store())
    for _ in range(100):
        cascade.update(_State(), TrajectorySetpoint(pos_ned_m=(0.0, 0.0, -8.0)), DT, landed=True)
    assert cascade.velocity.integral_ned_mps2 == [0.0, 0.0, 0.0]
    assert cascade.rate.integral_radps2 == [0.0, 0.0, 0.0]


def test_attitude_setpoint_entry_flies_rates_or_attitude() -> None:
    cascade = Cascade(AIRFRAME, _store())
    rates = AttitudeSetpoint(att_q=None, thrust_n=WEIGHT_N, rates_sp_frd_radps=(0.2, 0.0, 0.0))
    out = cascade.update_attitude(_State(), rates, DT)
    assert out.rates_sp_frd_radps == (0.2, 0.0, 0.0) and out.torque_sp_frd_nm[0] > 0.0
    out = cascade.update_attitude(_State(), AttitudeSetpoint(att_q=_q(pitch_deg=5.0), thrust_n=WEIGHT_N), DT)
    assert out.rates_sp_frd_radps[1] > 0.0
    assert out.thrust_sp_ned_n[0] < 0.0  # nose up: thrust leans south


# ---- closed loop on the toy plant ----------------------------------------------------------------------------------
def _fly(
    setpoint: TrajectorySetpoint,
    duration_s: float,
    *,
    start: tuple[float, float, float] = (0.0, 0.0, -5.0),
    wind: GustyWind | None = None,
    mass_scale: float = 1.0,
) -> Flight:
    plant = ToyPlant(AIRFRAME, pos_ned_m=start, mass_scale=mass_scale)
    return fly(
        Cascade(AIRFRAME, _store()), plant, lambda _t: setpoint, duration_s, estimate=NoisyEstimate(seed=7), wind=wind
    )


def _settling_time_s(flight: Flight, distance_m: np.ndarray, tolerance: float) -> float:
    outside = np.nonzero(distance_m > tolerance)[0]
    return float(flight.time_s[outside[-1]]) if len(outside) else 0.0


def test_hover_holds_position() -> None:
    target = (0.0, 0.0, -5.0)
    flight = _fly(TrajectorySetpoint(pos_ned_m=target, yaw_rad=0.0), 6.0)
    err = flight.pos_ned_m[400:] - np.array(target)
    assert math.sqrt(float(np.mean(np.sum(err**2, axis=1)))) < 0.02


@pytest.mark.parametrize(
    ("north", "east", "yaw_deg"), [(5.0, 0.0, 0.0), (0.0, -5.0, 0.0), (-3.0, 4.0, 90.0), (3.5355, 3.5355, -135.0)]
)
def test_5m_step_settles_fast_without_overshoot_inside_the_tilt_limit(
    north: float, east: float, yaw_deg: float
) -> None:
    # GIVEN a hovering vehicle WHEN the position setpoint jumps 5 m horizontally (the heading held at the same time)
    flight = _fly(TrajectorySetpoint(pos_ned_m=(north, east, -5.0), yaw_rad=math.radians(yaw_deg)), 6.0)
    # THEN it settles within 0.3 m in under 4 s, overshoots less than 5 % and never tilts beyond the limit
    direction = np.array((north, east)) / 5.0
    along = flight.pos_ned_m[:, :2] @ direction
    distance = np.linalg.norm(flight.pos_ned_m - np.array((north, east, -5.0)), axis=1)
    assert _settling_time_s(flight, distance, 0.3) <= 4.0
    assert along.max() - 5.0 < 0.05 * 5.0
    assert math.degrees(flight.tilt_rad.max()) <= 45.0
    assert np.abs(flight.pos_ned_m[:, 2] + 5.0).max() < 0.3  # altitude held through the manoeuvre


def test_takeoff_from_the_ground_to_3m() -> None:
    flight = _fly(TrajectorySetpoint(pos_ned_m=(0.0, 0.0, -3.0), yaw_rad=0.0), 6.0, start=(0.0, 0.0, 0.0))
    altitude = -flight.pos_ned_m[:, 2]
    assert _settling_time_s(flight, np.abs(altitude - 3.0), 0.2) <= 4.0
    assert altitude.max() - 3.0 < 0.1


@pytest.mark.parametrize("yaw_deg", [90.0, -90.0, 179.0])
def test_yaw_step_settles_and_position_is_held(yaw_deg: float) -> None:
    flight = _fly(TrajectorySetpoint(pos_ned_m=(0.0, 0.0, -5.0), yaw_rad=math.radians(yaw_deg)), 4.0)
    yaw = np.degrees(flight.yaw_rad)
    assert _settling_time_s(flight, np.abs(yaw - yaw_deg), 3.0) <= 3.0
    assert (yaw * math.copysign(1.0, yaw_deg)).max() - abs(yaw_deg) < 3.0  # overshoot
    assert np.abs(flight.pos_ned_m - np.array((0.0, 0.0, -5.0))).max() < 0.1


@pytest.mark.parametrize("gust_seed", [3, 4])
def test_holds_position_in_wind_with_gusts(gust_seed: int) -> None:
    # GIVEN a 5 m/s wind with 1.5 m/s RMS gusts WHEN hovering THEN the position error stays well inside 0.3 m RMS
    wind = GustyWind(mean_ned_mps=(5.0, 0.0, 0.0), gust_sigma_mps=1.5, gust_time_constant_s=2.0, seed=gust_seed)
    flight = _fly(TrajectorySetpoint(pos_ned_m=(0.0, 0.0, -5.0), yaw_rad=0.0), 20.0, wind=wind)
    err = flight.pos_ned_m[2000:] - np.array((0.0, 0.0, -5.0))
    assert math.sqrt(float(np.mean(np.sum(err**2, axis=1)))) < 0.25


def test_integrators_absorb_an_unknown_payload() -> None:
    # GIVEN a vehicle 30 % heavier than the airframe file says
    flight = _fly(TrajectorySetpoint(pos_ned_m=(0.0, 0.0, -5.0), yaw_rad=0.0), 10.0, mass_scale=1.3)
    # THEN it sags at first but returns to the setpoint
    assert np.abs(flight.pos_ned_m[-400:, 2] + 5.0).max() < 0.05
