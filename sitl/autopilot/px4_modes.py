"""PX4's flight modes, as the autopilot knows itself: the (main mode, sub mode) pairs of px4_custom_mode.h, the
packed ``custom_mode`` word, and which failsafe is in force.

The autopilot's mode units, its commander and failsafe table name modes with ``Px4Mode``; the MAVLink services
(sitl/protocol/modes.py) only encode and decode them on the wire, as PX4's mavlink module reads the commander's state.
"""

from __future__ import annotations

from enum import Enum

MAIN_MANUAL = 1
MAIN_ALTCTL = 2
MAIN_POSCTL = 3
MAIN_AUTO = 4
MAIN_ACRO = 5
MAIN_OFFBOARD = 6
MAIN_STABILIZED = 7
SUB_POSCTL_ORBIT = 1  # PX4_CUSTOM_SUB_MODE_POSCTL_ORBIT: Orbit is a sub mode of POSCTL on the wire


class Px4Mode(Enum):
    """PX4 modes a client can name. The value is (main mode, sub mode)."""

    MANUAL = (MAIN_MANUAL, 0)
    ALTCTL = (MAIN_ALTCTL, 0)
    POSCTL = (MAIN_POSCTL, 0)
    ORBIT = (MAIN_POSCTL, SUB_POSCTL_ORBIT)  # PX4's nav state ORBIT (MAV_CMD_DO_ORBIT)
    AUTO_READY = (MAIN_AUTO, 1)
    AUTO_TAKEOFF = (MAIN_AUTO, 2)
    AUTO_LOITER = (MAIN_AUTO, 3)  # "Hold"
    AUTO_MISSION = (MAIN_AUTO, 4)
    AUTO_RTL = (MAIN_AUTO, 5)
    AUTO_LAND = (MAIN_AUTO, 6)
    AUTO_FOLLOW_TARGET = (MAIN_AUTO, 8)
    AUTO_PRECLAND = (MAIN_AUTO, 9)
    ACRO = (MAIN_ACRO, 0)
    OFFBOARD = (MAIN_OFFBOARD, 0)
    STABILIZED = (MAIN_STABILIZED, 0)

    @property
    def main_mode(self) -> int:
        return self.value[0]

    @property
    def sub_mode(self) -> int:
        return self.value[1]

    @property
    def custom_mode(self) -> int:
        """The HEARTBEAT ``custom_mode`` word."""
        return (self.main_mode << 16) | (self.sub_mode << 24)

    @property
    def px4_name(self) -> str:
        """The name PX4 prints (``AUTO.LOITER``, ``OFFBOARD``...)."""
        return self.name.replace("AUTO_", "AUTO.", 1)

    @classmethod
    def from_main_sub(cls, main_mode: int, sub_mode: int) -> Px4Mode | None:
        """Decode PX4's (main, sub) pair; None if PX4 would not know it.

        As in PX4's commander, the sub mode only matters for AUTO and POSCTL: AUTO with sub mode 0 means MISSION,
        POSCTL with a sub mode other than ORBIT is POSCTL.
        """
        if main_mode == MAIN_AUTO:
            if sub_mode == 0:
                return cls.AUTO_MISSION
            return _BY_MAIN_SUB.get((main_mode, sub_mode))
        if main_mode == MAIN_POSCTL and sub_mode == SUB_POSCTL_ORBIT:
            return cls.ORBIT
        return _BY_MAIN_SUB.get((main_mode, 0))

    @classmethod
    def from_custom_mode(cls, custom_mode: int) -> Px4Mode | None:
        """Decode a HEARTBEAT/SET_MODE ``custom_mode`` word."""
        return cls.from_main_sub((custom_mode >> 16) & 0xFF, (custom_mode >> 24) & 0xFF)


_BY_MAIN_SUB: dict[tuple[int, int], Px4Mode] = {m.value: m for m in Px4Mode}


class FailsafeKind(Enum):
    """Which failsafe is in force, as a ground station shows it (``NONE`` when none is).

    Defined beside the modes because it is part of what a client is told about the vehicle (the snapshot, the
    status table, the flight report), while the decisions that set it live in sitl/autopilot/failsafe.py.
    """

    NONE = "none"
    OFFBOARD_LOSS = "offboard_loss"
    DATALINK_LOSS = "datalink_loss"
    BATTERY_LOW = "battery_low"
    BATTERY_CRITICAL = "battery_critical"
    BATTERY_EMERGENCY = "battery_emergency"
    POSITION_LOSS = "position_loss"
    GEOFENCE = "geofence"
