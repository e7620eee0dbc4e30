"""pymavlink helpers for the tests that talk MAVLink directly, the way classic scripts and MAVProxy do.

pymavlink's own waits (``motors_armed_wait``, ``recv_match(blocking=True)``) have no deadline; a drone that never
answers would hang the test until its global timeout with no hint of what was missing. These helpers wrap them
with a wall-clock deadline and fail with the last message seen.
"""

from __future__ import annotations

import contextlib
import math
import os
import struct
import time
from collections.abc import Callable, Iterator
from typing import Any, Final

from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mavlink

PREARM_CHECK_BIT: Final = mavlink.MAV_SYS_STATUS_PREARM_CHECK  # 0x10000000: "armable" in SYS_STATUS health
ARMED_FLAG: Final = mavlink.MAV_MODE_FLAG_SAFETY_ARMED
AUTOPILOT_COMPID: Final = 1
RESEND_INTERVAL_S: Final = 1.0
PX4_AUTO_LOITER: Final = 50593792  # custom_mode of AUTO.LOITER (Hold): main 4 << 16 | sub 3 << 24
PX4_AUTO_LAND: Final = 100925440  # AUTO.LAND: main 4 << 16 | sub 6 << 24

Message = Any  # pymavlink message objects are dynamically typed


# pymavlink switches itself to MAVLink 2 on the first MAVLink 2 frame it receives by setting MAVLINK20 in the
# environment of the whole process; every connection here starts from the environment the suite was started with,
# so each test sees pymavlink as a freshly started script does, whatever ran before it.
_MAVLINK20_AT_START: Final = os.environ.get("MAVLINK20")


def _restore_wire_protocol() -> None:
    if _MAVLINK20_AT_START is None:
        os.environ.pop("MAVLINK20", None)
    else:
        os.environ["MAVLINK20"] = _MAVLINK20_AT_START
    mavutil.set_dialect(mavutil.current_dialect)


@contextlib.contextmanager
def mavlink_connection(url: str) -> Iterator[mavutil.mavfile]:
    """``mavutil.mavlink_connection`` as a fresh script opens it, always closed so its UDP port is free again."""
    _restore_wire_protocol()
    conn = mavutil.mavlink_connection(url)
    try:
        yield conn
    finally:
        conn.close()
        _restore_wire_protocol()


def wait_vehicle_heartbeat(conn: mavutil.mavfile, sysid: int | None, timeout_s: float) -> Message:
    """``wait_heartbeat`` for the autopilot (compid 1) of ``sysid`` (None: the first autopilot heard); locks onto it."""

    def is_vehicle(msg: Message) -> bool:
        return (
            msg.get_srcComponent() == AUTOPILOT_COMPID
            and msg.autopilot != mavlink.MAV_AUTOPILOT_INVALID
            and (sysid is None or msg.get_srcSystem() == sysid)
        )

    hb = recv_until(conn, "HEARTBEAT", is_vehicle, timeout_s, f"HEARTBEAT from sysid {sysid or 'any'}, compid 1")
    conn.target_system = hb.get_srcSystem()  # target_component stays 0, as in plain pymavlink scripts
    return hb


def recv_until(
    conn: mavutil.mavfile,
    msg_type: str | list[str],
    predicate: Callable[[Message], bool],
    timeout_s: float,
    what: str,
) -> Message:
    """The first message of ``msg_type`` from the target system that satisfies ``predicate``."""
    deadline = time.monotonic() + timeout_s
    last: Message | None = None
    while (remaining := deadline - time.monotonic()) > 0:
        msg = conn.recv_match(type=msg_type, blocking=True, timeout=min(remaining, 0.5))
        if msg is None:
            continue
        if conn.target_system and msg.get_srcSystem() != conn.target_system:
            continue
        last = msg
        if predicate(msg):
            return msg
    raise AssertionError(f"{what}: not within {timeout_s:.1f} s (last {msg_type}: {last})")


def command_long(conn: mavutil.mavfile, command: int, params: tuple[float, ...], timeout_s: float = 5.0) -> Message:
    """Send COMMAND_LONG, resending once a second like a ground station (confirmation counting up), until its
    COMMAND_ACK arrives; returns the ACK."""
    padded = (*params, *([0.0] * (7 - len(params))))
    deadline = time.monotonic() + timeout_s
    confirmation = 0
    while True:
        conn.mav.command_long_send(conn.target_system, conn.target_component, command, confirmation, *padded)
        with contextlib.suppress(AssertionError):
            return recv_until(conn, "COMMAND_ACK", lambda m: m.command == command, RESEND_INTERVAL_S, "ack")
        confirmation = min(confirmation + 1, 255)
        if time.monotonic() >= deadline:
            raise AssertionError(f"no COMMAND_ACK for command {command} {padded} within {timeout_s:.1f} s")


def wait_armable(conn: mavutil.mavfile, timeout_s: float) -> Message:
    return recv_until(
        conn,
        "SYS_STATUS",
        lambda m: bool(m.onboard_control_sensors_health & PREARM_CHECK_BIT),
        timeout_s,
        "SYS_STATUS with the pre-arm check bit healthy",
    )


def heartbeat_armed(hb: Message) -> bool:
    return bool(hb.base_mode & ARMED_FLAG)


def wait_armed_state(conn: mavutil.mavfile, armed: bool, timeout_s: float) -> Message:
    return recv_until(
        conn,
        "HEARTBEAT",
        lambda m: m.get_srcComponent() == AUTOPILOT_COMPID and heartbeat_armed(m) == armed,
        timeout_s,
        "HEARTBEAT armed" if armed else "HEARTBEAT disarmed",
    )


def wait_relative_alt(conn: mavutil.mavfile, target_m: float, tolerance_m: float, timeout_s: float) -> Message:
    return recv_until(
        conn,
        "GLOBAL_POSITION_INT",
        lambda m: abs(m.relative_alt / 1000.0 - target_m) <= tolerance_m,
        timeout_s,
        f"GLOBAL_POSITION_INT.relative_alt {target_m:.1f} ± {tolerance_m:.2f} m",
    )


def upload_mission(conn: mavutil.mavfile, items: list[Message], timeout_s: float) -> Message:
    """MISSION_COUNT, answer each MISSION_REQUEST_INT, return the final MISSION_ACK."""
    conn.mav.mission_count_send(conn.target_system, conn.target_component, len(items), mavlink.MAV_MISSION_TYPE_MISSION)
    deadline = time.monotonic() + timeout_s
    while True:
        msg = recv_until(
            conn,
            ["MISSION_REQUEST_INT", "MISSION_REQUEST", "MISSION_ACK"],
            lambda m: getattr(m, "mission_type", 0) == mavlink.MAV_MISSION_TYPE_MISSION,
            max(deadline - time.monotonic(), 0.01),
            "mission upload handshake",
        )
        if msg.get_type() == "MISSION_ACK":
            return msg
        conn.mav.send(items[msg.seq])


def arm_and_take_off(conn: mavutil.mavfile, timeout_s: float) -> float:
    """Arm (retrying until accepted) and NAV_TAKEOFF with NaN altitude (MIS_TAKEOFF_ALT); returns the altitude
    reached above home once the drone holds there in AUTO.LOITER."""
    deadline = time.monotonic() + timeout_s
    wait_armable(conn, timeout_s)
    while True:
        ack = command_long(conn, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, (1,), timeout_s)
        if ack.result == mavlink.MAV_RESULT_ACCEPTED:
            break
        if time.monotonic() > deadline:
            raise AssertionError(f"arming refused: {ack}")
        time.sleep(0.2)
    nan = float("nan")
    ack = command_long(conn, mavlink.MAV_CMD_NAV_TAKEOFF, (nan,) * 7, timeout_s)
    assert ack.result == mavlink.MAV_RESULT_ACCEPTED, f"takeoff refused: {ack}"
    param = recv_param(conn, "MIS_TAKEOFF_ALT", timeout_s)
    wait_relative_alt(conn, param, 0.3, max(deadline - time.monotonic(), 1.0))
    wait_custom_mode(conn, PX4_AUTO_LOITER, max(deadline - time.monotonic(), 1.0), "Hold after takeoff")
    return param


def wait_custom_mode(conn: mavutil.mavfile, custom_mode: int, timeout_s: float, what: str) -> Message:
    return recv_until(
        conn,
        "HEARTBEAT",
        lambda m: m.get_srcComponent() == AUTOPILOT_COMPID and m.custom_mode == custom_mode,
        timeout_s,
        f"HEARTBEAT with custom_mode {custom_mode} ({what})",
    )


def recv_param(conn: mavutil.mavfile, name: str, timeout_s: float) -> float:
    conn.mav.param_request_read_send(conn.target_system, conn.target_component, name.encode(), -1)
    msg = recv_until(conn, "PARAM_VALUE", lambda m: m.param_id == name, timeout_s, f"PARAM_VALUE {name}")
    return float(msg.param_value)


def set_param(conn: mavutil.mavfile, name: str, value: float, *, integer: bool = False) -> None:
    """PARAM_SET (INT32 bytewise as PX4 and QGroundControl send it, or REAL32); waits for the echo and checks it."""
    kind = mavlink.MAV_PARAM_TYPE_INT32 if integer else mavlink.MAV_PARAM_TYPE_REAL32
    wire = struct.unpack("<f", struct.pack("<i", int(value)))[0] if integer else value
    conn.mav.param_set_send(conn.target_system, 1, name.encode(), wire, kind)
    echo = recv_until(conn, "PARAM_VALUE", lambda m: m.param_id == name, 5.0, f"PARAM_VALUE {name}")
    got = struct.unpack("<i", struct.pack("<f", echo.param_value))[0] if integer else echo.param_value
    assert got == value if integer else math.isclose(got, value, rel_tol=1e-6), (name, value, got)


def request_message(conn: mavutil.mavfile, msg_id: int, msg_type: str, timeout_s: float) -> tuple[Message, Message]:
    """MAV_CMD_REQUEST_MESSAGE; returns (COMMAND_ACK, the message), which may arrive in either order."""
    conn.mav.command_long_send(
        conn.target_system, conn.target_component, mavlink.MAV_CMD_REQUEST_MESSAGE, 0, msg_id, 0, 0, 0, 0, 0, 0
    )
    got: dict[str, Message] = {}

    def both(msg: Message) -> bool:
        if msg.get_type() == msg_type or msg.command == mavlink.MAV_CMD_REQUEST_MESSAGE:
            got[msg.get_type()] = msg
        return len(got) == 2

    recv_until(conn, ["COMMAND_ACK", msg_type], both, timeout_s, f"COMMAND_ACK and {msg_type}")
    return got["COMMAND_ACK"], got[msg_type]
