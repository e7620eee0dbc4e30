"""The MAVLink mission protocol as a ground station speaks it: upload, download and progress, with no IO and no clock.

Like gcs/mavlink/commands.py and gcs/mavlink/params.py, ``MissionClient`` is fed every received message with the current
time and returns ``Send`` effects; the caller sends them and calls ``poll`` when ``next_due_s`` comes. A finished
transfer is collected with ``take``. Any number of drones may be served at once, one transfer per drone at a time (a PX4
mission server runs one transfer at a time, of any mission type, and answers a second with "busy").

Mission types 0 (mission) and 1 (fence) travel the same way, as PX4 and QGroundControl move them:

- Upload: MISSION_COUNT -> the vehicle asks MISSION_REQUEST_INT {seq} (or MISSION_REQUEST) for each item and gets
  MISSION_ITEM_INT -> MISSION_ACK ends it. A request for an item already sent is answered again (our item was
  lost); the vehicle drives the pace and re-requests what it misses. Without any answer to MISSION_COUNT it is sent
  again every ``timeout_s``; while items flow the client only waits, as MAVSDK does, since the vehicle's own
  re-requests recover lost items and a client resending on its own timer would race them. Only after the last item
  does nobody else recover a loss: if no MISSION_ACK comes, the last item is sent again, which a vehicle holding
  the whole mission answers with its ACK again (the ACK was lost) and one still waiting for it takes (the item was).
- Download: MISSION_REQUEST_LIST -> MISSION_COUNT -> we request each item with MISSION_REQUEST_INT -> the last one
  is acknowledged with MISSION_ACK ACCEPTED. A silent try is repeated (the list request, or the request of the item
  we wait for).
- Timeouts and retries are MAVSDK's mission-transfer rules: ``MISSION_TIMEOUT_S`` (0.5 s) per try,
  ``MISSION_RETRIES`` (5) tries again without progress; progress (an item requested or received) resets the count.
  Giving up sends MISSION_ACK OPERATION_CANCELLED so the vehicle drops its half of the transfer at once.
- A MISSION_ACK with any result but ACCEPTED ends the transfer with that result, named as MAVLink names it
  (``MAV_MISSION_UNSUPPORTED_FRAME``), with the item it concerns when the vehicle was asking for one.

``MissionProgress`` follows what the vehicles report of a mission in flight: MISSION_CURRENT (seq, total, state)
and MISSION_ITEM_REACHED, per drone.

Times are the caller's clock (the swarm's simulated seconds), so tests advance a number instead of sleeping.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import Enum
from typing import Any, Final

from pymavlink.dialects.v20 import common as mavlink

from gcs.mavlink.commands import AUTOPILOT_COMPID, Send
from gcs.mavlink.transactions import Transactions
from gcs.mavlink.transport import GCS_COMPID, GCS_SYSID

MISSION_TIMEOUT_S: Final = 0.5  # MAVSDK's per-try timeout of a mission transfer
MISSION_RETRIES: Final = 5  # MAVSDK's tries again without progress before a transfer fails
MISSION_TYPE_MISSION: Final = mavlink.MAV_MISSION_TYPE_MISSION
MISSION_TYPE_FENCE: Final = mavlink.MAV_MISSION_TYPE_FENCE
# MISSION_CURRENT.mission_state: complete means the mission has run to its end (MAVSDK's is_mission_finished)
MISSION_STATE_COMPLETE: Final = mavlink.MISSION_STATE_COMPLETE
MISSION_STATE_NAMES: Final = {  # MISSION_STATE_NOT_STARTED -> "not started", as the status table shows them
    value: entry.name.removeprefix("MISSION_STATE_").replace("_", " ").lower()
    for value, entry in mavlink.enums["MISSION_STATE"].items()
    if entry.name.startswith("MISSION_STATE_") and not entry.name.endswith("ENUM_END")
}
GLOBAL_FRAMES: Final = frozenset(
    {
        mavlink.MAV_FRAME_GLOBAL,
        mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT,
        mavlink.MAV_FRAME_GLOBAL_INT,
        mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
        mavlink.MAV_FRAME_GLOBAL_TERRAIN_ALT,
        mavlink.MAV_FRAME_GLOBAL_TERRAIN_ALT_INT,
    }
)


@dataclass(frozen=True, slots=True, kw_only=True)
class WireItem:
    """One MISSION_ITEM_INT's contents. ``x``/``y`` are integers as the INT message carries them: latitude and
    longitude in degE7 for global frames, the parameter itself (rounded) otherwise. NaN params mean "not set"."""

    seq: int
    frame: int
    command: int
    autocontinue: bool = True
    param1: float = 0.0
    param2: float = 0.0
    param3: float = 0.0
    param4: float = 0.0
    x: int = 0
    y: int = 0
    z: float = 0.0
    mission_type: int = MISSION_TYPE_MISSION

    @property
    def is_global(self) -> bool:
        return self.frame in GLOBAL_FRAMES

    def message(self, target_sysid: int, target_compid: int = AUTOPILOT_COMPID) -> Any:
        return mavlink.MAVLink_mission_item_int_message(
            target_sysid, target_compid, self.seq, self.frame, self.command, 0, int(self.autocontinue),
            self.param1, self.param2, self.param3, self.param4, self.x, self.y, self.z, self.mission_type,
        )  # fmt: skip


def item_from_message(msg: Any) -> WireItem:
    """A received MISSION_ITEM_INT (or a float MISSION_ITEM, converted to the INT encoding) as a ``WireItem``."""
    x, y = msg.x, msg.y
    if msg.get_type() == "MISSION_ITEM":
        scale = 1e7 if msg.frame in GLOBAL_FRAMES else 1.0
        x = round(x * scale) if math.isfinite(x) else 0
        y = round(y * scale) if math.isfinite(y) else 0
    return WireItem(seq=msg.seq, frame=msg.frame, command=msg.command, autocontinue=bool(msg.autocontinue),
                    param1=msg.param1, param2=msg.param2, param3=msg.param3, param4=msg.param4, x=int(x), y=int(y),
                    z=msg.z, mission_type=getattr(msg, "mission_type", 0))  # fmt: skip


def result_name(result: int) -> str:
    """MAV_MISSION_RESULT as MAVLink names it (``MAV_MISSION_UNSUPPORTED_FRAME``), or the number if unknown."""
    entry = mavlink.enums["MAV_MISSION_RESULT"].get(result)
    return entry.name if entry is not None else f"MAV_MISSION_RESULT {result}"


def type_name(mission_type: int) -> str:
    return {MISSION_TYPE_MISSION: "mission", MISSION_TYPE_FENCE: "fence"}.get(mission_type, f"type {mission_type}")


class Direction(Enum):
    UPLOAD = "upload"
    DOWNLOAD = "download"


@dataclass(frozen=True, slots=True, kw_only=True)
class TransferResult:
    """How one transfer with one drone ended: ``error`` None when it succeeded (a download's items then in
    ``items``), else one line saying why (refused with a MAV_MISSION_RESULT, or no answer)."""

    sysid: int
    mission_type: int
    direction: Direction
    items: tuple[WireItem, ...] = ()
    error: str | None = None
    result: int | None = None  # the MAV_MISSION_RESULT that ended it; None: no answer

    @property
    def ok(self) -> bool:
        return self.error is None


class TransferInFlight(RuntimeError):
    """Our own misuse: a second transfer with a drone whose first has not ended."""


@dataclass(slots=True, kw_only=True)
class _Transfer:
    sysid: int
    mission_type: int
    direction: Direction
    items: list[WireItem]  # upload: what to send; download: what has arrived
    due_s: float = 0.0
    retries_left: int = 0
    count: int | None = None  # download: announced by the vehicle's MISSION_COUNT; upload: len(items)
    last_requested: int | None = None  # upload: the seq the vehicle asked for last
    int_mode: bool = True  # download: the vehicle answers float MISSION_ITEM, ask in kind (classic clients)


class MissionClient:
    """Mission transfers in flight with any number of drones; see the module docstring for the rules."""

    def __init__(
        self,
        *,
        timeout_s: float = MISSION_TIMEOUT_S,
        retries: int = MISSION_RETRIES,
        own_sysid: int = GCS_SYSID,
        own_compid: int = GCS_COMPID,
    ) -> None:
        self.own_sysid = own_sysid
        self.own_compid = own_compid
        # sysid -> its transfer (one at a time with a drone), and (sysid, mission type) -> how it ended
        self._core: Transactions[int, _Transfer, tuple[int, int], TransferResult] = Transactions(timeout_s, retries)

    # ---- starting --------------------------------------------------------------------------------------------------
    def start_upload(self, sysid: int, items: list[WireItem], mission_type: int, now_s: float) -> list[Send]:
        """Begin uploading ``items`` (their seq 0..n-1, their mission_type ``mission_type``); the MISSION_COUNT."""
        if [item.seq for item in items] != list(range(len(items))):
            raise ValueError("mission items must be numbered 0..n-1 in order")
        if any(item.mission_type != mission_type for item in items):
            raise ValueError(f"every item of a {type_name(mission_type)} upload must carry mission_type {mission_type}")
        work = self._begin(sysid, mission_type, Direction.UPLOAD, list(items), now_s)
        work.count = len(items)
        return [self._count(work)]

    def start_download(self, sysid: int, mission_type: int, now_s: float) -> list[Send]:
        """Begin downloading the drone's list of ``mission_type``; the MISSION_REQUEST_LIST."""
        work = self._begin(sysid, mission_type, Direction.DOWNLOAD, [], now_s)
        return [self._request_list(work)]

    def _begin(self, sysid: int, mission_type: int, direction: Direction, items: list[WireItem],
               now_s: float) -> _Transfer:  # fmt: skip
        running = self._core.running(sysid)
        if running is not None:
            raise TransferInFlight(
                f"sysid {sysid}: a {type_name(running.mission_type)} {running.direction.value} is still running"
            )
        work = _Transfer(sysid=sysid, mission_type=mission_type, direction=direction, items=items)
        return self._core.begin(sysid, (sysid, mission_type), work, now_s)

    # ---- messages out ----------------------------------------------------------------------------------------------
    def _count(self, work: _Transfer) -> Send:
        return Send(work.sysid, mavlink.MAVLink_mission_count_message(
            work.sysid, AUTOPILOT_COMPID, len(work.items), work.mission_type))  # fmt: skip

    def _request_list(self, work: _Transfer) -> Send:
        return Send(work.sysid, mavlink.MAVLink_mission_request_list_message(
            work.sysid, AUTOPILOT_COMPID, work.mission_type))  # fmt: skip

    def _request_item(self, work: _Transfer) -> Send:
        cls = mavlink.MAVLink_mission_request_int_message if work.int_mode else mavlink.MAVLink_mission_request_message
        return Send(work.sysid, cls(work.sysid, AUTOPILOT_COMPID, len(work.items), work.mission_type))

    def _ack(self, work: _Transfer, result: int) -> Send:
        return Send(work.sysid, mavlink.MAVLink_mission_ack_message(
            work.sysid, AUTOPILOT_COMPID, result, work.mission_type))  # fmt: skip

    # ---- messages in -----------------------------------------------------------------------------------------------
    def handle(self, msg: Any, now_s: float) -> list[Send]:
        """A received message; the mission protocol's ones from a drone in a transfer move it on."""
        kind = msg.get_type()
        if kind not in _HANDLED or msg.get_srcComponent() != AUTOPILOT_COMPID:
            return []
        work = self._core.running(msg.get_srcSystem())
        if work is None:
            return []
        target_system = getattr(msg, "target_system", 0)
        target_component = getattr(msg, "target_component", 0)
        if (target_system and target_system != self.own_sysid) or (
            target_component and target_component != self.own_compid
        ):
            return []  # a transfer with another ground station
        if getattr(msg, "mission_type", 0) != work.mission_type:
            return []
        if work.direction is Direction.UPLOAD:
            return self._handle_upload(work, kind, msg, now_s)
        return self._handle_download(work, kind, msg, now_s)

    def _handle_upload(self, work: _Transfer, kind: str, msg: Any, now_s: float) -> list[Send]:
        if kind in ("MISSION_REQUEST_INT", "MISSION_REQUEST"):
            seq = msg.seq
            if not 0 <= seq < len(work.items):
                self._finish(work, f"the drone asked for item {seq} of {len(work.items)}", None)
                return [self._ack(work, mavlink.MAV_MISSION_INVALID_SEQUENCE)]
            work.last_requested = seq
            self._core.fresh(work, now_s)
            item = work.items[seq]
            if kind == "MISSION_REQUEST":  # the vehicle asks for the float flavour: answer in kind
                return [Send(work.sysid, _float_item_message(item, work.sysid))]
            return [Send(work.sysid, item.message(work.sysid))]
        if kind == "MISSION_ACK":
            result = msg.type
            if result == mavlink.MAV_MISSION_ACCEPTED:
                if work.items and work.last_requested != len(work.items) - 1:
                    return []  # an ACK of something earlier (a previous transfer's, repeated): not ours
                self._finish(work, None, result)
            else:
                where = f" (item {work.last_requested})" if work.last_requested is not None else ""
                self._finish(work, f"refused{where}: {result_name(result)}", result)
        return []

    def _handle_download(self, work: _Transfer, kind: str, msg: Any, now_s: float) -> list[Send]:
        if kind == "MISSION_COUNT" and work.count is None:
            work.count = msg.count
            self._core.fresh(work, now_s)
            if work.count == 0:
                self._finish(work, None, mavlink.MAV_MISSION_ACCEPTED)
                return [self._ack(work, mavlink.MAV_MISSION_ACCEPTED)]
            return [self._request_item(work)]
        if kind in ("MISSION_ITEM_INT", "MISSION_ITEM") and work.count is not None:
            if msg.seq != len(work.items):
                return []  # a duplicate or out of order: the request for the right one is repeated on the timer
            work.items.append(item_from_message(msg))
            self._core.fresh(work, now_s)
            if len(work.items) < work.count:
                return [self._request_item(work)]
            self._finish(work, None, mavlink.MAV_MISSION_ACCEPTED)
            return [self._ack(work, mavlink.MAV_MISSION_ACCEPTED)]
        if kind == "MISSION_ACK" and msg.type != mavlink.MAV_MISSION_ACCEPTED:
            if msg.type == mavlink.MAV_MISSION_UNSUPPORTED and work.int_mode and work.count is not None:
                work.int_mode = False  # the vehicle cannot do the INT flavour: ask in the float one
                return [self._request_item(work)]
            self._finish(work, f"refused: {result_name(msg.type)}", msg.type)
        return []

    def poll(self, now_s: float) -> list[Send]:
        """Repeat every try that timed out; end (and cancel on the drone) those out of retries."""
        out: list[Send] = []
        for work, exhausted in self._core.timed_out(now_s):
            if exhausted:
                self._finish(work, f"no answer after {self._core.retries + 1} tries", None)
                out.append(self._ack(work, mavlink.MAV_MISSION_OPERATION_CANCELLED))
                continue
            if work.direction is Direction.UPLOAD:
                if work.last_requested is None:
                    out.append(self._count(work))  # MISSION_COUNT lost, or its first request: announce again
                elif work.last_requested == len(work.items) - 1:
                    # The last item sent and no MISSION_ACK: the item or the ACK was lost. The vehicle asks for
                    # nothing more, so send the last item again; a vehicle that has the whole mission answers a
                    # repeated last item with its ACK again (PX4 does).
                    last = work.items[-1]
                    out.append(Send(work.sysid, last.message(work.sysid)))
                # else: the vehicle re-requests what it misses; we only count its silence
            elif work.count is None:
                out.append(self._request_list(work))
            else:
                out.append(self._request_item(work))
        return out

    def _finish(self, work: _Transfer, error: str | None, result: int | None) -> None:
        what = f"{type_name(work.mission_type)} {work.direction.value}"
        items = tuple(work.items) if work.direction is Direction.DOWNLOAD and error is None else ()
        self._core.finish(work.sysid, (work.sysid, work.mission_type), TransferResult(
            sysid=work.sysid, mission_type=work.mission_type, direction=work.direction, items=items,
            error=None if error is None else f"sysid {work.sysid}: {what} {error}", result=result,
        ))  # fmt: skip

    # ---- the caller's side -----------------------------------------------------------------------------------------
    def next_due_s(self) -> float:
        """When ``poll`` next has something to do (inf: nothing in flight)."""
        return self._core.next_due_s()

    def in_flight(self, sysid: int) -> bool:
        return self._core.running(sysid) is not None

    def cancel(self, sysid: int, mission_type: int) -> None:
        """Forget a transfer (its caller gave up waiting): nothing more is sent, late answers are ignored."""
        work = self._core.running(sysid)
        if work is None or work.mission_type == mission_type:
            self._core.cancel(sysid, (sysid, mission_type))
        else:  # another type's transfer runs on: only this type's outcome goes
            self._core.take((sysid, mission_type))

    def take(self, sysid: int, mission_type: int) -> TransferResult | None:
        """How the transfer of ``mission_type`` with ``sysid`` ended, once (None while running or never started)."""
        return self._core.take((sysid, mission_type))


_HANDLED: Final = frozenset(
    {"MISSION_REQUEST_INT", "MISSION_REQUEST", "MISSION_ACK", "MISSION_COUNT", "MISSION_ITEM_INT", "MISSION_ITEM"}
)


def _float_item_message(item: WireItem, target_sysid: int) -> Any:
    scale = 1e7 if item.is_global else 1.0
    return mavlink.MAVLink_mission_item_message(
        target_sysid, AUTOPILOT_COMPID, item.seq, item.frame, item.command, 0, int(item.autocontinue),
        item.param1, item.param2, item.param3, item.param4, item.x / scale, item.y / scale, item.z, item.mission_type,
    )  # fmt: skip


# ---- progress of a mission in flight ---------------------------------------------------------------------------------
@dataclass(slots=True)
class DroneProgress:
    """What one drone has said of its mission: the item it flies, of how many, its MISSION_STATE, what it reached."""

    current_seq: int = -1
    total: int = 0
    state: int = 0  # MISSION_STATE; 0: not reported (an old MISSION_CURRENT without the field)
    reached: list[int] = field(default_factory=list)  # MISSION_ITEM_REACHED seqs, in the order they came


class MissionProgress:
    """Every drone's mission progress from MISSION_CURRENT and MISSION_ITEM_REACHED (pure: messages in)."""

    def __init__(self) -> None:
        self.drones: dict[int, DroneProgress] = {}

    def handle(self, msg: Any, _now_s: float = 0.0) -> None:
        kind = msg.get_type()
        if kind not in ("MISSION_CURRENT", "MISSION_ITEM_REACHED") or msg.get_srcComponent() != AUTOPILOT_COMPID:
            return
        progress = self.drones.setdefault(msg.get_srcSystem(), DroneProgress())
        if kind == "MISSION_CURRENT":
            progress.current_seq, progress.total = msg.seq, msg.total
            progress.state = getattr(msg, "mission_state", 0)
        elif not progress.reached or progress.reached[-1] != msg.seq:  # PX4 repeats it; keep each arrival once
            progress.reached.append(msg.seq)

    def reset(self, sysid: int) -> None:
        """Forget a drone's progress (a new mission is about to start)."""
        self.drones.pop(sysid, None)

    def finished(self, sysid: int, last_seq: int) -> bool:
        """Whether the drone says its mission is complete, or reports the last item reached."""
        progress = self.drones.get(sysid)
        if progress is None:
            return False
        return progress.state == MISSION_STATE_COMPLETE or last_seq in progress.reached
