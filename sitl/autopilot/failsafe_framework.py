"""The failsafe framework's mechanics: precedence, the hold before an action, and clearing, over any table of rows.

Shaped like PX4's commander failsafe framework (failsafe/framework.cpp), apart from the policy it runs
(sitl/autopilot/failsafe.py, PX4's failsafe.cpp): every step the table's conditions are checked against a snapshot of
the vehicle (``FailsafeInputs``), all at once, as a word with a bit per row (``Conditions``); only a row whose bit
differs from what it last did is looked at further (the event mask: on nearly every tick none is). A row fires on the
step its condition becomes true, and its action is taken when it
is more severe than the action already in force (PX4 ranks actions by severity: warn < hold < return < land <
descend < disarm < terminate). A row that holds first holds for COM_FAIL_ACT_T and takes its action when that delay
has passed, so an operator can take over; any mode the operator commands clears the failsafe (PX4's "on mode change
or disarm"). A row clears when its condition does, or only on arming; a mode-fallback row gives the operator's mode
back when its cause clears.

Pure: inputs and parameters in, orders out. sitl/autopilot/mode_authority.py applies the orders (switches mode, emits
the STATUSTEXT) and reports the row in force as ``VehicleStatus.active_failsafe``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from enum import Enum, IntEnum
from typing import NamedTuple

from sitl.autopilot.px4_modes import FailsafeKind, Px4Mode
from sitl.kernels import failsafe as fk
from sitl.params import ParamStore

# MAV_SEVERITY of the texts: a failsafe action is critical, a warning a warning, a recovery information.
SEVERITY_CRITICAL = 2
SEVERITY_WARNING = 4
SEVERITY_INFO = 6


class FailsafeAction(IntEnum):
    """What a failsafe does, in PX4's order of severity (a more severe action overrides a less severe one)."""

    NONE = 0
    WARN = 1
    HOLD = 2
    RTL = 3
    LAND = 4
    DESCEND = 5  # land without a horizontal position: level, at a controlled sink rate
    DISARM = 6  # PX4's "lockdown": motors off where it is
    TERMINATE = 7  # flight termination: motors off, the vehicle stays down

    @property
    def verb(self) -> str:
        return _VERBS[self]


_VERBS = {
    FailsafeAction.NONE: "",
    FailsafeAction.WARN: "",
    FailsafeAction.HOLD: "holding",
    FailsafeAction.RTL: "returning to launch",
    FailsafeAction.LAND: "landing",
    FailsafeAction.DESCEND: "descending",
    FailsafeAction.DISARM: "disarming",
    FailsafeAction.TERMINATE: "terminating flight",
}


class Clear(Enum):
    """When a row that fired may fire again."""

    WHEN_CONDITION_CLEARS = "when_condition_clears"  # a link that comes back and is lost again triggers again
    ON_ARMING = "on_arming"  # battery levels: once per flight


class FailsafeInputs(NamedTuple):
    """What the rows look at, sampled once per control step.

    A NamedTuple rather than a frozen dataclass: it is built every control step of every drone, and a frozen
    dataclass's field-by-field ``object.__setattr__`` made it cost 4 us more per step (measured)."""

    now_s: float
    landed: bool
    mode: Px4Mode
    needs_position: bool  # the mode the operator chose cannot fly without a horizontal position
    offboard_alive: bool  # a setpoint arrived within COM_OF_LOSS_T
    gcs_heartbeat_s: float  # time of the last ground-station HEARTBEAT; NaN before the first
    battery_remaining: float  # 0..1
    position_valid: bool
    altitude_valid: bool
    fence_breach: str | None  # why the fence is breached, None inside it (or with no fence)


# Every row's condition at once: bit ``k`` set when row ``k`` of the table holds (sitl/kernels/failsafe.py).
Conditions = Callable[[FailsafeInputs, ParamStore], int]
ActionOf = Callable[[ParamStore], FailsafeAction]
Describe = Callable[[FailsafeInputs], str]


@dataclass(frozen=True, slots=True, kw_only=True)
class FailsafeRow:
    kind: FailsafeKind  # its condition is its table's bit for it (``Conditions``)
    action: ActionOf  # from the row's PX4 parameter
    cause: Describe  # the STATUSTEXT: "Failsafe: <cause>, <action verb>" (a warning is the cause alone)
    clear: Clear
    hold_first: bool  # hold COM_FAIL_ACT_T before an action more severe than Hold (PX4's failsafe delay)
    recovered: str | None = None  # said when the condition clears ("Data link regained")
    # The action is a fallback for a mode that cannot run (PX4's mode fallback): when the condition clears while it
    # is in force, the vehicle goes back to the mode the operator had chosen.
    resume_when_clear: bool = False


@dataclass(frozen=True, slots=True, kw_only=True)
class FailsafeOrder:
    """One thing the vehicle must do now: say ``text`` and, unless NONE/WARN, switch to ``action``."""

    kind: FailsafeKind
    action: FailsafeAction
    severity: int
    text: str
    resume: bool = False  # the cause cleared: go back to the operator's mode if the fallback is still flying


@dataclass(slots=True)
class _Pending:
    kind: FailsafeKind
    action: FailsafeAction
    since_s: float


class FailsafeState:
    """The failsafe framework's memory: which rows fired, the action in force, a delayed action pending."""

    def __init__(self, table: tuple[FailsafeRow, ...], conditions: Conditions) -> None:
        self.table = table
        self.conditions = conditions
        self.active = FailsafeKind.NONE
        self.active_action = FailsafeAction.NONE
        # Bit k: row k has fired and not yet re-armed.
        self._fired = 0
        # Bit k: row k re-arms only on arming, so its condition clearing changes nothing.
        self._on_arming = sum(1 << k for k, row in enumerate(table) if row.clear is Clear.ON_ARMING)
        self._pending: _Pending | None = None
        # What was in force when a mode-fallback row took over, restored when its cause clears.
        self._before_fallback: tuple[FailsafeKind, FailsafeAction, _Pending | None] | None = None

    @property
    def fired_word(self) -> int:
        """Bit k: row k has fired and not yet re-armed."""
        return self._fired

    @property
    def on_arming_word(self) -> int:
        """Bit k: row k re-arms only on arming."""
        return self._on_arming

    @property
    def in_failsafe(self) -> bool:
        """Is an action beyond a warning in force (HEARTBEAT system_status CRITICAL)?"""
        return self.active_action > FailsafeAction.WARN

    def on_arming(self) -> None:
        self._fired = 0
        self.cleared()

    def cleared(self) -> None:
        """The operator took over (a commanded mode) or the vehicle disarmed: nothing is in force any more. Rows
        that fired stay fired until their condition clears, so a persisting cause does not re-trigger at once."""
        self.active = FailsafeKind.NONE
        self.active_action = FailsafeAction.NONE
        self._pending = None
        self._before_fallback = None

    def evaluate(self, inputs: FailsafeInputs, params: ParamStore) -> list[FailsafeOrder]:
        """The orders of the rows whose condition changed since they last acted, in the table's order."""
        holds = self.conditions(inputs, params)
        events = fk.events(holds, self._fired, self._on_arming)
        if not events:
            return []
        orders: list[FailsafeOrder] = []
        for index, row in enumerate(self.table):
            bit = 1 << index
            if not events & bit:
                continue
            if not holds & bit:  # cleared: re-armed
                self._fired &= ~bit
                resume = row.resume_when_clear and self.active is row.kind
                if resume and self._before_fallback is not None:
                    self.active, self.active_action, self._pending = self._before_fallback
                    self._before_fallback = None
                if row.recovered is not None:
                    orders.append(
                        FailsafeOrder(
                            kind=row.kind,
                            action=FailsafeAction.NONE,
                            severity=SEVERITY_INFO,
                            text=row.recovered,
                            resume=resume,
                        )
                    )
                continue
            self._fired |= bit
            action = row.action(params)
            if action is FailsafeAction.NONE:
                continue
            if action is FailsafeAction.WARN:
                orders.append(
                    FailsafeOrder(kind=row.kind, action=action, severity=SEVERITY_WARNING, text=row.cause(inputs))
                )
                continue
            if action <= self.active_action:
                # A more severe action is already in force: say what happened, change nothing.
                orders.append(
                    FailsafeOrder(
                        kind=row.kind,
                        action=FailsafeAction.NONE,
                        severity=SEVERITY_CRITICAL,
                        text=f"Failsafe: {row.cause(inputs)}, {action.verb}",
                    )
                )
                continue
            now_action = action
            if row.resume_when_clear:
                self._before_fallback = (self.active, self.active_action, self._pending)
            self._pending = None  # a more severe failsafe supersedes a delayed one
            if row.hold_first and action > FailsafeAction.HOLD:
                now_action = FailsafeAction.HOLD
                self._pending = _Pending(kind=row.kind, action=action, since_s=inputs.now_s)
            self.active = row.kind
            self.active_action = now_action
            orders.append(
                FailsafeOrder(
                    kind=row.kind,
                    action=now_action,
                    severity=SEVERITY_CRITICAL,
                    text=f"Failsafe: {row.cause(inputs)}, {now_action.verb}",
                )
            )
        return orders

    def delayed_action(self, now_s: float, mode: Px4Mode, delay_s: float) -> FailsafeOrder | None:
        """The held action, once the vehicle has held for ``delay_s`` (COM_FAIL_ACT_T) without being taken over."""
        pending = self._pending
        if pending is None or mode is not Px4Mode.AUTO_LOITER or now_s - pending.since_s < delay_s:
            return None
        self._pending = None
        self.active = pending.kind
        self.active_action = pending.action
        return FailsafeOrder(
            kind=pending.kind,
            action=pending.action,
            severity=SEVERITY_CRITICAL,
            text=f"Failsafe: {pending.action.verb}",
        )
