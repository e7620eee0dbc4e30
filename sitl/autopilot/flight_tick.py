"""The commander's tick and the physics steps between ticks: estimate and time in, motor commands out.

The tick (mode units, failsafes, the land detector, collision prevention and the position loops) runs at
MPC_LOOP_HZ, as PX4's flight tasks run with its position controller and its commander at about 100 Hz; the attitude,
rate and allocation loops run at every physics step. Between ticks a step repeats what the last tick decided: motors
off, idle, or the inner loops towards the attitude the position loops last produced. A command (arming, a mode, a
setpoint, a target: ``CommanderState.tick_due``) or a parameter change makes the next step a tick, so nothing waits
for the tick's clock to be acted on.

In a tick the flying unit is given its inputs and returns its decisions (sitl/autopilot/mode_io.py), which the mode
authority carries out; the failsafe table is given this tick's inputs; the unit's setpoint, or the shared reference
it tracks, is flown through collision prevention and the cascade.

A steady tick needs none of that Python: in OFFBOARD with a streamed trajectory setpoint the unit neither advances nor
reads its inputs, so when no failsafe row acts the tick is the setpoint flown. Such a tick is taken in a kernel with
the step's sensing (``steady_tick_ready``, sitl/kernels/between_ticks.py ``steady_tick``), which hands it back to
``step`` the moment a failsafe row would act; this module only notes it.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

from sitl.autopilot.commander_state import CommanderState
from sitl.autopilot.failsafe import failsafe_limits
from sitl.autopilot.failsafe_framework import FailsafeInputs
from sitl.autopilot.guidance import floats3
from sitl.autopilot.mode_authority import ModeAuthority
from sitl.autopilot.mode_io import ModeInputs, ModeParams, Track, new_mode_inputs
from sitl.autopilot.modes import ModeUnit
from sitl.autopilot.tracking import TargetTracker
from sitl.autopilot.vehicle_api import LandedState
from sitl.avoidance.collision_prevention import CollisionPrevention, Rows, compared
from sitl.control.cascade import AttitudeSetpoint, Cascade, TrajectorySetpoint
from sitl.control.params import outer_loop_period_s
from sitl.estimation.estimator import Estimate
from sitl.params import ParamStore

# Armed on the ground the rotors spin at idle so a person sees the vehicle is live (PX4 and ArduPilot do this).
ARMED_IDLE_CMD = 0.15


def commander_tick_s(params: ParamStore, dt_s: float) -> float:
    """The longest time between two commander ticks (``Commander.step``) at a physics step of ``dt_s``: MPC_LOOP_HZ's
    period rounded up to whole steps. A time the commander watches (a timeout, a failsafe's delay) is acted on at most
    this late; a command brings a tick at once."""
    return max(1, math.ceil((outer_loop_period_s(params) - 1e-9) / dt_s)) * dt_s


# What ``steady_tick_avoiding_plan`` hands the kernel: whether the outer loops run for the streamed setpoint and over
# what time, whether their period is up, whether a corrected setpoint equals the last but for its horizontal velocity,
# the last one's horizontal velocity, then collision prevention's inputs (``CollisionPrevention.run_inputs``).
AvoidingPlan = tuple[
    bool, float, bool, bool, float, float, Rows, float, Rows, float, float, float, int, Rows, bool, Rows
]


@dataclass(frozen=True, slots=True, kw_only=True)
class _Held:
    """What the commander's last tick decided, repeated by the physics steps until the next tick: fixed motor
    commands (off, or idle on the ground), or the inner loops towards an attitude setpoint or the output of the
    position loops for a trajectory setpoint (exactly one is set)."""

    motors: tuple[float, ...] | None = None
    attitude: AttitudeSetpoint | None = None
    trajectory: TrajectorySetpoint | None = None


class FlightTick:
    def __init__(
        self,
        state: CommanderState,
        tracker: TargetTracker,
        authority: ModeAuthority,
        params: ParamStore,
        cascade: Cascade,
        collision_prevention: CollisionPrevention,
        *,
        rotor_count: int,
        hover_thrust_n: float,
        battery_remaining: Callable[[], float],
    ) -> None:
        self._state = state
        self._tracker = tracker
        self._authority = authority
        self._params = params
        self._cascade = cascade
        self._collision_prevention = collision_prevention
        self._hover_thrust_n = hover_thrust_n
        self._off = (0.0,) * rotor_count
        self._idle = (ARMED_IDLE_CMD,) * rotor_count
        self._battery_remaining = battery_remaining
        self._held: _Held | None = None  # what the last tick decided; None: the next step is a tick
        self._since_tick_s = 0.0
        self._tick_version = -1  # the parameter store's version at the last tick (a change forces a tick)
        self._tick_period_s = outer_loop_period_s(params)
        self._mode_params_version = -1
        self._mode_params: ModeParams | None = None
        self._failsafe_limits = failsafe_limits(params)  # as of the last tick (a change forces a tick)
        # The step ``steady_tick_plan`` planned: the setpoint, whether the outer loops run, their elapsed time.
        self._steady: tuple[TrajectorySetpoint, bool, float] | None = None
        self._avoiding: tuple[TrajectorySetpoint, float] | None = None  # ``steady_tick_avoiding_plan``'s, until flown

    # ---- the step --------------------------------------------------------------------------------------------------
    def step(self, est: Estimate, now_s: float, dt_s: float) -> tuple[float, ...]:
        """One physics step: returns motor commands in [0, 1] (all zero when disarmed); a tick when one is due."""
        state = self._state
        state.est = est
        state.now_s = now_s
        self._since_tick_s += dt_s
        # Between ticks the thrust shown (status.thrust_n) stays the one the last tick set: the held collective.
        held = self._held
        if held is not None and not state.tick_due and self._params.version == self._tick_version:
            cascade = self._cascade
            if held.trajectory is not None:
                if not cascade.outer_due(dt_s):  # as ``holds_inner_loops`` says
                    return cascade.fly(est, held.trajectory, dt_s, landed=state.landed)
            elif self._since_tick_s < self._tick_period_s - 1e-9:
                if held.motors is not None:
                    return held.motors
                if held.attitude is not None:
                    self._tracker.trajectory.reset(est.pos_ned_m)
                    return cascade.update_attitude(est, held.attitude, dt_s, landed=state.landed).motor_cmds
        motors = self._tick(est, now_s, dt_s)
        state.tick_due = False  # after the whole tick: what it decided holds, whatever it changed on the way
        return motors

    def holds_inner_loops(self, dt_s: float) -> bool:
        """Will the next step, of ``dt_s``, only run the inner loops towards the position loops' held output (no
        tick, no attitude setpoint)? Then the caller may take it with ``inner_loops_stepped`` instead of ``step``."""
        held = self._held
        return (
            held is not None
            and held.trajectory is not None
            and not self._state.tick_due
            and self._params.version == self._tick_version
            and not self._cascade.outer_due(dt_s)
        )

    def inner_loops_stepped(self, est: Estimate, now_s: float, dt_s: float) -> tuple[float, ...]:
        """The step ``holds_inner_loops`` announced was taken outside (sitl/kernels/between_ticks.py: the inner
        loops on the cascade's rows, to the estimate ``est``): note it as ``step`` would have, and return its motor
        commands."""
        self._state.est = est
        self._state.now_s = now_s
        self._since_tick_s += dt_s
        return self._cascade.inner_step_taken(dt_s)

    # ---- the steady tick -------------------------------------------------------------------------------------------
    def steady_tick_ready(self, now_s: float, dt_s: float) -> bool:
        """Will the next step, at ``now_s``, of ``dt_s``, be a steady tick: a tick (a command, or the outer loops'
        period) of a drone armed in the air in OFFBOARD flying a trajectory setpoint, with the parameters of the last
        tick, and no fence to watch? Then the caller may take it in one kernel (sitl/kernels/between_ticks.py
        ``steady_tick``, with ``steady_tick_plan``'s inputs), which hands it back (``TICK_EVENT``) when a failsafe
        row acts; ``steady_tick_taken`` notes it. A steady tick is the tick ``step`` would run with what it would
        decide: the offboard unit neither advances nor reads its inputs and no failsafe row acts. When collision
        prevention is due to run, it runs on the kernel's estimate (``TICK_QUIET``, ``steady_tick_run``); otherwise
        it only applies what it holds, in the kernel."""
        held = self._held
        state = self._state
        if held is None or held.trajectory is None or self._params.version != self._tick_version:
            return False
        if not state.tick_due and not self._cascade.outer_due(dt_s):
            return False  # a step between ticks
        offboard = self._authority.units.offboard
        return (
            self._authority.unit is offboard
            and type(offboard.setpoint_in) is TrajectorySetpoint
            and state.status.armed
            and not state.landed
            and not self._fence_watched()
        )

    def steady_tick_plan(
        self, now_s: float, dt_s: float
    ) -> tuple[bool, bool, float, float, float, float, float, float, int, int, bool, bool, float]:
        """The steady tick's inputs besides the rows (``steady_tick_ready`` said yes): what the failsafe table's
        conditions read that the estimate does not give (whether the operator's mode needs a position, whether the
        offboard stream is alive, the last ground-station heartbeat, the battery, the limits), the rows that fired and
        those that re-arm only on arming; then whether the kernel flies the tick (collision prevention is not due to
        run) and, if it does, whether the outer loops run and over what time (``Cascade.outer_plan``, the setpoint's
        row written)."""
        authority = self._authority
        prevention = self._collision_prevention
        self._steady = None
        fly, due, elapsed_s = prevention.holds(now_s), False, 0.0
        if fly:
            streamed = authority.units.offboard.setpoint_in
            assert isinstance(streamed, TrajectorySetpoint)
            setpoint = prevention.held(streamed)
            due, elapsed_s = self._cascade.outer_plan(setpoint, dt_s)
            self._steady = (setpoint, due, elapsed_s)
        failsafes = authority.failsafes
        dl, low, crit, emerg = self._failsafe_limits
        return (authority.needs_position(), authority.offboard_alive(now_s), self._state.gcs_heartbeat_s,
                self._battery_remaining(), dl, low, crit, emerg, failsafes.fired_word, failsafes.on_arming_word, fly,
                due, elapsed_s)  # fmt: skip

    def steady_tick_taken(self, est: Estimate, now_s: float) -> tuple[float, ...]:
        """The steady tick ``steady_tick_plan`` planned was flown to the estimate ``est`` (``TICK_STEADY``): note it as
        ``step`` notes a tick, and return its motor commands."""
        assert self._steady is not None
        setpoint, due, elapsed_s = self._steady
        self._steady = None
        self._steady_tick_begins(est, now_s)
        held = self._held
        if held is None or held.trajectory is not setpoint:
            self._held = _Held(trajectory=setpoint)
        cascade = self._cascade
        motors = cascade.trajectory_flown(setpoint, due, elapsed_s)
        return self._steady_tick_ends(est, now_s, motors, cascade.collective_sp_n)

    def steady_tick_avoiding_plan(self, now_s: float, dt_s: float) -> AvoidingPlan | None:
        """A steady tick ``steady_tick_plan`` did not fly, when collision prevention's run is due and made in the tick's
        kernel (sitl/kernels/between_ticks.py ``steady_tick_avoiding``, whose docstring says what it is given): the
        setpoint row is written with the streamed setpoint. None when the tick is ``steady_tick_run``'s to fly."""
        prevention = self._collision_prevention
        if not prevention.due(now_s):
            return None
        streamed = self._authority.units.offboard.setpoint_in
        assert isinstance(streamed, TrajectorySetpoint)
        cascade = self._cascade
        streamed_due, elapsed_s = cascade.outer_plan(streamed, dt_s)
        self._avoiding = (streamed, elapsed_s)
        return (streamed_due, elapsed_s, cascade.outer_due(dt_s), *compared(streamed, cascade.outer_setpoint),
                *prevention.run_inputs(now_s))  # fmt: skip

    def steady_tick_avoided(self, est: Estimate, now_s: float, outer_ran: bool) -> tuple[float, ...]:
        """The tick ``steady_tick_avoiding_plan`` planned was flown to ``est`` (``outer_ran``: ``TICK_AVOIDED_OUTER``):
        noted as ``steady_tick_run`` notes what it flies; its motor commands."""
        assert self._avoiding is not None
        (streamed, elapsed_s), self._avoiding = self._avoiding, None
        self._steady_tick_begins(est, now_s)
        self._collision_prevention.ran(now_s)
        self._held = _Held(trajectory=(setpoint := self._collision_prevention.held(streamed)))
        cascade = self._cascade
        cascade.setpoint_row_written(setpoint)
        motors = cascade.trajectory_flown(setpoint, outer_ran, elapsed_s)
        return self._steady_tick_ends(est, now_s, motors, cascade.collective_sp_n)

    def steady_tick_run(self, est: Estimate, now_s: float, dt_s: float) -> tuple[float, ...]:
        """A steady tick the kernel left to the caller (``TICK_QUIET``: collision prevention is due to run), on the
        estimate ``est`` it sensed: the streamed setpoint through collision prevention and the cascade, as ``step``'s
        tick flies it, and the tick noted."""
        setpoint = self._authority.units.offboard.setpoint_in
        assert isinstance(setpoint, TrajectorySetpoint)
        self._steady_tick_begins(est, now_s)
        motors, collective_n = self._fly_trajectory(setpoint, est, now_s, dt_s)
        return self._steady_tick_ends(est, now_s, motors, collective_n)

    def _steady_tick_begins(self, est: Estimate, now_s: float) -> None:
        state = self._state
        state.est = est
        state.now_s = now_s
        self._since_tick_s = 0.0  # the tick's time since the last tick is the offboard unit's to ignore
        # The unit's own setpoint: the auto-mode reference follows the vehicle (as ``_control``).
        self._tracker.trajectory.reset(est.pos_ned_m)

    def _steady_tick_ends(
        self, est: Estimate, now_s: float, motors: tuple[float, ...], collective_n: float
    ) -> tuple[float, ...]:
        motors = self._after_control(self._authority.unit, est, now_s, motors, collective_n)
        self._state.tick_due = False
        return motors

    # ---- the tick --------------------------------------------------------------------------------------------------
    def _tick(self, est: Estimate, now_s: float, dt_s: float) -> tuple[float, ...]:
        """The commander's tick, with the mode units advanced by the time since the last tick."""
        state, status, authority, detector = self._state, self._state.status, self._authority, self._state.land_detector
        tick_dt_s = self._since_tick_s
        self._since_tick_s = 0.0
        version = self._params.version
        if version != self._tick_version:
            self._tick_version = version
            self._tick_period_s = outer_loop_period_s(self._params)
            self._failsafe_limits = failsafe_limits(self._params)
        if not status.armed:
            if not state.landed and detector.update(
                now_s, float(est.vel_ned_mps[2]), 0.0, state.altitude_above_home_m()
            ):
                # Killed in the air: the detector keeps watching with the motors off, so once the vehicle lies
                # still on the ground it counts as landed again and may re-arm (PX4 treats disarmed as landed).
                state.event(6, "Landing detected")
            status.landed_state = LandedState.ON_GROUND if state.landed else LandedState.IN_AIR
            status.thrust_n = 0.0
            self._held = _Held(motors=self._off)
            return self._off
        authority.carry_out(authority.unit.advance(self._mode_inputs(est, now_s)))
        authority.respond_to_failsafes(self._failsafe_inputs(est, now_s))
        unit = authority.unit
        if state.landed and not unit.wants_air(True):
            # Armed on the ground: motors idle, controllers held at rest so nothing winds up.
            self._cascade.reset()
            self._tracker.trajectory.reset(est.pos_ned_m)
            self._tracker.target_ned_m = est.pos_ned_m.copy()
            status.thrust_n = 0.0
            self._check_auto_disarm(now_s)
            status.landed_state = LandedState.ON_GROUND
            self._held = _Held(motors=self._idle) if status.armed else None
            return self._idle
        motors, collective_n = self._control(unit, est, now_s, dt_s, tick_dt_s)
        return self._after_control(unit, est, now_s, motors, collective_n)

    def _after_control(
        self, unit: ModeUnit, est: Estimate, now_s: float, motors: tuple[float, ...], collective_n: float
    ) -> tuple[float, ...]:
        """The end of a tick that flew: the thrust shown, the land detector, a touchdown's handling."""
        state, status, detector = self._state, self._state.status, self._state.land_detector
        status.thrust_n = collective_n
        was_landed = state.landed
        landed = detector.update(
            now_s, float(est.vel_ned_mps[2]), collective_n / self._hover_thrust_n, state.altitude_above_home_m()
        )
        if was_landed and not landed:
            state.event(6, "Takeoff detected")
        elif landed and not was_landed:
            state.event(6, "Landing detected")
            state.landed_since_s = now_s
            self._authority.carry_out(unit.on_touchdown(self._mode_inputs(est, now_s)))
            self._cascade.reset()
            self._held = None
            return self._idle
        status.landed_state = unit.landed_state(landed)
        return motors

    def _control(
        self, unit: ModeUnit, est: Estimate, now_s: float, dt_s: float, tick_dt_s: float
    ) -> tuple[tuple[float, ...], float]:
        """The unit's setpoint flown through collision prevention and the cascade: the motor commands and the
        collective thrust asked for (newtons)."""
        decided = unit.setpoint(self._mode_inputs(est, now_s), tick_dt_s)
        landed = self._state.landed
        # Held only while armed: a failsafe that disarmed in this tick (lockdown, termination) leaves the next step a
        # tick, which stops the motors.
        armed = self._state.status.armed
        if isinstance(decided, Track):
            setpoint = self._tracker.fly(decided, tick_dt_s)
        else:
            # A setpoint of the unit's own: the auto-mode reference follows the vehicle, so a switch back to an auto
            # mode starts where the vehicle is.
            self._tracker.trajectory.reset(est.pos_ned_m)
            if isinstance(decided, AttitudeSetpoint):
                self._held = _Held(attitude=decided) if armed else None
                out = self._cascade.update_attitude(est, decided, dt_s, landed=landed)
                return out.motor_cmds, out.collective_sp_n
            setpoint = decided
        return self._fly_trajectory(setpoint, est, now_s, dt_s)

    def _fly_trajectory(
        self, setpoint: TrajectorySetpoint, est: Estimate, now_s: float, dt_s: float
    ) -> tuple[tuple[float, ...], float]:
        """A trajectory setpoint flown through collision prevention (in the air) and the cascade, and held while
        armed: the motor commands and the collective thrust asked for (newtons)."""
        landed = self._state.landed
        if not landed:
            setpoint = self._collision_prevention.apply(setpoint, est.pos_ned_m, est.vel_ned_mps, now_s)
        self._held = _Held(trajectory=setpoint) if self._state.status.armed else None
        cascade = self._cascade
        return cascade.fly(est, setpoint, dt_s, landed=landed), cascade.collective_sp_n

    def _check_auto_disarm(self, now_s: float) -> None:
        state = self._state
        since = state.landed_since_s if state.landed_since_s is not None else now_s
        took_off = since > state.armed_since_s
        delay = self._params["COM_DISARM_LAND"] if took_off else self._params["COM_DISARM_PRFLT"]
        if delay >= 0 and now_s - since >= delay:
            self._authority.disarm("Auto-disarmed after landing" if took_off else "Auto-disarmed: no takeoff")

    # ---- what the unit and the failsafe table are given ------------------------------------------------------------
    def _mode_inputs(self, est: Estimate, now_s: float) -> ModeInputs:
        """What the flying unit reads, as it is now."""
        params = self._mode_params
        if params is None or self._mode_params_version != self._params.version:
            # Taken again only when a parameter changed (this runs several times a tick).
            self._mode_params_version = self._params.version
            self._mode_params = params = ModeParams.from_store(self._params)
        state, tracker = self._state, self._tracker
        return new_mode_inputs(
            est=est,
            now_s=now_s,
            landed=state.landed,
            home_ned_m=state.home_ned_m,
            home_yaw_rad=state.home_yaw_rad,
            reference_ned_m=tracker.trajectory.position_floats,
            target_ned_m=tracker.target_ned_m,
            target_yaw_rad=tracker.target_yaw_rad,
            speed_override_mps=tracker.speed_override_mps,
            params=params,
        )

    def _failsafe_inputs(self, est: Estimate, now_s: float) -> FailsafeInputs:
        state = self._state
        return FailsafeInputs(
            now_s=now_s,
            landed=state.landed,
            mode=state.status.mode,
            needs_position=self._authority.needs_position(),
            offboard_alive=self._authority.offboard_alive(now_s),
            gcs_heartbeat_s=state.gcs_heartbeat_s,
            battery_remaining=self._battery_remaining(),
            position_valid=est.position_valid,
            altitude_valid=est.altitude_valid,
            fence_breach=self._fence_breach(est),
        )

    def _fence_watched(self) -> bool:
        """Is there a fence to stay within: zones, or a distance limit from home?"""
        params = self._params
        return bool(self._state.fence.zones) or params["GF_MAX_HOR_DIST"] > 0.0 or params["GF_MAX_VER_DIST"] > 0.0

    def _fence_breach(self, est: Estimate) -> str | None:
        if not est.position_valid or not self._fence_watched():
            return None
        params = self._params
        return self._state.fence.breach(floats3(est.pos_ned_m), floats3(self._state.home_ned_m),
                                        params["GF_MAX_HOR_DIST"], params["GF_MAX_VER_DIST"])  # fmt: skip
