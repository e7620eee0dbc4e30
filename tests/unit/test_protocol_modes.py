"""PX4 mode encoding on the wire: custom_mode packing, DO_SET_MODE / SET_MODE decoding, HEARTBEAT flags."""

from __future__ import annotations

import math

import pytest
from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mavlink

from sitl.autopilot.px4_modes import Px4Mode
from sitl.protocol.core import PeerInputError
from sitl.protocol.modes import base_mode, decode_do_set_mode, decode_set_mode_message, system_status

CUSTOM = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
NAN = math.nan


@pytest.mark.parametrize(
    ("mode", "custom_mode"),
    [
        (Px4Mode.MANUAL, 65536),
        (Px4Mode.ALTCTL, 131072),
        (Px4Mode.POSCTL, 196608),
        (Px4Mode.AUTO_READY, 17039360),
        (Px4Mode.AUTO_TAKEOFF, 33816576),
        (Px4Mode.AUTO_LOITER, 50593792),
        (Px4Mode.AUTO_MISSION, 67371008),
        (Px4Mode.AUTO_RTL, 84148224),
        (Px4Mode.AUTO_LAND, 100925440),
        (Px4Mode.AUTO_FOLLOW_TARGET, 134479872),
        (Px4Mode.OFFBOARD, 393216),
        (Px4Mode.STABILIZED, 458752),
    ],
)
def test_custom_mode_word_matches_the_px4_table(mode: Px4Mode, custom_mode: int) -> None:
    # GIVEN a PX4 mode  WHEN packed for HEARTBEAT  THEN it is PX4's word, and it decodes back to the same mode
    assert mode.custom_mode == custom_mode
    assert Px4Mode.from_custom_mode(custom_mode) is mode


@pytest.mark.parametrize("name", ["LOITER", "MISSION", "RTL", "LAND", "OFFBOARD", "TAKEOFF", "POSCTL", "ALTCTL"])
def test_pymavlink_reads_our_heartbeat_as_the_mode_it_asked_for(name: str) -> None:
    # GIVEN the triple pymavlink's set_mode(name) sends as DO_SET_MODE params
    flags, main, sub = mavutil.px4_map[name]
    # WHEN we decode it and report the resulting mode in a heartbeat
    mode = decode_do_set_mode(float(flags), float(main), float(sub))
    assert mode is not None
    # THEN pymavlink's own interpretation of our heartbeat gives the same name back
    assert mavutil.interpret_px4_mode(base_mode(mode, armed=False), mode.custom_mode) == name


def test_mavsdk_style_set_mode_with_nan_sub_mode_for_offboard() -> None:
    # GIVEN MAVSDK's DO_SET_MODE for offboard with unused params NaN WHEN decoded THEN OFFBOARD
    assert decode_do_set_mode(float(CUSTOM | 128), 6.0, NAN) is Px4Mode.OFFBOARD


def test_auto_with_sub_mode_zero_means_mission_as_in_px4() -> None:
    assert decode_do_set_mode(float(CUSTOM), 4.0, 0.0) is Px4Mode.AUTO_MISSION


def test_a_main_mode_without_sub_modes_ignores_the_sub_mode() -> None:
    # PX4's commander reads a sub mode only for AUTO and for POSCTL, where sub mode 1 is ORBIT and any other POSCTL
    assert decode_do_set_mode(float(CUSTOM), 2.0, 1.0) is Px4Mode.ALTCTL
    assert decode_do_set_mode(float(CUSTOM), 3.0, 1.0) is Px4Mode.ORBIT
    assert decode_do_set_mode(float(CUSTOM), 3.0, 2.0) is Px4Mode.POSCTL


@pytest.mark.parametrize(("p2", "p3"), [(99.0, 0.0), (4.0, 7.0), (NAN, 0.0), (4.0, 300.0), (-1.0, 0.0)])
def test_unknown_or_malformed_custom_modes_are_rejected(p2: float, p3: float) -> None:
    with pytest.raises(PeerInputError):
        decode_do_set_mode(float(CUSTOM), p2, p3)


def test_base_mode_that_is_not_a_byte_is_rejected() -> None:
    with pytest.raises(PeerInputError):
        decode_do_set_mode(NAN, 4.0, 3.0)
    with pytest.raises(PeerInputError):
        decode_do_set_mode(1000.0, 4.0, 3.0)


@pytest.mark.parametrize(
    ("flags", "mode"),
    [
        (mavlink.MAV_MODE_AUTO_ARMED, Px4Mode.AUTO_MISSION),
        (mavlink.MAV_MODE_GUIDED_ARMED, Px4Mode.POSCTL),
        (mavlink.MAV_MODE_STABILIZE_ARMED, Px4Mode.STABILIZED),
        (mavlink.MAV_MODE_MANUAL_ARMED, Px4Mode.MANUAL),
        (0, None),
    ],
)
def test_legacy_base_mode_without_custom_flag_follows_px4(flags: int, mode: Px4Mode | None) -> None:
    # GIVEN pymavlink's set_mode_manual()/set_mode_flag() style requests WHEN decoded THEN PX4's legacy mapping
    assert decode_do_set_mode(float(flags), 0.0, 0.0) is mode
    assert decode_set_mode_message(flags, 0) is mode


def test_set_mode_message_carries_the_packed_word() -> None:
    assert decode_set_mode_message(CUSTOM, Px4Mode.AUTO_RTL.custom_mode) is Px4Mode.AUTO_RTL
    with pytest.raises(PeerInputError):
        decode_set_mode_message(CUSTOM, 0x63 << 16)


def test_base_mode_flags_for_armed_auto_and_offboard() -> None:
    # GIVEN an armed vehicle in an auto mode WHEN the heartbeat is built THEN custom|armed|stabilize|guided|auto
    expected = CUSTOM | 128 | 16 | 8 | 4
    assert base_mode(Px4Mode.AUTO_LOITER, armed=True) == expected
    assert base_mode(Px4Mode.OFFBOARD, armed=True) == expected
    assert base_mode(Px4Mode.AUTO_LOITER, armed=False) == expected & ~128
    assert base_mode(Px4Mode.POSCTL, armed=False) & mavlink.MAV_MODE_FLAG_AUTO_ENABLED == 0


def test_system_status_rules() -> None:
    assert system_status(armed=False, failsafe=False) == mavlink.MAV_STATE_STANDBY
    assert system_status(armed=True, failsafe=False) == mavlink.MAV_STATE_ACTIVE
    assert system_status(armed=True, failsafe=True) == mavlink.MAV_STATE_CRITICAL
    assert system_status(armed=False, failsafe=False, terminated=True) == mavlink.MAV_STATE_FLIGHT_TERMINATION


def test_px4_names() -> None:
    assert Px4Mode.AUTO_LOITER.px4_name == "AUTO.LOITER"
    assert Px4Mode.OFFBOARD.px4_name == "OFFBOARD"
