"""COMMAND_LONG with MAVSDK's retry rules, as a protocol object with no IO and no clock of its own.

The caller owns the socket and the clock: it ``start``s a command, feeds every received message to ``handle`` with
the current time, calls ``poll`` when ``next_due_s`` comes, and sends whatever ``Send`` effects the three return.
A finished command is collected with ``take``. Several commands (to several drones, or several commands to one)
may be in flight at once; the same command to the same drone may not be twice, because a COMMAND_ACK names only
the command and its sender and could not say which of the two it answers (MAVSDK refuses that too).

The rules are MAVSDK's ``MavlinkCommandSender``:

- one try waits ``timeout_s`` (0.5 s); without an answer the command is sent again, at most ``retries`` (3) times,
  then it ends with no answer (``Ack.result`` None). Each resend counts up COMMAND_LONG's ``confirmation`` field, as
  the MAVLink command protocol asks, so a vehicle can tell a retry from a new command.
- COMMAND_ACK IN_PROGRESS says the command arrived and runs: no more resends are needed for now, and the wait grows
  to what the remaining retries would have taken (at least one try), so a slow command is not cut short.
- Every other result ends the command at once: ACCEPTED, and also TEMPORARILY_REJECTED, DENIED, UNSUPPORTED,
  FAILED, CANCELLED, COMMAND_INT_ONLY (a refusal is an answer; retrying a TEMPORARILY_REJECTED command later is
  the caller's choice).
- An ACK counts only for the command it names, from the system the command went to (its component), and when it
  is addressed to someone, to us. Anything else (another command's ACK, a late duplicate after the end) is ignored.

Times are whatever clock the caller uses (the swarm's: simulated seconds), so tests advance a number instead of
sleeping.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Final

from pymavlink.dialects.v20 import common as mavlink

from gcs.mavlink.transactions import Transactions
from gcs.mavlink.transport import GCS_COMPID, GCS_SYSID

COMMAND_TIMEOUT_S: Final = 0.5  # MAVSDK's per-try timeout
COMMAND_RETRIES: Final = 3  # MAVSDK's resends after the first try
# MAV_CMD_COMPONENT_ARM_DISARM param2 that disarms even in the air (MAVLink's "force" value; PX4 and MAVSDK's kill())
FORCE_DISARM_MAGIC: Final = 21196.0
AUTOPILOT_COMPID: Final = mavlink.MAV_COMP_ID_AUTOPILOT1

MAV_RESULT_CANCELLED: Final = 6  # MAVLink's value; this pymavlink's common.xml predates it
# Results that end a command (MAVSDK erases the work item on each); IN_PROGRESS extends it, unknown ones are ignored.
# COMMAND_INT_ONLY ends it too: the vehicle will not take this command as COMMAND_LONG, so resending cannot help.
FINAL_RESULTS: Final = frozenset(
    {
        mavlink.MAV_RESULT_ACCEPTED,
        mavlink.MAV_RESULT_TEMPORARILY_REJECTED,
        mavlink.MAV_RESULT_DENIED,
        mavlink.MAV_RESULT_UNSUPPORTED,
        mavlink.MAV_RESULT_FAILED,
        MAV_RESULT_CANCELLED,
        mavlink.MAV_RESULT_COMMAND_INT_ONLY,
    }
)


@dataclass(frozen=True, slots=True)
class Ack:
    """How one command to one drone ended."""

    sysid: int
    result: int | None  # MAV_RESULT, None when no answer came after every retry

    @property
    def ok(self) -> bool:
        return self.result == mavlink.MAV_RESULT_ACCEPTED


@dataclass(frozen=True, slots=True)
class Send:
    """An effect: send ``message`` (a pymavlink message object, not yet packed) to drone ``sysid``."""

    sysid: int
    message: Any


class CommandInFlight(RuntimeError):
    """Our own misuse: the same command to the same drone while the first is still waiting for its answer."""


@dataclass(slots=True, kw_only=True)
class _Work:
    sysid: int
    compid: int
    command: int
    params: tuple[float, ...]
    retries_left: int = 0
    due_s: float = 0.0  # when this try times out
    confirmation: int = 0
    frame: int | None = None  # COMMAND_INT in this MAV_FRAME (params 5/6 are x/y); None: COMMAND_LONG
    started_s: float = 0.0  # when it was first sent

    def message(self) -> Any:
        if self.frame is not None:  # COMMAND_INT has no confirmation field: its retries are sent as they are
            p = self.params
            return mavlink.MAVLink_command_int_message(
                self.sysid, self.compid, self.frame, self.command, 0, 0, p[0], p[1], p[2], p[3], int(p[4]), int(p[5]),
                p[6],
            )  # fmt: skip
        return mavlink.MAVLink_command_long_message(
            self.sysid, self.compid, self.command, self.confirmation, *self.params
        )


class CommandClient:
    """Commands in flight to any number of drones; see the module docstring for the rules."""

    def __init__(
        self,
        *,
        timeout_s: float = COMMAND_TIMEOUT_S,
        retries: int = COMMAND_RETRIES,
        own_sysid: int = GCS_SYSID,
        own_compid: int = GCS_COMPID,
    ) -> None:
        self.own_sysid = own_sysid
        self.own_compid = own_compid
        # (sysid, command) -> the command waiting for its answer, and how it ended
        self._core: Transactions[tuple[int, int], _Work, tuple[int, int], Ack] = Transactions(timeout_s, retries)

    def start(
        self, sysid: int, command: int, params: tuple[float, ...] = (), now_s: float = 0.0, *,
        compid: int = AUTOPILOT_COMPID, frame: int | None = None,
    ) -> list[Send]:  # fmt: skip
        """Begin a command (params 1-7; missing ones are 0); returns its first COMMAND_LONG to send now, or its
        first COMMAND_INT in ``frame`` (params 5 and 6 then are the integers x and y: latitude, longitude in degE7)."""
        key = (sysid, command)
        if self._core.running(key) is not None:
            raise CommandInFlight(f"command {command} to sysid {sysid} is already waiting for its answer")
        if len(params) > 7:
            raise ValueError(f"COMMAND_LONG has 7 params, got {len(params)}")
        padded = (*params, *([0.0] * (7 - len(params))))
        work = self._core.begin(key, key, _Work(sysid=sysid, compid=compid, command=command, params=padded,
                                                frame=frame, started_s=now_s), now_s)  # fmt: skip
        return [Send(sysid, work.message())]

    def handle(self, msg: Any, now_s: float) -> list[Send]:
        """A received message; COMMAND_ACKs that answer a command in flight end or extend it. Never sends."""
        if msg.get_type() != "COMMAND_ACK":
            return []
        target_system = getattr(msg, "target_system", 0)
        target_component = getattr(msg, "target_component", 0)
        if (target_system and target_system != self.own_sysid) or (
            target_component and target_component != self.own_compid
        ):
            return []  # an answer to another ground station
        key = (msg.get_srcSystem(), msg.command)
        work = self._core.running(key)
        if work is None or msg.get_srcComponent() != work.compid:
            return []  # not ours: another command's, or a late duplicate of one already ended
        if msg.result == mavlink.MAV_RESULT_IN_PROGRESS:
            work.due_s = now_s + max(1, work.retries_left) * self._core.timeout_s
        elif msg.result in FINAL_RESULTS:
            self._core.finish(key, key, Ack(work.sysid, int(msg.result)))
        return []

    def poll(self, now_s: float) -> list[Send]:
        """Resend every command whose try timed out (counting up its confirmation); end those out of retries with
        no answer."""
        out: list[Send] = []
        for work, exhausted in self._core.timed_out(now_s):
            key = (work.sysid, work.command)
            if exhausted:
                self._core.finish(key, key, Ack(work.sysid, None))
                continue
            work.confirmation += 1
            out.append(Send(work.sysid, work.message()))
        return out

    def next_due_s(self) -> float:
        """When ``poll`` next has something to do (inf: nothing in flight)."""
        return self._core.next_due_s()

    def waiting_since(self) -> dict[int, float]:
        """For each system with a command waiting for its answer, when the oldest of them was first sent."""
        out: dict[int, float] = {}
        for work in self._core.works():
            out[work.sysid] = min(out.get(work.sysid, work.started_s), work.started_s)
        return out

    def in_flight(self, sysid: int, command: int) -> bool:
        return self._core.running((sysid, command)) is not None

    def cancel(self, sysid: int, command: int) -> None:
        """Forget a command (its caller gave up waiting, e.g. interrupted): no more resends, a late ACK is ignored."""
        self._core.cancel((sysid, command), (sysid, command))

    def take(self, sysid: int, command: int) -> Ack | None:
        """How the command to ``sysid`` ended, once (None while it is still in flight or was never started)."""
        return self._core.take((sysid, command))
