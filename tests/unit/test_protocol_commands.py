"""The command service, driven through a link with messages that really went through pymavlink's wire format."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import pytest
from pymavlink.dialects.v20 import common as mavlink

from sitl.autopilot.px4_modes import Px4Mode
from sitl.autopilot.vehicle_api import (
    Arm,
    ChangeSpeed,
    CommandResult,
    Disarm,
    Kill,
    Land,
    MissionStart,
    Orbit,
    OrbitYaw,
    Reposition,
    ReturnToLaunch,
    SetHome,
    SetMissionCurrent,
    SetMode,
    SpeedKind,
    Takeoff,
)
from sitl.params import ParamDef, ParamStore
from sitl.protocol import Identity, LinkServices, ProtocolUsageError
from sitl.protocol.commands import CommandService
from sitl.protocol.core import MAVLinkMessage
from sitl.protocol.messages import CAPABILITIES
from sitl.protocol.telemetry import TelemetryScheduler
from sitl.protocol.testing import FakeVehicle, Wire, make_snapshot, of_type

NAN = math.nan
SYSID = 1
MAVSDK = (245, 190)  # MAVSDK's own ids as a ground station
PYMAVLINK = (255, 0)
ACCEPTED = mavlink.MAV_RESULT_ACCEPTED
DENIED = mavlink.MAV_RESULT_DENIED
UNSUPPORTED = mavlink.MAV_RESULT_UNSUPPORTED


@dataclass
class Rig:
    """A link with a fake vehicle, a client wire in and a vehicle wire out."""

    vehicle: FakeVehicle = field(default_factory=FakeVehicle)
    client: tuple[int, int] = MAVSDK
    now_s: float = 10.0

    def __post_init__(self) -> None:
        store = ParamStore([ParamDef(name="MIS_TAKEOFF_ALT", default=2.5, min=0.5, max=100, unit="m", description="")])
        self.link = LinkServices(Identity(sysid=SYSID), self.vehicle, store)
        self.up = Wire(*self.client)
        self.down = Wire(SYSID, 1)
        self.link.poll(self.now_s)  # the periodic streams have started, as in a running vehicle

    def send(self, msg: MAVLinkMessage) -> list[MAVLinkMessage]:
        self.now_s += 0.01
        return self.down.carry(self.link.handle(self.up(msg), self.now_s))

    def ack(self, msg: MAVLinkMessage) -> MAVLinkMessage:
        acks = of_type(self.send(msg), "COMMAND_ACK")
        assert len(acks) == 1, acks
        return acks[0]


def long(command: int, *params: float, target: tuple[int, int] = (SYSID, 1), confirmation: int = 0) -> MAVLinkMessage:
    """COMMAND_LONG the MAVSDK way: unused params NaN."""
    full = list(params) + [NAN] * (7 - len(params))
    return mavlink.MAVLink_command_long_message(target[0], target[1], command, confirmation, *full)


def zeros(command: int, *params: float) -> MAVLinkMessage:
    """COMMAND_LONG the pymavlink way: unused params 0, target component 0."""
    full = list(params) + [0.0] * (7 - len(params))
    return mavlink.MAVLink_command_long_message(SYSID, 0, command, 0, *full)


def cmd_int(command: int, frame: int, x: int, y: int, z: float, *params: float) -> MAVLinkMessage:
    p = list(params) + [NAN] * (4 - len(params))
    return mavlink.MAVLink_command_int_message(SYSID, 1, frame, command, 0, 0, *p, x, y, z)


# ---- addressing and acknowledgement ------------------------------------------------------------------------
def test_every_command_is_acknowledged_to_its_sender_from_the_autopilot() -> None:
    # GIVEN a MAVSDK client  WHEN it arms  THEN one ACK with the command id, addressed back to the client
    rig = Rig()
    ack = rig.ack(long(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1))
    assert (ack.command, ack.result) == (mavlink.MAV_CMD_COMPONENT_ARM_DISARM, ACCEPTED)
    assert (ack.target_system, ack.target_component) == MAVSDK
    assert (ack.get_srcSystem(), ack.get_srcComponent()) == (SYSID, 1)
    assert rig.vehicle.requests == [Arm(force=False)]


def test_pymavlink_zero_filled_command_to_component_zero_is_accepted() -> None:
    rig = Rig(client=PYMAVLINK)
    ack = rig.ack(zeros(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1))
    assert ack.result == ACCEPTED
    assert (ack.target_system, ack.target_component) == PYMAVLINK


@pytest.mark.parametrize("target", [(2, 1), (7, 0), (SYSID, 100)])
def test_commands_for_another_system_or_component_are_ignored(target: tuple[int, int]) -> None:
    # GIVEN several vehicles behind one client socket  WHEN a command targets another one  THEN silence
    rig = Rig()
    assert rig.send(long(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1, target=target)) == []
    assert rig.vehicle.requests == []


def test_broadcast_system_id_zero_is_for_us() -> None:
    rig = Rig()
    assert rig.ack(long(mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH, target=(0, 0))).result == ACCEPTED


@pytest.mark.parametrize("command", [mavlink.MAV_CMD_DO_FOLLOW, 31000, mavlink.MAV_CMD_DO_SET_SERVO])
def test_unknown_commands_are_unsupported_not_silent(command: int) -> None:
    rig = Rig()
    out = rig.send(long(command, 1, 2, 3))
    assert [m.result for m in of_type(out, "COMMAND_ACK")] == [UNSUPPORTED]
    assert of_type(out, "STATUSTEXT") == []


def test_request_protocol_version_is_unsupported_since_the_dialect_has_no_such_message() -> None:
    rig = Rig()
    assert rig.ack(long(mavlink.MAV_CMD_REQUEST_PROTOCOL_VERSION, 1)).result == UNSUPPORTED


def test_a_denial_comes_with_a_statustext_carrying_the_reason() -> None:
    # GIVEN a vehicle whose pre-arm checks fail
    rig = Rig()
    rig.vehicle.refuse(Arm, CommandResult.DENIED, "Preflight Fail: no GPS fix yet")
    # WHEN a client arms
    out = rig.send(long(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1))
    # THEN DENIED and the reason as a critical STATUSTEXT
    assert of_type(out, "COMMAND_ACK")[0].result == DENIED
    texts = of_type(out, "STATUSTEXT")
    assert [(t.severity, t.text) for t in texts] == [(mavlink.MAV_SEVERITY_CRITICAL, "Preflight Fail: no GPS fix yet")]


def test_reboot_is_denied_with_an_explanation() -> None:
    rig = Rig()
    out = rig.send(long(mavlink.MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN, 1))
    assert of_type(out, "COMMAND_ACK")[0].result == DENIED
    assert "Reboot" in of_type(out, "STATUSTEXT")[0].text


# ---- retries -----------------------------------------------------------------------------------------------
def test_a_retransmission_is_answered_with_the_first_result_without_asking_the_vehicle_again() -> None:
    # GIVEN an arm that was accepted (but whose ACK the client may have missed)
    rig = Rig()
    rig.ack(long(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1))
    # WHEN the client retransmits it (confirmation 1)
    ack = rig.ack(long(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1, confirmation=1))
    # THEN the same answer, and the vehicle saw one request
    assert ack.result == ACCEPTED
    assert rig.vehicle.requests == [Arm(force=False)]


def test_a_retransmission_after_the_replay_window_reaches_the_vehicle() -> None:
    rig = Rig()
    rig.ack(long(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1))
    rig.now_s += 10.0
    rig.link.poll(rig.now_s)
    rig.ack(long(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1, confirmation=1))
    assert len(rig.vehicle.requests) == 2


def test_a_repeated_arm_while_armed_is_accepted() -> None:
    # GIVEN an armed vehicle  WHEN a pymavlink script arms again (confirmation 0)  THEN ACCEPTED (idempotent)
    rig = Rig(client=PYMAVLINK)
    assert rig.ack(zeros(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1)).result == ACCEPTED
    assert rig.ack(zeros(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1)).result == ACCEPTED
    assert rig.vehicle.snap.armed


def test_a_replayed_denial_does_not_repeat_the_statustext() -> None:
    rig = Rig()
    rig.vehicle.refuse(Takeoff, CommandResult.DENIED, "Takeoff denied: disarmed")
    rig.send(long(mavlink.MAV_CMD_NAV_TAKEOFF))
    out = rig.send(long(mavlink.MAV_CMD_NAV_TAKEOFF, confirmation=1))
    assert of_type(out, "COMMAND_ACK")[0].result == DENIED
    assert of_type(out, "STATUSTEXT") == []


# ---- flight commands ---------------------------------------------------------------------------------------
def test_arm_state_change_sends_an_extra_heartbeat_right_after_the_ack() -> None:
    rig = Rig()
    out = rig.send(long(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1))
    assert [m.get_type() for m in out] == ["COMMAND_ACK", "HEARTBEAT"]
    assert out[1].base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED


@pytest.mark.parametrize(
    ("params", "expected"),
    [
        ((1.0, 21196.0), Arm(force=True)),
        ((0.0,), Disarm(force=False)),
        ((0.0, 21196.0), Disarm(force=True)),  # MAVSDK's kill()
    ],
)
def test_arm_disarm_variants(params: tuple[float, ...], expected: object) -> None:
    rig = Rig()
    rig.ack(long(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, *params))
    assert rig.vehicle.requests == [expected]


def test_arm_with_a_nonsense_action_is_denied() -> None:
    rig = Rig()
    assert rig.ack(long(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 5)).result == DENIED
    assert rig.vehicle.requests == []


def test_flight_termination_kills() -> None:
    rig = Rig()
    rig.ack(long(mavlink.MAV_CMD_DO_FLIGHTTERMINATION, 1))
    assert rig.vehicle.requests == [Kill()]


def test_mavsdk_takeoff_with_all_nan_leaves_the_altitude_to_the_vehicle() -> None:
    rig = Rig()
    rig.ack(long(mavlink.MAV_CMD_NAV_TAKEOFF))
    (request,) = rig.vehicle.requests
    assert isinstance(request, Takeoff)
    assert all(math.isnan(v) for v in (request.alt_amsl_m, request.lat_deg, request.lon_deg, request.yaw_rad))


def test_takeoff_param7_is_an_amsl_altitude_and_zero_lat_lon_means_here() -> None:
    rig = Rig(client=PYMAVLINK)
    rig.ack(zeros(mavlink.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 90, 0, 0, 498.0))
    (request,) = rig.vehicle.requests
    assert isinstance(request, Takeoff)
    assert request.alt_amsl_m == 498.0
    assert math.isnan(request.lat_deg) and math.isnan(request.lon_deg)
    assert request.yaw_rad == pytest.approx(math.pi / 2)


def test_land_here_and_land_there() -> None:
    rig = Rig()
    rig.ack(long(mavlink.MAV_CMD_NAV_LAND))
    rig.ack(long(mavlink.MAV_CMD_NAV_LAND, 0, 0, 0, NAN, 47.5, 8.5))
    here, there = rig.vehicle.requests
    assert isinstance(here, Land) and math.isnan(here.lat_deg)
    assert isinstance(there, Land) and (there.lat_deg, there.lon_deg) == pytest.approx((47.5, 8.5))


def test_pymavlink_rtl_command_and_mavsdk_rtl_mode() -> None:
    rig = Rig()
    rig.ack(zeros(mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH))
    rig.ack(long(mavlink.MAV_CMD_DO_SET_MODE, mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 4, 5))
    assert rig.vehicle.requests == [ReturnToLaunch(), SetMode(mode=Px4Mode.AUTO_RTL)]


def test_mode_change_is_reported_by_an_immediate_heartbeat() -> None:
    rig = Rig()
    out = rig.send(long(mavlink.MAV_CMD_DO_SET_MODE, mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 6, 0))
    heartbeats = of_type(out, "HEARTBEAT")
    assert [h.custom_mode for h in heartbeats] == [Px4Mode.OFFBOARD.custom_mode]


def test_unknown_mode_is_denied_with_text() -> None:
    rig = Rig()
    out = rig.send(long(mavlink.MAV_CMD_DO_SET_MODE, mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 42, 0))
    assert of_type(out, "COMMAND_ACK")[0].result == DENIED
    assert of_type(out, "STATUSTEXT")
    assert rig.vehicle.requests == []


def test_refused_mode_change_passes_the_vehicle_result_through() -> None:
    rig = Rig()
    rig.vehicle.refuse(SetMode, CommandResult.TEMPORARILY_REJECTED, "Offboard denied: no setpoint stream")
    ack = rig.ack(long(mavlink.MAV_CMD_DO_SET_MODE, 1, 6, 0))
    assert ack.result == mavlink.MAV_RESULT_TEMPORARILY_REJECTED


def test_old_set_mode_message_is_acknowledged_as_do_set_mode() -> None:
    rig = Rig(client=PYMAVLINK)
    ack = rig.ack(mavlink.MAVLink_set_mode_message(SYSID, 1, Px4Mode.AUTO_LOITER.custom_mode))
    assert (ack.command, ack.result) == (mavlink.MAV_CMD_DO_SET_MODE, ACCEPTED)
    assert rig.vehicle.requests == [SetMode(mode=Px4Mode.AUTO_LOITER)]


def test_set_mode_message_for_another_system_is_ignored() -> None:
    rig = Rig()
    assert rig.send(mavlink.MAVLink_set_mode_message(3, 1, Px4Mode.AUTO_LOITER.custom_mode)) == []


def test_pymavlink_loiter_command_means_hold() -> None:
    rig = Rig(client=PYMAVLINK)
    rig.ack(zeros(mavlink.MAV_CMD_NAV_LOITER_UNLIM))
    assert rig.vehicle.requests == [SetMode(mode=Px4Mode.AUTO_LOITER)]


# ---- reposition and other positional commands --------------------------------------------------------------
def test_mavsdk_goto_location_as_command_int_global_frame() -> None:
    # GIVEN MAVSDK's goto_location: COMMAND_INT 192, frame GLOBAL_INT, lat/lon * 1e7, AMSL z, yaw in rad
    rig = Rig()
    msg = cmd_int(
        mavlink.MAV_CMD_DO_REPOSITION, mavlink.MAV_FRAME_GLOBAL_INT, 473980000, 85460000, 500.0, -1, 1, NAN, 0.5
    )
    assert rig.ack(msg).result == ACCEPTED
    (request,) = rig.vehicle.requests
    assert isinstance(request, Reposition)
    assert (request.lat_deg, request.lon_deg, request.alt_amsl_m) == pytest.approx((47.398, 8.546, 500.0))
    assert request.yaw_rad == pytest.approx(0.5)
    assert math.isnan(request.ground_speed_mps)
    assert request.change_mode


def test_reposition_relative_altitude_frame_adds_home() -> None:
    rig = Rig()
    msg = cmd_int(mavlink.MAV_CMD_DO_REPOSITION, mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, 473980000, 85460000, 12.0)
    rig.ack(msg)
    (request,) = rig.vehicle.requests
    assert isinstance(request, Reposition)
    assert request.alt_amsl_m == pytest.approx(488.0 + 12.0)


def test_reposition_relative_altitude_without_home_is_temporarily_rejected() -> None:
    rig = Rig(vehicle=FakeVehicle(make_snapshot(home=None)))
    msg = cmd_int(mavlink.MAV_CMD_DO_REPOSITION, mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, 473980000, 85460000, 12.0)
    assert rig.ack(msg).result == mavlink.MAV_RESULT_TEMPORARILY_REJECTED
    assert rig.vehicle.requests == []


def test_reposition_with_int32_max_keeps_the_current_position() -> None:
    rig = Rig()
    rig.ack(cmd_int(mavlink.MAV_CMD_DO_REPOSITION, mavlink.MAV_FRAME_GLOBAL_INT, 0x7FFFFFFF, 0x7FFFFFFF, NAN))
    (request,) = rig.vehicle.requests
    assert isinstance(request, Reposition)
    assert math.isnan(request.lat_deg) and math.isnan(request.alt_amsl_m)


@pytest.mark.parametrize(
    ("frame", "x"),
    [
        (mavlink.MAV_FRAME_LOCAL_NED, 473980000),
        (mavlink.MAV_FRAME_GLOBAL_TERRAIN_ALT_INT, 473980000),
        (mavlink.MAV_FRAME_GLOBAL_INT, 950000000),
    ],
)
def test_reposition_in_an_unsupported_frame_or_off_the_globe_is_denied(frame: int, x: int) -> None:
    rig = Rig()
    assert rig.ack(cmd_int(mavlink.MAV_CMD_DO_REPOSITION, frame, x, 85460000, 10.0)).result == DENIED
    assert rig.vehicle.requests == []


def test_reposition_by_command_long_uses_float_degrees() -> None:
    rig = Rig()
    rig.ack(long(mavlink.MAV_CMD_DO_REPOSITION, 3.0, 0, NAN, NAN, 47.4, 8.55, 495.0))
    (request,) = rig.vehicle.requests
    assert isinstance(request, Reposition)
    assert (request.lat_deg, request.lon_deg, request.alt_amsl_m) == pytest.approx((47.4, 8.55, 495.0))
    assert request.ground_speed_mps == 3.0
    assert not request.change_mode


@pytest.mark.parametrize(
    ("params", "expected"),
    [
        ((1.0, 4.0), ChangeSpeed(kind=SpeedKind.HORIZONTAL, speed_mps=4.0)),
        ((0.0, 2.5), ChangeSpeed(kind=SpeedKind.HORIZONTAL, speed_mps=2.5)),
        ((2.0, 1.0), ChangeSpeed(kind=SpeedKind.CLIMB, speed_mps=1.0)),
        ((3.0, 0.75), ChangeSpeed(kind=SpeedKind.DESCENT, speed_mps=0.75)),
    ],
)
def test_change_speed_kinds(params: tuple[float, float], expected: ChangeSpeed) -> None:
    rig = Rig()
    rig.ack(long(mavlink.MAV_CMD_DO_CHANGE_SPEED, *params))
    assert rig.vehicle.requests == [expected]


def test_change_speed_minus_one_is_no_change_and_minus_two_restores_the_default() -> None:
    rig = Rig()
    assert rig.ack(long(mavlink.MAV_CMD_DO_CHANGE_SPEED, 1, -1)).result == ACCEPTED
    rig.ack(long(mavlink.MAV_CMD_DO_CHANGE_SPEED, 1, -2))
    (request,) = rig.vehicle.requests
    assert isinstance(request, ChangeSpeed) and math.isnan(request.speed_mps)


@pytest.mark.parametrize("params", [(1.0, NAN), (1.0, -5.0), (9.0, 3.0)])
def test_change_speed_nonsense_is_denied(params: tuple[float, float]) -> None:
    rig = Rig()
    assert rig.ack(long(mavlink.MAV_CMD_DO_CHANGE_SPEED, *params)).result == DENIED


def test_set_home_current_or_given() -> None:
    rig = Rig()
    rig.ack(long(mavlink.MAV_CMD_DO_SET_HOME, 1))
    rig.ack(long(mavlink.MAV_CMD_DO_SET_HOME, 0, NAN, NAN, NAN, 47.4, 8.5, 490.0))
    assert rig.vehicle.requests[0] == SetHome(use_current=True)
    given = rig.vehicle.requests[1]
    assert isinstance(given, SetHome) and not given.use_current
    assert (given.lat_deg, given.lon_deg, given.alt_amsl_m) == pytest.approx((47.4, 8.5, 490.0))
    assert rig.ack(long(mavlink.MAV_CMD_DO_SET_HOME, 0)).result == DENIED  # no position given


def test_pymavlink_set_mode_auto_starts_the_mission_from_item_zero() -> None:
    rig = Rig(client=PYMAVLINK)
    rig.ack(zeros(mavlink.MAV_CMD_MISSION_START))
    assert rig.vehicle.requests == [MissionStart(first_seq=0, last_seq=None)]


def test_mission_start_nan_continues_and_negative_is_denied() -> None:
    rig = Rig()
    rig.ack(long(mavlink.MAV_CMD_MISSION_START))
    assert rig.vehicle.requests == [MissionStart(first_seq=None, last_seq=None)]
    assert rig.ack(long(mavlink.MAV_CMD_MISSION_START, -7)).result == DENIED


def test_set_mission_current_command() -> None:
    rig = Rig()
    rig.ack(long(mavlink.MAV_CMD_DO_SET_MISSION_CURRENT, 3, 1))
    assert rig.vehicle.requests == [SetMissionCurrent(seq=3, reset=True)]


# ---- information requests ----------------------------------------------------------------------------------
def test_request_autopilot_version_returns_message_then_ack_with_mission_int_capability() -> None:
    # GIVEN MAVSDK right after discovery  WHEN it requests AUTOPILOT_VERSION (512, p1=148)
    rig = Rig()
    out = rig.send(long(mavlink.MAV_CMD_REQUEST_MESSAGE, mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION))
    # THEN the message comes first, then the ACK
    assert [m.get_type() for m in out] == ["AUTOPILOT_VERSION", "COMMAND_ACK"]
    caps = out[0].capabilities
    for bit in (
        mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_INT,
        mavlink.MAV_PROTOCOL_CAPABILITY_COMMAND_INT,
        mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE,
        mavlink.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_LOCAL_NED,
        mavlink.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_GLOBAL_INT,
        mavlink.MAV_PROTOCOL_CAPABILITY_MAVLINK2,
    ):
        assert caps & bit
    assert caps == CAPABILITIES
    assert (out[0].flight_sw_version >> 24, (out[0].flight_sw_version >> 16) & 0xFF) == (1, 15)


def test_old_autopilot_capabilities_request() -> None:
    rig = Rig()
    out = rig.send(long(mavlink.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES, 1))
    assert [m.get_type() for m in out] == ["AUTOPILOT_VERSION", "COMMAND_ACK"]


def test_request_home_position_before_and_after_home_is_set() -> None:
    # GIVEN no home yet  WHEN MAVSDK asks  THEN DENIED without STATUSTEXT spam (it keeps asking)
    rig = Rig(vehicle=FakeVehicle(make_snapshot(home=None)))
    out = rig.send(long(mavlink.MAV_CMD_REQUEST_MESSAGE, mavlink.MAVLINK_MSG_ID_HOME_POSITION))
    assert [m.get_type() for m in out] == ["COMMAND_ACK"]
    assert out[0].result == DENIED
    # WHEN home exists THEN HOME_POSITION then ACCEPTED
    rig.vehicle.update(home=make_snapshot().home)
    out = rig.send(long(mavlink.MAV_CMD_REQUEST_MESSAGE, mavlink.MAVLINK_MSG_ID_HOME_POSITION))
    assert [m.get_type() for m in out[:2]] == ["HOME_POSITION", "COMMAND_ACK"]
    assert out[0].latitude == 473977420


def test_request_of_a_message_we_cannot_build_is_denied() -> None:
    rig = Rig()
    assert rig.ack(long(mavlink.MAV_CMD_REQUEST_MESSAGE, mavlink.MAVLINK_MSG_ID_CAMERA_INFORMATION)).result == DENIED
    assert rig.ack(long(mavlink.MAV_CMD_REQUEST_MESSAGE, NAN)).result == DENIED


def test_set_and_get_message_interval() -> None:
    # GIVEN default telemetry  WHEN a client sets GLOBAL_POSITION_INT to 20 Hz and asks the interval back
    rig = Rig()
    assert rig.ack(long(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, 33, 50000)).result == ACCEPTED
    out = rig.send(long(mavlink.MAV_CMD_GET_MESSAGE_INTERVAL, 33))
    # THEN MESSAGE_INTERVAL reports 50 ms
    (interval,) = of_type(out, "MESSAGE_INTERVAL")
    assert (interval.message_id, interval.interval_us) == (33, 50000)
    assert rig.ack(long(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, 33, -1)).result == ACCEPTED
    assert of_type(rig.send(long(mavlink.MAV_CMD_GET_MESSAGE_INTERVAL, 33)), "MESSAGE_INTERVAL")[0].interval_us == -1
    assert rig.ack(long(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, 33, -5)).result == DENIED
    assert rig.ack(long(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, 12345, 1000)).result == UNSUPPORTED


# ---- malformed input ---------------------------------------------------------------------------------------
def test_a_command_with_wrongly_typed_params_is_denied_not_raised() -> None:
    # GIVEN a message object built by buggy code (a string where a float belongs), never packed
    vehicle = FakeVehicle()
    service = CommandService(Identity(sysid=SYSID), vehicle, TelemetryScheduler(Identity(sysid=SYSID), vehicle))
    bad = mavlink.MAVLink_command_long_message(SYSID, 1, 400, 0, "one", NAN, NAN, NAN, NAN, NAN, NAN)
    # WHEN handled  THEN a DENIED ack and no vehicle request
    out = service.handle(bad, 1.0)
    assert [e.msg.result for e in out if e.msg.get_type() == "COMMAND_ACK"] == [DENIED]
    assert vehicle.requests == []


def test_a_command_without_usable_target_is_dropped() -> None:
    vehicle = FakeVehicle()
    service = CommandService(Identity(sysid=SYSID), vehicle, TelemetryScheduler(Identity(sysid=SYSID), vehicle))
    bad = mavlink.MAVLink_command_long_message(None, 1, 400, 0, 1, NAN, NAN, NAN, NAN, NAN, NAN)
    assert service.handle(bad, 1.0) == []


def test_our_own_misuse_is_a_usage_error() -> None:
    rig = Rig()
    with pytest.raises(ProtocolUsageError):
        rig.link.handle("not a message", 1.0)
    with pytest.raises(ProtocolUsageError):
        rig.link.poll(math.nan)


# ---- MAV_CMD_DO_ORBIT ------------------------------------------------------------------------------------------
INT32_MAX = 2**31 - 1


@pytest.mark.parametrize(
    ("msg", "expected"),
    [
        # MAVSDK's do_orbit: COMMAND_INT in GLOBAL_RELATIVE_ALT, an AMSL altitude all the same (PX4 reads z as AMSL)
        (
            cmd_int(mavlink.MAV_CMD_DO_ORBIT, mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT, 473977420, 85455940, 500.0,
                    15.0, 2.0, mavlink.ORBIT_YAW_BEHAVIOUR_HOLD_FRONT_TANGENT_TO_CIRCLE),
            Orbit(radius_m=15.0, velocity_mps=2.0, yaw=OrbitYaw.TANGENT, lat_deg=47.397742, lon_deg=8.545594,
                  alt_amsl_m=500.0),
        ),
        # ... with the centre left out (INT32_MAX) and the yaw behaviour unchanged
        (
            cmd_int(mavlink.MAV_CMD_DO_ORBIT, mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT, INT32_MAX, INT32_MAX, NAN,
                    -5.0, NAN, mavlink.ORBIT_YAW_BEHAVIOUR_UNCHANGED),
            Orbit(radius_m=-5.0),
        ),
        # COMMAND_LONG the MAVSDK way: NaN for what is not given
        (long(mavlink.MAV_CMD_DO_ORBIT, 8.0), Orbit(radius_m=8.0)),
        # pymavlink's zeros: yaw 0 is facing the centre, and 0/0 and an altitude of 0 m are not given
        (
            zeros(mavlink.MAV_CMD_DO_ORBIT, 8.0, 1.5),
            Orbit(radius_m=8.0, velocity_mps=1.5, yaw=OrbitYaw.FRONT_TO_CENTRE),
        ),
        # a yaw behaviour PX4 does not know is flown as its default
        (long(mavlink.MAV_CMD_DO_ORBIT, 8.0, NAN, 9.0), Orbit(radius_m=8.0, yaw=OrbitYaw.FRONT_TO_CENTRE)),
    ],
)  # fmt: skip
def test_do_orbit_reaches_the_vehicle_as_px4_reads_it(msg: MAVLinkMessage, expected: Orbit) -> None:
    rig = Rig()
    assert rig.ack(msg).result == ACCEPTED
    (request,) = rig.vehicle.requests
    assert isinstance(request, Orbit)
    got = (request.radius_m, request.velocity_mps, request.yaw, request.lat_deg, request.lon_deg, request.alt_amsl_m)
    want = (expected.radius_m, expected.velocity_mps, expected.yaw, expected.lat_deg, expected.lon_deg,
            expected.alt_amsl_m)  # fmt: skip
    assert got[2] is want[2]
    assert all((math.isnan(a) and math.isnan(b)) or a == pytest.approx(b, abs=1e-7) for a, b in
               zip(got[:2] + got[3:], want[:2] + want[3:], strict=True)), (got, want)  # fmt: skip


@pytest.mark.parametrize(
    ("result", "reason"),
    [
        (CommandResult.TEMPORARILY_REJECTED, "Orbit command rejected: not flying"),
        (CommandResult.DENIED, "Orbit radius limit exceeded"),
    ],
)
def test_a_refused_orbit_is_answered_with_the_vehicles_result_and_reason(result: CommandResult, reason: str) -> None:
    rig = Rig()
    rig.vehicle.refuse(Orbit, result, reason)
    out = rig.send(long(mavlink.MAV_CMD_DO_ORBIT, 5000.0))
    assert [a.result for a in of_type(out, "COMMAND_ACK")] == [int(result)]
    assert [t.text for t in of_type(out, "STATUSTEXT")] == [reason]


def test_a_centre_in_a_local_frame_is_denied() -> None:
    rig = Rig()
    ack = rig.ack(cmd_int(mavlink.MAV_CMD_DO_ORBIT, mavlink.MAV_FRAME_LOCAL_NED, 10, 10, NAN, 5.0))
    assert ack.result == DENIED and rig.vehicle.requests == []
