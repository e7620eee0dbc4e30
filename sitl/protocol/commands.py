"""The command service: COMMAND_LONG, COMMAND_INT and the old SET_MODE message, answered the way PX4 answers.

Every command addressed to us gets exactly one COMMAND_ACK from our component, addressed back to the sender's
sysid/compid; MAVSDK matches acks on that and an unanswered command costs a client seconds of retries. Unknown
commands are UNSUPPORTED, never silent. A refusal also goes out as a STATUSTEXT carrying the vehicle's reason.

Both client dialects are accepted: MAVSDK fills unused params with NaN and targets component 1; pymavlink fills
them with 0 and often targets component 0. Positional commands accept COMMAND_LONG (degrees as floats) and
COMMAND_INT (degE7 integers, frame GLOBAL/GLOBAL_INT for AMSL altitude, GLOBAL_RELATIVE_ALT(_INT) for altitude
above home). A retransmission (confirmation > 0) of an identical command within ``REPLAY_WINDOW_S`` is answered with
the first result without asking the vehicle again; plain repeats reach the vehicle, whose requests are idempotent.
"""

from __future__ import annotations

import math
import struct
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass
from typing import Final, Protocol

from pymavlink.dialects.v20 import common as mavlink

from sitl.autopilot.px4_modes import Px4Mode
from sitl.autopilot.vehicle_api import (
    Arm,
    ChangeSpeed,
    CommandOutcome,
    CommandResult,
    Disarm,
    InjectFailure,
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
    VehicleApi,
    VehicleRequest,
)
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
    message_id,
    param_to_int,
    read_float,
    read_int,
    source_of,
)
from sitl.protocol.messages import command_ack
from sitl.protocol.modes import decode_do_set_mode, decode_set_mode_message
from sitl.protocol.statustext import Severity, StatusTextEncoder

NAN = math.nan
FORCE_MAGIC: Final = 21196  # MAV_CMD_COMPONENT_ARM_DISARM param2: force (arm without checks / disarm in the air)
REPLAY_WINDOW_S: Final = 3.0  # longer than MAVSDK's whole retry cycle (0.5 s timeout, 3 retries)
REPLAY_CACHE_SIZE: Final = 32

# Requests for information: PX4 answers them whatever the target component, and they are never replayed
# (a retry must send the message again).
_INFO_COMMANDS: Final = frozenset(
    {
        mavlink.MAV_CMD_REQUEST_MESSAGE,
        mavlink.MAV_CMD_SET_MESSAGE_INTERVAL,
        mavlink.MAV_CMD_GET_MESSAGE_INTERVAL,
        mavlink.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES,
        mavlink.MAV_CMD_REQUEST_PROTOCOL_VERSION,
        mavlink.MAV_CMD_GET_HOME_POSITION,
    }
)
_AMSL_FRAMES: Final = frozenset({mavlink.MAV_FRAME_GLOBAL, mavlink.MAV_FRAME_GLOBAL_INT})
_RELATIVE_FRAMES: Final = frozenset({mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT, mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT})

_ORBIT_YAWS: Final = frozenset(int(y) for y in OrbitYaw)

_LABELS: Final[dict[int, str]] = {
    mavlink.MAV_CMD_COMPONENT_ARM_DISARM: "Arm/disarm",
    mavlink.MAV_CMD_NAV_TAKEOFF: "Takeoff",
    mavlink.MAV_CMD_NAV_LAND: "Land",
    mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH: "Return to launch",
    mavlink.MAV_CMD_DO_SET_MODE: "Mode change",
    mavlink.MAV_CMD_DO_REPOSITION: "Reposition",
    mavlink.MAV_CMD_DO_ORBIT: "Orbit",
    mavlink.MAV_CMD_DO_CHANGE_SPEED: "Speed change",
    mavlink.MAV_CMD_DO_SET_HOME: "Set home",
    mavlink.MAV_CMD_MISSION_START: "Mission start",
    mavlink.MAV_CMD_DO_SET_MISSION_CURRENT: "Set mission item",
    mavlink.MAV_CMD_DO_FLIGHTTERMINATION: "Flight termination",
    mavlink.MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN: "Reboot",
    mavlink.MAV_CMD_INJECT_FAILURE: "Failure injection",
}


class StreamControl(Protocol):
    """What the command service needs from the link's telemetry scheduler (TelemetryScheduler implements it)."""

    def set_message_interval(self, msg_id: int, interval_us: float, now_s: float) -> CommandResult: ...

    def message_interval_us(self, msg_id: int) -> int: ...

    def request_message(self, msg_id: int, now_s: float) -> tuple[CommandResult, list[Effect]]: ...


@dataclass(frozen=True, slots=True)
class DecodedCommand:
    """A COMMAND_LONG or COMMAND_INT reduced to what handlers need."""

    command: int
    params: tuple[float, float, float, float, float, float, float]  # COMMAND_INT: p5/p6 are x/y as numbers
    frame: int | None  # None for COMMAND_LONG
    x: int  # COMMAND_INT raw x/y (degE7 for global frames); 0 for COMMAND_LONG
    y: int
    confirmation: int
    source: Peer

    @property
    def is_int(self) -> bool:
        return self.frame is not None


@dataclass(frozen=True, slots=True)
class _Reply:
    result: CommandResult
    reason: str = ""
    effects: tuple[Effect, ...] = ()  # sent before the ACK (a requested message, MESSAGE_INTERVAL)


@dataclass(frozen=True, slots=True)
class _Cached:
    time_s: float
    result: CommandResult


class _Reject(Exception):
    """Raised inside a handler to refuse with a result and a reason."""

    def __init__(self, result: CommandResult, reason: str) -> None:
        super().__init__(reason)
        self.result = result
        self.reason = reason


def decode_command(msg: MAVLinkMessage, msg_id: int) -> DecodedCommand:
    """Read a COMMAND_LONG/COMMAND_INT; PeerInputError when a field has the wrong type."""
    command = read_int(msg, "command", lo=0, hi=0xFFFF)
    p1, p2, p3, p4 = (read_float(msg, f"param{i}") for i in range(1, 5))
    source = source_of(msg)
    if msg_id == mavlink.MAVLINK_MSG_ID_COMMAND_INT:
        x, y = read_int(msg, "x"), read_int(msg, "y")
        z = read_float(msg, "z")
        frame = read_int(msg, "frame", lo=0, hi=255)
        return DecodedCommand(command, (p1, p2, p3, p4, float(x), float(y), z), frame, x, y, 0, source)
    p5, p6, p7 = (read_float(msg, f"param{i}") for i in range(5, 8))
    confirmation = read_int(msg, "confirmation", lo=0, hi=255)
    return DecodedCommand(command, (p1, p2, p3, p4, p5, p6, p7), None, 0, 0, confirmation, source)


class CommandService:
    """Answers COMMAND_LONG, COMMAND_INT and SET_MODE for one link."""

    handles: frozenset[int] = frozenset(
        {mavlink.MAVLINK_MSG_ID_COMMAND_LONG, mavlink.MAVLINK_MSG_ID_COMMAND_INT, mavlink.MAVLINK_MSG_ID_SET_MODE}
    )

    def __init__(
        self,
        identity: Identity,
        vehicle: VehicleApi,
        streams: StreamControl,
        *,
        statustext: StatusTextEncoder | None = None,
    ) -> None:
        self._identity = identity
        self._vehicle = vehicle
        self._streams = streams
        self._statustext = statustext or StatusTextEncoder()
        self._replay: OrderedDict[tuple[object, ...], _Cached] = OrderedDict()
        self._handlers: dict[int, Callable[[DecodedCommand, float], _Reply]] = {
            mavlink.MAV_CMD_COMPONENT_ARM_DISARM: self._arm_disarm,
            mavlink.MAV_CMD_NAV_TAKEOFF: self._takeoff,
            mavlink.MAV_CMD_NAV_LAND: self._land,
            mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH: self._rtl,
            mavlink.MAV_CMD_NAV_LOITER_UNLIM: self._hold,
            mavlink.MAV_CMD_DO_SET_MODE: self._set_mode,
            mavlink.MAV_CMD_DO_REPOSITION: self._reposition,
            mavlink.MAV_CMD_DO_ORBIT: self._orbit,
            mavlink.MAV_CMD_DO_CHANGE_SPEED: self._change_speed,
            mavlink.MAV_CMD_DO_SET_HOME: self._set_home,
            mavlink.MAV_CMD_MISSION_START: self._mission_start,
            mavlink.MAV_CMD_DO_SET_MISSION_CURRENT: self._set_mission_current,
            mavlink.MAV_CMD_DO_FLIGHTTERMINATION: self._flight_termination,
            mavlink.MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN: self._reboot,
            mavlink.MAV_CMD_INJECT_FAILURE: self._inject_failure,
            mavlink.MAV_CMD_SET_MESSAGE_INTERVAL: self._set_message_interval,
            mavlink.MAV_CMD_GET_MESSAGE_INTERVAL: self._get_message_interval,
            mavlink.MAV_CMD_REQUEST_MESSAGE: self._request_message,
            mavlink.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES: self._request_autopilot_capabilities,
            mavlink.MAV_CMD_GET_HOME_POSITION: self._get_home_position,
        }

    # ---- the service interface -----------------------------------------------------------------------------
    def handle(self, msg: MAVLinkMessage, now_s: float) -> list[Effect]:
        now_s = check_now(now_s)
        msg_id = message_id(msg)
        try:
            if msg_id == mavlink.MAVLINK_MSG_ID_SET_MODE:
                return self._handle_set_mode_message(msg, now_s)
            if msg_id in (mavlink.MAVLINK_MSG_ID_COMMAND_LONG, mavlink.MAVLINK_MSG_ID_COMMAND_INT):
                return self._handle_command(msg, msg_id, now_s)
        except PeerInputError:
            pass  # not even addressable (no usable target or command id): nothing sensible to answer
        return []

    def poll(self, now_s: float) -> list[Effect]:
        now_s = check_now(now_s)
        while self._replay:
            key, cached = next(iter(self._replay.items()))
            if now_s - cached.time_s <= REPLAY_WINDOW_S:
                break
            del self._replay[key]
        return []

    # ---- the single choke point ----------------------------------------------------------------------------
    def _handle_command(self, msg: MAVLinkMessage, msg_id: int, now_s: float) -> list[Effect]:
        command_id = read_int(msg, "command", lo=0, hi=0xFFFF)
        if not addressed_to(msg, self._identity, any_component=command_id in _INFO_COMMANDS):
            return []
        source = source_of(msg)
        try:
            cmd = decode_command(msg, msg_id)
        except PeerInputError as exc:
            reply = _Reply(CommandResult.DENIED, f"Command {command_id}: {exc}")
            return self._answer(command_id, source, reply, announce=True)

        key = (source, msg_id, cmd.command, cmd.frame, _param_bits(cmd.params))
        cached = self._replay.get(key)
        if (
            cmd.confirmation > 0
            and cmd.command not in _INFO_COMMANDS
            and cached is not None
            and now_s - cached.time_s <= REPLAY_WINDOW_S
        ):
            return [Send(command_ack(cmd.command, cached.result, source.sysid, source.compid))]

        handler = self._handlers.get(cmd.command)
        if handler is None:
            reply = _Reply(CommandResult.UNSUPPORTED)
        else:
            try:
                reply = handler(cmd, now_s)
            except _Reject as rej:
                reply = _Reply(rej.result, rej.reason)
        self._remember(key, now_s, reply.result)
        # Information requests are refused routinely (MAVSDK asks for HOME_POSITION until home exists): no text.
        return self._answer(cmd.command, source, reply, announce=cmd.command not in _INFO_COMMANDS)

    def _answer(self, command_id: int, source: Peer, reply: _Reply, *, announce: bool) -> list[Effect]:
        out = list(reply.effects)
        out.append(Send(command_ack(command_id, int(reply.result), source.sysid, source.compid)))
        if announce and reply.result not in (CommandResult.ACCEPTED, CommandResult.UNSUPPORTED):
            label = _LABELS.get(command_id, f"Command {command_id}")
            text = reply.reason or f"{label} {reply.result.name.lower().replace('_', ' ')}"
            out.extend(Send(m) for m in self._statustext.encode(Severity.CRITICAL, text))
        return out

    def _remember(self, key: tuple[object, ...], now_s: float, result: CommandResult) -> None:
        self._replay[key] = _Cached(now_s, result)
        self._replay.move_to_end(key)
        while len(self._replay) > REPLAY_CACHE_SIZE:
            self._replay.popitem(last=False)

    def _ask(self, request: VehicleRequest, now_s: float) -> _Reply:
        outcome = self._vehicle.command(request, now_s)
        if not isinstance(outcome, CommandOutcome):
            return _Reply(CommandResult.FAILED, "Vehicle gave no outcome")
        return _Reply(CommandResult(outcome.result), outcome.reason)

    # ---- SET_MODE message ----------------------------------------------------------------------------------
    def _handle_set_mode_message(self, msg: MAVLinkMessage, now_s: float) -> list[Effect]:
        if not addressed_to(msg, self._identity, any_component=True):
            return []
        source = source_of(msg)
        try:
            mode = decode_set_mode_message(read_int(msg, "base_mode"), read_int(msg, "custom_mode"))
        except PeerInputError as exc:
            reply = _Reply(CommandResult.DENIED, f"Mode change denied: {exc}")
        else:
            reply = _Reply(CommandResult.ACCEPTED) if mode is None else self._ask(SetMode(mode=mode), now_s)
        # PX4 turns SET_MODE into a DO_SET_MODE command internally and acknowledges that.
        return self._answer(mavlink.MAV_CMD_DO_SET_MODE, source, reply, announce=True)

    # ---- position helpers ----------------------------------------------------------------------------------
    def _lat_lon(self, cmd: DecodedCommand) -> tuple[float, float]:
        """Latitude/longitude in degrees from params 5/6 (COMMAND_LONG) or x/y (COMMAND_INT); NaN when not given.

        0/0 counts as "not given": pymavlink fills unused params with 0 and nobody means the Gulf of Guinea.
        """
        if cmd.frame is None:
            lat, lon = cmd.params[4], cmd.params[5]
            if not (math.isfinite(lat) and math.isfinite(lon)) or (lat == 0 and lon == 0):
                return NAN, NAN
        else:
            if cmd.x == INT32_MAX or cmd.y == INT32_MAX or (cmd.x == 0 and cmd.y == 0):
                return NAN, NAN
            if cmd.frame not in _AMSL_FRAMES | _RELATIVE_FRAMES:
                raise _Reject(CommandResult.DENIED, f"Frame {cmd.frame} not supported for positions")
            lat, lon = cmd.x * 1e-7, cmd.y * 1e-7
        if not (-90.0 <= lat <= 90.0 and -180.0 <= lon <= 180.0):
            raise _Reject(CommandResult.DENIED, f"Position {lat:.7f}, {lon:.7f} out of range")
        return lat, lon

    def _alt_amsl(self, cmd: DecodedCommand) -> float:
        """Altitude AMSL from param7/z: AMSL for COMMAND_LONG and global frames, + home for relative frames."""
        z = cmd.params[6]
        if not math.isfinite(z):
            return NAN
        if cmd.frame is None or cmd.frame in _AMSL_FRAMES:
            return z
        if cmd.frame in _RELATIVE_FRAMES:
            home = self._vehicle.snapshot().home
            if home is None:
                raise _Reject(CommandResult.TEMPORARILY_REJECTED, "Home position not set yet")
            return home.position.alt_amsl_m + z
        raise _Reject(CommandResult.DENIED, f"Frame {cmd.frame} not supported for altitudes")

    # ---- handlers: flight ----------------------------------------------------------------------------------
    def _arm_disarm(self, cmd: DecodedCommand, now_s: float) -> _Reply:
        action = param_to_int(cmd.params[0])
        force = param_to_int(cmd.params[1]) == FORCE_MAGIC
        if action == 1:
            return self._ask(Arm(force=force), now_s)
        if action == 0:
            return self._ask(Disarm(force=force), now_s)
        return _Reply(CommandResult.DENIED, f"Unsupported ARM_DISARM param {cmd.params[0]!r}")

    def _takeoff(self, cmd: DecodedCommand, now_s: float) -> _Reply:
        lat, lon = self._lat_lon(cmd)
        yaw_deg = cmd.params[3]  # MAV_CMD_NAV_TAKEOFF param4 is in degrees
        yaw = math.radians(yaw_deg) if math.isfinite(yaw_deg) else NAN
        return self._ask(Takeoff(alt_amsl_m=self._alt_amsl(cmd), lat_deg=lat, lon_deg=lon, yaw_rad=yaw), now_s)

    def _land(self, cmd: DecodedCommand, now_s: float) -> _Reply:
        lat, lon = self._lat_lon(cmd)
        yaw_deg = cmd.params[3]  # MAV_CMD_NAV_LAND param4 is in degrees
        yaw = math.radians(yaw_deg) if math.isfinite(yaw_deg) else NAN
        return self._ask(Land(lat_deg=lat, lon_deg=lon, yaw_rad=yaw), now_s)

    def _rtl(self, cmd: DecodedCommand, now_s: float) -> _Reply:
        return self._ask(ReturnToLaunch(), now_s)

    def _hold(self, cmd: DecodedCommand, now_s: float) -> _Reply:
        """NAV_LOITER_UNLIM as a command is pymavlink's set_mode_loiter(): Hold."""
        return self._ask(SetMode(mode=Px4Mode.AUTO_LOITER), now_s)

    def _set_mode(self, cmd: DecodedCommand, now_s: float) -> _Reply:
        try:
            mode = decode_do_set_mode(cmd.params[0], cmd.params[1], cmd.params[2])
        except PeerInputError as exc:
            return _Reply(CommandResult.DENIED, f"Mode change denied: {exc}")
        if mode is None:
            return _Reply(CommandResult.ACCEPTED)  # PX4: no mode named, nothing changes
        return self._ask(SetMode(mode=mode), now_s)

    def _reposition(self, cmd: DecodedCommand, now_s: float) -> _Reply:
        speed = cmd.params[0]
        flags = param_to_int(cmd.params[1]) or 0
        yaw = cmd.params[3]  # DO_REPOSITION param4 is in radians
        lat, lon = self._lat_lon(cmd)
        request = Reposition(
            lat_deg=lat,
            lon_deg=lon,
            alt_amsl_m=self._alt_amsl(cmd),
            yaw_rad=yaw if math.isfinite(yaw) else NAN,
            ground_speed_mps=speed if math.isfinite(speed) and speed > 0 else NAN,
            change_mode=bool(flags & mavlink.MAV_DO_REPOSITION_FLAGS_CHANGE_MODE),
        )
        return self._ask(request, now_s)

    def _orbit(self, cmd: DecodedCommand, now_s: float) -> _Reply:
        """MAV_CMD_DO_ORBIT as PX4 reads it: p1 radius (its sign the direction), p2 tangential speed, p3
        ORBIT_YAW_BEHAVIOUR, p5/p6 (x/y) the centre, p7 (z) the circle's altitude, AMSL whatever the COMMAND_INT
        frame (PX4 ignores it; MAVSDK's do_orbit sends an AMSL altitude in GLOBAL_RELATIVE_ALT). NaN is "not given";
        so is an altitude of exactly 0 m, pymavlink's fill, as 0/0 is for the centre."""
        p1, p2, p3 = cmd.params[:3]
        yaw: OrbitYaw | None = None
        if math.isfinite(p3):
            code = param_to_int(p3)
            if code != mavlink.ORBIT_YAW_BEHAVIOUR_UNCHANGED:
                # PX4 flies a value it does not know as its default, facing the centre.
                yaw = OrbitYaw(code) if code is not None and code in _ORBIT_YAWS else OrbitYaw.FRONT_TO_CENTRE
        lat, lon = self._lat_lon(cmd)
        alt = cmd.params[6]
        request = Orbit(
            radius_m=p1,
            velocity_mps=p2,
            yaw=yaw,
            lat_deg=lat,
            lon_deg=lon,
            alt_amsl_m=alt if math.isfinite(alt) and alt != 0.0 else NAN,
        )
        return self._ask(request, now_s)

    def _change_speed(self, cmd: DecodedCommand, now_s: float) -> _Reply:
        kinds = {0: SpeedKind.HORIZONTAL, 1: SpeedKind.HORIZONTAL, 2: SpeedKind.CLIMB, 3: SpeedKind.DESCENT}
        speed_type = 1 if math.isnan(cmd.params[0]) else param_to_int(cmd.params[0])
        kind = kinds.get(speed_type) if speed_type is not None else None
        speed = cmd.params[1]
        if kind is None:
            return _Reply(CommandResult.DENIED, f"Speed type {cmd.params[0]!r} not supported")
        if speed == -1:
            return _Reply(CommandResult.ACCEPTED)  # "no change"
        if speed == -2:
            return self._ask(ChangeSpeed(kind=kind, speed_mps=NAN), now_s)  # back to the default
        if not math.isfinite(speed) or speed < 0:
            return _Reply(CommandResult.DENIED, f"Speed {speed!r} m/s not valid")
        return self._ask(ChangeSpeed(kind=kind, speed_mps=speed), now_s)

    def _set_home(self, cmd: DecodedCommand, now_s: float) -> _Reply:
        if param_to_int(cmd.params[0]) == 1:
            return self._ask(SetHome(use_current=True), now_s)
        lat, lon = self._lat_lon(cmd)
        alt = self._alt_amsl(cmd)
        if not all(math.isfinite(v) for v in (lat, lon, alt)):
            return _Reply(CommandResult.DENIED, "Set home denied: position missing")
        return self._ask(SetHome(use_current=False, lat_deg=lat, lon_deg=lon, alt_amsl_m=alt), now_s)

    def _mission_start(self, cmd: DecodedCommand, now_s: float) -> _Reply:
        first: int | None = None  # NaN or -1: continue from the current item (PX4)
        if not math.isnan(cmd.params[0]):
            first = param_to_int(cmd.params[0])
            if first is None or first < -1:
                return _Reply(CommandResult.DENIED, f"Mission start denied: item {cmd.params[0]!r}")
            if first == -1:
                first = None
        last = param_to_int(cmd.params[1])  # 0 (pymavlink's fill) or NaN: to the end
        return self._ask(MissionStart(first_seq=first, last_seq=last if last is not None and last > 0 else None), now_s)

    def _set_mission_current(self, cmd: DecodedCommand, now_s: float) -> _Reply:
        seq = param_to_int(cmd.params[0])
        if seq is None or seq < -1:
            return _Reply(CommandResult.DENIED, f"Mission item {cmd.params[0]!r} not valid")
        if seq == -1:
            seq = self._vehicle.snapshot().mission.current_seq  # -1: keep the current item
        return self._ask(SetMissionCurrent(seq=seq, reset=param_to_int(cmd.params[1]) == 1), now_s)

    def _flight_termination(self, cmd: DecodedCommand, now_s: float) -> _Reply:
        if cmd.params[0] > 0.5:
            return self._ask(Kill(), now_s)
        return _Reply(CommandResult.ACCEPTED)  # "terminate off": nothing to undo

    def _inject_failure(self, cmd: DecodedCommand, now_s: float) -> _Reply:
        """MAV_CMD_INJECT_FAILURE. An accepted injection is announced with a STATUSTEXT (sent before the ACK) so that
        every log of the link, a ground station's tlog included, records when which failure began."""
        p1, p2, p3, p4 = cmd.params[:4]
        request = InjectFailure(
            unit=param_to_int(p1),
            failure_type=param_to_int(p2),
            instance=0 if math.isnan(p3) else param_to_int(p3),  # unset (NaN) means all instances
            duration_s=p4 if math.isfinite(p4) and p4 > 0 else math.inf,  # unset (0, NaN): for good
        )
        reply = self._ask(request, now_s)
        if reply.result is CommandResult.ACCEPTED and reply.reason:
            text = tuple(Send(m) for m in self._statustext.encode(Severity.WARNING, reply.reason))
            return _Reply(CommandResult.ACCEPTED, effects=text)
        return reply

    def _reboot(self, cmd: DecodedCommand, now_s: float) -> _Reply:
        return _Reply(CommandResult.DENIED, "Reboot not supported by the simulator")

    # ---- handlers: information -----------------------------------------------------------------------------
    def _message_id_param(self, value: float) -> int:
        msg_id = param_to_int(value)
        if msg_id is None or not 0 <= msg_id <= 0xFFFFFF:
            raise _Reject(CommandResult.DENIED, f"Message id {value!r} not valid")
        return msg_id

    def _set_message_interval(self, cmd: DecodedCommand, now_s: float) -> _Reply:
        msg_id = self._message_id_param(cmd.params[0])
        return _Reply(self._streams.set_message_interval(msg_id, cmd.params[1], now_s))

    def _get_message_interval(self, cmd: DecodedCommand, now_s: float) -> _Reply:
        msg_id = self._message_id_param(cmd.params[0])
        interval = self._streams.message_interval_us(msg_id)
        reply_msg = mavlink.MAVLink_message_interval_message(msg_id & 0xFFFF, interval)
        return _Reply(CommandResult.ACCEPTED, effects=(Send(reply_msg),))

    def _request_message(self, cmd: DecodedCommand, now_s: float) -> _Reply:
        result, effects = self._streams.request_message(self._message_id_param(cmd.params[0]), now_s)
        return _Reply(result, effects=tuple(effects))

    def _request_autopilot_capabilities(self, cmd: DecodedCommand, now_s: float) -> _Reply:
        if not cmd.params[0] >= 0.5:
            return _Reply(CommandResult.ACCEPTED)
        result, effects = self._streams.request_message(mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION, now_s)
        return _Reply(result, effects=tuple(effects))

    def _get_home_position(self, cmd: DecodedCommand, now_s: float) -> _Reply:
        result, effects = self._streams.request_message(mavlink.MAVLINK_MSG_ID_HOME_POSITION, now_s)
        return _Reply(result, effects=tuple(effects))


def _param_bits(params: tuple[float, ...]) -> bytes:
    """Params as float32 bytes: a hashable key in which NaN equals NaN (as on the wire)."""
    return struct.pack(f"<{len(params)}d", *params)
