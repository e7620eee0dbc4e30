"""The ground station decodes PX4 modes with pymavlink's mapping; the drone encodes them with its own code.

Two independent implementations that must agree on the wire: a mode the simulated autopilot encoded wrongly would
show here under another name, rather than cancel out as it would if both sides shared one table.
"""

from __future__ import annotations

from pymavlink import mavutil

from gcs.mavlink.modes import mode_name, set_mode_params
from sitl.autopilot.px4_modes import Px4Mode
from sitl.protocol.modes import decode_do_set_mode

# Modes the drone can report that pymavlink's PX4 map does not name (it lists no READY or PRECLAND sub mode)
NOT_IN_PYMAVLINK = {Px4Mode.AUTO_READY, Px4Mode.AUTO_PRECLAND}


def test_every_mode_the_drone_reports_reads_back_under_px4s_name() -> None:
    for mode in Px4Mode:
        if mode in NOT_IN_PYMAVLINK:
            assert mode_name(mode.custom_mode) == f"custom {mode.custom_mode}"
        else:
            assert mode_name(mode.custom_mode) == mode.px4_name, mode


def test_set_mode_params_from_pymavlink_name_the_mode_the_drone_decodes() -> None:
    not_in_the_drone = {"RATTITUDE", "RTGS"}  # removed from PX4 / a return variant the drone does not fly
    for name, (_base, main_mode, sub_mode) in mavutil.px4_map.items():
        if name in not_in_the_drone:
            continue
        decoded = decode_do_set_mode(*set_mode_params(name))
        assert decoded is not None and decoded.px4_name == mode_name((main_mode << 16) | (sub_mode << 24)), name
    assert decode_do_set_mode(*set_mode_params("LOITER")) is Px4Mode.AUTO_LOITER


def test_orbit_is_posctl_with_sub_mode_orbit_and_any_other_posctl_sub_mode_is_posctl() -> None:
    # PX4's px4_custom_mode.h: PX4_CUSTOM_SUB_MODE_POSCTL_ORBIT = 1; its commander reads other sub modes as POSCTL
    assert Px4Mode.ORBIT.custom_mode == 3 << 16 | 1 << 24
    assert Px4Mode.from_custom_mode(Px4Mode.ORBIT.custom_mode) is Px4Mode.ORBIT
    assert decode_do_set_mode(1.0, 3.0, 1.0) is Px4Mode.ORBIT
    assert decode_do_set_mode(1.0, 3.0, 2.0) is Px4Mode.POSCTL
