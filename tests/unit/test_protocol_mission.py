"""The mission server against clients built from pymavlink messages: uploads, downloads, losses and timeouts."""

from __future__ import annotations

import math
from collections.abc import Callable

import pytest
from pymavlink.dialects.v20 import common as mavlink

from sitl.autopilot.vehicle_api import CommandResult, MissionItem, SetMission, SetMissionCurrent
from sitl.protocol.core import Identity, MAVLinkMessage
from sitl.protocol.mission import (
    MISSION_IDLE_TIMEOUT_S,
    MISSION_MAX_RETRIES,
    MISSION_RETRY_TIMEOUT_S,
    MissionServer,
    TransferState,
)
from sitl.protocol.testing import FakeVehicle, Wire, of_type

NAN = math.nan
SYSID = 1
CLIENT = (245, 190)
ACCEPTED = mavlink.MAV_MISSION_ACCEPTED
REL_INT = mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT


def waypoint(seq: int, lat_e7: int = 473977420, lon_e7: int = 85455940, alt: float = 10.0) -> MAVLinkMessage:
    """A MISSION_ITEM_INT as MAVSDK uploads a waypoint (yaw NaN, acceptance radius 1 m)."""
    return mavlink.MAVLink_mission_item_int_message(
        SYSID, 1, seq, REL_INT, mavlink.MAV_CMD_NAV_WAYPOINT, int(seq == 0), 1, 0.0, 1.0, 0.0, NAN,
        lat_e7 + 1000 * seq, lon_e7 + 1000 * seq, alt, 0
    )  # fmt: skip


def speed_item(seq: int) -> MAVLinkMessage:
    """DO_CHANGE_SPEED in MAV_FRAME_MISSION, as MAVSDK inserts it."""
    return mavlink.MAVLink_mission_item_int_message(
        SYSID,
        1,
        seq,
        mavlink.MAV_FRAME_MISSION,
        mavlink.MAV_CMD_DO_CHANGE_SPEED,
        0,
        1,
        1.0,
        5.0,
        -1.0,
        0.0,
        0,
        0,
        NAN,
        0,
    )


class Harness:
    """A mission server, a fake vehicle, a fake clock and a lossy two-way wire with a pymavlink client end."""

    def __init__(self, vehicle: FakeVehicle | None = None) -> None:
        self.vehicle = vehicle or FakeVehicle()
        self.server = MissionServer(Identity(sysid=SYSID), self.vehicle)
        self.up = Wire(*CLIENT)
        self.down = Wire(SYSID, 1)
        self.now_s = 100.0
        self.drop_down: Callable[[MAVLinkMessage], bool] = lambda m: False

    def send(self, msg: MAVLinkMessage, *, wire: Wire | None = None) -> list[MAVLinkMessage]:
        self.now_s += 0.001
        out = self.down.carry(self.server.handle((wire or self.up)(msg), self.now_s))
        return [m for m in out if not self.drop_down(m)]

    def wait(self, seconds: float, step_s: float = 0.05) -> list[MAVLinkMessage]:
        out: list[MAVLinkMessage] = []
        end = self.now_s + seconds
        while self.now_s < end:
            self.now_s += step_s
            out += [m for m in self.down.carry(self.server.poll(self.now_s)) if not self.drop_down(m)]
        return out

    # ---- a MAVSDK-like client ------------------------------------------------------------------------------
    def upload(self, items: list[MAVLinkMessage], mission_type: int = 0) -> int | None:
        """Upload as MAVSDK does: answer each request with the item it names, until MISSION_ACK."""
        inbox = self.send(mavlink.MAVLink_mission_count_message(SYSID, 1, len(items), mission_type))
        for _ in range(10 * len(items) + 20):
            if not inbox:
                inbox = self.wait(MISSION_RETRY_TIMEOUT_S)
                if not inbox:
                    return None
            msg = inbox.pop(0)
            if msg.get_type() == "MISSION_ACK":
                return int(msg.type)
            if msg.get_type() in ("MISSION_REQUEST_INT", "MISSION_REQUEST"):
                inbox += self.send(items[msg.seq])
        raise AssertionError("upload did not finish")

    def download(self, mission_type: int = 0, *, use_int: bool = True) -> list[MAVLinkMessage]:
        """Download as MAVSDK does (or as a classic float client with ``use_int=False``)."""
        (count,) = of_type(
            self.send(mavlink.MAVLink_mission_request_list_message(SYSID, 1, mission_type)), "MISSION_COUNT"
        )
        request = mavlink.MAVLink_mission_request_int_message if use_int else mavlink.MAVLink_mission_request_message
        items = []
        for seq in range(count.count):
            (item,) = self.send(request(SYSID, 1, seq, mission_type))
            items.append(item)
        self.send(mavlink.MAVLink_mission_ack_message(SYSID, 1, ACCEPTED, mission_type))
        return items


def stored(h: Harness) -> list[MissionItem]:
    return list(h.vehicle.mission_items())


# ---- uploads -----------------------------------------------------------------------------------------------
def test_full_upload_then_download_returns_exactly_what_was_uploaded() -> None:
    # GIVEN a MAVSDK-style mission: waypoints with NaN yaw and a DO_CHANGE_SPEED in the MISSION frame
    h = Harness()
    items = [waypoint(0), speed_item(1), waypoint(2), waypoint(3, alt=25.5)]
    # WHEN uploaded
    assert h.upload(items) == ACCEPTED
    # THEN the vehicle got the whole list in one SetMission, and the server is idle again
    assert [type(r) for r in h.vehicle.requests] == [SetMission]
    assert [i.command for i in stored(h)] == [16, 178, 16, 16]
    assert stored(h)[3].z == 25.5 and stored(h)[3].lat_deg == pytest.approx(47.3980420)
    assert h.server.state is TransferState.IDLE
    # WHEN downloaded  THEN every field comes back as sent
    back = h.download()
    for sent, got in zip(items, back, strict=True):
        for name in ("seq", "frame", "command", "autocontinue", "x", "y", "mission_type"):
            assert getattr(got, name) == getattr(sent, name)
        for name in ("param1", "param2", "param3", "param4", "z"):
            a, b = getattr(got, name), getattr(sent, name)
            assert (math.isnan(a) and math.isnan(b)) or a == b
    assert [i.current for i in back] == [1, 0, 0, 0]
    assert h.server.state is TransferState.IDLE


def test_lost_requests_are_repeated_until_the_upload_completes() -> None:
    # GIVEN a link that drops every second MISSION_REQUEST_INT
    h = Harness()
    dropped = {"n": 0}

    def drop_every_second(msg: MAVLinkMessage) -> bool:
        if msg.get_type() != "MISSION_REQUEST_INT":
            return False
        dropped["n"] += 1
        return dropped["n"] % 2 == 0

    h.drop_down = drop_every_second
    # WHEN uploading  THEN the retry timer recovers every loss
    assert h.upload([waypoint(i) for i in range(5)]) == ACCEPTED
    assert len(stored(h)) == 5


def test_a_client_that_vanishes_mid_upload_is_given_up_after_the_retries_and_the_state_is_clean() -> None:
    # GIVEN an upload of 3 items whose client never answers
    h = Harness()
    first = h.send(mavlink.MAVLink_mission_count_message(SYSID, 1, 3, 0))
    assert [(m.get_type(), m.seq) for m in first] == [("MISSION_REQUEST_INT", 0)]
    # WHEN time passes
    out = h.wait(MISSION_RETRY_TIMEOUT_S * (MISSION_MAX_RETRIES + 2))
    # THEN exactly MISSION_MAX_RETRIES repeats, then a cancelling MISSION_ACK and a STATUSTEXT, then silence
    assert [m.seq for m in of_type(out, "MISSION_REQUEST_INT")] == [0] * MISSION_MAX_RETRIES
    (ack,) = of_type(out, "MISSION_ACK")
    assert ack.type == mavlink.MAV_MISSION_OPERATION_CANCELLED
    assert (ack.target_system, ack.target_component) == CLIENT
    assert of_type(out, "STATUSTEXT")
    assert h.server.state is TransferState.IDLE
    assert h.vehicle.requests == []
    # AND a later upload works normally
    assert h.upload([waypoint(0)]) == ACCEPTED


def test_duplicate_and_out_of_sequence_items_are_tolerated() -> None:
    h = Harness()
    h.send(mavlink.MAVLink_mission_count_message(SYSID, 1, 3, 0))
    assert [m.seq for m in h.send(waypoint(0))] == [1]
    assert h.send(waypoint(0)) == []  # duplicate: ignored
    assert h.send(waypoint(2)) == []  # out of sequence: ignored
    assert [m.seq for m in h.wait(MISSION_RETRY_TIMEOUT_S + 0.05)] == [1]  # the timer asks again
    assert [m.seq for m in h.send(waypoint(1))] == [2]
    assert [m.type for m in h.send(waypoint(2))] == [ACCEPTED]
    assert len(stored(h)) == 3


def test_count_zero_clears_the_mission() -> None:
    h = Harness()
    h.upload([waypoint(0), waypoint(1)])
    assert h.upload([]) == ACCEPTED
    assert stored(h) == []


def test_too_many_items_is_no_space() -> None:
    h = Harness()
    (ack,) = h.send(mavlink.MAVLink_mission_count_message(SYSID, 1, 60000, 0))
    assert ack.type == mavlink.MAV_MISSION_NO_SPACE
    assert h.server.state is TransferState.IDLE


@pytest.mark.parametrize(
    ("bad_item", "code"),
    [
        (waypoint(1, lat_e7=950_000_000), mavlink.MAV_MISSION_INVALID_PARAM5_X),
        (waypoint(1, lon_e7=1_900_000_000), mavlink.MAV_MISSION_INVALID_PARAM6_Y),
        (waypoint(1, alt=NAN), mavlink.MAV_MISSION_INVALID_PARAM7),
        (
            mavlink.MAVLink_mission_item_int_message(
                SYSID, 1, 1, mavlink.MAV_FRAME_LOCAL_NED, 16, 0, 1, 0, 0, 0, 0, 10, 10, -5, 0
            ),
            mavlink.MAV_MISSION_UNSUPPORTED_FRAME,
        ),
        (
            mavlink.MAVLink_mission_item_int_message(SYSID, 1, 1, 2, 31337, 0, 1, 0, 0, 0, 0, 0, 0, 0, 0),
            mavlink.MAV_MISSION_UNSUPPORTED,
        ),
    ],
)
def test_an_invalid_item_aborts_the_upload_with_its_error_code(bad_item: MAVLinkMessage, code: int) -> None:
    # GIVEN an existing mission  WHEN an upload carries an invalid item  THEN that item's error, old mission kept
    h = Harness()
    h.upload([waypoint(0)])
    h.vehicle.requests.clear()
    assert h.upload([waypoint(0), bad_item, waypoint(2)]) == code
    assert h.server.state is TransferState.IDLE
    assert h.vehicle.requests == []
    assert len(stored(h)) == 1


def test_vehicle_refusing_the_mission_is_reported_as_denied_with_the_reason() -> None:
    h = Harness()
    h.vehicle.refuse(SetMission, CommandResult.DENIED, "Mission rejected: too far from home")
    h.send(mavlink.MAVLink_mission_count_message(SYSID, 1, 1, 0))
    out = h.send(waypoint(0))
    assert [m.type for m in of_type(out, "MISSION_ACK")] == [mavlink.MAV_MISSION_DENIED]
    assert of_type(out, "STATUSTEXT")[0].text == "Mission rejected: too far from home"


def test_a_repeated_last_item_after_completion_is_acknowledged_again() -> None:
    # GIVEN a finished upload whose final ACK the client missed
    h = Harness()
    h.upload([waypoint(0), waypoint(1)])
    # WHEN the client repeats the last item  THEN the same result again, the vehicle is not asked twice
    (ack,) = h.send(waypoint(1))
    assert ack.type == ACCEPTED
    assert len(h.vehicle.requests) == 1
    # AND an item out of the blue is an error
    (err,) = h.send(waypoint(0))
    assert err.type == mavlink.MAV_MISSION_ERROR


def test_client_cancel_mid_upload_leaves_idle_state() -> None:
    h = Harness()
    h.send(mavlink.MAVLink_mission_count_message(SYSID, 1, 3, 0))
    h.send(waypoint(0))
    h.send(mavlink.MAVLink_mission_ack_message(SYSID, 1, mavlink.MAV_MISSION_OPERATION_CANCELLED, 0))
    assert h.server.state is TransferState.IDLE
    assert h.wait(5.0) == []


def test_the_same_client_restarting_an_upload_is_followed() -> None:
    h = Harness()
    h.send(mavlink.MAVLink_mission_count_message(SYSID, 1, 3, 0))
    h.send(waypoint(0))
    assert h.upload([waypoint(0), waypoint(1)]) == ACCEPTED
    assert len(stored(h)) == 2


def test_a_repeated_count_before_any_item_repeats_the_first_request() -> None:
    h = Harness()
    h.send(mavlink.MAVLink_mission_count_message(SYSID, 1, 2, 0))
    again = h.send(mavlink.MAVLink_mission_count_message(SYSID, 1, 2, 0))
    assert [(m.get_type(), m.seq) for m in again] == [("MISSION_REQUEST_INT", 0)]


def test_another_client_cannot_barge_into_an_upload() -> None:
    h = Harness()
    h.send(mavlink.MAVLink_mission_count_message(SYSID, 1, 2, 0))
    other = Wire(200, 1)
    out = h.send(mavlink.MAVLink_mission_count_message(SYSID, 1, 5, 0), wire=other)
    (ack,) = of_type(out, "MISSION_ACK")
    assert (ack.type, ack.target_system) == (mavlink.MAV_MISSION_ERROR, 200)
    assert h.send(waypoint(0), wire=other) == []
    assert [m.seq for m in h.send(waypoint(0))] == [1]


def test_float_items_from_a_classic_pymavlink_script_are_accepted_and_followed() -> None:
    # GIVEN a client that answers MISSION_REQUEST_INT with a float MISSION_ITEM
    h = Harness()
    h.send(mavlink.MAVLink_mission_count_message(SYSID, 1, 2, 0))
    item0 = mavlink.MAVLink_mission_item_message(SYSID, 1, 0, 3, 16, 1, 1, 0, 0, 0, 0, 47.3978, 8.5456, 10.0, 0)
    # THEN the server switches to MISSION_REQUEST, as PX4 does
    (req,) = h.send(item0)
    assert (req.get_type(), req.seq) == ("MISSION_REQUEST", 1)
    item1 = mavlink.MAVLink_mission_item_message(SYSID, 1, 1, 3, 16, 0, 1, 0, 0, 0, 0, 47.3980, 8.5460, 12.0, 0)
    assert h.send(item1)[0].type == ACCEPTED
    assert stored(h)[1].lat_deg == pytest.approx(47.3980, abs=1e-5)


def test_float_items_with_unused_nan_coordinates_are_fine_unless_they_fly_somewhere() -> None:
    # GIVEN float items: a DO_CHANGE_SPEED without coordinates, then a waypoint without a latitude
    h = Harness()
    h.send(mavlink.MAVLink_mission_count_message(SYSID, 1, 2, 0))
    speed = mavlink.MAVLink_mission_item_message(SYSID, 1, 0, 2, 178, 1, 1, 1, 5, -1, 0, NAN, NAN, NAN, 0)
    wp = mavlink.MAVLink_mission_item_message(SYSID, 1, 1, 3, 16, 0, 1, 0, 0, 0, 0, NAN, 8.5, 10.0, 0)
    # THEN the first is taken, the second refused for its x (param5)
    assert [m.seq for m in h.send(speed)] == [1]
    assert of_type(h.send(wp), "MISSION_ACK")[0].type == mavlink.MAV_MISSION_INVALID_PARAM5_X


def test_a_client_refusing_int_gets_float_requests() -> None:
    h = Harness()
    h.send(mavlink.MAVLink_mission_count_message(SYSID, 1, 1, 0))
    (req,) = h.send(mavlink.MAVLink_mission_ack_message(SYSID, 1, mavlink.MAV_MISSION_UNSUPPORTED, 0))
    assert req.get_type() == "MISSION_REQUEST"


# ---- rally (fences: tests/unit/test_fence_upload.py) -------------------------------------------------------
def test_rally_is_empty_and_refused_properly() -> None:
    h = Harness()
    mission_type = mavlink.MAV_MISSION_TYPE_RALLY
    fence_item = mavlink.MAVLink_mission_item_int_message(SYSID, 1, 0, 5, 5100, 0, 1, 0, 0, 0, 0, 1, 1, 0, mission_type)
    assert h.upload([fence_item], mission_type) == mavlink.MAV_MISSION_UNSUPPORTED
    assert h.upload([], mission_type) == ACCEPTED
    assert h.download(mission_type) == []
    (ack,) = h.send(mavlink.MAVLink_mission_clear_all_message(SYSID, 1, mission_type))
    assert (ack.type, ack.mission_type) == (ACCEPTED, mission_type)
    assert h.vehicle.requests == []


def test_unknown_mission_type_is_unsupported() -> None:
    h = Harness()
    (ack,) = h.send(mavlink.MAVLink_mission_request_list_message(SYSID, 1, 7))
    assert ack.type == mavlink.MAV_MISSION_UNSUPPORTED


# ---- downloads ---------------------------------------------------------------------------------------------
def test_float_download_for_classic_clients_gives_degrees() -> None:
    h = Harness()
    h.upload([waypoint(0), speed_item(1)])
    items = h.download(use_int=False)
    assert [m.get_type() for m in items] == ["MISSION_ITEM", "MISSION_ITEM"]
    assert items[0].x == pytest.approx(47.397742, abs=1e-5)
    assert items[1].param2 == 5.0


def test_empty_mission_download_is_count_zero() -> None:
    h = Harness()
    assert h.download() == []
    assert h.server.state is TransferState.IDLE


def test_a_download_whose_client_vanishes_is_dropped_after_the_idle_timeout() -> None:
    h = Harness()
    h.upload([waypoint(0), waypoint(1)])
    h.send(mavlink.MAVLink_mission_request_list_message(SYSID, 1, 0))
    h.send(mavlink.MAVLink_mission_request_int_message(SYSID, 1, 0, 0))
    assert h.server.state is TransferState.SENDING
    out = h.wait(MISSION_IDLE_TIMEOUT_S + 0.1)
    assert h.server.state is TransferState.IDLE
    assert of_type(out, "STATUSTEXT")


def test_a_request_beyond_the_list_aborts_the_download() -> None:
    h = Harness()
    h.upload([waypoint(0)])
    h.send(mavlink.MAVLink_mission_request_list_message(SYSID, 1, 0))
    out = h.send(mavlink.MAVLink_mission_request_int_message(SYSID, 1, 4, 0))
    assert of_type(out, "MISSION_ACK")[0].type == mavlink.MAV_MISSION_ERROR
    assert h.server.state is TransferState.IDLE


def test_an_upload_right_after_a_download_whose_ack_was_lost_works() -> None:
    h = Harness()
    h.upload([waypoint(0)])
    h.send(mavlink.MAVLink_mission_request_list_message(SYSID, 1, 0))
    h.send(mavlink.MAVLink_mission_request_int_message(SYSID, 1, 0, 0))  # ... and the client's ACK is lost
    assert h.upload([waypoint(0), waypoint(1)]) == ACCEPTED


def test_requests_without_a_transfer_are_ignored_silently() -> None:
    h = Harness()
    assert h.send(mavlink.MAVLink_mission_request_int_message(SYSID, 1, 0, 0)) == []
    assert h.send(mavlink.MAVLink_mission_ack_message(SYSID, 1, ACCEPTED, 0)) == []


# ---- clear and set current ---------------------------------------------------------------------------------
def test_clear_all() -> None:
    h = Harness()
    h.upload([waypoint(0)])
    (ack,) = h.send(mavlink.MAVLink_mission_clear_all_message(SYSID, 1, 0))
    assert ack.type == ACCEPTED
    assert stored(h) == []


def test_set_current_is_answered_with_mission_current_as_mavsdk_waits_for() -> None:
    h = Harness()
    h.upload([waypoint(0), waypoint(1), waypoint(2)])
    (current,) = h.send(mavlink.MAVLink_mission_set_current_message(SYSID, 1, 2))
    assert (current.get_type(), current.seq, current.total) == ("MISSION_CURRENT", 2, 3)
    assert h.vehicle.requests[-1] == SetMissionCurrent(seq=2)


def test_set_current_refused_explains_why() -> None:
    h = Harness()
    h.vehicle.refuse(SetMissionCurrent, CommandResult.DENIED, "WPM: WP CURR CMD: Not in list")
    out = h.send(mavlink.MAVLink_mission_set_current_message(SYSID, 1, 9))
    assert [m.get_type() for m in out] == ["STATUSTEXT"]


def test_set_current_during_an_upload_is_busy() -> None:
    h = Harness()
    h.send(mavlink.MAVLink_mission_count_message(SYSID, 1, 2, 0))
    out = h.send(mavlink.MAVLink_mission_set_current_message(SYSID, 1, 0))
    assert [m.get_type() for m in out] == ["STATUSTEXT"]
    assert h.server.state is TransferState.RECEIVING


def test_messages_for_another_vehicle_are_ignored() -> None:
    h = Harness()
    assert h.send(mavlink.MAVLink_mission_count_message(2, 1, 2, 0)) == []
    assert h.server.state is TransferState.IDLE
