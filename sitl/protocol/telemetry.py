"""The per-link telemetry scheduler: what a PX4 vehicle streams without being asked, and on request.

Each link (API port, ground-station port) has its own scheduler, because clients change rates per link with
MAV_CMD_SET_MESSAGE_INTERVAL. ``poll(now_s)`` emits every stream that is due, built from one ``VehicleSnapshot``;
it also emits at once what clients must not wait for: an extra HEARTBEAT on arm/disarm/mode/status change (MAVSDK
reads armed and flight mode only from heartbeats), MISSION_CURRENT when the mission progresses,
MISSION_ITEM_REACHED, HOME_POSITION when home moves, EXTENDED_SYS_STATE when the landed state changes.

Rates are in simulation time, like everything else here; call ``poll`` at least twice as often as the fastest stream
(every physics step is fine: between the due time of the next stream and the next check for events, a poll returns
at once without building a snapshot of the vehicle, which is most of what telemetry costs).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Final

from pymavlink.dialects.v20 import common as mavlink

from sitl.autopilot.vehicle_api import CommandResult, VehicleApi, VehicleSnapshot
from sitl.protocol import messages
from sitl.protocol.core import INT32_MAX, Effect, Identity, MAVLinkMessage, Send, check_now
from sitl.protocol.messages import BUILDERS
from sitl.protocol.modes import base_mode, system_status
from sitl.protocol.statustext import StatusTextEncoder

# Streams a PX4 multicopter sends by default (contract section 8), at rates a laptop running a swarm can afford.
DEFAULT_RATES_HZ: Final[Mapping[int, float]] = {
    mavlink.MAVLINK_MSG_ID_HEARTBEAT: 1.0,
    mavlink.MAVLINK_MSG_ID_SYS_STATUS: 5.0,
    mavlink.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: 5.0,
    mavlink.MAVLINK_MSG_ID_GPS_RAW_INT: 5.0,
    mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: 10.0,
    mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED: 10.0,
    mavlink.MAVLINK_MSG_ID_ATTITUDE: 10.0,
    mavlink.MAVLINK_MSG_ID_ATTITUDE_QUATERNION: 10.0,
    mavlink.MAVLINK_MSG_ID_VFR_HUD: 4.0,
    mavlink.MAVLINK_MSG_ID_ALTITUDE: 1.0,
    mavlink.MAVLINK_MSG_ID_BATTERY_STATUS: 0.5,
    mavlink.MAVLINK_MSG_ID_HOME_POSITION: 0.5,
    mavlink.MAVLINK_MSG_ID_MISSION_CURRENT: 1.0,
    mavlink.MAVLINK_MSG_ID_SYSTEM_TIME: 1.0,
    mavlink.MAVLINK_MSG_ID_ORBIT_EXECUTION_STATUS: 2.0,  # PX4's rate; sent only while in Orbit
}
MAX_RATE_HZ: Final = 250.0  # SET_MESSAGE_INTERVAL faster than this is clamped
MIN_EXTRA_HEARTBEAT_INTERVAL_S: Final = 0.05  # extra heartbeats on state changes at most this often (flapping)
EVENT_CHECK_INTERVAL_S: Final = 0.01  # state changes the vehicle makes itself (landed, mode) go out within this


class PollShare:
    """What the telemetry of every link of one drone builds alike during one poll: the vehicle snapshot, and each
    stream message built from it.

    The links' schedulers run on one clock with the same default rates, so at a poll the same streams are
    usually due on both, and nothing changes the vehicle between one link's poll and the next (polls only time
    out transfers and emit telemetry). Opened around a poll of all links (``MavlinkEndpoint.poll``), every link
    gets the same snapshot and a message due on several links is built once and packed for each with its own
    sequence number. Closed, it passes every call through, so a scheduler used alone behaves as before.
    """

    def __init__(self, vehicle: VehicleApi) -> None:
        self._vehicle = vehicle
        self._open = False
        self._snap: VehicleSnapshot | None = None
        self._built: dict[tuple[int, int], MAVLinkMessage | None] = {}  # emptied at every poll

    def open(self) -> None:
        self._open = True

    def close(self) -> None:
        self._open = False
        self._snap = None
        self._built.clear()

    def snapshot(self) -> VehicleSnapshot:
        if not self._open:
            return self._vehicle.snapshot()
        if self._snap is None:
            self._snap = self._vehicle.snapshot()
        return self._snap

    def build(self, msg_id: int, snap: VehicleSnapshot, identity: Identity) -> MAVLinkMessage | None:
        """``BUILDERS[msg_id](snap, identity)``, once per poll while open (``snap`` is then this poll's)."""
        if not self._open:
            return BUILDERS[msg_id](snap, identity)
        key = (msg_id, id(identity))  # the record's identity: hashing its fields cost more than the look-up saves
        if key not in self._built:
            self._built[key] = BUILDERS[msg_id](snap, identity)
        return self._built[key]


@dataclass(slots=True)
class _Stream:
    interval_s: float
    next_due_s: float | None  # None: due at the next poll


class TelemetryScheduler:
    """Periodic and event-driven telemetry for one link; also serves SET_MESSAGE_INTERVAL and REQUEST_MESSAGE."""

    handles: frozenset[int] = frozenset()

    def __init__(
        self,
        identity: Identity,
        vehicle: VehicleApi,
        *,
        rates_hz: Mapping[int, float] = DEFAULT_RATES_HZ,
        statustext: StatusTextEncoder | None = None,
        share: PollShare | None = None,
    ) -> None:
        self._identity = identity
        self._vehicle = vehicle
        self._share = share if share is not None else PollShare(vehicle)
        self._defaults = {mid: hz for mid, hz in rates_hz.items() if mid in BUILDERS and hz > 0}
        self._streams: dict[int, _Stream] = {mid: _Stream(1.0 / hz, None) for mid, hz in self._defaults.items()}
        self._statustext = statustext or StatusTextEncoder()
        self._last_heartbeat_key: tuple[int, int, int] | None = None
        self._last_extra_heartbeat_s = -math.inf
        self._last_mission_key: tuple[int, int, int] | None = None
        self._last_reached: int | None = None
        self._last_home_key: tuple[float, float, float] | None = None
        self._last_landed: int | None = None
        self._primed = False
        self._next_poll_s = -math.inf  # nothing to do before this: no stream due, no event check
        # A vehicle may offer ``event_state()``: every input of the event messages, cheaper than a snapshot. A poll
        # with no stream due then builds no snapshot while it equals what the last check saw, unless an extra
        # HEARTBEAT is still held back by its rate limit. Without it, every poll builds one.
        self._event_state: Callable[[], object] | None = getattr(vehicle, "event_state", None)
        self._checked_event_state: object = None  # event_state() at the last event check (None: check next time)

    # ---- the service interface -----------------------------------------------------------------------------
    def handle(self, msg: MAVLinkMessage, now_s: float) -> list[Effect]:
        """Telemetry consumes no messages; rate changes arrive as commands (see CommandService)."""
        check_now(now_s)
        return []

    def poll(self, now_s: float) -> list[Effect]:
        now_s = check_now(now_s)
        if now_s < self._next_poll_s:
            return []
        event_state = self._event_state() if self._event_state is not None else None
        if event_state is not None and event_state == self._checked_event_state:
            next_poll_s = now_s + EVENT_CHECK_INTERVAL_S
            for stream in self._streams.values():
                due_s = stream.next_due_s
                if due_s is None or now_s >= due_s:
                    break  # a stream is due: go on below
                if due_s < next_poll_s:
                    next_poll_s = due_s
            else:
                self._next_poll_s = next_poll_s  # nothing due and nothing changed: no snapshot
                return []
        share = self._share
        snap = share.snapshot()
        out = self._events(snap, now_s)
        next_poll_s = now_s + EVENT_CHECK_INTERVAL_S
        for msg_id, stream in self._streams.items():
            due_s = stream.next_due_s
            if due_s is None or now_s >= due_s:
                msg = share.build(msg_id, snap, self._identity)
                if msg_id == mavlink.MAVLINK_MSG_ID_HEARTBEAT:
                    self._note_heartbeat(snap, now_s)
                if msg is not None:
                    out.append(Send(msg))
                due_s = stream.next_due_s = self._next_due(stream, now_s)
            if due_s < next_poll_s:
                next_poll_s = due_s
        self._next_poll_s = next_poll_s
        # An extra HEARTBEAT held back by its rate limit must be looked at again even if nothing else changes.
        held_back = self._heartbeat_key(snap) != self._last_heartbeat_key
        self._checked_event_state = None if held_back else event_state
        return out

    def state_change_effects(self, now_s: float) -> list[Effect]:
        """Only the event-driven messages (used right after a command so the new state goes out at once)."""
        now_s = check_now(now_s)
        self._checked_event_state = None  # a command changed the vehicle: the next poll checks in full
        return self._events(self._vehicle.snapshot(), now_s)

    # ---- rate control --------------------------------------------------------------------------------------
    def set_message_interval(self, msg_id: int, interval_us: float, now_s: float) -> CommandResult:
        """MAV_CMD_SET_MESSAGE_INTERVAL: 0 = default rate, -1 = off, > 0 = interval in microseconds."""
        check_now(now_s)
        if msg_id == mavlink.MAVLINK_MSG_ID_HEARTBEAT:
            # PX4 refuses (FAILED) to change the heartbeat: it is how every client knows the vehicle is there, and a
            # command turning it off or down to once an hour would make the vehicle look lost to all of them.
            return CommandResult.FAILED
        if msg_id not in BUILDERS:
            return CommandResult.UNSUPPORTED
        # MESSAGE_INTERVAL reports an interval as int32 microseconds: one it could not report (beyond 35 minutes) is
        # as invalid as a negative one, and storing it would make GET_MESSAGE_INTERVAL unpackable.
        if not math.isfinite(interval_us) or (interval_us < 0 and interval_us != -1) or interval_us > INT32_MAX:
            return CommandResult.DENIED
        if interval_us == -1:
            self._streams.pop(msg_id, None)
            return CommandResult.ACCEPTED
        if interval_us == 0:
            default_hz = self._defaults.get(msg_id)
            if default_hz is None:
                self._streams.pop(msg_id, None)  # PX4: a message without a default stream is off by default
                return CommandResult.ACCEPTED
            interval_s = 1.0 / default_hz
        else:
            interval_s = max(interval_us * 1e-6, 1.0 / MAX_RATE_HZ)
        self._streams[msg_id] = _Stream(interval_s, None)
        self._next_poll_s = -math.inf
        return CommandResult.ACCEPTED

    def message_interval_us(self, msg_id: int) -> int:
        """MESSAGE_INTERVAL.interval_us: -1 when not streamed, 0 when the message is unknown."""
        if msg_id not in BUILDERS:
            return 0
        stream = self._streams.get(msg_id)
        return -1 if stream is None else min(round(stream.interval_s * 1e6), INT32_MAX)

    def request_message(self, msg_id: int, now_s: float) -> tuple[CommandResult, list[Effect]]:
        """MAV_CMD_REQUEST_MESSAGE: the message now, or DENIED when it cannot be produced (PX4's answer)."""
        check_now(now_s)
        builder = BUILDERS.get(msg_id)
        if builder is None:
            return CommandResult.DENIED, []
        msg = builder(self._vehicle.snapshot(), self._identity)
        if msg is None:
            return CommandResult.DENIED, []
        return CommandResult.ACCEPTED, [Send(msg)]

    def statustext(self, severity: int, text: str) -> list[Effect]:
        """STATUSTEXT effects for an event of the vehicle (the shell forwards the autopilot's events with this)."""
        return [Send(m) for m in self._statustext.encode(severity, text)]

    # ---- internals -----------------------------------------------------------------------------------------
    @staticmethod
    def _next_due(stream: _Stream, now_s: float) -> float:
        if stream.next_due_s is None or now_s - stream.next_due_s >= stream.interval_s:
            return now_s + stream.interval_s  # first send, or polled too late: restart the phase, no burst
        return stream.next_due_s + stream.interval_s  # keep the average rate exact

    def _heartbeat_key(self, snap: VehicleSnapshot) -> tuple[int, int, int]:
        status = system_status(armed=snap.armed, failsafe=snap.failsafe, terminated=snap.flight_terminated)
        return base_mode(snap.mode, snap.armed), snap.mode.custom_mode, status

    def _note_heartbeat(self, snap: VehicleSnapshot, now_s: float) -> None:
        self._last_heartbeat_key = self._heartbeat_key(snap)

    def _events(self, snap: VehicleSnapshot, now_s: float) -> list[Effect]:
        home = snap.home
        home_key = (
            (home.position.lat_deg, home.position.lon_deg, home.position.alt_amsl_m) if home is not None else None
        )
        progress = snap.mission
        mission_key = (progress.current_seq, progress.total, int(progress.state))
        if not self._primed:  # the periodic streams report the initial state; events are changes only
            self._primed = True
            self._last_heartbeat_key = self._heartbeat_key(snap)
            self._last_mission_key = mission_key
            self._last_reached = progress.reached_seq
            self._last_home_key = home_key
            self._last_landed = int(snap.landed_state)
            return []

        out: list[Effect] = []
        key = self._heartbeat_key(snap)
        if key != self._last_heartbeat_key and now_s - self._last_extra_heartbeat_s >= MIN_EXTRA_HEARTBEAT_INTERVAL_S:
            out.append(Send(messages.heartbeat(snap, self._identity)))
            self._note_heartbeat(snap, now_s)
            self._last_extra_heartbeat_s = now_s
            stream = self._streams.get(mavlink.MAVLINK_MSG_ID_HEARTBEAT)
            if stream is not None:
                stream.next_due_s = now_s + stream.interval_s

        if mission_key != self._last_mission_key:
            out.append(Send(messages.mission_current(snap, self._identity)))
        self._last_mission_key = mission_key

        if progress.reached_seq != self._last_reached:
            reached = messages.mission_item_reached(snap, self._identity)
            if reached is not None:
                out.append(Send(reached))
        self._last_reached = progress.reached_seq

        if home_key != self._last_home_key:
            msg = messages.home_position(snap, self._identity)
            if msg is not None:
                out.append(Send(msg))
        self._last_home_key = home_key

        landed = int(snap.landed_state)
        if landed != self._last_landed:
            out.append(Send(messages.extended_sys_state(snap, self._identity)))
        self._last_landed = landed
        return out
