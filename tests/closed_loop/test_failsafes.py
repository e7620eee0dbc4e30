"""Closed-loop flights of each row of the failsafe table (docs/failsafes.md), triggered the way the vehicle sees the
fault: GCS heartbeats that stop, a pack swapped for a drained one, an estimate without a position, a fence.

Policy: a ClosedLoop stepped directly (JSBSim, sensor noise on), no sockets, no wall clock; positions are checked on
ground truth, which the autopilot never sees. Each flight is short (a few tens of simulated seconds).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink

from sitl.autopilot.geofence import CircleZone, FenceKind, Geofence
from sitl.autopilot.mission_plan import NavItem, NavKind
from sitl.autopilot.px4_modes import FailsafeKind, Px4Mode
from sitl.control.cascade import TrajectorySetpoint
from sitl.drone.closed_loop import ClosedLoop
from sitl.dynamics.battery import Battery
from sitl.estimation.estimator import Estimate
from sitl.protocol.modes import system_status
from tests.closed_loop.flight import boot_position, make_sim, reaction_tolerance_s, take_off

pytestmark = pytest.mark.timeout(60)


def _texts(sim: ClosedLoop) -> list[str]:
    return [e.text for e in sim.vehicle.events]


def _heartbeat_status(sim: ClosedLoop) -> int:
    status = sim.vehicle.status
    return system_status(armed=status.armed, failsafe=status.failsafe, terminated=sim.vehicle.crashed)


def _local(sim: ClosedLoop, north_m: float, east_m: float, alt_m: float) -> np.ndarray:
    home = sim.vehicle.home_ned_m
    return np.array((home[0] + north_m, home[1] + east_m, home[2] - alt_m))


def _fly_with_gcs(sim: ClosedLoop, duration_s: float) -> None:
    """Fly on while a ground station sends its 1 Hz HEARTBEAT."""
    for _ in range(round(duration_s)):
        sim.vehicle.note_gcs_heartbeat(sim.time_s)
        sim.run_for(1.0)


def _true_distance_from_boot_m(sim: ClosedLoop) -> float:
    return math.hypot(*(sim.truth.pos_ned_m - boot_position(sim))[:2])


# ---- ground-station datalink loss -----------------------------------------------------------------------------------
def test_datalink_loss_with_nav_dll_act_return_holds_then_returns_after_com_dl_loss_t() -> None:
    # GIVEN a drone 6 m from home with NAV_DLL_ACT = 2 (Return), hearing a ground station
    sim = make_sim(seed=31)
    sim.params.set("NAV_DLL_ACT", 2)
    sim.params.set("RTL_RETURN_ALT", 4.0)
    v = sim.vehicle
    v.note_gcs_heartbeat(sim.time_s)
    take_off(sim, 3.0)
    assert v.goto(_local(sim, 6.0, 0.0, 3.0)).ok
    _fly_with_gcs(sim, 5.0)
    # WHEN the heartbeats stop
    v.note_gcs_heartbeat(sim.time_s)
    last_heartbeat_s = sim.time_s
    # THEN after COM_DL_LOSS_T it holds with the failsafe shown (HEARTBEAT system_status CRITICAL) ...
    assert sim.run_until(lambda s: s.vehicle.status.failsafe, 15.0)
    assert sim.time_s - last_heartbeat_s == pytest.approx(v.params["COM_DL_LOSS_T"], abs=reaction_tolerance_s(sim))
    assert v.status.mode is Px4Mode.AUTO_LOITER
    assert v.status.active_failsafe is FailsafeKind.DATALINK_LOSS
    assert _heartbeat_status(sim) == mavlink.MAV_STATE_CRITICAL
    assert "Failsafe: no connection to the ground control station, holding" in _texts(sim)
    # ... and COM_FAIL_ACT_T later returns to launch, lands at home and disarms
    held_at_s = sim.time_s
    assert sim.run_until(lambda s: s.vehicle.status.mode is Px4Mode.AUTO_RTL, 10.0)
    assert sim.time_s - held_at_s == pytest.approx(v.params["COM_FAIL_ACT_T"], abs=reaction_tolerance_s(sim))
    assert v.status.active_failsafe is FailsafeKind.DATALINK_LOSS
    assert sim.run_until(lambda s: not s.vehicle.status.armed, 40.0)
    assert _true_distance_from_boot_m(sim) < 1.0
    # and a ground station heard again is announced
    v.note_gcs_heartbeat(sim.time_s)
    sim.run_for(0.1)
    assert "Data link regained" in _texts(sim)


def test_with_nav_dll_act_set_arming_needs_a_ground_station() -> None:
    sim = make_sim(seed=30)
    sim.params.set("NAV_DLL_ACT", 2)
    assert sim.run_until(
        lambda s: (
            s.vehicle.preflight_problem() is not None
            and s.vehicle.estimate is not None
            and s.vehicle.estimate.position_valid
        ),
        10.0,
    )
    sim.run_for(0.1)
    assert sim.vehicle.preflight_problem() == "Preflight Fail: No connection to the ground control station"
    assert not sim.vehicle.arm().ok
    sim.vehicle.note_gcs_heartbeat(sim.time_s)
    assert sim.vehicle.preflight_problem() is None
    assert sim.vehicle.arm().ok


def test_datalink_loss_is_ignored_before_any_gcs_heartbeat_and_with_the_px4_default() -> None:
    # GIVEN two hovering drones: one with NAV_DLL_ACT = 2 (set in the air) that never heard a ground station, one
    # that heard one and has PX4's default NAV_DLL_ACT = 0 (disabled)
    never_heard = make_sim(seed=32)
    take_off(never_heard, 2.0)
    never_heard.params.set("NAV_DLL_ACT", 2)
    default = make_sim(seed=33)
    default.vehicle.note_gcs_heartbeat(default.time_s)
    take_off(default, 2.0)
    # WHEN both fly on without a heartbeat for longer than COM_DL_LOSS_T
    for sim in (never_heard, default):
        sim.run_for(sim.params["COM_DL_LOSS_T"] + 2.0)
        # THEN neither fails safe
        assert sim.vehicle.status.mode is Px4Mode.AUTO_LOITER
        assert not sim.vehicle.status.failsafe
        assert sim.vehicle.status.active_failsafe is FailsafeKind.NONE


# ---- offboard loss ---------------------------------------------------------------------------------------------------
def test_offboard_loss_with_com_obl_rc_act_return_holds_then_returns() -> None:
    sim = make_sim(seed=34)
    sim.params.set("COM_OBL_RC_ACT", 3)
    sim.params.set("COM_FAIL_ACT_T", 1.0)
    take_off(sim, 3.0)
    v = sim.vehicle
    assert v.estimate is not None
    p = v.estimate.pos_ned_m
    setpoint = TrajectorySetpoint(pos_ned_m=(float(p[0]) + 3.0, float(p[1]), float(p[2])), yaw_rad=0.0)
    v.set_offboard_setpoint(setpoint, sim.time_s)
    assert v.start_offboard(sim.time_s).ok
    sim.run_for(3.0, lambda s: s.vehicle.set_offboard_setpoint(setpoint, s.time_s))
    assert sim.run_until(lambda s: s.vehicle.status.mode is not Px4Mode.OFFBOARD, 5.0)
    assert v.status.mode is Px4Mode.AUTO_LOITER and v.status.active_failsafe is FailsafeKind.OFFBOARD_LOSS
    assert sim.run_until(lambda s: s.vehicle.status.mode is not Px4Mode.AUTO_LOITER, 5.0)
    assert v.status.mode is Px4Mode.AUTO_RTL
    assert "Failsafe: returning to launch" in _texts(sim)


# ---- battery ---------------------------------------------------------------------------------------------------------
def _hover_away_then_drain(seed: int, action: int, remaining: float) -> ClosedLoop:
    sim = make_sim(seed=seed)
    sim.params.set("COM_LOW_BAT_ACT", action)
    sim.params.set("RTL_RETURN_ALT", 4.0)
    take_off(sim, 3.0)
    assert sim.vehicle.goto(_local(sim, 5.0, 0.0, 3.0)).ok
    sim.run_for(5.0)
    sim.battery = Battery(sim.config.battery, initial_remaining=remaining)
    return sim


def test_critical_battery_with_com_low_bat_act_land_lands_where_it_is() -> None:
    sim = _hover_away_then_drain(seed=35, action=2, remaining=0.065)
    where = sim.truth.pos_ned_m.copy()
    sim.run_for(0.1)
    v = sim.vehicle
    assert v.status.mode is Px4Mode.AUTO_LAND
    assert v.status.active_failsafe is FailsafeKind.BATTERY_CRITICAL
    assert _heartbeat_status(sim) == mavlink.MAV_STATE_CRITICAL
    assert "Failsafe: battery critical, landing" in _texts(sim)
    assert sim.run_until(lambda s: not s.vehicle.status.armed, 20.0)
    assert sim.truth.on_ground
    assert math.hypot(*(sim.truth.pos_ned_m - where)[:2]) < 0.5


def test_battery_with_the_px4_default_only_warns() -> None:
    sim = _hover_away_then_drain(seed=36, action=0, remaining=0.04)
    sim.run_for(1.0)
    v = sim.vehicle
    assert v.status.mode is Px4Mode.AUTO_LOITER
    assert not v.status.failsafe
    warnings = [e for e in v.events if e.severity == 4]
    assert [e.text for e in warnings] == ["Low battery: 4% remaining", "battery critical", "battery emergency"]


def test_com_low_bat_act_3_returns_at_critical_and_lands_at_emergency() -> None:
    sim = _hover_away_then_drain(seed=37, action=3, remaining=0.065)
    sim.run_for(1.0)
    v = sim.vehicle
    assert v.status.mode is Px4Mode.AUTO_RTL and v.status.active_failsafe is FailsafeKind.BATTERY_CRITICAL
    sim.battery = Battery(sim.config.battery, initial_remaining=0.045)
    sim.run_for(0.1)
    assert v.status.mode is Px4Mode.AUTO_LAND and v.status.active_failsafe is FailsafeKind.BATTERY_EMERGENCY
    assert "Failsafe: battery emergency, landing" in _texts(sim)


# ---- position loss ---------------------------------------------------------------------------------------------------
def _lose_position(sim: ClosedLoop) -> list[bool]:
    """From now on the estimator reports no horizontal position (as with the GPS receiver off), until the returned
    switch is set back to True."""
    valid = [False]
    estimator = sim.estimator

    def without_position(publish: Callable[..., Estimate]) -> Callable[..., Estimate]:
        def maybe_without_position(*args: object, **kwargs: object) -> Estimate:
            est = publish(*args, **kwargs)
            return est if valid[0] else dataclasses.replace(est, position_valid=False)

        return maybe_without_position

    # every way a step publishes its estimate: the shells' update, and the compiled step's two
    estimator.update = without_position(estimator.update)  # type: ignore[method-assign]
    estimator.published = without_position(estimator.published)  # type: ignore[method-assign]
    estimator.published_whole = without_position(estimator.published_whole)  # type: ignore[method-assign]
    return valid


def test_position_loss_descends_level_at_the_landing_speed_and_disarms_on_the_ground() -> None:
    # GIVEN a drone holding 5 m up
    sim = make_sim(seed=38)
    take_off(sim, 5.0)
    sim.run_for(1.0)
    where = sim.truth.pos_ned_m.copy()
    # WHEN its estimate loses the horizontal position
    _lose_position(sim)
    sim.run_for(0.1)
    # THEN it descends (PX4 shows Descend as AUTO.LAND) with the failsafe shown
    v = sim.vehicle
    assert v.status.mode is Px4Mode.AUTO_LAND
    assert v.status.active_failsafe is FailsafeKind.POSITION_LOSS
    assert _heartbeat_status(sim) == mavlink.MAV_STATE_CRITICAL
    assert "Failsafe: no global position, descending" in _texts(sim)
    # at about MPC_LAND_SPEED once the sink rate has settled
    sim.run_for(2.0)
    sink_mps = [float(sim.truth.vel_ned_mps[2])]
    sim.run_for(1.0, lambda s: sink_mps.append(float(s.truth.vel_ned_mps[2])))
    assert np.mean(sink_mps) == pytest.approx(v.params["MPC_LAND_SPEED"], abs=0.15)
    # and it comes down without a position loop to hold it: it drifts on the estimator's attitude error (about 1 deg,
    # which the position loop normally trims out), slowly, and disarms on the ground
    horizontal_mps: list[float] = []

    def record_until_disarmed(s: ClosedLoop) -> bool:
        horizontal_mps.append(math.hypot(*s.truth.vel_ned_mps[:2]))
        return not s.vehicle.status.armed

    assert sim.run_until(record_until_disarmed, 20.0)
    assert sim.truth.on_ground and not v.crashed
    assert max(horizontal_mps) < 1.5
    assert math.hypot(*(sim.truth.pos_ned_m - where)[:2]) < 6.0


def test_a_mission_interrupted_by_a_position_loss_resumes_when_the_position_returns() -> None:
    # GIVEN a drone flying a mission leg
    sim = make_sim(seed=44)
    take_off(sim, 4.0)
    v = sim.vehicle
    home = v.home_ned_m
    far = NavItem(seq=0, kind=NavKind.WAYPOINT, target_ned_m=(home[0] + 12.0, home[1], home[2] - 4.0))
    assert v.set_mission((far,)).ok and v.start_mission().ok
    sim.run_for(2.0)
    # WHEN the position is lost for a second, then comes back
    valid = _lose_position(sim)
    sim.run_for(1.0)
    assert v.status.mode is Px4Mode.AUTO_LAND and v.status.active_failsafe is FailsafeKind.POSITION_LOSS
    valid[0] = True
    sim.run_for(0.1)
    # THEN, as PX4 after a mode fallback, it goes back to the mission and the failsafe ends
    assert v.status.mode is Px4Mode.AUTO_MISSION
    assert not v.status.failsafe and v.status.active_failsafe is FailsafeKind.NONE
    assert "Global position regained" in _texts(sim)
    assert sim.run_until(lambda s: s.vehicle.mission.reached_seq == 0, 20.0)


# ---- geofence --------------------------------------------------------------------------------------------------------
def test_geofence_breach_with_gf_action_return_returns_and_lands_at_home() -> None:
    # GIVEN a 5 m inclusion circle round home and GF_ACTION = 3 (Return)
    sim = make_sim(seed=39)
    sim.params.set("GF_ACTION", 3)
    sim.params.set("RTL_RETURN_ALT", 4.0)
    take_off(sim, 3.0)
    v = sim.vehicle
    home = v.home_ned_m
    v.set_fence(Geofence(zones=(CircleZone(kind=FenceKind.INCLUSION, centre_ne_m=(home[0], home[1]), radius_m=5.0),)))
    # WHEN it is sent 10 m away
    assert v.goto(_local(sim, 10.0, 0.0, 3.0)).ok
    # THEN it returns as it crosses the fence
    assert sim.run_until(lambda s: s.vehicle.status.mode is Px4Mode.AUTO_RTL, 15.0)
    assert v.status.active_failsafe is FailsafeKind.GEOFENCE
    assert "Failsafe: geofence violation (Outside the geofence), returning to launch" in _texts(sim)
    assert 5.0 < _true_distance_from_boot_m(sim) < 5.5
    assert sim.run_until(lambda s: not s.vehicle.status.armed, 40.0)
    assert _true_distance_from_boot_m(sim) < 1.0


def test_geofence_max_horizontal_distance_with_gf_action_hold_stops_at_the_limit() -> None:
    sim = make_sim(seed=40)
    sim.params.set("GF_ACTION", 2)
    sim.params.set("GF_MAX_HOR_DIST", 4.0)
    take_off(sim, 3.0)
    v = sim.vehicle
    assert v.goto(_local(sim, 20.0, 0.0, 3.0)).ok
    assert sim.run_until(lambda s: s.vehicle.status.failsafe, 10.0)
    assert v.status.mode is Px4Mode.AUTO_LOITER and v.status.active_failsafe is FailsafeKind.GEOFENCE
    sim.run_for(4.0)
    # it stops where it can from cruise speed without a jerk: the limit plus about v^2 / (2 MPC_ACC_HOR) = 4.2 m
    assert 4.0 < _true_distance_from_boot_m(sim) < 9.0
    assert float(np.linalg.norm(sim.truth.vel_ned_mps)) < 0.2


def test_geofence_breach_with_the_px4_default_only_warns() -> None:
    sim = make_sim(seed=41)
    sim.params.set("GF_MAX_VER_DIST", 2.5)
    take_off(sim, 2.0)
    v = sim.vehicle
    assert v.goto(_local(sim, 0.0, 0.0, 3.5)).ok
    sim.run_for(4.0)
    assert v.status.mode is Px4Mode.AUTO_LOITER and not v.status.failsafe
    assert "geofence violation (Maximum altitude exceeded)" in _texts(sim)
    assert sim.altitude_above_start_m() > 3.2


def test_geofence_breach_with_gf_action_terminate_stops_the_motors_for_good() -> None:
    # GIVEN a 3 m ceiling and GF_ACTION = 4 (Terminate)
    sim = make_sim(seed=42)
    sim.params.set("GF_ACTION", 4)
    sim.params.set("GF_MAX_VER_DIST", 3.0)
    take_off(sim, 2.0)
    v = sim.vehicle
    # WHEN it climbs through the ceiling
    assert v.goto(_local(sim, 0.0, 0.0, 5.0)).ok
    assert sim.run_until(lambda s: not s.vehicle.status.armed, 10.0)
    # THEN the motors stop, HEARTBEAT says FLIGHT_TERMINATION, it falls and may not arm again
    assert v.crashed
    assert _heartbeat_status(sim) == mavlink.MAV_STATE_FLIGHT_TERMINATION
    assert "Flight termination" in _texts(sim)
    assert sim.run_until(lambda s: s.truth.on_ground, 5.0)
    sim.run_for(1.0)
    assert not v.arm().ok


def test_with_a_geofence_that_acts_arming_outside_it_is_refused() -> None:
    sim = make_sim(seed=43)
    sim.params.set("GF_ACTION", 3)
    assert sim.run_until(lambda s: s.vehicle.preflight_problem() is None, 10.0)
    est = sim.vehicle.estimate
    assert est is not None
    here = (float(est.pos_ned_m[0]), float(est.pos_ned_m[1]))
    sim.vehicle.set_fence(Geofence(zones=(CircleZone(kind=FenceKind.EXCLUSION, centre_ne_m=here, radius_m=2.0),)))
    assert sim.vehicle.preflight_problem() == "Preflight Fail: Vehicle outside geofence"
    assert not sim.vehicle.arm().ok
    sim.params.set("GF_ACTION", 1)  # a fence that only warns does not hold the vehicle on the ground
    assert sim.vehicle.arm().ok
