"""The parameter protocol as a ground station speaks it, with no IO and no clock of its own.

PARAM_SET and PARAM_VALUE as PX4 expects them: integers travel bytewise in the float field. ``ParamClient`` sets
parameters the way MAVSDK's parameter client does: a PARAM_SET is confirmed only by the drone's PARAM_VALUE echo of
the same name carrying the value that was sent. A try without an echo times out and is sent again; an echo with
another value may be a stale one still on its way, so it is sent again at once; after ``retries`` resends the set
ends, refused (the last echo says what the drone kept) or with no answer (PX4 does not answer an unknown name).
Several sets, to several drones, may be in flight at once; one per drone and name.

Like gcs/mavlink/commands.py the client is fed received messages and the current time and returns ``Send`` effects; the
caller sends them and calls ``poll`` when ``next_due_s`` comes.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass
from typing import Any, Final

from pymavlink.dialects.v20 import common as mavlink

from gcs.mavlink.commands import AUTOPILOT_COMPID, Send
from gcs.mavlink.transactions import Transactions

PARAM_TIMEOUT_S: Final = 1.0  # for a PARAM_VALUE echo, per try (on the caller's clock)
PARAM_RETRIES: Final = 3  # MAVSDK's resends after the first try

_INT_PARAM_TYPES = {
    mavlink.MAV_PARAM_TYPE_UINT8: "<B",
    mavlink.MAV_PARAM_TYPE_INT8: "<b",
    mavlink.MAV_PARAM_TYPE_UINT16: "<H",
    mavlink.MAV_PARAM_TYPE_INT16: "<h",
    mavlink.MAV_PARAM_TYPE_UINT32: "<I",
    mavlink.MAV_PARAM_TYPE_INT32: "<i",
}


def param_set_message(sysid: int, name: str, value: int | float) -> Any:
    """PARAM_SET as PX4 expects it: an int bytewise in the float field as INT32, a float as REAL32."""
    if isinstance(value, int):
        bits = struct.unpack("<f", struct.pack("<i", value))[0]
        return mavlink.MAVLink_param_set_message(sysid, 1, name.encode("ascii"), bits, mavlink.MAV_PARAM_TYPE_INT32)
    return mavlink.MAVLink_param_set_message(sysid, 1, name.encode("ascii"), value, mavlink.MAV_PARAM_TYPE_REAL32)


def param_value(msg: Any) -> float:
    """The number a PARAM_VALUE carries (integer types bytewise)."""
    fmt = _INT_PARAM_TYPES.get(msg.param_type)
    if fmt is None:
        return float(msg.param_value)
    raw = struct.pack("<f", msg.param_value)
    return float(struct.unpack(fmt, raw[: struct.calcsize(fmt)])[0])


def same_value(kept: float, sent: int | float) -> bool:
    """Whether an echo carries the value sent (a float travels as float32, so only to float32's precision)."""
    return math.isclose(kept, sent, rel_tol=1e-6, abs_tol=1e-9)


@dataclass(frozen=True, slots=True)
class ParamResult:
    """How one PARAM_SET to one drone ended."""

    sysid: int
    name: str
    value: int | float | None  # what was sent; None: a read (PARAM_REQUEST_READ)
    kept: float | None  # the value the drone's last echo carried; None when it never answered

    @property
    def ok(self) -> bool:
        return self.kept is not None and (self.value is None or same_value(self.kept, self.value))

    @property
    def refused(self) -> bool:
        return self.kept is not None and not self.ok


@dataclass(slots=True, kw_only=True)
class _Set:
    sysid: int
    name: str
    value: int | float | None  # None: a read
    retries_left: int = 0
    due_s: float = 0.0
    kept: float | None = None


class ParamInFlight(RuntimeError):
    """Our own misuse: a second set of the same parameter on the same drone before the first has ended."""


class ParamClient:
    """Parameter sets in flight to any number of drones; see the module docstring for the rules."""

    def __init__(self, *, timeout_s: float = PARAM_TIMEOUT_S, retries: int = PARAM_RETRIES) -> None:
        # (sysid, name) -> the set or read waiting for its echo, and how it ended
        self._core: Transactions[tuple[int, str], _Set, tuple[int, str], ParamResult] = Transactions(timeout_s, retries)

    def start(self, sysid: int, name: str, value: int | float | None, now_s: float) -> list[Send]:
        """Begin setting ``name`` on drone ``sysid`` (an int as INT32, a float as REAL32); the first PARAM_SET.
        ``value`` None reads it instead: PARAM_REQUEST_READ, ended by any PARAM_VALUE of the name (same retries)."""
        key = (sysid, name)
        if self._core.running(key) is not None:
            raise ParamInFlight(f"parameter {name} on sysid {sysid} is already being set")
        return [self._message(self._core.begin(key, key, _Set(sysid=sysid, name=name, value=value), now_s))]

    def handle(self, msg: Any, now_s: float) -> list[Send]:
        """A received message; a PARAM_VALUE echo from a drone being set ends the set or sends it again."""
        if msg.get_type() != "PARAM_VALUE" or msg.get_srcComponent() != AUTOPILOT_COMPID:
            return []
        key = (msg.get_srcSystem(), msg.param_id)
        work = self._core.running(key)
        if work is None:
            return []
        work.kept = param_value(msg)
        if work.value is None or same_value(work.kept, work.value):
            self._finish(work)
            return []
        if work.retries_left <= 0:  # a stale echo of another value, and no try left
            self._finish(work)
            return []
        self._core.retry(work, now_s)  # a stale echo of another value: sent again at once
        return [self._message(work)]

    def poll(self, now_s: float) -> list[Send]:
        """Send again every set whose try timed out; end those out of retries."""
        out: list[Send] = []
        for work, exhausted in self._core.timed_out(now_s):
            if exhausted:
                self._finish(work)
            else:
                out.append(self._message(work))
        return out

    @staticmethod
    def _message(work: _Set) -> Send:
        if work.value is None:
            name = work.name.encode()
            return Send(work.sysid, mavlink.MAVLink_param_request_read_message(work.sysid, AUTOPILOT_COMPID, name, -1))
        return Send(work.sysid, param_set_message(work.sysid, work.name, work.value))

    def _finish(self, work: _Set) -> None:
        key = (work.sysid, work.name)
        self._core.finish(key, key, ParamResult(work.sysid, work.name, work.value, work.kept))

    def next_due_s(self) -> float:
        """When ``poll`` next has something to do (inf: nothing in flight)."""
        return self._core.next_due_s()

    def cancel(self, sysid: int, name: str) -> None:
        """Forget a set (its caller gave up waiting): no more resends, a late echo is ignored."""
        self._core.cancel((sysid, name), (sysid, name))

    def take(self, sysid: int, name: str) -> ParamResult | None:
        """How setting ``name`` on ``sysid`` ended, once (None while in flight or never started)."""
        return self._core.take((sysid, name))
