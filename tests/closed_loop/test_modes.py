"""Closed-loop flights of the autopilot's modes and safety rules: RTL, offboard loss failsafe, arming and disarming
rules, kill, goto, parameter changes in flight, and the events a ground station hears.

Policy: a ClosedLoop stepped directly (JSBSim, sensor noise on), no sockets, no wall clock; every check is made on
ground truth, which the autopilot never sees.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import pytest

from sitl.autopilot.px4_modes import Px4Mode
from sitl.autopilot.vehicle_api import CommandResult, LandedState
from sitl.control.cascade import TrajectorySetpoint
from sitl.drone.closed_loop import ClosedLoop
from sitl.dynamics.battery import Battery
from tests.closed_loop.flight import Trace, arm_when_ready, boot_position, make_sim, reaction_tolerance_s, take_off

pytestmark = pytest.mark.timeout(60)


def _horizontal_speed(sim: ClosedLoop) -> float:
    return math.hypot(float(sim.truth.vel_ned_mps[0]), float(sim.truth.vel_ned_mps[1]))


def _local_target(sim: ClosedLoop, north_m: float, east_m: float, alt_above_home_m: float) -> np.ndarray:
    home = sim.vehicle.home_ned_m
    return np.array((home[0] + north_m, home[1] + east_m, home[2] - alt_above_home_m))


def _record_until(sim: ClosedLoop, trace: Trace, condition: Callable[[ClosedLoop], bool], timeout_s: float) -> bool:
    def record_then_check(s: ClosedLoop) -> bool:
        trace.record(s)
        return condition(s)

    return sim.run_until(record_then_check, timeout_s)


def _settled_at(sim: ClosedLoop, target_est: np.ndarray, timeout_s: float) -> bool:
    def near(s: ClosedLoop) -> bool:
        est = s.vehicle.estimate
        assert est is not None
        return bool(np.linalg.norm(est.pos_ned_m - target_est) < 0.2 and np.linalg.norm(est.vel_ned_mps) < 0.1)

    return sim.run_until(near, timeout_s)


# ---- RTL -----------------------------------------------------------------------------------------------------------
def test_rtl_climbs_to_the_return_altitude_returns_lands_at_home_and_disarms() -> None:
    # GIVEN a drone hovering 10 m north of home at 5 m, with RTL_RETURN_ALT 8 m
    sim = make_sim(seed=11)
    sim.params.set("RTL_RETURN_ALT", 8.0)
    home_true = boot_position(sim)
    take_off(sim, 5.0)
    assert sim.vehicle.goto(_local_target(sim, 10.0, 0.0, 5.0)).ok
    assert _settled_at(sim, _local_target(sim, 10.0, 0.0, 5.0), 15.0)
    start = sim.truth.pos_ned_m.copy()
    # WHEN it is told to return to launch
    assert sim.vehicle.return_to_launch().ok
    assert sim.vehicle.status.mode is Px4Mode.AUTO_RTL
    trace = Trace()
    assert _record_until(sim, trace, lambda s: not s.vehicle.status.armed, 60.0), "did not disarm"
    _, pos, _ = trace.arrays()
    alt = home_true[2] - pos[:, 2]
    from_start = np.hypot(pos[:, 0] - start[0], pos[:, 1] - start[1])
    # THEN it first climbs to 8 m where it is (less than 0.5 m sideways before it is up there)
    reached_alt = int(np.argmax(alt > 7.8))
    assert alt[reached_alt] > 7.8
    assert from_start[:reached_alt].max() < 0.5
    # and returns at that altitude without overshooting it by more than 0.3 m
    assert alt.max() < 8.3
    over_home = int(np.argmax(np.hypot(pos[:, 0] - home_true[0], pos[:, 1] - home_true[1]) < 1.0))
    assert over_home > reached_alt and alt[over_home] > 7.5
    # and lands within 1 m of home, disarmed with the motors stopped
    landed_at = sim.truth.pos_ned_m
    assert math.hypot(landed_at[0] - home_true[0], landed_at[1] - home_true[1]) < 1.0
    assert sim.truth.on_ground
    sim.run_for(0.5)
    assert max(sim.truth.motor_speeds_radps) < 1.0


def test_rtl_above_the_return_altitude_returns_at_its_current_altitude() -> None:
    # GIVEN a drone 6 m north of home at 6 m with RTL_RETURN_ALT 3 m (and RTL_DESCEND_ALT at its 10 m default)
    sim = make_sim(seed=12)
    sim.params.set("RTL_RETURN_ALT", 3.0)
    home_true = boot_position(sim)
    take_off(sim, 6.0)
    assert sim.vehicle.goto(_local_target(sim, 6.0, 0.0, 6.0)).ok
    assert _settled_at(sim, _local_target(sim, 6.0, 0.0, 6.0), 15.0)
    # WHEN it returns
    assert sim.vehicle.return_to_launch().ok
    trace = Trace()
    assert _record_until(sim, trace, lambda s: not s.vehicle.status.armed, 40.0)
    _, pos, _ = trace.arrays()
    # THEN it does not descend before it is over home
    over_home = int(np.argmax(np.hypot(pos[:, 0] - home_true[0], pos[:, 1] - home_true[1]) < 0.5))
    alt = home_true[2] - pos[:, 2]
    assert alt[: over_home + 1].min() > 5.7
    assert alt.max() < 6.3


def test_rtl_is_refused_on_the_ground() -> None:
    sim = make_sim(seed=13)
    arm_when_ready(sim)
    outcome = sim.vehicle.return_to_launch()
    assert outcome.result is CommandResult.DENIED


# ---- offboard loss -------------------------------------------------------------------------------------------------
def test_a_failsafe_that_disarms_in_a_commander_tick_stops_the_motors_at_the_next_step() -> None:
    # GIVEN a drone flying offboard with COM_OBL_RC_ACT = 7 (lockdown: disarm where it is), every motor command
    # the plant gets recorded
    sim = make_sim(seed=14)
    sim.params.set("COM_OBL_RC_ACT", 7)
    take_off(sim, 3.0)
    v = sim.vehicle
    assert v.estimate is not None
    here = v.estimate.pos_ned_m
    setpoint = TrajectorySetpoint(pos_ned_m=(here[0], here[1], here[2]), yaw_rad=0.0)
    v.set_offboard_setpoint(setpoint, sim.time_s)
    assert v.start_offboard(sim.time_s).ok
    sim.run_for(1.0, lambda s: s.vehicle.set_offboard_setpoint(setpoint, s.time_s))
    commands: list[tuple[bool, tuple[float, ...]]] = []
    plant_step = sim.plant.step

    def recorded(motors):  # type: ignore[no-untyped-def]
        commands.append((v.status.armed, tuple(motors)))
        return plant_step(motors)

    sim.plant.step = recorded  # type: ignore[method-assign]
    # WHEN the stream stops: offboard loss, hold, and COM_FAIL_ACT_T later the lockdown, decided in a tick
    assert sim.run_until(lambda s: not s.vehicle.status.armed, 15.0)
    sim.run_for(0.1)
    # THEN from the step that disarmed on, every command the motors get is zero, the steps between ticks included
    first = next(k for k, (armed, _) in enumerate(commands) if not armed)
    assert any(max(m) > 0.2 for _, m in commands[:first])
    assert all(m == (0.0,) * len(m) for _, m in commands[first + 1 :])
    assert "Motors stopped: lockdown" in [e.text for e in v.events]


def test_offboard_setpoint_loss_holds_then_lands_with_the_failsafe_flag_set() -> None:
    # GIVEN a drone flying offboard on a position setpoint stream
    sim = make_sim(seed=14)
    take_off(sim, 3.0)
    v = sim.vehicle
    assert v.estimate is not None
    hold_est = v.estimate.pos_ned_m + np.array((1.0, 0.0, 0.0))
    setpoint = TrajectorySetpoint(pos_ned_m=(hold_est[0], hold_est[1], hold_est[2]), yaw_rad=0.0)
    v.set_offboard_setpoint(setpoint, sim.time_s)
    assert v.start_offboard(sim.time_s).ok
    sim.run_for(3.0, lambda s: s.vehicle.set_offboard_setpoint(setpoint, s.time_s))
    assert v.status.mode is Px4Mode.OFFBOARD
    # WHEN the stream stops
    lost_at_s = sim.time_s
    where_lost = sim.truth.pos_ned_m.copy()
    # THEN it stays in offboard for COM_OF_LOSS_T, then holds with the failsafe flag set
    assert sim.run_until(lambda s: s.vehicle.status.mode is not Px4Mode.OFFBOARD, 5.0)
    assert sim.time_s - lost_at_s == pytest.approx(v.params["COM_OF_LOSS_T"], abs=reaction_tolerance_s(sim))
    assert v.status.mode is Px4Mode.AUTO_LOITER
    assert v.status.failsafe
    hold_started_s = sim.time_s
    # and holds where it was (it was not moving) until COM_FAIL_ACT_T has passed
    trace = Trace()
    assert _record_until(sim, trace, lambda s: s.vehicle.status.mode is not Px4Mode.AUTO_LOITER, 10.0)
    assert sim.time_s - hold_started_s == pytest.approx(v.params["COM_FAIL_ACT_T"], abs=reaction_tolerance_s(sim))
    _, pos, _ = trace.arrays()
    assert np.linalg.norm(pos - where_lost, axis=1).max() < 0.3
    # then it lands, still flagged, and disarms on the ground
    assert v.status.mode is Px4Mode.AUTO_LAND
    assert v.status.failsafe
    assert sim.run_until(lambda s: not s.vehicle.status.armed, 20.0)
    assert sim.truth.on_ground
    texts = [e.text for e in v.events]
    assert "Failsafe: offboard setpoints lost, holding" in texts and "Failsafe: landing" in texts


def test_offboard_cannot_start_without_a_setpoint_stream() -> None:
    sim = make_sim(seed=15)
    take_off(sim, 2.0)
    assert sim.vehicle.start_offboard(sim.time_s).result is CommandResult.DENIED
    assert sim.vehicle.status.mode is Px4Mode.AUTO_LOITER


# ---- battery -------------------------------------------------------------------------------------------------------
def test_a_low_battery_warns_once_and_a_critical_one_returns_to_launch() -> None:
    # GIVEN a drone hovering 6 m from home on a pack just above the low-battery threshold (15 %), with the critical
    # threshold raised to 14 % so that it is crossed within seconds
    sim = make_sim(seed=24)
    sim.params.set("RTL_RETURN_ALT", 4.0)
    sim.params.set("BAT_CRIT_THR", 0.14)
    sim.params.set("COM_LOW_BAT_ACT", 1)  # return at critical (PX4's default, 0, only warns)
    take_off(sim, 3.0)
    assert sim.vehicle.goto(_local_target(sim, 6.0, 0.0, 3.0)).ok
    sim.battery = Battery(sim.config.battery, initial_remaining=0.152)
    # WHEN it keeps hovering (about 1 % of the pack per 9 s)
    assert sim.run_until(lambda s: s.vehicle.status.mode is Px4Mode.AUTO_RTL, 30.0), "no RTL on critical battery"
    # THEN it warned once at BAT_LOW_THR, and at BAT_CRIT_THR it returned to launch with the failsafe flag set
    assert sim.battery.state().remaining == pytest.approx(0.14, abs=0.001)
    texts = [e.text for e in sim.vehicle.events]
    warnings = [e for e in sim.vehicle.events if e.text.startswith("Low battery")]
    assert len(warnings) == 1 and warnings[0].severity == 4
    assert texts.index(warnings[0].text) < texts.index("Failsafe: battery critical, returning to launch")
    assert sim.vehicle.status.failsafe
    # and it lands at home
    assert sim.run_until(lambda s: not s.vehicle.status.armed, 40.0)
    assert math.hypot(*(sim.truth.pos_ned_m - boot_position(sim))[:2]) < 1.0


def test_arming_is_refused_on_a_critical_battery() -> None:
    sim = make_sim(seed=25)
    sim.battery = Battery(sim.config.battery, initial_remaining=0.05)
    assert sim.run_until(lambda s: s.time_s > 5.0, 6.0)
    outcome = sim.vehicle.arm()
    assert outcome.result is CommandResult.DENIED and "battery" in outcome.reason


# ---- arming and disarming ------------------------------------------------------------------------------------------
def test_arming_is_refused_until_the_attitude_estimate_and_gps_position_are_valid() -> None:
    # GIVEN a drone just booted
    sim = make_sim(seed=16)
    v = sim.vehicle
    sim.step()
    # WHEN arming is asked for before the attitude estimate has converged, THEN it is refused
    first = v.arm()
    assert first.result is CommandResult.DENIED and "attitude" in first.reason
    # and once attitude is good but the GPS position is not yet valid, refused for that reason
    assert sim.run_until(lambda s: s.vehicle.estimate is not None and s.vehicle.estimate.attitude_valid, 5.0)
    assert v.estimate is not None and not v.estimate.position_valid
    second = v.arm()
    assert second.result is CommandResult.DENIED and "GPS" in second.reason
    assert not v.status.armed
    # with the reason told to the ground station
    assert any(e.severity == 4 and "GPS" in e.text for e in v.events)
    # and it is accepted only once the position is valid: 2.5 s after the first fix (which comes at 1.5 s)
    assert sim.run_until(lambda s: s.vehicle.preflight_problem() is None, 10.0)
    assert sim.time_s >= 4.0 - 1e-9
    assert v.arm().ok
    assert v.status.armed


def test_disarming_is_refused_in_the_air_and_kill_stops_the_motors() -> None:
    # GIVEN a drone hovering at 2 m
    sim = make_sim(seed=17)
    take_off(sim, 2.0)
    v = sim.vehicle
    # WHEN it is asked to disarm, THEN it refuses and keeps flying
    outcome = v.disarm()
    assert outcome.result is CommandResult.DENIED and "air" in outcome.reason
    sim.run_for(1.0)
    assert v.status.armed and sim.altitude_above_start_m() > 1.7
    # WHEN it is killed, THEN the motors stop at once and it falls
    assert v.kill().ok
    assert not v.status.armed
    sim.run_for(0.3)
    assert max(sim.truth.motor_speeds_radps) < 5.0
    assert sim.truth.vel_ned_mps[2] > 2.0
    # and while it is in the air it cannot be armed again
    refused = v.arm()
    assert refused.result is CommandResult.DENIED and "air" in refused.reason
    assert v.status.landed_state is LandedState.IN_AIR


def test_after_a_kill_in_the_air_it_can_arm_again_once_it_lies_on_the_ground() -> None:
    sim = make_sim(seed=18)
    take_off(sim, 0.4)  # low enough that the drop does not break it (sitl/drone/closed_loop.py GROUND_IMPACT_SPEED_MPS)
    v = sim.vehicle
    assert v.kill().ok
    assert sim.run_until(lambda s: s.truth.on_ground, 3.0)
    assert not v.crashed
    # WHEN it has come to rest on the ground
    sim.run_for(1.5)
    # THEN it counts as landed and may arm (the land detector keeps working with the motors off)
    assert v.landed
    assert v.status.landed_state is LandedState.ON_GROUND
    assert v.arm(force=True).ok


def test_armed_on_the_ground_without_taking_off_it_disarms_after_com_disarm_prflt() -> None:
    sim = make_sim(seed=19)
    sim.params.set("COM_DISARM_PRFLT", 3.0)
    arm_when_ready(sim)
    armed_at_s = sim.time_s
    assert sim.run_until(lambda s: not s.vehicle.status.armed, 10.0)
    assert sim.time_s - armed_at_s == pytest.approx(3.0, abs=reaction_tolerance_s(sim))
    assert sim.vehicle.events[-1].text == "Auto-disarmed: no takeoff"


# ---- goto and parameters -------------------------------------------------------------------------------------------
def test_goto_flies_to_the_point_and_holds_there() -> None:
    # GIVEN a drone hovering at 3 m
    sim = make_sim(seed=20)
    home_true = boot_position(sim)
    take_off(sim, 3.0)
    # WHEN it is repositioned 8 m north, 6 m west, 5 m up
    target = _local_target(sim, 8.0, -6.0, 5.0)
    assert sim.vehicle.goto(target).ok
    assert sim.vehicle.status.mode is Px4Mode.AUTO_LOITER
    trace = Trace()
    sim.run_for(10.0, trace.record)
    _, pos, _ = trace.arrays()
    # THEN it is there (true position within 0.2 m) and stays there
    target_true = home_true + np.array((8.0, -6.0, -5.0))
    assert np.linalg.norm(pos[-400:] - target_true, axis=1).max() < 0.25
    # without overshooting the point by more than 0.3 m along the way
    along = (pos - home_true) @ np.array((8.0, -6.0, 0.0)) / 10.0
    assert along.max() < 10.3


def test_goto_is_refused_on_the_ground_and_for_a_target_that_is_not_finite() -> None:
    sim = make_sim(seed=21)
    arm_when_ready(sim)
    assert sim.vehicle.goto(np.array((5.0, 0.0, -3.0))).result is CommandResult.DENIED
    take_off_sim = make_sim(seed=21)
    take_off(take_off_sim, 2.0)
    assert take_off_sim.vehicle.goto(np.array((math.nan, 0.0, -3.0))).result is CommandResult.DENIED


def test_a_cruise_speed_set_in_flight_takes_effect_on_the_current_leg() -> None:
    # GIVEN a drone cruising toward a point 40 m away at the default MPC_XY_CRUISE (5 m/s)
    sim = make_sim(seed=22)
    take_off(sim, 3.0)
    assert sim.vehicle.goto(_local_target(sim, 40.0, 0.0, 3.0)).ok
    sim.run_for(3.0)
    assert _horizontal_speed(sim) == pytest.approx(5.0, abs=0.4)
    # WHEN MPC_XY_CRUISE is set to 2 m/s
    sim.params.set("MPC_XY_CRUISE", 2.0)
    # THEN within 2 s it flies at 2 m/s, and no faster for the rest of the leg
    sim.run_for(2.0)
    speeds: list[float] = []
    sim.run_for(5.0, lambda s: speeds.append(_horizontal_speed(s)))
    assert max(speeds) < 2.3
    assert min(speeds) > 1.7


# ---- events --------------------------------------------------------------------------------------------------------
def test_takeoff_and_landing_are_announced_in_order() -> None:
    sim = make_sim(seed=23)
    take_off(sim, 2.0)
    assert sim.vehicle.land().ok
    assert sim.run_until(lambda s: not s.vehicle.status.armed, 20.0)
    texts = [e.text for e in sim.vehicle.events]
    expected = [
        "Armed",
        "Mode AUTO.TAKEOFF",
        "Takeoff detected",
        "Takeoff complete",
        "Mode AUTO.LAND",
        "Landing detected",
        "Auto-disarmed after landing",
    ]
    positions = [texts.index(text) for text in expected]
    assert positions == sorted(positions), texts
