"""The mission server: the MAVLink mission protocol as a state machine, as PX4's mission manager runs it.

Upload: client MISSION_COUNT -> we MISSION_REQUEST_INT {seq} ... <- MISSION_ITEM_INT ... -> we MISSION_ACK. The
whole list goes to the vehicle as one ``SetMission`` only when complete and valid, so a broken transfer never
leaves half a mission. Download: client MISSION_REQUEST_LIST -> we MISSION_COUNT, then answer each
MISSION_REQUEST_INT with MISSION_ITEM_INT until the client's MISSION_ACK. Also MISSION_CLEAR_ALL and
MISSION_SET_CURRENT (answered with MISSION_CURRENT, which is what MAVSDK waits for).

As PX4 does, the server speaks INT by default and follows a client that uses the float messages (MISSION_ITEM /
MISSION_REQUEST, classic pymavlink scripts) or that refuses INT with MISSION_ACK UNSUPPORTED.

Robustness, all driven by the injected time:
- an unanswered MISSION_REQUEST is repeated every ``MISSION_RETRY_TIMEOUT_S``; after ``MISSION_MAX_RETRIES``
  repeats without progress the upload is abandoned with MISSION_ACK OPERATION_CANCELLED and the state is clean;
- a download whose client goes quiet for ``MISSION_IDLE_TIMEOUT_S`` is dropped;
- duplicate and out-of-sequence items are ignored (the retry asks again), a duplicate of the last item after
  completion is acknowledged again (the client missed our ACK);
- a fence (type 1) runs through the same transfers; its items are checked as PX4 checks them (sitl/protocol/fence.py:
  polygon vertices with a count of at least 3, repeated on each vertex, circles with a positive radius) and the
  vehicle gets the whole fence as one ``SetFence``; MISSION_CLEAR_ALL of type 1 clears it, of type ALL clears both;
- rally points (2) are not stored: downloads report 0 items, clears succeed, uploads of items are refused with
  MAV_MISSION_UNSUPPORTED.

Legal (state, message) pairs are the table ``_ROUTES`` below; every other pair is ignored at one choke point.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from enum import Enum
from typing import Final

from pymavlink.dialects.v20 import common as mavlink

from sitl.autopilot.vehicle_api import (
    GLOBAL_FRAMES,
    CommandOutcome,
    CommandResult,
    MissionItem,
    MissionType,
    SetFence,
    SetMission,
    SetMissionCurrent,
    VehicleApi,
)
from sitl.protocol import messages
from sitl.protocol.core import (
    INT32_MAX,
    Effect,
    Identity,
    MAVLinkMessage,
    Peer,
    PeerInputError,
    Send,
    addressed_to,
    check_now,
    f32,
    message_id,
    read_float,
    read_int,
    source_of,
)
from sitl.protocol.fence import validate_fence, validate_fence_item
from sitl.protocol.statustext import Severity, StatusTextEncoder

MISSION_RETRY_TIMEOUT_S: Final = 0.5  # re-request an item after this long (MAVSDK's own timeout is 0.5 s)
MISSION_MAX_RETRIES: Final = 5  # re-requests of one item before the upload is abandoned (MAVSDK: 5 retries)
MISSION_IDLE_TIMEOUT_S: Final = 5.0  # a download waits this long for the client (PX4's protocol timeout)
MAX_MISSION_ITEMS: Final = 500  # PX4's dataman capacity for a mission

ID_COUNT: Final = mavlink.MAVLINK_MSG_ID_MISSION_COUNT
ID_ITEM: Final = mavlink.MAVLINK_MSG_ID_MISSION_ITEM
ID_ITEM_INT: Final = mavlink.MAVLINK_MSG_ID_MISSION_ITEM_INT
ID_REQUEST: Final = mavlink.MAVLINK_MSG_ID_MISSION_REQUEST
ID_REQUEST_INT: Final = mavlink.MAVLINK_MSG_ID_MISSION_REQUEST_INT
ID_REQUEST_LIST: Final = mavlink.MAVLINK_MSG_ID_MISSION_REQUEST_LIST
ID_ACK: Final = mavlink.MAVLINK_MSG_ID_MISSION_ACK
ID_CLEAR_ALL: Final = mavlink.MAVLINK_MSG_ID_MISSION_CLEAR_ALL
ID_SET_CURRENT: Final = mavlink.MAVLINK_MSG_ID_MISSION_SET_CURRENT

_LOCAL_FRAMES: Final = frozenset(
    {
        mavlink.MAV_FRAME_LOCAL_NED,
        mavlink.MAV_FRAME_LOCAL_ENU,
        mavlink.MAV_FRAME_LOCAL_OFFSET_NED,
        mavlink.MAV_FRAME_BODY_NED,
        mavlink.MAV_FRAME_BODY_OFFSET_NED,
        mavlink.MAV_FRAME_BODY_FRD,
        mavlink.MAV_FRAME_LOCAL_FRD,
        mavlink.MAV_FRAME_LOCAL_FLU,
    }
)
_FLYABLE_FRAMES: Final = frozenset(
    {
        mavlink.MAV_FRAME_GLOBAL,
        mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT,
        mavlink.MAV_FRAME_GLOBAL_INT,
        mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
    }
)
# Items that fly to a coordinate: they need a global frame PX4 supports and a valid position.
POSITIONAL_COMMANDS: Final = frozenset(
    {
        mavlink.MAV_CMD_NAV_WAYPOINT,
        mavlink.MAV_CMD_NAV_LOITER_UNLIM,
        mavlink.MAV_CMD_NAV_LOITER_TURNS,
        mavlink.MAV_CMD_NAV_LOITER_TIME,
        mavlink.MAV_CMD_NAV_LAND,
        mavlink.MAV_CMD_NAV_TAKEOFF,
        mavlink.MAV_CMD_NAV_LOITER_TO_ALT,
        mavlink.MAV_CMD_NAV_VTOL_TAKEOFF,
        mavlink.MAV_CMD_NAV_VTOL_LAND,
        mavlink.MAV_CMD_DO_SET_ROI_LOCATION,
    }
)
# Everything else PX4 (and MAVSDK's mission plugin) puts in a mission; the frame of these is not checked.
OTHER_MISSION_COMMANDS: Final = frozenset(
    {
        mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH,
        mavlink.MAV_CMD_NAV_DELAY,
        mavlink.MAV_CMD_NAV_ROI,
        mavlink.MAV_CMD_CONDITION_DELAY,
        mavlink.MAV_CMD_CONDITION_DISTANCE,
        mavlink.MAV_CMD_CONDITION_YAW,
        mavlink.MAV_CMD_DO_JUMP,
        mavlink.MAV_CMD_DO_CHANGE_SPEED,
        mavlink.MAV_CMD_DO_SET_HOME,
        mavlink.MAV_CMD_DO_SET_RELAY,
        mavlink.MAV_CMD_DO_SET_SERVO,
        mavlink.MAV_CMD_DO_SET_ACTUATOR,
        mavlink.MAV_CMD_DO_LAND_START,
        mavlink.MAV_CMD_DO_SET_ROI,
        mavlink.MAV_CMD_DO_SET_ROI_WPNEXT_OFFSET,
        mavlink.MAV_CMD_DO_SET_ROI_NONE,
        mavlink.MAV_CMD_DO_DIGICAM_CONTROL,
        mavlink.MAV_CMD_DO_MOUNT_CONFIGURE,
        mavlink.MAV_CMD_DO_MOUNT_CONTROL,
        mavlink.MAV_CMD_DO_SET_CAM_TRIGG_DIST,
        mavlink.MAV_CMD_DO_SET_CAM_TRIGG_INTERVAL,
        mavlink.MAV_CMD_DO_GRIPPER,
        mavlink.MAV_CMD_DO_WINCH,
        mavlink.MAV_CMD_DO_VTOL_TRANSITION,
        mavlink.MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW,
        mavlink.MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE,
        mavlink.MAV_CMD_SET_CAMERA_MODE,
        mavlink.MAV_CMD_SET_CAMERA_ZOOM,
        mavlink.MAV_CMD_SET_CAMERA_FOCUS,
        mavlink.MAV_CMD_IMAGE_START_CAPTURE,
        mavlink.MAV_CMD_IMAGE_STOP_CAPTURE,
        mavlink.MAV_CMD_VIDEO_START_CAPTURE,
        mavlink.MAV_CMD_VIDEO_STOP_CAPTURE,
    }
)

_OUTCOME_TO_MISSION_RESULT: Final[dict[CommandResult, int]] = {
    CommandResult.ACCEPTED: mavlink.MAV_MISSION_ACCEPTED,
    CommandResult.TEMPORARILY_REJECTED: mavlink.MAV_MISSION_DENIED,
    CommandResult.DENIED: mavlink.MAV_MISSION_DENIED,
    CommandResult.UNSUPPORTED: mavlink.MAV_MISSION_UNSUPPORTED,
    CommandResult.FAILED: mavlink.MAV_MISSION_ERROR,
}


class TransferState(Enum):
    IDLE = "idle"
    RECEIVING = "receiving"  # an upload from a client is in progress
    SENDING = "sending"  # a download to a client is in progress


@dataclass(slots=True)
class _Upload:
    partner: Peer
    mission_type: int
    count: int
    int_mode: bool
    last_request_s: float
    retries: int = 0
    items: list[MissionItem] = field(default_factory=list)

    @property
    def expected_seq(self) -> int:
        return len(self.items)


@dataclass(slots=True)
class _Download:
    partner: Peer
    mission_type: int
    items: tuple[MissionItem, ...]
    current_seq: int
    last_activity_s: float
    highest_sent: int = -1

    @property
    def all_sent(self) -> bool:
        return self.highest_sent >= len(self.items) - 1


@dataclass(frozen=True, slots=True)
class _Completed:
    """The last finished upload, to re-acknowledge a client that missed our final MISSION_ACK."""

    partner: Peer
    mission_type: int
    count: int
    result: int


# ---- item conversion and validation (pure) -----------------------------------------------------------------
def _scale_for(frame: int) -> float:
    """MISSION_ITEM_INT x/y = MISSION_ITEM x/y * scale: degE7 for global frames, 1e4 for local ones, else 1."""
    if frame in GLOBAL_FRAMES:
        return 1e7
    if frame in _LOCAL_FRAMES:
        return 1e4
    return 1.0


def _float_to_int_coordinate(value: float, frame: int, command: int, error: int) -> int:
    """A MISSION_ITEM x/y in the MISSION_ITEM_INT encoding; an unused (non-finite) one of a non-flying item is 0."""
    scaled = value * _scale_for(frame)
    if not math.isfinite(scaled) and command not in POSITIONAL_COMMANDS:
        return 0
    if not math.isfinite(scaled) or abs(scaled) > INT32_MAX:
        raise _ItemRejected(error)
    return round(scaled)


class _ItemRejected(Exception):
    def __init__(self, result: int) -> None:
        super().__init__(result)
        self.result = result


def item_from_message(msg: MAVLinkMessage, msg_id: int) -> MissionItem:
    """A MISSION_ITEM_INT or MISSION_ITEM as a MissionItem (float coordinates converted to the INT encoding)."""
    frame = read_int(msg, "frame", lo=0, hi=255)
    command = read_int(msg, "command", lo=0, hi=0xFFFF)
    if msg_id == ID_ITEM_INT:
        x, y = read_int(msg, "x"), read_int(msg, "y")
    else:
        x = _float_to_int_coordinate(read_float(msg, "x"), frame, command, mavlink.MAV_MISSION_INVALID_PARAM5_X)
        y = _float_to_int_coordinate(read_float(msg, "y"), frame, command, mavlink.MAV_MISSION_INVALID_PARAM6_Y)
    mission_type = read_int(msg, "mission_type", lo=0, hi=255)
    return MissionItem(
        seq=read_int(msg, "seq", lo=0, hi=0xFFFF),
        frame=frame,
        command=command,
        current=read_int(msg, "current") != 0,
        autocontinue=read_int(msg, "autocontinue") != 0,
        param1=read_float(msg, "param1"),
        param2=read_float(msg, "param2"),
        param3=read_float(msg, "param3"),
        param4=read_float(msg, "param4"),
        x=x,
        y=y,
        z=read_float(msg, "z"),
        mission_type=MissionType(mission_type) if mission_type in (0, 1, 2) else MissionType.MISSION,
    )


def validate_item(item: MissionItem) -> int:
    """MAV_MISSION_RESULT for one mission item: ACCEPTED, or why PX4 would refuse it."""
    if item.command in POSITIONAL_COMMANDS:
        if item.frame not in _FLYABLE_FRAMES:
            return int(mavlink.MAV_MISSION_UNSUPPORTED_FRAME)
        if not -900_000_000 <= item.x <= 900_000_000:
            return int(mavlink.MAV_MISSION_INVALID_PARAM5_X)
        if not -1_800_000_000 <= item.y <= 1_800_000_000:
            return int(mavlink.MAV_MISSION_INVALID_PARAM6_Y)
        if not math.isfinite(item.z):
            return int(mavlink.MAV_MISSION_INVALID_PARAM7)
        return int(mavlink.MAV_MISSION_ACCEPTED)
    if item.command in OTHER_MISSION_COMMANDS:
        return int(mavlink.MAV_MISSION_ACCEPTED)
    return int(mavlink.MAV_MISSION_UNSUPPORTED)


def item_message(item: MissionItem, partner: Peer, *, current: bool, int_mode: bool) -> MAVLinkMessage:
    """MISSION_ITEM_INT (or MISSION_ITEM for a float-mode client) carrying a stored item."""
    args = (partner.sysid, partner.compid, item.seq, item.frame, item.command, int(current), int(item.autocontinue))
    params = (f32(item.param1), f32(item.param2), f32(item.param3), f32(item.param4))
    if int_mode:
        return mavlink.MAVLink_mission_item_int_message(*args, *params, item.x, item.y, f32(item.z), item.mission_type)
    scale = _scale_for(item.frame)
    return mavlink.MAVLink_mission_item_message(
        *args, *params, f32(item.x / scale), f32(item.y / scale), f32(item.z), item.mission_type
    )


# ---- the server --------------------------------------------------------------------------------------------
_Handler = Callable[["MissionServer", MAVLinkMessage, int, float], list[Effect]]


class MissionServer:
    """The mission protocol for one link. Mission storage is the vehicle's (``SetMission`` / ``mission_items``)."""

    handles: frozenset[int] = frozenset(
        {
            ID_COUNT,
            ID_ITEM,
            ID_ITEM_INT,
            ID_REQUEST,
            ID_REQUEST_INT,
            ID_REQUEST_LIST,
            ID_ACK,
            ID_CLEAR_ALL,
            ID_SET_CURRENT,
        }
    )

    def __init__(self, identity: Identity, vehicle: VehicleApi, *, statustext: StatusTextEncoder | None = None) -> None:
        self._identity = identity
        self._vehicle = vehicle
        self._statustext = statustext or StatusTextEncoder()
        self._upload: _Upload | None = None
        self._download: _Download | None = None
        self._completed: _Completed | None = None

    @property
    def state(self) -> TransferState:
        if self._upload is not None:
            return TransferState.RECEIVING
        if self._download is not None:
            return TransferState.SENDING
        return TransferState.IDLE

    # ---- the service interface -----------------------------------------------------------------------------
    def handle(self, msg: MAVLinkMessage, now_s: float) -> list[Effect]:
        now_s = check_now(now_s)
        msg_id = message_id(msg)
        if msg_id not in self.handles:
            return []
        try:
            # PX4 also accepts target component MAV_COMP_ID_MISSIONPLANNER for the mission protocol.
            if not addressed_to(msg, self._identity, also_components=(mavlink.MAV_COMP_ID_MISSIONPLANNER,)):
                return []
            return self._dispatch(msg, msg_id, now_s)
        except PeerInputError:
            return []  # unreadable: ignored; a running transfer recovers through its retry timer

    def poll(self, now_s: float) -> list[Effect]:
        now_s = check_now(now_s)
        up = self._upload
        if up is not None and now_s - up.last_request_s >= MISSION_RETRY_TIMEOUT_S:
            if up.retries >= MISSION_MAX_RETRIES:
                self._upload = None
                return [
                    self._ack(up.partner, mavlink.MAV_MISSION_OPERATION_CANCELLED, up.mission_type),
                    *self._text(Severity.CRITICAL, "Mission upload timed out, transfer cancelled"),
                ]
            up.retries += 1
            up.last_request_s = now_s
            return [self._request(up)]
        down = self._download
        if down is not None and now_s - down.last_activity_s >= MISSION_IDLE_TIMEOUT_S:
            self._download = None
            if not down.all_sent:
                return self._text(Severity.CRITICAL, "Mission download timed out")
        return []

    def _dispatch(self, msg: MAVLinkMessage, msg_id: int, now_s: float) -> list[Effect]:
        handler = _ROUTES[self.state].get(msg_id, MissionServer._ignore)
        return handler(self, msg, msg_id, now_s)

    # ---- effects -------------------------------------------------------------------------------------------
    def _ack(self, to: Peer, result: int, mission_type: int) -> Effect:
        return Send(mavlink.MAVLink_mission_ack_message(to.sysid, to.compid, result, mission_type & 0xFF))

    def _request(self, up: _Upload) -> Effect:
        cls = mavlink.MAVLink_mission_request_int_message if up.int_mode else mavlink.MAVLink_mission_request_message
        return Send(cls(up.partner.sysid, up.partner.compid, up.expected_seq, up.mission_type))

    def _text(self, severity: int, text: str) -> list[Effect]:
        return [Send(m) for m in self._statustext.encode(severity, text)]

    def _refusal_text(self, result: int, reason: str) -> list[Effect]:
        if result == mavlink.MAV_MISSION_ACCEPTED:
            return []
        return self._text(Severity.CRITICAL, reason or f"Mission refused (MAV_MISSION_RESULT {result})")

    def _apply(
        self, items: tuple[MissionItem, ...], now_s: float, mission_type: int = MissionType.MISSION
    ) -> tuple[int, str]:
        """Hand a complete list to the vehicle: the mission, or the fence after the checks of the fence as a whole."""
        if mission_type == MissionType.FENCE:
            result, reason = validate_fence(items)
            if result != mavlink.MAV_MISSION_ACCEPTED:
                return result, reason
            outcome = self._vehicle.command(SetFence(items=items), now_s)
        else:
            outcome = self._vehicle.command(SetMission(items=items), now_s)
        if not isinstance(outcome, CommandOutcome):
            return int(mavlink.MAV_MISSION_ERROR), "Vehicle gave no outcome"
        return _OUTCOME_TO_MISSION_RESULT.get(outcome.result, mavlink.MAV_MISSION_ERROR), outcome.reason

    # ---- handlers ------------------------------------------------------------------------------------------
    def _ignore(self, msg: MAVLinkMessage, msg_id: int, now_s: float) -> list[Effect]:
        return []

    def _busy(self, msg: MAVLinkMessage, msg_id: int, now_s: float) -> list[Effect]:
        return self._text(Severity.CRITICAL, "Mission transfer busy, request ignored")

    def _start_upload(self, msg: MAVLinkMessage, msg_id: int, now_s: float) -> list[Effect]:
        source = source_of(msg)
        count = read_int(msg, "count", lo=0, hi=0xFFFF)
        mission_type = read_int(msg, "mission_type", lo=0, hi=255)
        self._completed = None
        if mission_type not in (MissionType.MISSION, MissionType.FENCE):
            if mission_type == MissionType.RALLY and count == 0:
                return [self._ack(source, mavlink.MAV_MISSION_ACCEPTED, mission_type)]
            return [self._ack(source, mavlink.MAV_MISSION_UNSUPPORTED, mission_type)]
        if count > MAX_MISSION_ITEMS:
            return [self._ack(source, mavlink.MAV_MISSION_NO_SPACE, mission_type)]
        if count == 0:
            result, reason = self._apply((), now_s, mission_type)
            return [self._ack(source, result, mission_type), *self._refusal_text(result, reason)]
        self._upload = _Upload(
            partner=source, mission_type=mission_type, count=count, int_mode=True, last_request_s=now_s
        )
        return [self._request(self._upload)]

    def _count_during_upload(self, msg: MAVLinkMessage, msg_id: int, now_s: float) -> list[Effect]:
        up = self._upload
        assert up is not None
        source = source_of(msg)
        if source != up.partner:
            mission_type = read_int(msg, "mission_type", lo=0, hi=255)
            return [self._ack(source, mavlink.MAV_MISSION_ERROR, mission_type), *self._busy(msg, msg_id, now_s)]
        if up.expected_seq == 0 and read_int(msg, "count") == up.count:
            up.last_request_s = now_s  # our first request was lost: ask again
            return [self._request(up)]
        self._upload = None  # the same client started over: follow it
        return self._start_upload(msg, msg_id, now_s)

    def _receive_item(self, msg: MAVLinkMessage, msg_id: int, now_s: float) -> list[Effect]:
        up = self._upload
        assert up is not None
        if source_of(msg) != up.partner:
            return []
        if read_int(msg, "mission_type", lo=0, hi=255) != up.mission_type:
            self._upload = None
            return [self._ack(up.partner, mavlink.MAV_MISSION_ERROR, up.mission_type)]
        seq = read_int(msg, "seq", lo=0, hi=0xFFFF)
        if seq != up.expected_seq:
            return []  # duplicate or out of sequence: the retry timer asks for the right one again
        try:
            item = item_from_message(msg, msg_id)
            result = validate_fence_item(item) if up.mission_type == MissionType.FENCE else validate_item(item)
        except _ItemRejected as rej:
            result = rej.result
        if result != mavlink.MAV_MISSION_ACCEPTED:
            self._upload = None
            return [
                self._ack(up.partner, result, up.mission_type),
                *self._text(Severity.CRITICAL, f"Mission item {seq} rejected (MAV_MISSION_RESULT {result})"),
            ]
        up.int_mode = msg_id == ID_ITEM_INT  # PX4 answers in the flavour the client uses
        up.items.append(item)
        up.retries = 0
        up.last_request_s = now_s
        if up.expected_seq < up.count:
            return [self._request(up)]
        self._upload = None
        result, reason = self._apply(tuple(up.items), now_s, up.mission_type)
        self._completed = _Completed(up.partner, up.mission_type, up.count, result)
        return [self._ack(up.partner, result, up.mission_type), *self._refusal_text(result, reason)]

    def _item_without_transfer(self, msg: MAVLinkMessage, msg_id: int, now_s: float) -> list[Effect]:
        source = source_of(msg)
        mission_type = read_int(msg, "mission_type", lo=0, hi=255)
        done = self._completed
        if (
            done is not None
            and done.partner == source
            and done.mission_type == mission_type
            and read_int(msg, "seq") == done.count - 1
        ):
            return [self._ack(source, done.result, mission_type)]  # the client missed our final ACK
        return [self._ack(source, mavlink.MAV_MISSION_ERROR, mission_type)]

    def _ack_during_upload(self, msg: MAVLinkMessage, msg_id: int, now_s: float) -> list[Effect]:
        up = self._upload
        assert up is not None
        if source_of(msg) != up.partner:
            return []
        result = read_int(msg, "type", lo=0, hi=255)
        if result == mavlink.MAV_MISSION_UNSUPPORTED:
            up.int_mode = not up.int_mode  # the client cannot do this flavour: offer the other one (PX4)
            up.last_request_s = now_s
            return [self._request(up)]
        if result != mavlink.MAV_MISSION_ACCEPTED:
            self._upload = None  # the client gave up (usually OPERATION_CANCELLED)
        return []

    def _start_download(self, msg: MAVLinkMessage, msg_id: int, now_s: float) -> list[Effect]:
        source = source_of(msg)
        mission_type = read_int(msg, "mission_type", lo=0, hi=255)
        if mission_type == MissionType.RALLY:
            return [Send(mavlink.MAVLink_mission_count_message(source.sysid, source.compid, 0, mission_type))]
        if mission_type not in (MissionType.MISSION, MissionType.FENCE):
            return [self._ack(source, mavlink.MAV_MISSION_UNSUPPORTED, mission_type)]
        fence = mission_type == MissionType.FENCE
        stored = self._vehicle.fence_items() if fence else self._vehicle.mission_items()
        items = tuple(stored)[:MAX_MISSION_ITEMS]
        count_msg = mavlink.MAVLink_mission_count_message(source.sysid, source.compid, len(items), mission_type)
        if items:
            current = -1 if fence else self._vehicle.snapshot().mission.current_seq
            self._download = _Download(source, mission_type, items, current, last_activity_s=now_s)
        return [Send(count_msg)]

    def _send_item(self, msg: MAVLinkMessage, msg_id: int, now_s: float) -> list[Effect]:
        down = self._download
        assert down is not None
        if source_of(msg) != down.partner or read_int(msg, "mission_type", lo=0, hi=255) != down.mission_type:
            return []
        seq = read_int(msg, "seq", lo=0, hi=0xFFFF)
        down.last_activity_s = now_s
        if seq >= len(down.items):
            self._download = None
            return [
                self._ack(down.partner, mavlink.MAV_MISSION_ERROR, down.mission_type),
                *self._text(Severity.CRITICAL, f"Mission item {seq} requested, only {len(down.items)} exist"),
            ]
        down.highest_sent = max(down.highest_sent, seq)
        item = down.items[seq]
        return [
            Send(item_message(item, down.partner, current=seq == down.current_seq, int_mode=msg_id == ID_REQUEST_INT))
        ]

    def _ack_during_download(self, msg: MAVLinkMessage, msg_id: int, now_s: float) -> list[Effect]:
        down = self._download
        assert down is not None
        if source_of(msg) == down.partner:
            self._download = None  # ACCEPTED or any error: the client is done with this transfer
        return []

    def _supersede_download(self, msg: MAVLinkMessage, msg_id: int, now_s: float) -> list[Effect]:
        """A new operation while a download runs: downloads change nothing, so the client's new wish wins."""
        down = self._download
        assert down is not None
        if source_of(msg) != down.partner and not down.all_sent:
            if msg_id == ID_COUNT:
                mission_type = read_int(msg, "mission_type", lo=0, hi=255)
                return [
                    self._ack(source_of(msg), mavlink.MAV_MISSION_ERROR, mission_type),
                    *self._busy(msg, msg_id, now_s),
                ]
            return self._busy(msg, msg_id, now_s)
        self._download = None
        return self._dispatch(msg, msg_id, now_s)

    def _clear_all(self, msg: MAVLinkMessage, msg_id: int, now_s: float) -> list[Effect]:
        source = source_of(msg)
        mission_type = read_int(msg, "mission_type", lo=0, hi=255)
        self._completed = None
        if mission_type == MissionType.RALLY:
            return [self._ack(source, mavlink.MAV_MISSION_ACCEPTED, mission_type)]  # nothing stored
        if mission_type == MissionType.FENCE:
            result, reason = self._apply((), now_s, MissionType.FENCE)
            return [self._ack(source, result, mission_type), *self._refusal_text(result, reason)]
        if mission_type not in (MissionType.MISSION, mavlink.MAV_MISSION_TYPE_ALL):
            return [self._ack(source, mavlink.MAV_MISSION_UNSUPPORTED, mission_type)]
        if mission_type == mavlink.MAV_MISSION_TYPE_ALL:
            result, reason = self._apply((), now_s, MissionType.FENCE)
            if result != mavlink.MAV_MISSION_ACCEPTED:
                return [self._ack(source, result, mission_type), *self._refusal_text(result, reason)]
        result, reason = self._apply((), now_s)
        return [self._ack(source, result, mission_type), *self._refusal_text(result, reason)]

    def _set_current(self, msg: MAVLinkMessage, msg_id: int, now_s: float) -> list[Effect]:
        seq = read_int(msg, "seq", lo=0, hi=0xFFFF)
        outcome = self._vehicle.command(SetMissionCurrent(seq=seq), now_s)
        if isinstance(outcome, CommandOutcome) and outcome.ok:
            # MAVSDK's set_current_mission_item waits for a MISSION_CURRENT with this seq.
            snap = self._vehicle.snapshot()
            return [Send(messages.mission_current(snap, self._identity, seq=seq))]
        reason = outcome.reason if isinstance(outcome, CommandOutcome) and outcome.reason else ""
        return self._text(Severity.CRITICAL, reason or f"Mission item {seq} cannot be made current")


# Legal (state, message) pairs; anything else is ignored by MissionServer._dispatch.
_ROUTES: Final[dict[TransferState, dict[int, _Handler]]] = {
    TransferState.IDLE: {
        ID_COUNT: MissionServer._start_upload,
        ID_REQUEST_LIST: MissionServer._start_download,
        ID_CLEAR_ALL: MissionServer._clear_all,
        ID_SET_CURRENT: MissionServer._set_current,
        ID_ITEM: MissionServer._item_without_transfer,
        ID_ITEM_INT: MissionServer._item_without_transfer,
        # MISSION_REQUEST(_INT) and MISSION_ACK without a transfer are ignored silently, as PX4 does.
    },
    TransferState.RECEIVING: {
        ID_COUNT: MissionServer._count_during_upload,
        ID_ITEM: MissionServer._receive_item,
        ID_ITEM_INT: MissionServer._receive_item,
        ID_ACK: MissionServer._ack_during_upload,
        ID_REQUEST_LIST: MissionServer._busy,
        ID_CLEAR_ALL: MissionServer._busy,
        ID_SET_CURRENT: MissionServer._busy,
    },
    TransferState.SENDING: {
        ID_REQUEST: MissionServer._send_item,
        ID_REQUEST_INT: MissionServer._send_item,
        ID_ACK: MissionServer._ack_during_download,
        ID_REQUEST_LIST: MissionServer._supersede_download,
        ID_COUNT: MissionServer._supersede_download,
        ID_CLEAR_ALL: MissionServer._supersede_download,
        ID_SET_CURRENT: MissionServer._supersede_download,
    },
}
