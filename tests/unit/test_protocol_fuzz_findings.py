"""What fuzzing a flying drone found (bench/fuzz.py, docs/reliability.md), each pinned where it was fixed.

Each test replays the shortest sequence of wire messages that broke the drone through a complete ``LinkServices``,
and packs every reply the way the IO shell does: a reply that cannot be packed is a traceback in the drone's log.
"""

from __future__ import annotations

from typing import Any

from pymavlink.dialects.v20 import common as mavlink

from sitl.protocol import Identity, LinkServices
from sitl.protocol.core import Effect
from sitl.protocol.testing import FakeVehicle
from sitl.simulation import build_param_store

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


def test_an_interval_message_interval_cannot_report_is_denied_and_get_message_interval_still_packs() -> None:
    # GIVEN a drone WHEN a client sets HEARTBEAT's interval to float32's largest value (some 10^32 s), which the
    # int32 interval_us of MESSAGE_INTERVAL cannot carry
    link = make_link()
    heartbeat = float(mavlink.MAVLINK_MSG_ID_HEARTBEAT)
    replies = send(link, command_long(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, heartbeat, FLOAT32_MAX))

    # THEN it is refused as an invalid parameter, and the stream keeps its rate
    assert acks(replies) == [mavlink.MAV_RESULT_DENIED]
    replies = send(link, command_long(mavlink.MAV_CMD_GET_MESSAGE_INTERVAL, heartbeat))
    (interval,) = [m for m in replies if m.get_type() == "MESSAGE_INTERVAL"]
    assert interval.interval_us == 1_000_000
    assert acks(replies) == [mavlink.MAV_RESULT_ACCEPTED]


def test_the_longest_interval_message_interval_can_report_is_accepted_and_reported() -> None:
    link = make_link()
    heartbeat = float(mavlink.MAVLINK_MSG_ID_HEARTBEAT)
    longest_us = float(2**31 - 128)  # the largest float32 below 2^31
    assert acks(send(link, command_long(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, heartbeat, longest_us))) == [
        mavlink.MAV_RESULT_ACCEPTED
    ]
    replies = send(link, command_long(mavlink.MAV_CMD_GET_MESSAGE_INTERVAL, heartbeat))
    (interval,) = [m for m in replies if m.get_type() == "MESSAGE_INTERVAL"]
    assert interval.interval_us == 2**31 - 128
