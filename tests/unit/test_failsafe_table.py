"""The failsafe table and its state machine (sitl/autopilot/failsafe.py), without a vehicle: which row fires, which
action each PX4 parameter value selects, severity ranking, the hold-first delay, clearing and re-arming."""

from __future__ import annotations

import math

import pytest

from sitl.autopilot.failsafe import FAILSAFE_TABLE, failsafe_conditions
from sitl.autopilot.failsafe_framework import FailsafeAction, FailsafeInputs, FailsafeState
from sitl.autopilot.px4_modes import FailsafeKind, Px4Mode
from sitl.drone.param_table import build_param_store
from sitl.params import ParamStore

pytestmark = pytest.mark.timeout(10)

FLYING = FailsafeInputs(
    now_s=100.0,
    landed=False,
    mode=Px4Mode.AUTO_LOITER,
    needs_position=True,
    offboard_alive=False,
    gcs_heartbeat_s=99.5,
    battery_remaining=0.8,
    position_valid=True,
    altitude_valid=True,
    fence_breach=None,
)


def _params(**values: float) -> ParamStore:
    params = build_param_store()
    for name, value in values.items():
        params.set(name, value)
    return params


def _state() -> FailsafeState:
    return FailsafeState(FAILSAFE_TABLE, failsafe_conditions)


def _actions(
    state: FailsafeState, inputs: FailsafeInputs, params: ParamStore
) -> list[tuple[FailsafeKind, FailsafeAction]]:
    return [(o.kind, o.action) for o in state.evaluate(inputs, params)]


def test_nothing_fires_in_normal_flight() -> None:
    assert _actions(_state(), FLYING, _params()) == []


@pytest.mark.parametrize(
    ("nav_dll_act", "final"),
    [
        (1, FailsafeAction.HOLD),
        (2, FailsafeAction.RTL),
        (3, FailsafeAction.LAND),
        (5, FailsafeAction.TERMINATE),
        (6, FailsafeAction.DISARM),
    ],
)
def test_nav_dll_act_selects_the_datalink_action_after_a_hold_of_com_fail_act_t(
    nav_dll_act: int, final: FailsafeAction
) -> None:
    params = _params(NAV_DLL_ACT=nav_dll_act)
    state = _state()
    lost = FLYING._replace(now_s=FLYING.gcs_heartbeat_s + 10.01)
    assert _actions(state, lost, params) == [(FailsafeKind.DATALINK_LOSS, FailsafeAction.HOLD)]
    assert state.in_failsafe and state.active is FailsafeKind.DATALINK_LOSS
    delay = params["COM_FAIL_ACT_T"]
    assert state.delayed_action(lost.now_s + delay - 0.01, Px4Mode.AUTO_LOITER, delay) is None
    order = state.delayed_action(lost.now_s + delay, Px4Mode.AUTO_LOITER, delay)
    if final is FailsafeAction.HOLD:
        assert order is None  # Hold is already the action
    else:
        assert order is not None and order.action is final


def test_datalink_loss_needs_a_heartbeat_first_a_timeout_and_is_off_by_default_and_while_landing() -> None:
    on = _params(NAV_DLL_ACT=2)
    lost = FLYING._replace(now_s=FLYING.gcs_heartbeat_s + 10.01)
    assert _actions(_state(), lost, _params()) == []  # PX4's default NAV_DLL_ACT = 0
    assert _actions(_state(), lost._replace(gcs_heartbeat_s=math.nan), on) == []
    assert _actions(_state(), lost._replace(now_s=FLYING.gcs_heartbeat_s + 9.99), on) == []
    assert _actions(_state(), lost._replace(mode=Px4Mode.AUTO_LAND), on) == []


def test_a_link_that_comes_back_is_announced_and_a_second_loss_fires_again() -> None:
    params = _params(NAV_DLL_ACT=1)
    state = _state()
    lost = FLYING._replace(now_s=FLYING.gcs_heartbeat_s + 11.0)
    assert _actions(state, lost, params) == [(FailsafeKind.DATALINK_LOSS, FailsafeAction.HOLD)]
    assert _actions(state, lost._replace(now_s=lost.now_s + 1.0), params) == []  # fires once
    back = state.evaluate(lost._replace(gcs_heartbeat_s=lost.now_s), params)
    assert [o.text for o in back] == ["Data link regained"]
    state.cleared()  # the operator commands a mode
    again = lost._replace(now_s=lost.now_s + 11.0, gcs_heartbeat_s=lost.now_s)
    assert _actions(state, again, params) == [(FailsafeKind.DATALINK_LOSS, FailsafeAction.HOLD)]


@pytest.mark.parametrize(
    ("com_low_bat_act", "critical", "emergency"),
    [
        (0, FailsafeAction.WARN, FailsafeAction.WARN),
        (1, FailsafeAction.RTL, FailsafeAction.RTL),
        (2, FailsafeAction.LAND, FailsafeAction.LAND),
        (3, FailsafeAction.RTL, FailsafeAction.LAND),
    ],
)
def test_com_low_bat_act_selects_the_critical_and_emergency_actions(
    com_low_bat_act: int, critical: FailsafeAction, emergency: FailsafeAction
) -> None:
    params = _params(COM_LOW_BAT_ACT=com_low_bat_act)
    state = _state()
    crit = _actions(state, FLYING._replace(battery_remaining=0.06), params)
    assert crit == [(FailsafeKind.BATTERY_LOW, FailsafeAction.WARN), (FailsafeKind.BATTERY_CRITICAL, critical)]
    emerg = _actions(state, FLYING._replace(battery_remaining=0.04), params)
    # An emergency action no more severe than the one in force is only said, not taken (action NONE).
    taken = emergency if emergency is FailsafeAction.WARN or emergency > critical else FailsafeAction.NONE
    assert emerg == [(FailsafeKind.BATTERY_EMERGENCY, taken)]


def test_battery_levels_fire_once_per_flight_and_rearm_on_arming() -> None:
    params = _params(COM_LOW_BAT_ACT=2)
    state = _state()
    low = FLYING._replace(battery_remaining=0.06)
    assert len(state.evaluate(low, params)) == 2
    state.cleared()
    assert state.evaluate(low, params) == []
    state.on_arming()
    assert len(state.evaluate(low, params)) == 2


def test_a_more_severe_failsafe_supersedes_a_held_one_and_a_milder_one_does_not() -> None:
    params = _params(COM_LOW_BAT_ACT=1)
    state = _state()
    offboard_lost = FLYING._replace(mode=Px4Mode.OFFBOARD)
    assert _actions(state, offboard_lost, params) == [(FailsafeKind.OFFBOARD_LOSS, FailsafeAction.HOLD)]
    # a critical battery during the hold: Return beats Hold, and the delayed landing is dropped
    critical = FLYING._replace(battery_remaining=0.06)
    assert (FailsafeKind.BATTERY_CRITICAL, FailsafeAction.RTL) in _actions(state, critical, params)
    assert state.delayed_action(1e9, Px4Mode.AUTO_LOITER, 0.0) is None
    # a geofence Hold while returning changes nothing but is said
    params.set("GF_ACTION", 2)
    breach = critical._replace(fence_breach="Outside the geofence")
    orders = state.evaluate(breach, params)
    assert [(o.kind, o.action) for o in orders] == [(FailsafeKind.GEOFENCE, FailsafeAction.NONE)]
    assert orders[0].text == "Failsafe: geofence violation (Outside the geofence), holding"
    assert state.active is FailsafeKind.BATTERY_CRITICAL


def test_the_delayed_action_waits_for_hold_and_is_dropped_when_the_operator_takes_over() -> None:
    params = _params()
    state = _state()
    state.evaluate(FLYING._replace(mode=Px4Mode.OFFBOARD), params)
    assert state.delayed_action(FLYING.now_s + 10.0, Px4Mode.AUTO_RTL, 5.0) is None  # not while in another mode
    state.cleared()
    assert state.delayed_action(FLYING.now_s + 10.0, Px4Mode.AUTO_LOITER, 5.0) is None
    assert not state.in_failsafe and state.active is FailsafeKind.NONE


@pytest.mark.parametrize(
    ("gf_action", "action"),
    [
        (0, None),
        (1, FailsafeAction.WARN),
        (2, FailsafeAction.HOLD),
        (3, FailsafeAction.RTL),
        (4, FailsafeAction.TERMINATE),
        (5, FailsafeAction.LAND),
    ],
)
def test_gf_action_selects_the_geofence_action_at_once(gf_action: int, action: FailsafeAction | None) -> None:
    breach = FLYING._replace(fence_breach="Maximum altitude exceeded")
    expected = [] if action is None else [(FailsafeKind.GEOFENCE, action)]
    assert _actions(_state(), breach, _params(GF_ACTION=gf_action)) == expected


def test_position_loss_descends_only_in_a_mode_that_needs_a_position_and_only_in_the_air() -> None:
    params = _params()
    lost = FLYING._replace(position_valid=False)
    assert _actions(_state(), lost, params) == [(FailsafeKind.POSITION_LOSS, FailsafeAction.DESCEND)]
    assert _actions(_state(), lost._replace(needs_position=False), params) == []
    assert _actions(_state(), lost._replace(landed=True), params) == []


def test_a_position_that_returns_resumes_the_operators_mode_only_while_the_fallback_is_in_force() -> None:
    params = _params()
    lost = FLYING._replace(position_valid=False)
    state = _state()
    state.evaluate(lost, params)
    back = state.evaluate(FLYING, params)
    assert [(o.text, o.resume) for o in back] == [("Global position regained", True)]
    state = _state()
    state.evaluate(lost, params)
    state.cleared()  # the operator took over meanwhile
    assert [o.resume for o in state.evaluate(FLYING, params)] == [False]


def test_a_fallback_that_ends_restores_the_failsafe_it_replaced() -> None:
    params = _params(COM_LOW_BAT_ACT=1)
    state = _state()
    critical = FLYING._replace(battery_remaining=0.06, mode=Px4Mode.AUTO_RTL)
    state.evaluate(critical, params)
    assert state.active is FailsafeKind.BATTERY_CRITICAL
    assert (FailsafeKind.POSITION_LOSS, FailsafeAction.DESCEND) in _actions(
        state, critical._replace(position_valid=False), params
    )
    back = state.evaluate(critical, params)
    assert [o.resume for o in back] == [True]
    assert state.active is FailsafeKind.BATTERY_CRITICAL and state.active_action is FailsafeAction.RTL
