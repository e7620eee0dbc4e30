"""PX4 flight modes as a ground station reads and sets them: pymavlink's own PX4 mapping, not the drone's code.

Decoding HEARTBEAT ``custom_mode`` with the simulated autopilot's encoder would let an encoding bug cancel out in
every test; pymavlink's ``interpret_px4_mode`` and ``px4_map`` are what MAVProxy and many scripts use against real
PX4. Modes are shown under the names PX4 itself prints (``AUTO.LOITER``), which the CLI, the report and the docs
use.
"""

from __future__ import annotations

from typing import Final

from pymavlink import mavutil

# pymavlink's names for PX4's AUTO sub modes -> the names PX4 prints; the other modes' names are the same in both.
_AUTO_NAMES: Final = {
    "LOITER": "AUTO.LOITER",
    "MISSION": "AUTO.MISSION",
    "RTL": "AUTO.RTL",
    "LAND": "AUTO.LAND",
    "TAKEOFF": "AUTO.TAKEOFF",
    "FOLLOWME": "AUTO.FOLLOW_TARGET",
    "RTGS": "AUTO.RTGS",
}


def mode_name(custom_mode: int) -> str:
    """The PX4 name of a HEARTBEAT ``custom_mode`` (``custom N`` for one pymavlink does not know)."""
    name = str(mavutil.interpret_px4_mode(0, custom_mode))
    if name == "UNKNOWN":
        return f"custom {custom_mode}"
    return _AUTO_NAMES.get(name, name)


def set_mode_params(pymavlink_name: str) -> tuple[float, float, float]:
    """MAV_CMD_DO_SET_MODE params 1-3 (base mode flags, PX4 main mode, sub mode) for a mode in pymavlink's PX4 map."""
    base_mode, main_mode, sub_mode = mavutil.px4_map[pymavlink_name]
    return float(base_mode), float(main_mode), float(sub_mode)
