"""Closed-loop flights through the MAVLink adapter (SimVehicleApi): wire-level requests in, snapshots out.

Policy: a ClosedLoop stepped directly (JSBSim, sensor noise on), no sockets, no wall clock. The drone is driven only
with sitl.autopilot.vehicle_api request objects and read through ``snapshot()``, as the MAVLink services do; ground
truth is used only to check where it really went.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import TypeVar

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink

from sitl.autopilot import vehicle_api as api
from sitl.autopilot.px4_modes import Px4Mode
from sitl.drone.closed_loop import ClosedLoop
from sitl.drone.sim_vehicle_api import SimVehicleApi
from sitl.dynamics.geodesy import ned_from_geo
from sitl.dynamics.plant import GeoPoint
from tests.closed_loop.flight import boot_position, make_sim

pytestmark = pytest.mark.timeout(60)

T = TypeVar("T")


class Drone:
    """A ClosedLoop behind SimVehicleApi, with the helpers a ground station script would have."""

    def __init__(self, seed: int) -> None:
        self.sim: ClosedLoop = make_sim(seed=seed)
        self.api = SimVehicleApi(self.sim)
        self.home_true = boot_position(self.sim)

    def command(self, request: api.VehicleRequest) -> api.CommandOutcome:
        return self.api.command(request, self.sim.time_s)

    def snap(self) -> api.VehicleSnapshot:
        return self.api.snapshot()

    def run_until(self, condition: Callable[[], object], timeout_s: float) -> bool:
        return self.sim.run_until(lambda _s: bool(condition()), timeout_s)

    def wait_armable(self) -> None:
        assert self.run_until(lambda: self.snap().prearm_ok, 10.0)

    def geo_at(self, north_m: float, east_m: float) -> GeoPoint:
        """The geodetic point north/east of the local origin (on the origin's altitude)."""
        return self.api.frame.geo_from_ned((north_m, east_m, 0.0))

    def true_alt_m(self) -> float:
        return self.sim.altitude_above_start_m()

    def true_ne(self) -> np.ndarray:
        return (self.sim.truth.pos_ned_m - self.home_true)[:2]


def _waypoint(drone: Drone, seq: int, north_m: float, east_m: float, alt_rel_m: float) -> api.MissionItem:
    point = drone.geo_at(north_m, east_m)
    return api.MissionItem(
        seq=seq,
        frame=mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
        command=mavlink.MAV_CMD_NAV_WAYPOINT,
        param1=0.0,
        param2=0.0,
        x=round(point.lat_deg * 1e7),
        y=round(point.lon_deg * 1e7),
        z=alt_rel_m,
    )


def _change_speed(seq: int, speed_mps: float) -> api.MissionItem:
    return api.MissionItem(
        seq=seq, frame=mavlink.MAV_FRAME_MISSION, command=mavlink.MAV_CMD_DO_CHANGE_SPEED, param1=1.0, param2=speed_mps
    )


def _compress(values: list[T]) -> list[T]:
    """Consecutive duplicates removed: the sequence of distinct states."""
    return [v for i, v in enumerate(values) if i == 0 or v != values[i - 1]]


# ---- snapshot ------------------------------------------------------------------------------------------------------
def test_snapshot_before_and_after_the_position_becomes_valid() -> None:
    # GIVEN a drone just booted
    drone = Drone(seed=31)
    drone.sim.step()
    snap = drone.snap()
    # THEN it reports no position, no home, not armable, on the ground, no GPS fix yet
    assert not snap.prearm_ok and not snap.armed
    assert snap.home is None and snap.global_position is None
    assert all(math.isnan(c) for c in snap.pos_ned_m)
    assert snap.landed_state is api.LandedState.ON_GROUND
    assert snap.gps.fix_type < api.GpsFixType.FIX_3D and snap.gps.position is None
    assert snap.local_origin == drone.api.origin
    # WHEN the position becomes valid
    assert drone.run_until(lambda: drone.snap().home is not None, 10.0)
    snap = drone.snap()
    # THEN home is set, at the resting position (the local origin)
    assert snap.home is not None
    assert snap.home.pos_ned_m == pytest.approx((0.0, 0.0, 0.0), abs=1e-9)
    assert snap.home.position.alt_amsl_m == pytest.approx(drone.api.origin.alt_amsl_m)
    assert snap.gps.fix_type >= api.GpsFixType.FIX_3D
    # and it does not move while the drone sits there
    home_then = snap.home
    drone.sim.run_for(2.0)
    assert drone.snap().home == home_then
    # and the global position is the local one expressed geodetically, within a metre of where the drone truly is
    snap = drone.snap()
    assert snap.global_position is not None
    local_of_global = ned_from_geo(snap.global_position, drone.api.origin)
    assert local_of_global == pytest.approx(snap.pos_ned_m, abs=1e-3)
    true_geo = drone.sim.truth.geo
    true_ned = ned_from_geo(true_geo, drone.api.origin)
    assert math.dist(local_of_global[:2], true_ned[:2]) < 1.0
    assert snap.global_position.alt_amsl_m == pytest.approx(true_geo.alt_amsl_m, abs=0.5)
    assert snap.alt_above_home_m == pytest.approx(0.0, abs=0.3)


def test_prearm_turns_true_when_arming_becomes_possible() -> None:
    drone = Drone(seed=32)
    drone.sim.step()
    assert not drone.snap().prearm_ok
    assert drone.command(api.Arm()).result is api.CommandResult.DENIED
    drone.wait_armable()
    assert drone.command(api.Arm()).ok


def test_a_snapshot_taken_right_after_a_command_shows_its_effect() -> None:
    drone = Drone(seed=33)
    drone.wait_armable()
    assert not drone.snap().armed  # cached for this step
    assert drone.command(api.Arm()).ok
    assert drone.snap().armed  # same simulation time, no step in between
    assert drone.command(api.SetMode(mode=Px4Mode.AUTO_TAKEOFF)).ok
    assert drone.snap().mode is Px4Mode.AUTO_TAKEOFF
    assert drone.snap().landed_state is api.LandedState.ON_GROUND  # the vehicle has not stepped yet


# ---- takeoff, land, reposition -------------------------------------------------------------------------------------
def test_takeoff_without_altitude_then_land_reports_each_landed_state_in_turn() -> None:
    # GIVEN an armed drone
    drone = Drone(seed=34)
    drone.wait_armable()
    assert drone.command(api.Arm()).ok
    landed_states: list[api.LandedState] = [drone.snap().landed_state]

    def watch() -> api.VehicleSnapshot:
        landed_states.append(drone.snap().landed_state)
        return drone.snap()

    # WHEN it takes off with no altitude given
    assert drone.command(api.Takeoff()).ok
    assert drone.run_until(lambda: watch().mode is Px4Mode.AUTO_LOITER, 15.0)
    # THEN it climbs to MIS_TAKEOFF_ALT above home and holds
    drone.sim.run_for(2.0)
    assert drone.true_alt_m() == pytest.approx(drone.sim.params["MIS_TAKEOFF_ALT"], abs=0.2)
    assert drone.snap().alt_above_home_m == pytest.approx(drone.sim.params["MIS_TAKEOFF_ALT"], abs=0.2)
    # WHEN it is switched to AUTO.LAND
    assert drone.command(api.SetMode(mode=Px4Mode.AUTO_LAND)).ok
    assert drone.run_until(lambda: not watch().armed, 20.0)
    # THEN it lands and disarms, and the landed state went ON_GROUND -> TAKEOFF -> IN_AIR -> LANDING -> ON_GROUND
    assert drone.sim.truth.on_ground
    assert _compress(landed_states) == [
        api.LandedState.ON_GROUND,
        api.LandedState.TAKEOFF,
        api.LandedState.IN_AIR,
        api.LandedState.LANDING,
        api.LandedState.ON_GROUND,
    ]


def test_takeoff_to_an_amsl_altitude_climbs_to_it_and_a_too_low_one_is_raised() -> None:
    drone = Drone(seed=35)
    drone.wait_armable()
    assert drone.command(api.Arm()).ok
    home = drone.snap().home
    assert home is not None
    # WHEN told to take off to 4 m above home, given as AMSL
    assert drone.command(api.Takeoff(alt_amsl_m=home.position.alt_amsl_m + 4.0)).ok
    assert drone.run_until(lambda: drone.snap().mode is Px4Mode.AUTO_LOITER, 15.0)
    drone.sim.run_for(1.0)
    # THEN it holds 4 m above home
    assert drone.true_alt_m() == pytest.approx(4.0, abs=0.2)
    # and a second drone told to take off to 0 m AMSL (a relative altitude sent by mistake) goes to MIS_TAKEOFF_ALT
    other = Drone(seed=36)
    other.wait_armable()
    assert other.command(api.Arm()).ok
    assert other.command(api.Takeoff(alt_amsl_m=0.0)).ok
    assert other.run_until(lambda: other.snap().mode is Px4Mode.AUTO_LOITER, 15.0)
    other.sim.run_for(1.0)
    assert other.true_alt_m() == pytest.approx(other.sim.params["MIS_TAKEOFF_ALT"], abs=0.2)


def test_reposition_to_a_lat_lon_taken_from_the_snapshot_flies_there() -> None:
    # GIVEN a drone hovering at the takeoff altitude
    drone = Drone(seed=37)
    drone.wait_armable()
    assert drone.command(api.Arm()).ok
    assert drone.command(api.Takeoff()).ok
    assert drone.run_until(lambda: drone.snap().mode is Px4Mode.AUTO_LOITER, 15.0)
    here = drone.snap().global_position
    assert here is not None
    # WHEN it is repositioned 6 m north and 4 m east of where the snapshot says it is, 1.5 m higher
    here_ned = ned_from_geo(here, drone.api.origin)
    target = drone.api.frame.geo_from_ned((here_ned[0] + 6.0, here_ned[1] + 4.0, here_ned[2]))
    request = api.Reposition(lat_deg=target.lat_deg, lon_deg=target.lon_deg, alt_amsl_m=here.alt_amsl_m + 1.5)
    alt_before = drone.true_alt_m()
    ne_before = drone.true_ne()
    assert drone.command(request).ok
    drone.sim.run_for(8.0)
    # THEN it is there, truly, and the snapshot agrees
    assert drone.true_ne() - ne_before == pytest.approx((6.0, 4.0), abs=0.3)
    assert drone.true_alt_m() - alt_before == pytest.approx(1.5, abs=0.2)
    now = drone.snap().global_position
    assert now is not None
    assert math.dist(ned_from_geo(now, drone.api.origin)[:2], ned_from_geo(target, drone.api.origin)[:2]) < 0.3
    assert drone.snap().mode is Px4Mode.AUTO_LOITER


def test_land_at_a_lat_lon_touches_down_there() -> None:
    drone = Drone(seed=38)
    drone.wait_armable()
    assert drone.command(api.Arm()).ok
    assert drone.command(api.Takeoff()).ok
    assert drone.run_until(lambda: drone.snap().mode is Px4Mode.AUTO_LOITER, 15.0)
    spot = drone.geo_at(4.0, -3.0)
    assert drone.command(api.Land(lat_deg=spot.lat_deg, lon_deg=spot.lon_deg)).ok
    assert drone.run_until(lambda: not drone.snap().armed, 25.0)
    assert drone.true_ne() == pytest.approx((4.0, -3.0), abs=0.5)
    assert drone.sim.truth.on_ground


# ---- mission -------------------------------------------------------------------------------------------------------
def test_mission_started_on_the_ground_takes_off_flies_every_item_then_rtl_lands_at_home() -> None:
    # GIVEN an armed drone on the ground with a mission: a square of 4 waypoints at 3 m, a speed change to 2 m/s
    # after the first one
    drone = Drone(seed=39)
    drone.sim.params.set("RTL_RETURN_ALT", 4.0)
    drone.wait_armable()
    legs = [(6.0, 0.0), (6.0, 6.0), (0.0, 6.0), (0.0, 0.0)]
    items = (
        _waypoint(drone, 0, *legs[0], 3.0),
        _change_speed(1, 2.0),
        _waypoint(drone, 2, *legs[1], 3.0),
        _waypoint(drone, 3, *legs[2], 3.0),
        _waypoint(drone, 4, *legs[3], 3.0),
    )
    assert drone.command(api.SetMission(items=items)).ok
    assert tuple(drone.api.mission_items()) == items
    assert drone.snap().mission.state is api.MissionState.NOT_STARTED
    assert drone.command(api.Arm()).ok
    # WHEN it is switched to AUTO.MISSION
    assert drone.command(api.SetMode(mode=Px4Mode.AUTO_MISSION)).ok
    progress: list[tuple[int, api.MissionState, int]] = []
    near_waypoint = {0: math.inf, 2: math.inf, 3: math.inf, 4: math.inf}
    speeds_after_change: list[float] = []

    def watch() -> bool:
        m = drone.snap().mission
        progress.append((m.current_seq, m.state, m.reached_seq))
        for seq, (n, e) in zip((0, 2, 3, 4), legs, strict=True):
            miss = math.hypot(*(drone.true_ne() - (n, e)), drone.true_alt_m() - 3.0)
            near_waypoint[seq] = min(near_waypoint[seq], miss)
        if m.current_seq >= 3 and m.state is api.MissionState.ACTIVE:  # the legs after the one it turned onto
            speeds_after_change.append(math.hypot(*drone.sim.truth.vel_ned_mps[:2]))
        return m.state is api.MissionState.COMPLETE

    assert drone.run_until(watch, 60.0), progress[-1]
    # THEN it took off and flew every waypoint (each passed within the 1 m acceptance radius)
    assert max(near_waypoint.values()) < 1.0, near_waypoint
    # with the mission reported ACTIVE, then COMPLETE
    states = _compress([state for _, state, _ in progress])
    assert states == [api.MissionState.ACTIVE, api.MissionState.COMPLETE]
    # the current item advancing through the items (the speed change completes at once) and the reached item
    # following it
    assert _compress([seq for seq, _, _ in progress]) in ([0, 1, 2, 3, 4], [0, 2, 3, 4])
    reached = _compress([r for _, _, r in progress])
    assert reached == sorted(reached) and reached[0] == -1 and reached[-1] == 4
    assert {0, 2, 3, 4} <= set(reached)
    # and the later legs were flown at the new 2 m/s, not the 5 m/s default (plus tracking error)
    assert max(speeds_after_change) < 2.4
    assert max(speeds_after_change) > 1.5
    # WHEN it is told to return to launch
    assert drone.command(api.ReturnToLaunch()).ok
    assert drone.snap().mode is Px4Mode.AUTO_RTL
    # THEN it lands at home and disarms
    assert drone.run_until(lambda: not drone.snap().armed, 40.0)
    assert drone.sim.truth.on_ground
    assert float(np.linalg.norm(drone.true_ne())) < 1.0
    assert drone.snap().landed_state is api.LandedState.ON_GROUND


def test_mission_relative_altitudes_are_above_the_current_home() -> None:
    # GIVEN a mission uploaded with a waypoint 3 m above home, and then home set 2 m higher (DO_SET_HOME)
    drone = Drone(seed=40)
    drone.wait_armable()
    assert drone.command(api.SetMission(items=(_waypoint(drone, 0, 3.0, 0.0, 3.0),))).ok
    assert drone.command(api.Arm()).ok
    home = drone.snap().home
    assert home is not None
    raised = api.SetHome(
        use_current=False,
        lat_deg=home.position.lat_deg,
        lon_deg=home.position.lon_deg,
        alt_amsl_m=home.position.alt_amsl_m + 2.0,
    )
    assert drone.command(raised).ok
    # WHEN the mission is flown
    assert drone.command(api.SetMode(mode=Px4Mode.AUTO_MISSION)).ok
    assert drone.run_until(lambda: drone.snap().mission.state is api.MissionState.COMPLETE, 30.0)
    drone.sim.run_for(2.0)
    # THEN the waypoint is 3 m above the new home: 5 m above the ground
    assert drone.true_alt_m() == pytest.approx(5.0, abs=0.25)


def test_mode_changes_the_vehicle_cannot_make_are_temporarily_rejected() -> None:
    drone = Drone(seed=41)
    drone.wait_armable()
    assert drone.command(api.SetMode(mode=Px4Mode.POSCTL)).result is api.CommandResult.TEMPORARILY_REJECTED
    assert drone.command(api.SetMode(mode=Px4Mode.AUTO_RTL)).result is api.CommandResult.TEMPORARILY_REJECTED
    assert drone.command(api.SetMode(mode=Px4Mode.AUTO_MISSION)).result is api.CommandResult.TEMPORARILY_REJECTED
    assert drone.snap().mode is Px4Mode.AUTO_LOITER
