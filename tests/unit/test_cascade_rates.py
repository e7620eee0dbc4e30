"""The cascade's loop rates: position and velocity at MPC_LOOP_HZ, attitude, rate and allocation at every step."""

from __future__ import annotations

import dataclasses
import math

import pytest

from sitl.control.cascade import AttitudeSetpoint, Cascade, CascadeOutput, TrajectorySetpoint
from sitl.control.params import CONTROL_PARAMS
from sitl.dynamics.airframe import load_airframe
from sitl.mathutil import GRAVITY_MPS2
from sitl.params import ParamStore

pytestmark = pytest.mark.timeout(30)

AIRFRAME = load_airframe("quad_x_f450")
DT_S = 1.0 / 400.0
WEIGHT_N = AIRFRAME.mass_kg * GRAVITY_MPS2


@dataclasses.dataclass(frozen=True)
class _State:
    pos_ned_m: tuple[float, float, float] = (0.0, 0.0, -5.0)
    vel_ned_mps: tuple[float, float, float] = (0.0, 0.0, 0.0)
    att_q_frd_to_ned: tuple[float, float, float, float] = (1.0, 0.0, 0.0, 0.0)
    rates_frd_radps: tuple[float, float, float] = (0.0, 0.0, 0.0)


def _cascade(loop_hz: float) -> tuple[Cascade, ParamStore]:
    store = ParamStore(CONTROL_PARAMS)
    store.set("MPC_LOOP_HZ", loop_hz)
    return Cascade(AIRFRAME, store), store


def _drifting(step: int) -> _State:
    """A vehicle sliding north and rolling slowly: every stage's input changes at every step."""
    return _State(
        pos_ned_m=(0.01 * step, 0.0, -5.0),
        vel_ned_mps=(0.4, 0.0, 0.0),
        rates_frd_radps=(0.001 * step, 0.0, 0.0),
    )


def _fly(cascade: Cascade, setpoint: TrajectorySetpoint, steps: int) -> list[CascadeOutput]:
    return [cascade.update(_drifting(i), setpoint, DT_S) for i in range(steps)]


def test_outer_loops_run_at_the_loop_rate_and_inner_loops_at_every_step() -> None:
    # GIVEN the outer loops at 100 Hz and a setpoint that holds still
    cascade, _ = _cascade(100.0)
    setpoint = TrajectorySetpoint(pos_ned_m=(1.0, 0.0, -5.0), yaw_rad=0.0)
    # WHEN it runs 12 physics steps while the state changes at every step
    outs = _fly(cascade, setpoint, 12)
    # THEN the velocity setpoint changes every 4th step (400 / 100) and is held in between
    vel_sp = [out.vel_sp_ned_mps for out in outs]
    changed = [i for i in range(1, 12) if vel_sp[i] != vel_sp[i - 1]]
    assert changed == [4, 8]
    assert [out.att_sp_q for out in outs[4:8]] == [outs[4].att_sp_q] * 4
    # AND the rate loop's torque follows the state at every step
    torques = [out.torque_sp_frd_nm for out in outs]
    assert all(torques[i] != torques[i - 1] for i in range(1, 12))


def test_at_the_physics_rate_the_cascade_is_single_rate() -> None:
    cascade, _ = _cascade(400.0)
    outs = _fly(cascade, TrajectorySetpoint(pos_ned_m=(1.0, 0.0, -5.0), yaw_rad=0.0), 8)
    assert all(outs[i].vel_sp_ned_mps != outs[i - 1].vel_sp_ned_mps for i in range(1, 8))


def test_a_new_setpoint_is_acted_on_at_the_next_step() -> None:
    cascade, _ = _cascade(50.0)
    first = cascade.update(_State(), TrajectorySetpoint(pos_ned_m=(1.0, 0.0, -5.0)), DT_S)
    # The same values in a new object change nothing; other values are flown at once, between loop runs.
    same = cascade.update(_State(), TrajectorySetpoint(pos_ned_m=(1.0, 0.0, -5.0)), DT_S)
    assert same.vel_sp_ned_mps == first.vel_sp_ned_mps
    moved = cascade.update(_State(), TrajectorySetpoint(pos_ned_m=(2.0, 0.0, -5.0)), DT_S)
    assert moved.vel_sp_ned_mps[0] == pytest.approx(2.0 * 0.95)


def test_a_parameter_change_is_acted_on_at_the_next_step() -> None:
    cascade, store = _cascade(50.0)
    setpoint = TrajectorySetpoint(pos_ned_m=(1.0, 0.0, -5.0))
    assert cascade.update(_State(), setpoint, DT_S).vel_sp_ned_mps[0] == pytest.approx(0.95)
    store.set("MPC_XY_P", 0.5)
    assert cascade.update(_State(), setpoint, DT_S).vel_sp_ned_mps[0] == pytest.approx(0.5)


@pytest.mark.parametrize("loop_hz", [400.0, 100.0, 30.0])
def test_the_velocity_integrator_integrates_elapsed_time_at_any_loop_rate(loop_hz: float) -> None:
    # GIVEN a constant 0.5 m/s northward velocity error held for one second
    cascade, _ = _cascade(loop_hz)
    setpoint = TrajectorySetpoint(vel_ned_mps=(0.5, 0.0, 0.0), pos_ned_m=(math.nan, math.nan, -5.0))
    for _ in range(400):
        cascade.update(_State(), setpoint, DT_S)
    # THEN the integral is MPC_XY_VEL_I_ACC * error * time, whatever the rate (up to the last unfinished period)
    period_s = max(DT_S, 1.0 / loop_hz)
    assert cascade.velocity.integral_ned_mps2[0] == pytest.approx(0.4 * 0.5 * 1.0, abs=0.4 * 0.5 * period_s + 1e-9)


def test_outer_loops_restart_at_once_after_attitude_control() -> None:
    cascade, _ = _cascade(50.0)
    setpoint = TrajectorySetpoint(pos_ned_m=(1.0, 0.0, -5.0))
    cascade.update(_State(), setpoint, DT_S)
    attitude = cascade.update_attitude(_State(), AttitudeSetpoint(att_q=None, thrust_n=WEIGHT_N), DT_S)
    assert all(math.isnan(v) for v in attitude.vel_sp_ned_mps)
    # Back on the same trajectory setpoint object, the outer loops run now rather than at their next period.
    back = cascade.update(_State(pos_ned_m=(0.5, 0.0, -5.0)), setpoint, DT_S)
    assert back.vel_sp_ned_mps[0] == pytest.approx(0.5 * 0.95)
