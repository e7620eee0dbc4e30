"""Injected faults are real in the simulation: a failed rotor gives no thrust, a lost GPS invalidates the position,
a glitching GPS is gated out, a battery fault reads below its threshold.

Policy: a ClosedLoop stepped directly (JSBSim, sensor noise on), faults injected through SimVehicleApi with the same
request the MAVLink command service makes of MAV_CMD_INJECT_FAILURE; ground truth checks what really happened.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink

from sitl.autopilot import vehicle_api as api
from sitl.drone.closed_loop import GROUND_IMPACT_SPEED_MPS, ClosedLoop
from sitl.drone.sim_vehicle_api import SimVehicleApi
from sitl.estimation.estimator import Estimate
from sitl.faults.failures import BATTERY_TRIGGER_MARGIN, GPS_GLITCH_OFFSET_NE_M, FailureType, FailureUnit
from tests.closed_loop.flight import make_sim, take_off

pytestmark = pytest.mark.timeout(90)

MOTOR, GPS, BATTERY, LINK = (FailureUnit.SYSTEM_MOTOR, FailureUnit.SENSOR_GPS, FailureUnit.SYSTEM_BATTERY,
                             FailureUnit.SYSTEM_MAVLINK_SIGNAL)  # fmt: skip
OK, OFF, WRONG = FailureType.OK, FailureType.OFF, FailureType.WRONG


def inject(sim: ClosedLoop, unit: int, kind: int, instance: int = 0) -> api.CommandOutcome:
    request = api.InjectFailure(unit=int(unit), failure_type=int(kind), instance=instance)
    return SimVehicleApi(sim).command(request, sim.time_s)


def enabled_sim(seed: int) -> ClosedLoop:
    sim = make_sim(seed=seed)
    sim.params.set("SYS_FAILURE_EN", 1)
    return sim


def test_injection_is_denied_unless_enabled_and_unsupported_failures_are_unsupported() -> None:
    sim = make_sim(seed=3)
    outcome = inject(sim, MOTOR, OFF, 1)
    assert (outcome.result, outcome.reason) == (api.CommandResult.DENIED, "Failure injection disabled")
    assert sim.faults.motors_off == frozenset()
    sim.params.set("SYS_FAILURE_EN", 1)
    assert inject(sim, 0, OFF).result is api.CommandResult.UNSUPPORTED  # FAILURE_UNIT_SENSOR_GYRO
    assert inject(sim, MOTOR, WRONG, 1).result is api.CommandResult.UNSUPPORTED
    assert inject(sim, MOTOR, 3).result is api.CommandResult.UNSUPPORTED  # FAILURE_TYPE_STUCK
    assert inject(sim, MOTOR, OFF, 5).result is api.CommandResult.DENIED  # a quadrotor has no motor 5
    accepted = inject(sim, MOTOR, OFF, 2)
    assert accepted.ok and accepted.reason == "Injected: motor off, instances 2"
    assert sim.plant.failed_motors == frozenset({1})
    assert inject(sim, MOTOR, OK, 2).ok and sim.plant.failed_motors == frozenset()


def test_a_quadrotor_with_one_motor_off_falls() -> None:
    sim = enabled_sim(seed=4)
    take_off(sim, 3.0)
    assert inject(sim, MOTOR, OFF, 1).ok
    commanded: list[float] = []
    spinning: list[float] = []
    control = sim.vehicle.step

    def step(est: Estimate, now_s: float, dt_s: float) -> tuple[float, ...]:  # what the mixer commands, passed on
        motors = control(est, now_s, dt_s)
        commanded.append(float(motors[0]))
        return motors

    sim.vehicle.step = step  # type: ignore[method-assign]
    sim.run_for(0.3, lambda s: spinning.append(s.truth.motor_speeds_radps[0]))
    sim.vehicle.step = control  # type: ignore[method-assign]
    # The mixer still commands the failed rotor; the rotor spins down through its motor lag and stays stopped.
    assert max(commanded[-10:]) > 0.1 and max(spinning[-10:]) < 1.0, (commanded[-10:], spinning[-10:])
    # Three rotors cannot hold a quadrotor: it comes down within 3 s of the failure (3 m up, free fall takes 0.8 s).
    assert sim.run_until(lambda s: s.altitude_above_start_m() < 0.3, 3.0), sim.altitude_above_start_m()
    # It hits the ground far faster than a landing: the airframe is broken, the motors stop and the heartbeat says
    # FLIGHT_TERMINATION, which is how a ground station learns that the drone is down.
    assert sim.run_until(lambda s: s.vehicle.crashed, 1.0)
    impact = [e.text for e in sim.vehicle.events if e.text.startswith("Ground impact at ")]
    assert len(impact) == 1 and float(impact[0].split()[3]) > GROUND_IMPACT_SPEED_MPS, impact
    snap = SimVehicleApi(sim).snapshot()
    assert not snap.armed and snap.flight_terminated


def test_gps_off_invalidates_the_position_after_the_timeout_and_recovers() -> None:
    sim = enabled_sim(seed=5)
    take_off(sim, 2.5)
    timeout_s = sim.estimator.config.gps_timeout_s
    assert inject(sim, GPS, OFF).ok
    t_off = sim.time_s
    sim.run_for(0.3)
    snap = SimVehicleApi(sim).snapshot()
    assert snap.gps.fix_type is api.GpsFixType.NO_FIX and snap.gps.position is None  # GPS_RAW_INT: no fix
    assert not snap.sensors.healthy & mavlink.MAV_SYS_STATUS_SENSOR_GPS  # SYS_STATUS: GPS unhealthy
    assert sim.estimate is not None and sim.estimate.position_valid  # dead reckoning, not yet timed out
    assert sim.run_until(lambda s: s.estimate is not None and not s.estimate.position_valid, timeout_s + 1.0)
    assert timeout_s - 0.2 <= sim.time_s - t_off <= timeout_s + 0.2, sim.time_s - t_off
    assert inject(sim, GPS, OK).ok
    assert sim.run_until(lambda s: s.estimate is not None and s.estimate.position_valid, 0.5)
    assert sim.estimate is not None
    error = np.linalg.norm(sim.estimate.pos_ned_m[:2] - sim.truth.pos_ned_m[:2])
    assert error < 0.5, error  # reset to the new fix


def test_gps_glitch_is_gated_out_then_declared_invalid() -> None:
    sim = enabled_sim(seed=6)
    take_off(sim, 2.5)
    timeout_s = sim.estimator.config.gps_timeout_s
    assert inject(sim, GPS, WRONG).reason == "Injected: gps wrong, all instances"
    assert sim.last_gps is not None
    errors = []

    def record(s: ClosedLoop) -> None:
        assert s.estimate is not None
        errors.append(float(np.linalg.norm(s.estimate.pos_ned_m[:2] - s.truth.pos_ned_m[:2])))

    sim.run_for(timeout_s - 0.5, record)
    # The receiver reports the jump, the estimator does not follow it.
    assert sim.last_gps.pos_ned_m[0] - sim.truth.pos_ned_m[0] == pytest.approx(GPS_GLITCH_OFFSET_NE_M[0], abs=1.0)
    assert max(errors) < 0.5, max(errors)
    assert sim.estimate is not None and sim.estimate.position_valid
    assert sim.run_until(lambda s: s.estimate is not None and not s.estimate.position_valid, 1.0)
    assert inject(sim, GPS, OK).ok
    assert sim.run_until(lambda s: s.estimate is not None and s.estimate.position_valid, 0.5)


def test_battery_faults_read_just_below_their_threshold_and_clear() -> None:
    sim = enabled_sim(seed=7)
    api_ = SimVehicleApi(sim)
    true_remaining = sim.battery.true_remaining
    grades = (
        (1, "BAT_LOW_THR", mavlink.MAV_BATTERY_CHARGE_STATE_LOW),
        (2, "BAT_CRIT_THR", mavlink.MAV_BATTERY_CHARGE_STATE_CRITICAL),
        (3, "BAT_EMERGEN_THR", mavlink.MAV_BATTERY_CHARGE_STATE_EMERGENCY),
    )
    assert api_.snapshot().battery.charge_state == mavlink.MAV_BATTERY_CHARGE_STATE_OK
    for level, threshold, charge_state in grades:
        sim.params.set("SYS_FAIL_BAT_LVL", level)
        outcome = inject(sim, BATTERY, WRONG)
        if threshold not in sim.params:  # declared with the battery failsafe (sitl/autopilot/params.py)
            assert outcome.result is api.CommandResult.UNSUPPORTED
            continue
        assert outcome.ok, outcome
        expected = sim.params[threshold] - BATTERY_TRIGGER_MARGIN
        sim.run_for(0.1)
        assert sim.battery.remaining == pytest.approx(expected)
        assert api_.snapshot().battery.remaining == pytest.approx(expected)
        assert api_.snapshot().battery.charge_state == charge_state  # BATTERY_STATUS as PX4 grades it
    assert inject(sim, BATTERY, OFF).ok
    sim.run_for(0.1)
    assert api_.snapshot().battery.remaining == 0.0
    assert inject(sim, BATTERY, OK).ok
    sim.run_for(0.1)
    assert sim.battery.remaining == pytest.approx(true_remaining, abs=1e-3)


def test_a_low_battery_fault_reaches_the_autopilot() -> None:
    sim = enabled_sim(seed=8)
    take_off(sim, 2.5)
    sim.params.set("SYS_FAIL_BAT_LVL", 1)
    assert inject(sim, BATTERY, WRONG).ok
    sim.run_for(0.5)
    assert any("battery" in e.text.lower() for e in sim.vehicle.events), [e.text for e in sim.vehicle.events]


def test_link_off_is_only_a_time_for_the_endpoint_for_good_or_for_param4_seconds() -> None:
    sim = enabled_sim(seed=9)
    vehicle_api = SimVehicleApi(sim)
    assert vehicle_api.mavlink_silent_until_s() == -math.inf
    sim.run_for(1.0)
    lasting = api.InjectFailure(unit=int(LINK), failure_type=int(OFF), instance=0, duration_s=6.0)
    assert vehicle_api.command(lasting, sim.time_s).reason == "Injected: mavlink_signal off 6 s, all instances"
    assert vehicle_api.mavlink_silent_until_s() == pytest.approx(sim.time_s + 6.0)
    # param4 unset (0, NaN: what PX4's clients send) is for good, as PX4's failure
    assert inject(sim, LINK, OFF).reason == "Injected: mavlink_signal off, all instances"
    assert vehicle_api.mavlink_silent_until_s() == math.inf
