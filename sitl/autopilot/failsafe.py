"""The failsafe policy: one row per failsafe (action from its PX4 parameter, delay, clearing, texts) and the rows'
conditions (``failsafe_conditions``), run by the framework's mechanics (sitl/autopilot/failsafe_framework.py), as PX4's
failsafe.cpp is run by framework.cpp.

The conditions are one kernel (sitl/kernels/failsafe.py), a bit per row, so that a tick on which nothing changed costs
one call. Adding a failsafe means one row in ``FAILSAFE_TABLE``, its condition's bit in the kernel, and its parameters
in sitl/autopilot/params.py.
"""

from __future__ import annotations

from sitl.autopilot.failsafe_framework import Clear, FailsafeAction, FailsafeInputs, FailsafeRow
from sitl.autopilot.px4_modes import FailsafeKind, Px4Mode
from sitl.kernels import failsafe as fk
from sitl.params import ParamStore


def _int(params: ParamStore, name: str) -> int:
    return round(params[name])


# ---- the actions each PX4 parameter selects ----------------------------------------------------------------------
_DLL_ACTIONS = {  # NAV_DLL_ACT (PX4 gcs_connection_loss_failsafe_mode; 4 was removed from PX4)
    1: FailsafeAction.HOLD,
    2: FailsafeAction.RTL,
    3: FailsafeAction.LAND,
    5: FailsafeAction.TERMINATE,
    6: FailsafeAction.DISARM,
}
_OBL_ACTIONS = {  # COM_OBL_RC_ACT (PX4 offboard_loss_failsafe_mode)
    # 0 Position, 1 Altitude and 2 Stabilized need a pilot on sticks; a swarm drone has no RC, so (as PX4 without
    # manual control) they fall back to Hold, then land after COM_FAIL_ACT_T.
    0: FailsafeAction.LAND,
    1: FailsafeAction.LAND,
    2: FailsafeAction.LAND,
    3: FailsafeAction.RTL,
    4: FailsafeAction.LAND,
    5: FailsafeAction.HOLD,
    6: FailsafeAction.TERMINATE,
    7: FailsafeAction.DISARM,
}
_GF_ACTIONS = {  # GF_ACTION (PX4 geofence_violation_action)
    0: FailsafeAction.NONE,
    1: FailsafeAction.WARN,
    2: FailsafeAction.HOLD,
    3: FailsafeAction.RTL,
    4: FailsafeAction.TERMINATE,
    5: FailsafeAction.LAND,
}
# COM_LOW_BAT_ACT: 0 warning, 1 return, 2 land, 3 return at critical and land at emergency (PX4 LowBatteryAction).
_BAT_CRITICAL_ACTIONS = {0: FailsafeAction.WARN, 1: FailsafeAction.RTL, 2: FailsafeAction.LAND, 3: FailsafeAction.RTL}
_BAT_EMERGENCY_ACTIONS = {0: FailsafeAction.WARN, 1: FailsafeAction.RTL, 2: FailsafeAction.LAND, 3: FailsafeAction.LAND}


def _pct(i: FailsafeInputs) -> str:
    return f"{i.battery_remaining:.0%} remaining"


FAILSAFE_TABLE: tuple[FailsafeRow, ...] = (
    FailsafeRow(
        kind=FailsafeKind.OFFBOARD_LOSS,
        action=lambda p: _OBL_ACTIONS.get(_int(p, "COM_OBL_RC_ACT"), FailsafeAction.LAND),
        cause=lambda i: "offboard setpoints lost",
        clear=Clear.WHEN_CONDITION_CLEARS,
        hold_first=True,
    ),
    FailsafeRow(
        kind=FailsafeKind.DATALINK_LOSS,
        action=lambda p: _DLL_ACTIONS.get(_int(p, "NAV_DLL_ACT"), FailsafeAction.NONE),
        cause=lambda i: "no connection to the ground control station",
        clear=Clear.WHEN_CONDITION_CLEARS,
        hold_first=True,
        recovered="Data link regained",
    ),
    FailsafeRow(
        kind=FailsafeKind.BATTERY_LOW,
        action=lambda p: FailsafeAction.WARN,  # PX4 only warns at the low level, whatever COM_LOW_BAT_ACT says
        cause=lambda i: f"Low battery: {_pct(i)}",
        clear=Clear.ON_ARMING,
        hold_first=False,
    ),
    FailsafeRow(
        kind=FailsafeKind.BATTERY_CRITICAL,
        action=lambda p: _BAT_CRITICAL_ACTIONS.get(_int(p, "COM_LOW_BAT_ACT"), FailsafeAction.WARN),
        cause=lambda i: "battery critical",
        clear=Clear.ON_ARMING,
        hold_first=False,  # the pack drains on: act at once
    ),
    FailsafeRow(
        kind=FailsafeKind.BATTERY_EMERGENCY,
        action=lambda p: _BAT_EMERGENCY_ACTIONS.get(_int(p, "COM_LOW_BAT_ACT"), FailsafeAction.WARN),
        cause=lambda i: "battery emergency",
        clear=Clear.ON_ARMING,
        hold_first=False,
    ),
    FailsafeRow(
        kind=FailsafeKind.POSITION_LOSS,
        # PX4's mode fallback: a mode that needs a position cannot run without one, so the vehicle comes down
        # (Land needs a position too: without one it descends level at a controlled sink rate).
        action=lambda p: FailsafeAction.DESCEND,
        cause=lambda i: "no global position",
        clear=Clear.WHEN_CONDITION_CLEARS,
        hold_first=False,  # Hold needs the position that is missing
        recovered="Global position regained",
        resume_when_clear=True,
    ),
    FailsafeRow(
        kind=FailsafeKind.GEOFENCE,
        action=lambda p: _GF_ACTIONS.get(_int(p, "GF_ACTION"), FailsafeAction.WARN),
        cause=lambda i: f"geofence violation ({i.fence_breach})",
        clear=Clear.WHEN_CONDITION_CLEARS,
        hold_first=False,  # PX4 acts on a breach at once
    ),
)


# Each row's bit in the conditions' word (sitl/kernels/failsafe.py), by kind: the table's order must be the kernel's.
_BITS = {
    FailsafeKind.OFFBOARD_LOSS: fk.OFFBOARD_LOSS,
    FailsafeKind.DATALINK_LOSS: fk.DATALINK_LOSS,
    FailsafeKind.BATTERY_LOW: fk.BATTERY_LOW,
    FailsafeKind.BATTERY_CRITICAL: fk.BATTERY_CRITICAL,
    FailsafeKind.BATTERY_EMERGENCY: fk.BATTERY_EMERGENCY,
    FailsafeKind.POSITION_LOSS: fk.POSITION_LOSS,
    FailsafeKind.GEOFENCE: fk.GEOFENCE,
}
if [_BITS[row.kind] for row in FAILSAFE_TABLE] != list(range(fk.ROWS)):
    raise ImportError("FAILSAFE_TABLE's rows are not in the order of their bits in sitl/kernels/failsafe.py")


def failsafe_limits(p: ParamStore) -> tuple[float, float, float, float]:
    """The parameters the conditions compare with, in the kernel's order: COM_DL_LOSS_T, BAT_LOW_THR, BAT_CRIT_THR,
    BAT_EMERGEN_THR."""
    return p["COM_DL_LOSS_T"], p["BAT_LOW_THR"], p["BAT_CRIT_THR"], p["BAT_EMERGEN_THR"]


def failsafe_conditions(i: FailsafeInputs, p: ParamStore) -> int:
    """Which rows of ``FAILSAFE_TABLE`` hold for ``i``: bit ``k`` for row ``k`` (the framework's ``Conditions``)."""
    return fk.conditions(
        i.now_s, i.landed, i.mode is Px4Mode.OFFBOARD, i.mode is Px4Mode.AUTO_LAND, i.needs_position,
        i.offboard_alive, i.gcs_heartbeat_s, i.battery_remaining, i.position_valid, i.fence_breach is not None,
        *failsafe_limits(p),
    )  # fmt: skip
