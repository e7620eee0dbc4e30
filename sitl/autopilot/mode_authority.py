"""The one authority for mode transitions: which mode unit flies, and every way a mode is entered or left.

The operator's requests (sitl/autopilot/requests.py), a unit's own decisions (``carry_out``, from the flight tick),
the failsafe table's orders (``respond_to_failsafes``) and disarming all switch modes here and nowhere else, as PX4's
Commander alone switches its navigation state. A unit only asks for a mode (sitl/autopilot/mode_io.py); the authority
enters it as the operator's request would: a mission's RTL item gets the same checked, planned return as
DO_RETURN_TO_LAUNCH.

The failsafes live here too because every action of theirs is a transition, and their bookkeeping (the operator's
intended mode, the mode a fallback replaced) is cleared by the operator's own transitions. The table's decisions are
pure (sitl/autopilot/failsafe.py, failsafe_framework.py); this applies them.
"""

from __future__ import annotations

from sitl.autopilot.commander_state import CommanderState
from sitl.autopilot.failsafe import FAILSAFE_TABLE, failsafe_conditions
from sitl.autopilot.failsafe_framework import FailsafeAction, FailsafeInputs, FailsafeOrder, FailsafeState
from sitl.autopilot.mode_io import NO_CHANGE, ModeDecision
from sitl.autopilot.modes import ModeUnit, Units
from sitl.autopilot.px4_modes import FailsafeKind, Px4Mode
from sitl.autopilot.tracking import TargetTracker
from sitl.autopilot.vehicle_api import CommandOutcome, CommandResult
from sitl.control.cascade import Cascade
from sitl.params import ParamStore

ACCEPTED = CommandOutcome.accepted()


class ModeAuthority:
    def __init__(
        self, state: CommanderState, tracker: TargetTracker, units: Units, params: ParamStore, cascade: Cascade
    ) -> None:
        self._state = state
        self._tracker = tracker
        self.units = units
        self._params = params
        self._cascade = cascade
        self._unit_of: dict[Px4Mode, ModeUnit] = units.by_mode()
        self.unit: ModeUnit = self._unit_of[state.status.mode]  # the unit flying now
        # The unit the operator (or the normal flow of modes) chose, while a failsafe flies another one: PX4's "user
        # intended mode", the one the position-loss row asks "can it run without a position?".
        self._intended: ModeUnit | None = None
        self._fallback_from: ModeUnit | None = None  # the unit Descend replaced, flown again if the position returns
        self.failsafes = FailsafeState(FAILSAFE_TABLE, failsafe_conditions)

    # ---- transitions -----------------------------------------------------------------------------------------------
    def enter(self, mode: Px4Mode) -> None:
        """Switch to the unit flying ``mode`` (the old unit drops what must not survive the switch)."""
        self._switch_to(self._unit_of[mode])

    def _switch_to(self, unit: ModeUnit) -> None:
        if unit is self.unit:
            return
        state = self._state
        state.tick_due = True
        self.unit.exit()
        self.unit = unit
        mode = unit.mode
        if mode is not state.status.mode:
            state.status.mode = mode
            state.event(6, f"Mode {mode.px4_name}")

    def carry_out(self, decision: ModeDecision) -> None:
        """Do what the flying unit decided, in the order ``ModeDecision`` gives."""
        if decision is NO_CHANGE:
            return
        if decision.text is not None:
            self._state.event(6, decision.text)
        if decision.speed_limit_mps is not None:
            self._tracker.limit_speed(decision.speed_limit_mps)
        goto = decision.goto
        if goto is not None:
            if goto.from_rest:
                self._tracker.trajectory.reset(self._state.current_pos())
            self._tracker.goto(goto.target_ned_m, goto.yaw_rad)
        if decision.request is Px4Mode.AUTO_RTL:
            self.return_to_launch()
        elif decision.request is not None:
            self.enter(decision.request)

    def operator_takes_over(self) -> None:
        """A mode commanded by the operator ends the failsafe in force (PX4: cleared on mode change)."""
        self._intended = None
        self._fallback_from = None
        self.failsafes.cleared()
        status = self._state.status
        status.failsafe = False
        status.active_failsafe = FailsafeKind.NONE

    def return_to_launch(self) -> CommandOutcome:
        state = self._state
        if not state.status.armed or state.landed:
            return CommandOutcome(CommandResult.DENIED, "RTL denied: not flying")
        if state.status.mode is not Px4Mode.AUTO_RTL:
            self._start_return()
        return ACCEPTED

    def _start_return(self) -> None:
        """Enter RTL with its plan made from here (the caller has checked the vehicle is flying)."""
        state = self._state
        climb = self.units.rtl.start(state.current_pos(), state.home_ned_m, self._params["RTL_RETURN_ALT"])
        self._tracker.hold()
        self._tracker.goto(climb.target_ned_m, climb.yaw_rad)
        self.enter(Px4Mode.AUTO_RTL)

    def offboard_alive(self, now_s: float) -> bool:
        return self.units.offboard.alive(now_s, self._params["COM_OF_LOSS_T"])

    def disarm(self, text: str) -> None:
        state = self._state
        state.status.armed = False
        state.tick_due = True  # the motors stop at the next step, not at the next tick
        self.units.rtl.plan = None
        self.operator_takes_over()
        self._cascade.reset()
        if state.status.mode is not Px4Mode.OFFBOARD:
            self.enter(Px4Mode.AUTO_LOITER)
        state.event(6, text)

    def stop_for_good(self, text: str, disarm_text: str) -> None:
        """A crash or a flight termination (the first one counts): say why, stop the motors, refuse to arm again."""
        state = self._state
        if state.crashed:
            return
        state.crashed = True
        state.event(2, text)
        if state.status.armed:
            self.disarm(disarm_text)

    def terminate(self, text: str) -> None:
        """Flight termination (PX4): the motors stop and stay stopped; like a crash, arming is refused after it."""
        self.stop_for_good(text, "Flight terminated")

    # ---- failsafes -------------------------------------------------------------------------------------------------
    def needs_position(self) -> bool:
        """Can the mode the operator chose (not a failsafe's) fly without a horizontal position?"""
        return (self._intended or self.unit).needs_position()

    def respond_to_failsafes(self, inputs: FailsafeInputs) -> None:
        """Evaluate the failsafe table on this tick's inputs and carry out its orders, and a held action whose
        delay (COM_FAIL_ACT_T) has passed."""
        for order in self.failsafes.evaluate(inputs, self._params):
            self._apply_failsafe(order)
        delayed = self.failsafes.delayed_action(inputs.now_s, self._state.status.mode, self._params["COM_FAIL_ACT_T"])
        if delayed is not None:
            self._apply_failsafe(delayed)

    def _apply_failsafe(self, order: FailsafeOrder) -> None:
        state = self._state
        status = state.status
        state.event(order.severity, order.text)
        if order.resume:
            self._resume_after_fallback()
        action = order.action
        if action <= FailsafeAction.WARN:
            return
        if not status.failsafe:
            self._intended = self.unit
        status.failsafe = True
        status.active_failsafe = order.kind
        mode = status.mode
        if action is FailsafeAction.HOLD:
            self._tracker.hold()
            self.enter(Px4Mode.AUTO_LOITER)
        elif action is FailsafeAction.RTL:
            if mode not in (Px4Mode.AUTO_RTL, Px4Mode.AUTO_LAND):  # never climb back out of a landing
                self.return_to_launch()
        elif action is FailsafeAction.LAND and mode is not Px4Mode.AUTO_LAND:
            self._tracker.hold()
            self.enter(Px4Mode.AUTO_LAND)
        elif action is FailsafeAction.DESCEND:
            descend = self.units.descend
            if self.unit is not descend:
                self._fallback_from = self.unit
            descend.start(state.est)
            self._switch_to(descend)
        elif action is FailsafeAction.DISARM:
            self.disarm("Motors stopped: lockdown")
        elif action is FailsafeAction.TERMINATE:
            self.terminate("Flight termination")

    def _resume_after_fallback(self) -> None:
        """The cause of a mode fallback (Descend) cleared while it still flies: back to the mode it replaced, and to
        whatever failsafe was in force before it (FailsafeState has restored that)."""
        before = self._fallback_from
        self._fallback_from = None
        units = self.units
        state = self._state
        if before is None or self.unit is not units.descend or state.landed:
            return
        if before is units.mission:
            self.enter(Px4Mode.AUTO_MISSION)
            units.mission.executor.start()
        elif before is units.rtl:
            self._start_return()
        elif before is units.land:
            self._tracker.hold()
            self.enter(Px4Mode.AUTO_LAND)
        elif before is units.offboard and self.offboard_alive(state.now_s):
            self.enter(Px4Mode.OFFBOARD)
        else:
            self._tracker.hold()
            self.enter(Px4Mode.AUTO_LOITER)
        state.status.failsafe = self.failsafes.in_failsafe
        state.status.active_failsafe = self.failsafes.active
        if not state.status.failsafe:
            self._intended = None
