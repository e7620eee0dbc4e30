"""The mission executor on its own: what it asks the vehicle to do, and when it moves to the next item."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sitl.autopilot.mission_exec import LAND_GOTO_ACCEPT_M, MissionAction, MissionExecutor, MissionRun
from sitl.autopilot.mission_plan import NAN3, NavItem, NavKind

pytestmark = pytest.mark.timeout(10)

RADIUS_M = 1.0  # NAV_ACC_RAD
HOVER = np.array((0.0, 0.0, -5.0))


def _wp(seq: int, north: float, east: float, down: float = -5.0, **fields: float) -> NavItem:
    return NavItem(seq=seq, kind=NavKind.WAYPOINT, target_ned_m=(north, east, down), **fields)


def _started(*items: NavItem) -> MissionExecutor:
    executor = MissionExecutor()
    executor.load(items)
    assert executor.state is MissionRun.NOT_STARTED
    assert executor.start()
    assert executor.state is MissionRun.ACTIVE
    return executor


def _step(
    executor: MissionExecutor, now_s: float, pos: tuple[float, float, float] | np.ndarray, landed: bool = False
) -> MissionAction | None:
    return executor.step(now_s, np.asarray(pos, dtype=np.float64), landed, RADIUS_M)


def test_an_empty_mission_cannot_start() -> None:
    executor = MissionExecutor()
    executor.load(())
    assert executor.state is MissionRun.NO_MISSION
    assert not executor.start()
    assert _step(executor, 0.0, HOVER) is None


def test_a_waypoint_is_flown_then_reached_within_the_acceptance_radius() -> None:
    # GIVEN a started mission of two waypoints
    executor = _started(_wp(0, 10.0, 0.0), _wp(1, 10.0, 10.0))
    # WHEN it steps at the start position
    action = _step(executor, 0.0, HOVER)
    # THEN it asks to fly to the first waypoint, and asks nothing new on the next steps
    assert action == MissionAction(kind=NavKind.WAYPOINT, target_ned_m=(10.0, 0.0, -5.0))
    assert _step(executor, 0.1, HOVER) is None
    # and 1.1 m away the waypoint is not yet reached
    assert _step(executor, 1.0, (8.9, 0.0, -5.0)) is None
    assert executor.current_seq == 0 and executor.reached_seq == -1
    # but 0.9 m away it is, and the next waypoint is asked for
    assert _step(executor, 2.0, (9.1, 0.0, -5.0)) is None
    assert executor.reached_seq == 0
    action = _step(executor, 2.1, (9.1, 0.0, -5.0))
    assert action is not None and action.target_ned_m == (10.0, 10.0, -5.0)
    assert executor.current_seq == 1


def test_the_mission_completes_after_the_last_item_is_reached() -> None:
    executor = _started(_wp(0, 3.0, 0.0))
    _step(executor, 0.0, HOVER)
    _step(executor, 1.0, (3.0, 0.0, -5.0))
    assert executor.state is MissionRun.COMPLETE
    assert executor.reached_seq == 0 and executor.current_seq == 0
    assert _step(executor, 2.0, (3.0, 0.0, -5.0)) is None


def test_acceptance_radius_is_three_dimensional() -> None:
    executor = _started(_wp(0, 0.0, 0.0, -10.0))
    _step(executor, 0.0, HOVER)
    _step(executor, 1.0, (0.0, 0.0, -8.5))  # right below it, 1.5 m short
    assert executor.state is MissionRun.ACTIVE
    _step(executor, 2.0, (0.0, 0.0, -9.5))
    assert executor.state is MissionRun.COMPLETE


def test_an_item_acceptance_radius_overrides_the_default() -> None:
    executor = _started(_wp(0, 10.0, 0.0, acceptance_radius_m=3.0))
    _step(executor, 0.0, HOVER)
    _step(executor, 1.0, (7.5, 0.0, -5.0))  # 2.5 m away: outside the default, inside the item's radius
    assert executor.reached_seq == 0


def test_a_hold_time_keeps_the_vehicle_at_the_waypoint_before_moving_on() -> None:
    executor = _started(_wp(0, 0.0, 0.0, hold_s=5.0), _wp(1, 5.0, 0.0))
    _step(executor, 0.0, HOVER)
    _step(executor, 1.0, HOVER)  # arrives at t = 1 s
    _step(executor, 5.9, HOVER)
    assert executor.reached_seq == -1 and executor.current_seq == 0
    _step(executor, 6.0, HOVER)
    assert executor.reached_seq == 0
    assert _step(executor, 6.1, HOVER) is not None


def test_unset_target_components_are_where_the_vehicle_is_when_the_item_starts() -> None:
    executor = _started(NavItem(seq=0, kind=NavKind.WAYPOINT, target_ned_m=(math.nan, math.nan, -12.0)))
    action = _step(executor, 0.0, (3.0, 4.0, -5.0))
    assert action is not None and action.target_ned_m == (3.0, 4.0, -12.0)
    # the target does not move with the vehicle afterwards
    _step(executor, 1.0, (6.0, 4.0, -12.0))
    assert executor.state is MissionRun.ACTIVE


def test_items_with_nothing_to_fly_are_skipped_in_the_same_step() -> None:
    executor = _started(
        NavItem(seq=0, kind=NavKind.SKIP),
        NavItem(seq=1, kind=NavKind.SKIP),
        _wp(2, 10.0, 0.0),
        NavItem(seq=3, kind=NavKind.SKIP),
    )
    action = _step(executor, 0.0, HOVER)
    assert action is not None and action.kind is NavKind.WAYPOINT and action.target_ned_m == (10.0, 0.0, -5.0)
    assert executor.current_seq == 2
    # a trailing skip item does not keep the mission open
    _step(executor, 1.0, (10.0, 0.0, -5.0))
    _step(executor, 1.1, (10.0, 0.0, -5.0))
    assert executor.state is MissionRun.COMPLETE


def test_a_speed_change_is_an_action_that_completes_at_once() -> None:
    executor = _started(NavItem(seq=0, kind=NavKind.SPEED, speed_mps=2.0), _wp(1, 10.0, 0.0))
    action = _step(executor, 0.0, HOVER)
    assert action is not None and action.kind is NavKind.SPEED and action.speed_mps == 2.0
    assert executor.reached_seq == 0
    action = _step(executor, 0.0025, HOVER)
    assert action is not None and action.kind is NavKind.WAYPOINT


def test_takeoff_is_reached_in_the_air_near_its_altitude_only() -> None:
    executor = _started(NavItem(seq=0, kind=NavKind.TAKEOFF, target_ned_m=(math.nan, math.nan, -5.0)), _wp(1, 5.0, 0.0))
    action = _step(executor, 0.0, (0.0, 0.0, 0.0), landed=True)
    assert action is not None and action.kind is NavKind.TAKEOFF and action.target_ned_m == (0.0, 0.0, -5.0)
    _step(executor, 1.0, (0.0, 0.0, -5.0), landed=True)  # landed (e.g. estimate glitch): not reached
    _step(executor, 2.0, (0.0, 0.0, -4.5), landed=False)  # 0.5 m short
    assert executor.current_seq == 0
    _step(executor, 3.0, (0.0, 0.0, -4.8), landed=False)
    assert executor.reached_seq == 0


def test_land_with_a_position_flies_there_at_its_altitude_then_descends_and_completes_on_touchdown() -> None:
    executor = _started(NavItem(seq=0, kind=NavKind.LAND, target_ned_m=(20.0, 0.0, 0.0)))
    # WHEN it starts 20 m away
    action = _step(executor, 0.0, HOVER)
    # THEN it first flies there without descending
    assert action is not None and action.kind is NavKind.WAYPOINT and action.target_ned_m == (20.0, 0.0, -5.0)
    assert _step(executor, 1.0, (19.0, 0.0, -5.0)) is None
    # and once over the point it lands
    action = _step(executor, 2.0, (20.0 - LAND_GOTO_ACCEPT_M / 2, 0.0, -5.0))
    assert action is not None and action.kind is NavKind.LAND
    assert executor.state is MissionRun.ACTIVE
    _step(executor, 3.0, (20.0, 0.0, -0.1), landed=False)
    assert executor.state is MissionRun.ACTIVE
    # and touchdown completes the mission
    _step(executor, 4.0, (20.0, 0.0, 0.0), landed=True)
    assert executor.state is MissionRun.COMPLETE
    assert executor.reached_seq == 0


def test_land_without_a_position_lands_where_the_vehicle_is() -> None:
    executor = _started(NavItem(seq=0, kind=NavKind.LAND, target_ned_m=(math.nan, math.nan, 0.0)))
    action = _step(executor, 0.0, (7.0, -3.0, -5.0))
    assert action is not None and action.kind is NavKind.LAND
    assert action.target_ned_m[:2] == (7.0, -3.0)
    _step(executor, 5.0, (7.0, -3.0, 0.0), landed=True)
    assert executor.state is MissionRun.COMPLETE


def test_return_to_launch_hands_over_to_rtl_and_completes_the_mission() -> None:
    executor = _started(_wp(0, 0.0, 0.0), NavItem(seq=1, kind=NavKind.RTL), _wp(2, 50.0, 0.0))
    _step(executor, 0.0, HOVER)
    _step(executor, 1.0, HOVER)
    action = _step(executor, 1.1, HOVER)
    assert action is not None and action.kind is NavKind.RTL
    assert executor.state is MissionRun.COMPLETE
    assert executor.reached_seq == 1
    assert _step(executor, 2.0, HOVER) is None  # the item after RTL is never flown


def test_a_delay_holds_where_the_vehicle_is_for_its_time() -> None:
    executor = _started(NavItem(seq=0, kind=NavKind.DELAY, target_ned_m=NAN3, hold_s=3.0), _wp(1, 5.0, 0.0))
    action = _step(executor, 10.0, (1.0, 2.0, -5.0))
    assert action is not None and action.target_ned_m == (1.0, 2.0, -5.0)
    _step(executor, 10.0025, (1.0, 2.0, -5.0))  # the hold is timed from the first check, one step later
    _step(executor, 12.99, (1.0, 2.0, -5.0))
    assert executor.current_seq == 0
    _step(executor, 13.0025, (1.0, 2.0, -5.0))
    assert executor.reached_seq == 0


def test_loiter_unlimited_never_completes_by_itself() -> None:
    executor = _started(NavItem(seq=0, kind=NavKind.LOITER_UNLIMITED, target_ned_m=(0.0, 0.0, -5.0)), _wp(1, 5.0, 0.0))
    _step(executor, 0.0, HOVER)
    for t in range(1, 100):
        assert _step(executor, float(t), HOVER) is None
    assert executor.current_seq == 0 and executor.state is MissionRun.ACTIVE


def test_set_current_jumps_to_an_item_and_refuses_one_that_does_not_exist() -> None:
    executor = _started(_wp(0, 10.0, 0.0), _wp(1, 20.0, 0.0), _wp(2, 30.0, 0.0))
    _step(executor, 0.0, HOVER)
    assert not executor.set_current(3)
    assert not executor.set_current(-1)
    assert executor.set_current(2)
    assert executor.current_seq == 2
    action = _step(executor, 0.1, HOVER)
    assert action is not None and action.target_ned_m == (30.0, 0.0, -5.0)


def test_set_current_after_completion_pauses_and_start_resumes_from_that_item() -> None:
    executor = _started(_wp(0, 0.0, 0.0, -5.0), _wp(1, 0.0, 1.0, -5.0))
    _step(executor, 0.0, HOVER)
    _step(executor, 0.1, HOVER)
    _step(executor, 0.2, HOVER)
    _step(executor, 0.3, HOVER)
    assert executor.state is MissionRun.COMPLETE
    assert executor.set_current(1)
    assert executor.state is MissionRun.PAUSED
    assert executor.start()
    action = _step(executor, 1.0, HOVER)
    assert action is not None and action.target_ned_m == (0.0, 1.0, -5.0)


def test_starting_again_after_completion_restarts_from_the_first_item() -> None:
    executor = _started(_wp(0, 0.0, 0.0), _wp(1, 0.0, 0.5))
    for k in range(4):
        _step(executor, 0.1 * k, HOVER)
    assert executor.state is MissionRun.COMPLETE and executor.reached_seq == 1
    assert executor.start()
    assert executor.state is MissionRun.ACTIVE
    assert executor.current_seq == 0 and executor.reached_seq == -1
    action = _step(executor, 1.0, (50.0, 0.0, -5.0))
    assert action is not None and action.target_ned_m == (0.0, 0.0, -5.0)


def test_a_paused_mission_makes_no_progress_and_resumes_by_re_issuing_the_current_item() -> None:
    executor = _started(_wp(0, 10.0, 0.0), _wp(1, 20.0, 0.0))
    _step(executor, 0.0, HOVER)
    executor.pause()
    assert executor.state is MissionRun.PAUSED
    assert _step(executor, 1.0, (10.0, 0.0, -5.0)) is None  # at the waypoint, but paused
    assert executor.reached_seq == -1
    assert executor.start()
    action = _step(executor, 2.0, (4.0, 0.0, -5.0))
    assert action is not None and action.target_ned_m == (10.0, 0.0, -5.0)


def test_loading_a_new_mission_starts_over() -> None:
    executor = _started(_wp(0, 0.0, 0.0), _wp(1, 0.0, 0.5))
    _step(executor, 0.0, HOVER)
    _step(executor, 0.1, HOVER)
    assert executor.reached_seq == 0
    executor.load((_wp(0, 5.0, 5.0),))
    assert executor.state is MissionRun.NOT_STARTED
    assert executor.current_seq == 0 and executor.reached_seq == -1
    assert _step(executor, 1.0, HOVER) is None  # not started yet


def test_retargeting_keeps_progress_and_later_items_fly_to_their_new_targets() -> None:
    # GIVEN a mission flying its first item
    executor = _started(_wp(0, 10.0, 0.0, -5.0), _wp(1, 20.0, 0.0, -5.0))
    _step(executor, 0.0, HOVER)
    # WHEN the same mission arrives with every target 2 m higher (home moved up)
    executor.retarget((_wp(0, 10.0, 0.0, -7.0), _wp(1, 20.0, 0.0, -7.0)))
    # THEN the item in progress keeps its target, the mission is not restarted, and the next item uses its new one
    assert executor.state is MissionRun.ACTIVE and executor.current_seq == 0
    assert _step(executor, 1.0, (10.0, 0.0, -5.0)) is None
    assert executor.reached_seq == 0
    action = _step(executor, 1.1, (10.0, 0.0, -5.0))
    assert action is not None and action.target_ned_m == (20.0, 0.0, -7.0)


def test_retargeting_with_a_different_mission_is_refused() -> None:
    executor = _started(_wp(0, 10.0, 0.0), _wp(1, 20.0, 0.0))
    with pytest.raises(ValueError, match="same mission"):
        executor.retarget((_wp(0, 10.0, 0.0),))
