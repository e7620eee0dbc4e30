"""What fuzzing a flying drone found (bench/fuzz.py, docs/reliability.md), each pinned where it was fixed.

Each test replays the shortest sequence of wire messages that broke the drone through a complete ``LinkServices``,
and packs every reply the way the IO shell does: a reply that cannot be packed is a traceback in the drone's log.
"""

from __future__ import annotations

from typing import Any

from pymavlink.dialects.v20 import common as mavlink

from sitl.drone.param_table import build_param_store
from sitl.protocol import Identity, LinkServices
from sitl.protocol.core import Effect
from sitl.protocol.testing import FakeVehicle

SYSID = 1
CLIENT = (255, 190)
FLOAT32_MAX = 3.4028234663852886e38


def make_link() -> LinkServices:
    return LinkServices(Identity(sysid=SYSID), FakeVehicle(), build_param_store())


def send(link: LinkServices, msg: Any, now_s: float = 1.0) -> list[Any]:
    """``msg`` through pymavlink's encoder and parser into the link; its replies, each packed as the shell packs."""
    encoder = mavlink.MAVLink(None, srcSystem=CLIENT[0], srcComponent=CLIENT[1])
    parser = mavlink.MAVLink(None)
    (received,) = parser.parse_buffer(msg.pack(encoder))
    effects: list[Effect] = link.handle(received, now_s)
    replies = [effect.msg for effect in effects]
    for reply in replies:
        reply.pack(mavlink.MAVLink(None, srcSystem=SYSID, srcComponent=1))  # raises what the shell would log
    return replies


def acks(replies: list[Any]) -> list[int]:
    return [m.result for m in replies if m.get_type() == "COMMAND_ACK"]


def command_long(command: int, *params: float) -> Any:
    p = [*params, *([0.0] * (7 - len(params)))]
    return mavlink.MAVLink_command_long_message(SYSID, 1, command, 0, *p)


# ---- SET_MESSAGE_INTERVAL beyond what MESSAGE_INTERVAL can report ------------------------------------------------


def reported_interval_us(link: LinkServices, msg_id: int) -> int:
    replies = send(link, command_long(mavlink.MAV_CMD_GET_MESSAGE_INTERVAL, float(msg_id)))
    assert acks(replies) == [mavlink.MAV_RESULT_ACCEPTED]
    (interval,) = [m for m in replies if m.get_type() == "MESSAGE_INTERVAL"]
    return int(interval.interval_us)


def test_an_interval_message_interval_cannot_report_is_denied_and_get_message_interval_still_packs() -> None:
    # GIVEN a drone WHEN a client sets SYS_STATUS's interval to float32's largest value (some 10^32 s), which the
    # int32 interval_us of MESSAGE_INTERVAL cannot carry
    link = make_link()
    sys_status = mavlink.MAVLINK_MSG_ID_SYS_STATUS
    before_us = reported_interval_us(link, sys_status)
    replies = send(link, command_long(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, float(sys_status), FLOAT32_MAX))

    # THEN it is refused as an invalid parameter, and the stream keeps its rate (reported in a MESSAGE_INTERVAL
    # that packs: before the fix the set was accepted and this reply raised struct.error in the IO shell)
    assert acks(replies) == [mavlink.MAV_RESULT_DENIED]
    assert reported_interval_us(link, sys_status) == before_us > 0


def test_the_longest_interval_message_interval_can_report_is_accepted_and_reported() -> None:
    link = make_link()
    sys_status = mavlink.MAVLINK_MSG_ID_SYS_STATUS
    longest_us = float(2**31 - 128)  # the largest float32 below 2^31
    replies = send(link, command_long(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, float(sys_status), longest_us))
    assert acks(replies) == [mavlink.MAV_RESULT_ACCEPTED]
    assert reported_interval_us(link, sys_status) == 2**31 - 128


# ---- the heartbeat cannot be slowed or switched off ---------------------------------------------------------------


def test_the_heartbeat_interval_cannot_be_changed_as_px4_refuses_it() -> None:
    # GIVEN a drone WHEN a client asks for its HEARTBEAT off (-1), once an hour, or at 50 Hz
    link = make_link()
    heartbeat = float(mavlink.MAVLINK_MSG_ID_HEARTBEAT)
    for interval_us in (-1.0, 3.6e9, 20_000.0, 0.0):
        replies = send(link, command_long(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, heartbeat, interval_us))
        # THEN PX4's answer comes back (FAILED), and the heartbeat keeps its 1 Hz
        assert acks(replies) == [mavlink.MAV_RESULT_FAILED]
    assert reported_interval_us(link, mavlink.MAVLINK_MSG_ID_HEARTBEAT) == 1_000_000
    sent = [effect.msg for k in range(300) for effect in link.poll(1.0 + k * 0.01)]
    assert 2 <= sum(m.get_type() == "HEARTBEAT" for m in sent) <= 4  # 3 s at 1 Hz
