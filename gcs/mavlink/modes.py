"""Flight modes as a ground station reads and sets them, for the autopilots it commands: PX4 (the simulated drones,
and an attached PX4) and ArduPilot Copter (an attached one), through pymavlink's own mappings, not the drone's code.

Decoding HEARTBEAT ``custom_mode`` with the simulated autopilot's encoder would let an encoding bug cancel out in
every test; pymavlink's ``interpret_px4_mode``, ``px4_map`` and ``mode_mapping_bynumber`` are what MAVProxy and many
scripts use against real autopilots. PX4 modes are shown under the names PX4 itself prints (``AUTO.LOITER``),
ArduPilot's under its own (``GUIDED``), which the CLI, the report and the docs use.

What the swarm asks of a vehicle it commands is a purpose, not a mode: ``OFFBOARD`` (fly the setpoints the ground
station streams: PX4's OFFBOARD, ArduPilot's GUIDED) and ``HOLD`` (stay where it is: PX4's AUTO.LOITER, ArduPilot's
LOITER). ``purpose_params`` gives the DO_SET_MODE parameters of a purpose for an autopilot.
"""

from __future__ import annotations

from typing import Final

from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mavlink

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
PX4: Final = mavlink.MAV_AUTOPILOT_PX4
ARDUPILOT: Final = mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA
COMMANDED: Final = (PX4, ARDUPILOT)  # the autopilots whose modes the swarm can set

# Purposes (see the module docstring), and each autopilot's mode for them in its mapping's names
OFFBOARD: Final = "offboard"
HOLD: Final = "hold"
_PX4_MODES: Final = {OFFBOARD: "OFFBOARD", HOLD: "LOITER"}  # pymavlink's px4_map names
_ARDUPILOT_MODES: Final = {OFFBOARD: "GUIDED", HOLD: "LOITER"}  # ArduCopter's names
_CUSTOM: Final = float(mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED)
_PX4_ORBIT: Final = (3 << 16) | (1 << 24)  # custom_mode of PX4's Orbit: main mode POSCTL (3), sub mode ORBIT (1)


def mode_name(custom_mode: int, autopilot: int = PX4, vehicle_type: int = mavlink.MAV_TYPE_QUADROTOR) -> str:
    """The name of a HEARTBEAT ``custom_mode`` for its autopilot (``custom N`` for one pymavlink does not know)."""
    if autopilot == ARDUPILOT:
        name = (mavutil.mode_mapping_bynumber(vehicle_type) or {}).get(custom_mode)
        return str(name) if name is not None else f"custom {custom_mode}"
    if custom_mode == _PX4_ORBIT:  # pymavlink reads no POSCTL sub mode: Orbit would read back as POSCTL
        return "ORBIT"
    name = str(mavutil.interpret_px4_mode(0, custom_mode))
    if name == "UNKNOWN":
        return f"custom {custom_mode}"
    return _AUTO_NAMES.get(name, name)


def set_mode_params(pymavlink_name: str) -> tuple[float, float, float]:
    """MAV_CMD_DO_SET_MODE params 1-3 (base mode flags, PX4 main mode, sub mode) for a mode in pymavlink's PX4 map."""
    base_mode, main_mode, sub_mode = mavutil.px4_map[pymavlink_name]
    return float(base_mode), float(main_mode), float(sub_mode)


def purpose_params(purpose: str, autopilot: int = PX4,
                   vehicle_type: int = mavlink.MAV_TYPE_QUADROTOR) -> tuple[float, float, float]:  # fmt: skip
    """MAV_CMD_DO_SET_MODE params 1-3 for a purpose (``OFFBOARD``, ``HOLD``) on an autopilot: PX4's main and sub mode,
    or ArduPilot's custom mode number (the copter's mapping for a multirotor)."""
    if autopilot == ARDUPILOT:
        numbers = {name: number for number, name in (mavutil.mode_mapping_bynumber(vehicle_type) or {}).items()}
        return _CUSTOM, float(numbers[_ARDUPILOT_MODES[purpose]]), 0.0
    if purpose == OFFBOARD:  # PX4's main mode alone, as MAVSDK asks for it
        return _CUSTOM, float(mavutil.px4_map["OFFBOARD"][1]), 0.0
    return set_mode_params(_PX4_MODES[purpose])


def purpose_mode_name(purpose: str, autopilot: int = PX4) -> str:
    """The mode a purpose is, as ``mode_name`` shows it (``OFFBOARD``, ``AUTO.LOITER``, ``GUIDED``, ``LOITER``)."""
    if autopilot == ARDUPILOT:
        return _ARDUPILOT_MODES[purpose]
    name = _PX4_MODES[purpose]
    return _AUTO_NAMES.get(name, name)
