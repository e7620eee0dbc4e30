"""PX4 flight modes as they appear on the wire (sitl/autopilot/px4_modes.py defines them), and the HEARTBEAT fields
derived from them.

A PX4 mode is a (main mode, sub mode) pair. HEARTBEAT carries it packed as ``custom_mode = main << 16 | sub << 24``;
``MAV_CMD_DO_SET_MODE`` carries the two small numbers in param2/param3 and the old SET_MODE message the packed word.
Clients (MAVSDK, pymavlink's ``mode_mapping``/``interpret_px4_mode``) read the flight mode from ``custom_mode`` and
armed from ``base_mode``, so both must be exactly what PX4 sends (px4_custom_mode.h, commander's
``get_mavlink_mode_state``).
"""

from __future__ import annotations

import math

from pymavlink.dialects.v20 import common as mavlink

from sitl.autopilot.px4_modes import MAIN_AUTO, MAIN_OFFBOARD, MAIN_POSCTL, Px4Mode
from sitl.protocol.core import PeerInputError, param_to_int

_AUTO_FLAGS = (
    mavlink.MAV_MODE_FLAG_AUTO_ENABLED | mavlink.MAV_MODE_FLAG_STABILIZE_ENABLED | mavlink.MAV_MODE_FLAG_GUIDED_ENABLED
)


def base_mode(mode: Px4Mode, armed: bool) -> int:
    """HEARTBEAT ``base_mode`` as PX4 builds it for a multicopter."""
    flags = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
    if armed:
        flags |= mavlink.MAV_MODE_FLAG_SAFETY_ARMED
    manual = mavlink.MAV_MODE_FLAG_MANUAL_INPUT_ENABLED
    stabilize = mavlink.MAV_MODE_FLAG_STABILIZE_ENABLED
    if mode.main_mode in (MAIN_AUTO, MAIN_OFFBOARD):
        flags |= _AUTO_FLAGS
    elif mode.main_mode == MAIN_POSCTL:  # POSCTL and its sub mode ORBIT alike, as PX4's get_mavlink_mode_state
        flags |= manual | stabilize | mavlink.MAV_MODE_FLAG_GUIDED_ENABLED
    elif mode in (Px4Mode.MANUAL, Px4Mode.ALTCTL, Px4Mode.STABILIZED):
        flags |= manual | stabilize  # PX4 marks MANUAL stabilised on rotary wings
    elif mode is Px4Mode.ACRO:
        flags |= manual
    return flags


def system_status(*, armed: bool, failsafe: bool, terminated: bool = False) -> int:
    """HEARTBEAT ``system_status``: STANDBY disarmed, ACTIVE armed, CRITICAL in failsafe, as PX4."""
    if terminated:
        return mavlink.MAV_STATE_FLIGHT_TERMINATION
    if failsafe:
        return mavlink.MAV_STATE_CRITICAL
    return mavlink.MAV_STATE_ACTIVE if armed else mavlink.MAV_STATE_STANDBY


def mode_from_base_mode_flags(flags: int) -> Px4Mode | None:
    """PX4's reading of a DO_SET_MODE/SET_MODE without CUSTOM_MODE_ENABLED (the armed bit is ignored).

    None means "no mode named": PX4 then changes nothing and still acknowledges.
    """
    if flags & mavlink.MAV_MODE_FLAG_AUTO_ENABLED:
        return Px4Mode.AUTO_MISSION
    if flags & mavlink.MAV_MODE_FLAG_MANUAL_INPUT_ENABLED:
        if flags & mavlink.MAV_MODE_FLAG_GUIDED_ENABLED:
            return Px4Mode.POSCTL
        if flags & mavlink.MAV_MODE_FLAG_STABILIZE_ENABLED:
            return Px4Mode.STABILIZED
        return Px4Mode.MANUAL
    return None


def decode_do_set_mode(param1: float, param2: float, param3: float) -> Px4Mode | None:
    """Decode ``MAV_CMD_DO_SET_MODE`` (param1 base mode flags, param2 main mode, param3 sub mode).

    MAVSDK and pymavlink send small numbers here, never the packed word. Returns None when the request names no
    mode; raises PeerInputError for a malformed or unknown mode.
    """
    flags = param_to_int(param1)
    if flags is None or not 0 <= flags <= 255:
        raise PeerInputError(f"base mode {param1!r} is not a byte")
    if not flags & mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
        return mode_from_base_mode_flags(flags)
    main_mode = param_to_int(param2)
    sub_mode = 0 if math.isnan(param3) else param_to_int(param3)
    if main_mode is None or sub_mode is None or not (0 <= main_mode <= 255 and 0 <= sub_mode <= 255):
        raise PeerInputError(f"mode ({param2!r}, {param3!r}) is not a PX4 main/sub mode pair")
    mode = Px4Mode.from_main_sub(main_mode, sub_mode)
    if mode is None:
        raise PeerInputError(f"unknown PX4 mode main {main_mode} sub {sub_mode}")
    return mode


def decode_set_mode_message(base_mode_flags: int, custom_mode: int) -> Px4Mode | None:
    """Decode the old SET_MODE message (``custom_mode`` is the packed word there)."""
    if not 0 <= base_mode_flags <= 255 or not 0 <= custom_mode <= 0xFFFFFFFF:
        raise PeerInputError("SET_MODE fields out of range")
    if not base_mode_flags & mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
        return mode_from_base_mode_flags(base_mode_flags)
    mode = Px4Mode.from_custom_mode(custom_mode)
    if mode is None:
        raise PeerInputError(f"unknown PX4 custom mode {custom_mode}")
    return mode
