"""The ground station's command and parameter clients (gcs/mavlink/commands.py, gcs/mavlink/params.py), with a number
for a clock.

Every message a client receives here went through pymavlink's packer and parser with the sender's system and
component ids in its header, as it would arrive from a drone; nothing is sent anywhere.
"""

from __future__ import annotations

import math
import struct
from typing import Any

import pytest
from pymavlink.dialects.v20 import common as mavlink

from gcs.mavlink.commands import (
    COMMAND_RETRIES,
    COMMAND_TIMEOUT_S,
    MAV_RESULT_CANCELLED,
    Ack,
    CommandClient,
    CommandInFlight,
    Send,
)
from gcs.mavlink.params import PARAM_RETRIES, PARAM_TIMEOUT_S, ParamClient, ParamInFlight, param_value
from gcs.mavlink.transport import GCS_COMPID, GCS_SYSID

ARM = mavlink.MAV_CMD_COMPONENT_ARM_DISARM
TAKEOFF = mavlink.MAV_CMD_NAV_TAKEOFF
ACCEPTED = mavlink.MAV_RESULT_ACCEPTED


def from_drone(msg: Any, sysid: int, compid: int = 1) -> Any:
    """``msg`` as a ground station receives it from system ``sysid``: packed with that header, then parsed."""
    encoder = mavlink.MAVLink(None, srcSystem=sysid, srcComponent=compid)
    parsed = mavlink.MAVLink(None).parse_buffer(msg.pack(encoder))
    assert parsed is not None and len(parsed) == 1
    return parsed[0]


def ack(sysid: int, command: int, result: int, *, to: tuple[int, int] = (GCS_SYSID, GCS_COMPID), progress: int = 0,
        compid: int = 1) -> Any:  # fmt: skip
    return from_drone(mavlink.MAVLink_command_ack_message(command, result, progress, 0, *to), sysid, compid)


def sent_confirmations(effects: list[Send]) -> list[tuple[int, int]]:
    return [(e.sysid, e.message.confirmation) for e in effects]


# ---- COMMAND_LONG ------------------------------------------------------------------------------------------------


def test_a_command_is_sent_at_once_to_its_target_with_every_param_and_ends_with_its_ack() -> None:
    client = CommandClient()
    effects = client.start(3, TAKEOFF, (0, 0, 0, math.nan, math.nan, math.nan, 491.0), now_s=10.0)
    [send] = effects
    msg = send.message
    assert (send.sysid, msg.target_system, msg.target_component, msg.command, msg.confirmation) == (3, 3, 1, TAKEOFF, 0)
    assert msg.param7 == 491.0 and math.isnan(msg.param4)
    assert client.take(3, TAKEOFF) is None  # still in flight
    assert client.next_due_s() == pytest.approx(10.0 + COMMAND_TIMEOUT_S)
    client.handle(ack(3, TAKEOFF, ACCEPTED), 10.1)
    assert client.take(3, TAKEOFF) == Ack(3, ACCEPTED)
    assert client.take(3, TAKEOFF) is None  # taken once
    assert client.next_due_s() == math.inf


def test_missing_params_are_zero() -> None:
    [send] = CommandClient().start(1, ARM, (1.0,), now_s=0.0)
    assert [send.message.param1, send.message.param2, send.message.param7] == [1.0, 0.0, 0.0]


def test_without_an_answer_it_is_resent_after_each_timeout_counting_confirmation_then_ends_with_no_answer() -> None:
    client = CommandClient()
    client.start(2, ARM, (1.0,), now_s=0.0)
    resends: list[tuple[int, int]] = []
    t = 0.0
    while client.take(2, ARM) is None:
        assert client.poll(client.next_due_s() - 1e-6) == []  # nothing before the try times out
        t = client.next_due_s()
        resends += sent_confirmations(client.poll(t))
    assert resends == [(2, n) for n in range(1, COMMAND_RETRIES + 1)]  # MAVSDK: three resends after the first try
    assert t == pytest.approx((COMMAND_RETRIES + 1) * COMMAND_TIMEOUT_S)
    client.start(2, ARM, (1.0,), now_s=t)  # and the same command may go again once it has ended
    assert client.in_flight(2, ARM)


def test_the_last_ack_of_a_resent_command_ends_it_whichever_try_it_answers() -> None:
    client = CommandClient()
    client.start(4, ARM, (1.0,), now_s=0.0)
    assert sent_confirmations(client.poll(COMMAND_TIMEOUT_S)) == [(4, 1)]
    client.handle(ack(4, ARM, ACCEPTED), 0.6)  # the answer to the first try, late: COMMAND_ACK cannot say which
    assert client.take(4, ARM) == Ack(4, ACCEPTED)
    assert client.poll(10.0) == []


@pytest.mark.parametrize(
    "result",
    [
        mavlink.MAV_RESULT_TEMPORARILY_REJECTED,
        mavlink.MAV_RESULT_DENIED,
        mavlink.MAV_RESULT_UNSUPPORTED,
        mavlink.MAV_RESULT_FAILED,
        MAV_RESULT_CANCELLED,
        mavlink.MAV_RESULT_COMMAND_INT_ONLY,
    ],
)
def test_a_refusal_is_an_answer_and_ends_the_command_without_retrying(result: int) -> None:
    client = CommandClient()
    client.start(1, ARM, (1.0,), now_s=0.0)
    client.handle(ack(1, ARM, result), 0.1)
    assert client.take(1, ARM) == Ack(1, result)
    assert not client.take(1, ARM)
    assert client.poll(100.0) == [] and client.next_due_s() == math.inf


def test_in_progress_stops_the_resends_for_what_the_retries_would_have_taken_then_the_final_ack_ends_it() -> None:
    client = CommandClient()
    client.start(1, TAKEOFF, now_s=0.0)
    client.handle(ack(1, TAKEOFF, mavlink.MAV_RESULT_IN_PROGRESS, progress=40), 0.2)
    assert client.take(1, TAKEOFF) is None
    assert client.next_due_s() == pytest.approx(0.2 + COMMAND_RETRIES * COMMAND_TIMEOUT_S)
    assert client.poll(1.0) == []  # where a plain timeout would have resent at 0.5
    client.handle(ack(1, TAKEOFF, ACCEPTED), 1.5)
    assert client.take(1, TAKEOFF) == Ack(1, ACCEPTED)


def test_in_progress_on_the_last_try_still_waits_one_more_timeout() -> None:
    client = CommandClient(retries=0)
    client.start(1, TAKEOFF, now_s=0.0)
    client.handle(ack(1, TAKEOFF, mavlink.MAV_RESULT_IN_PROGRESS), 0.4)
    assert client.poll(0.8) == [] and client.take(1, TAKEOFF) is None
    client.poll(0.4 + COMMAND_TIMEOUT_S)
    assert client.take(1, TAKEOFF) == Ack(1, None)


def test_acks_for_another_command_another_system_or_another_ground_station_are_ignored() -> None:
    client = CommandClient()
    client.start(5, ARM, (1.0,), now_s=0.0)
    for stray in (
        ack(5, TAKEOFF, ACCEPTED),  # another command
        ack(6, ARM, ACCEPTED),  # another drone
        ack(5, ARM, ACCEPTED, to=(254, GCS_COMPID)),  # addressed to another ground station
        ack(5, ARM, ACCEPTED, to=(GCS_SYSID, 191)),  # to another component of ours
        ack(5, ARM, ACCEPTED, compid=mavlink.MAV_COMP_ID_CAMERA),  # from another component of the drone
        from_drone(mavlink.MAVLink_heartbeat_message(2, 12, 0, 0, 3, 3), 5),  # not an ACK at all
    ):
        assert client.handle(stray, 0.1) == []
    assert client.take(5, ARM) is None and client.in_flight(5, ARM)
    client.handle(ack(5, ARM, ACCEPTED, to=(0, 0)), 0.2)  # an ACK addressed to nobody in particular counts
    assert client.take(5, ARM) == Ack(5, ACCEPTED)


def test_an_unknown_result_is_ignored_and_the_command_goes_on() -> None:
    client = CommandClient()
    client.start(1, ARM, (1.0,), now_s=0.0)
    client.handle(ack(1, ARM, 77), 0.1)
    assert client.in_flight(1, ARM)
    assert sent_confirmations(client.poll(COMMAND_TIMEOUT_S)) == [(1, 1)]


def test_a_duplicate_ack_after_the_end_changes_nothing() -> None:
    client = CommandClient()
    client.start(1, ARM, (1.0,), now_s=0.0)
    client.handle(ack(1, ARM, ACCEPTED), 0.1)
    client.handle(ack(1, ARM, mavlink.MAV_RESULT_DENIED), 0.2)  # a second answer, to a resend
    assert client.take(1, ARM) == Ack(1, ACCEPTED)
    assert client.take(1, ARM) is None


def test_several_drones_in_flight_at_once_each_answered_out_of_order_or_not_at_all() -> None:
    # GIVEN arming sent to three drones and a takeoff to a fourth, all at t=0
    client = CommandClient()
    for sysid in (1, 2, 3):
        client.start(sysid, ARM, (1.0,), now_s=0.0)
    client.start(1, TAKEOFF, now_s=0.0)
    # WHEN drone 3 answers first, drone 2 refuses, drone 1 answers its takeoff but never its arming
    client.handle(ack(3, ARM, ACCEPTED), 0.05)
    client.handle(ack(2, ARM, mavlink.MAV_RESULT_DENIED), 0.1)
    client.handle(ack(1, TAKEOFF, ACCEPTED), 0.2)
    # THEN only drone 1's arming is resent, with its own count, until it ends with no answer
    assert sent_confirmations(client.poll(COMMAND_TIMEOUT_S)) == [(1, 1)]
    assert client.take(3, ARM) == Ack(3, ACCEPTED)
    assert client.take(2, ARM) == Ack(2, mavlink.MAV_RESULT_DENIED)
    assert client.take(1, TAKEOFF) == Ack(1, ACCEPTED)
    while client.take(1, ARM) is None:
        client.poll(client.next_due_s())
    assert client.next_due_s() == math.inf


def test_the_same_command_to_the_same_drone_twice_at_once_is_our_own_mistake() -> None:
    client = CommandClient()
    client.start(1, ARM, (1.0,), now_s=0.0)
    with pytest.raises(CommandInFlight):
        client.start(1, ARM, (0.0,), now_s=0.1)
    client.start(2, ARM, (1.0,), now_s=0.1)  # another drone is fine


def test_a_cancelled_command_is_not_resent_its_late_ack_is_ignored_and_it_may_start_again() -> None:
    client = CommandClient()
    client.start(1, ARM, (1.0,), now_s=0.0)
    client.cancel(1, ARM)
    assert client.poll(10.0) == [] and client.next_due_s() == math.inf
    client.handle(ack(1, ARM, ACCEPTED), 0.1)
    assert client.take(1, ARM) is None
    client.start(1, ARM, (1.0,), now_s=0.2)


# ---- parameters --------------------------------------------------------------------------------------------------


def echo(sysid: int, name: str, value: float, param_type: int = mavlink.MAV_PARAM_TYPE_REAL32) -> Any:
    return from_drone(mavlink.MAVLink_param_value_message(name.encode(), value, param_type, 300, 7), sysid)


def int_echo(sysid: int, name: str, value: int) -> Any:
    """An INT32 echo as PX4 sends it: the integer's bytes in the float field."""
    bits = struct.unpack("<f", struct.pack("<i", value))[0]
    return echo(sysid, name, bits, mavlink.MAV_PARAM_TYPE_INT32)


def test_a_set_is_confirmed_by_the_echo_of_its_value() -> None:
    client = ParamClient()
    [send] = client.start(2, "MPC_XY_VEL_MAX", 4.5, now_s=0.0)
    assert (send.sysid, send.message.param_id, send.message.param_value) == (2, "MPC_XY_VEL_MAX", 4.5)
    client.handle(echo(2, "MPC_XY_VEL_MAX", 4.5), 0.1)
    result = client.take(2, "MPC_XY_VEL_MAX")
    assert result is not None and result.ok and not result.refused and result.kept == 4.5


def test_an_integer_travels_bytewise_and_is_confirmed_bytewise() -> None:
    client = ParamClient()
    [send] = client.start(1, "SYS_FAILURE_EN", 1, now_s=0.0)
    assert send.message.param_type == mavlink.MAV_PARAM_TYPE_INT32
    msg = int_echo(1, "SYS_FAILURE_EN", 1)
    assert param_value(msg) == 1.0
    client.handle(msg, 0.1)
    result = client.take(1, "SYS_FAILURE_EN")
    assert result is not None and result.ok


def test_an_echo_of_another_value_is_sent_again_at_once_and_after_every_retry_the_set_is_refused() -> None:
    # GIVEN a drone that keeps its old value (PX4 echoes the stored value when it refuses one)
    client = ParamClient()
    client.start(1, "MPC_XY_VEL_MAX", 99.0, now_s=0.0)
    resent = 0
    for k in range(PARAM_RETRIES + 1):
        resent += len(client.handle(echo(1, "MPC_XY_VEL_MAX", 12.0), 0.01 * (k + 1)))
    # THEN it was sent again (the echo might have been a stale one) until the retries ran out: refused
    assert resent == PARAM_RETRIES
    result = client.take(1, "MPC_XY_VEL_MAX")
    assert result is not None and result.refused and result.kept == 12.0


def test_a_stale_echo_then_the_right_one_is_a_success() -> None:
    client = ParamClient()
    client.start(1, "MPC_XY_VEL_MAX", 5.0, now_s=0.0)
    assert len(client.handle(echo(1, "MPC_XY_VEL_MAX", 12.0), 0.1)) == 1
    client.handle(echo(1, "MPC_XY_VEL_MAX", 5.0), 0.2)
    result = client.take(1, "MPC_XY_VEL_MAX")
    assert result is not None and result.ok


def test_no_echo_is_retried_per_timeout_then_ends_with_no_answer() -> None:
    client = ParamClient()
    client.start(3, "NO_SUCH_PARAM", 1.0, now_s=0.0)
    sends = 0
    while client.take(3, "NO_SUCH_PARAM") is None:
        assert client.poll(client.next_due_s() - 1e-6) == []
        sends += len(client.poll(client.next_due_s()))
    assert sends == PARAM_RETRIES


def test_a_read_asks_by_name_is_retried_without_an_answer_and_ends_with_whatever_value_comes() -> None:
    # GIVEN a read of MIS_TAKEOFF_ALT (None for the value): PARAM_REQUEST_READ by name (index -1) to the autopilot
    client = ParamClient()
    [send] = client.start(2, "MIS_TAKEOFF_ALT", None, now_s=0.0)
    assert send.message.get_type() == "PARAM_REQUEST_READ"
    assert (send.message.target_system, send.message.param_id, send.message.param_index) == (2, "MIS_TAKEOFF_ALT", -1)
    # WHEN the first try goes unanswered THEN it is asked again, the same way
    [again] = client.poll(client.next_due_s())
    assert again.message.get_type() == "PARAM_REQUEST_READ"
    # WHEN the value comes THEN the read ends with it, whatever it is
    client.handle(echo(2, "MIS_TAKEOFF_ALT", 2.5), 1.1)
    result = client.take(2, "MIS_TAKEOFF_ALT")
    assert result is not None and result.ok and not result.refused and result.kept == 2.5


def test_echoes_of_other_names_or_drones_do_not_count_and_several_drones_are_set_at_once() -> None:
    client = ParamClient()
    for sysid in (1, 2):
        client.start(sysid, "MPC_XY_VEL_MAX", 5.0, now_s=0.0)
    client.handle(echo(3, "MPC_XY_VEL_MAX", 5.0), 0.1)  # a drone that is not being set
    client.handle(echo(1, "MPC_Z_VEL_MAX_UP", 5.0), 0.1)  # another parameter
    client.handle(echo(2, "MPC_XY_VEL_MAX", 5.0), 0.2)
    assert client.take(1, "MPC_XY_VEL_MAX") is None
    result = client.take(2, "MPC_XY_VEL_MAX")
    assert result is not None and result.ok
    assert len(client.poll(PARAM_TIMEOUT_S)) == 1  # only drone 1 is sent again
    with pytest.raises(ParamInFlight):
        client.start(1, "MPC_XY_VEL_MAX", 6.0, now_s=1.0)
    client.cancel(1, "MPC_XY_VEL_MAX")
    assert client.poll(100.0) == []
    client.start(1, "MPC_XY_VEL_MAX", 6.0, now_s=1.0)


def test_a_command_in_a_frame_goes_as_command_int_with_integer_coordinates_and_is_retried_the_same() -> None:
    client = CommandClient()
    # GIVEN a land command at a point, in the global frame
    (first,) = client.start(7, mavlink.MAV_CMD_NAV_LAND, (0, 0, 0, math.nan, 473977123.0, 85455941.0, math.nan),
                            0.0, frame=mavlink.MAV_FRAME_GLOBAL)  # fmt: skip
    # THEN it leaves as COMMAND_INT, the point in degE7 to the unit
    msg = first.message
    assert msg.get_type() == "COMMAND_INT" and msg.frame == mavlink.MAV_FRAME_GLOBAL
    assert (msg.x, msg.y) == (473977123, 85455941) and msg.target_system == 7
    # AND a timeout resends the same COMMAND_INT (it has no confirmation count to raise)
    (again,) = client.poll(COMMAND_TIMEOUT_S + 0.01)
    assert again.message.get_type() == "COMMAND_INT" and (again.message.x, again.message.y) == (473977123, 85455941)
    # AND its COMMAND_ACK ends it as any other
    client.handle(from_drone(mavlink.MAVLink_command_ack_message(mavlink.MAV_CMD_NAV_LAND, ACCEPTED, 0, 0, GCS_SYSID,
                                                                 GCS_COMPID), 7), 1.0)  # fmt: skip
    assert client.take(7, mavlink.MAV_CMD_NAV_LAND) == Ack(7, ACCEPTED)
