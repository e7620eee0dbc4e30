"""The failsafe table's conditions as one kernel: every row's condition (sitl/autopilot/failsafe.py) in one word, a bit
per row in the table's order.

The commander looks at its failsafes on every tick of every drone, and on nearly every tick nothing has changed: the
word is compared with the rows that have fired (sitl/autopilot/failsafe_framework.py ``FailsafeState``) and the Python
mechanics run only for a row whose bit differs. Each condition is written here and nowhere else; the Python table
gives each row its action, its texts and its clearing, and checks that its rows are these, in this order.
"""

from __future__ import annotations

import math

from sitl.kernels import kernel

# The rows' bits, in the order of sitl/autopilot/failsafe.py ``FAILSAFE_TABLE``.
OFFBOARD_LOSS = 0
DATALINK_LOSS = 1
BATTERY_LOW = 2
BATTERY_CRITICAL = 3
BATTERY_EMERGENCY = 4
POSITION_LOSS = 5
GEOFENCE = 6
ROWS = 7


@kernel(
    "int64(float64, boolean, boolean, boolean, boolean, boolean, float64, float64, boolean, boolean,"
    " float64, float64, float64, float64)"
)
def conditions(
    now_s: float,
    landed: bool,
    mode_offboard: bool,
    mode_land: bool,
    needs_position: bool,
    offboard_alive: bool,
    gcs_heartbeat_s: float,
    battery_remaining: float,
    position_valid: bool,
    fence_breached: bool,
    datalink_loss_s: float,
    battery_low: float,
    battery_critical: float,
    battery_emergency: float,
) -> int:
    """Which rows' conditions hold now: bit ``k`` for row ``k``. ``gcs_heartbeat_s`` is NaN before the first ground
    station HEARTBEAT; the last four are COM_DL_LOSS_T, BAT_LOW_THR, BAT_CRIT_THR and BAT_EMERGEN_THR."""
    word = 0
    if mode_offboard and not offboard_alive:
        word |= 1 << OFFBOARD_LOSS
    # Armed only once a ground station has been heard (PX4 does not fail safe for a link it never had), and, as PX4,
    # never while landing: landing is already what a lost vehicle should do.
    if not (math.isnan(gcs_heartbeat_s) or landed or mode_land) and now_s - gcs_heartbeat_s > datalink_loss_s:
        word |= 1 << DATALINK_LOSS
    if battery_remaining < battery_low:
        word |= 1 << BATTERY_LOW
    if battery_remaining < battery_critical and not landed:
        word |= 1 << BATTERY_CRITICAL
    if battery_remaining < battery_emergency and not landed:
        word |= 1 << BATTERY_EMERGENCY
    # PX4's mode fallback: a mode that needs a position cannot run without one.
    if not position_valid and needs_position and not landed:
        word |= 1 << POSITION_LOSS
    if fence_breached and not landed:
        word |= 1 << GEOFENCE
    return word


@kernel("int64(int64, int64, int64)")
def events(holds: int, fired: int, on_arming: int) -> int:
    """The rows that act now, given which hold (``conditions``), which have fired and which re-arm only on arming: a
    row whose condition starts to hold and that has not fired, or stops holding after it fired and re-arms when its
    condition clears. Any other row does nothing now (nearly every tick, every row)."""
    return (holds & ~fired) | (fired & ~holds & ~on_arming)
