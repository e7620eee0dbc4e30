"""The autopilot: arming, flight modes, failsafes. Pure: estimate and time in, motor commands out.

This is the drone's "commander + navigator" in PX4 terms. It arms and disarms, keeps home, and runs the active
flight mode's unit (sitl/autopilot/modes.py: one small unit per mode behind one interface) and the failsafe table
(sitl/autopilot/failsafe.py: pure decisions, applied here). It turns the mode's setpoint into motor commands through
the controller cascade (sitl/control). It never reads ground truth, a clock or a socket: the simulation loop passes
the estimate and the simulation time, and the MAVLink layer calls the request methods (arm, takeoff, set_mode, ...),
each answering with an ``Outcome``.

Behaviour follows PX4 where a client could notice: takeoff climbs to MIS_TAKEOFF_ALT and switches to Hold; land
descends and auto-disarms COM_DISARM_LAND seconds after touchdown; RTL climbs to RTL_RETURN_ALT, returns and lands;
offboard needs a live setpoint stream; the failsafes (link losses, battery levels, position loss, geofence) act as
PX4's parameters say (docs/failsafes.md).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from sitl.autopilot.failsafe import FAILSAFE_TABLE
from sitl.autopilot.failsafe_framework import FailsafeAction, FailsafeInputs, FailsafeOrder, FailsafeState
from sitl.autopilot.geofence import Geofence
from sitl.autopilot.guidance import MotionLimits, StraightLineTrajectory
from sitl.autopilot.land_detector import LandDetector, LandDetectorConfig
from sitl.autopilot.mission_exec import MissionExecutor, MissionRun
from sitl.autopilot.mission_plan import NavItem
from sitl.autopilot.mode_io import NO_CHANGE, ModeDecision, ModeInputs, ModeParams, Track, new_mode_inputs
from sitl.autopilot.modes import ModeUnit, build_units
from sitl.autopilot.px4_modes import FailsafeKind, Px4Mode
from sitl.autopilot.vehicle_api import CommandOutcome, CommandResult, LandedState
from sitl.avoidance.collision_prevention import CollisionPrevention
from sitl.control.cascade import AttitudeSetpoint, Cascade, CascadeOutput, TrajectorySetpoint
from sitl.control.params import outer_loop_period_s
from sitl.dynamics.airframe import Airframe
from sitl.estimation.estimator import Estimate
from sitl.mathutil import Vec3, vec3
from sitl.params import ParamStore

NAN3 = (math.nan, math.nan, math.nan)
# Armed on the ground the rotors spin at idle so a person sees the vehicle is live (PX4 and ArduPilot do this).
ARMED_IDLE_CMD = 0.15


def _tuple3(v: Vec3) -> tuple[float, float, float]:
    return (float(v[0]), float(v[1]), float(v[2]))


ACCEPTED = CommandOutcome.accepted()


def commander_tick_s(params: ParamStore, dt_s: float) -> float:
    """The longest time between two commander ticks (``Commander.step``) at a physics step of ``dt_s``: MPC_LOOP_HZ's
    period rounded up to whole steps. A time the commander watches (a timeout, a failsafe's delay) is acted on at most
    this late; a command brings a tick at once."""
    return max(1, math.ceil((outer_loop_period_s(params) - 1e-9) / dt_s)) * dt_s


@dataclass(frozen=True, slots=True, kw_only=True)
class _Held:
    """What the commander's last tick decided, repeated by the physics steps until the next tick: fixed motor
    commands (off, or idle on the ground), or the inner loops towards an attitude setpoint or the output of the
    position loops for a trajectory setpoint (exactly one is set)."""

    motors: tuple[float, ...] | None = None
    attitude: AttitudeSetpoint | None = None
    trajectory: TrajectorySetpoint | None = None


@dataclass(frozen=True, slots=True, kw_only=True)
class VehicleEvent:
    """Something a ground station should hear about (becomes a STATUSTEXT)."""

    severity: int  # MAV_SEVERITY: 2 critical, 4 warning, 6 info
    text: str


@dataclass(slots=True)
class VehicleStatus:
    """Mutable view of the autopilot's state, read by telemetry."""

    armed: bool = False
    mode: Px4Mode = Px4Mode.AUTO_LOITER
    landed_state: LandedState = LandedState.ON_GROUND
    failsafe: bool = False  # an action beyond a warning is in force: HEARTBEAT system_status CRITICAL
    active_failsafe: FailsafeKind = FailsafeKind.NONE  # which row of the failsafe table put it there
    thrust_n: float = 0.0


class Commander:
    def __init__(
        self,
        airframe: Airframe,
        params: ParamStore,
        cascade: Cascade,
        *,
        battery_remaining: Callable[[], float] = lambda: 1.0,
    ) -> None:
        self.airframe = airframe
        self.params = params
        self.cascade = cascade
        self.status = VehicleStatus()
        self.crashed = False
        self._mode_params_version = -1
        self._mode_params_cache: ModeParams | None = None
        self.events: list[VehicleEvent] = []
        self._battery_remaining = battery_remaining
        self._hover_thrust_n = airframe.mass_kg * 9.80665
        self._idle = (ARMED_IDLE_CMD,) * len(airframe.rotors)
        self._land_detector = LandDetector(LandDetectorConfig())
        # The smooth reference every auto mode flies, and the point it is heading for (shared by the mode units so a
        # switch between modes continues from where the reference is, without a jump).
        self.trajectory = StraightLineTrajectory(np.zeros(3))
        self.target_ned_m: Vec3 = np.zeros(3)
        self.target_yaw_rad = math.nan
        self.speed_override_mps = math.inf
        self.units = build_units(self._hover_thrust_n)
        self._unit_of: dict[Px4Mode, ModeUnit] = self.units.by_mode()
        self._unit: ModeUnit = self._unit_of[self.status.mode]
        # The unit the operator (or the normal flow of modes) chose, while a failsafe flies another one: PX4's "user
        # intended mode", the one the position-loss row asks "can it run without a position?".
        self._intended: ModeUnit | None = None
        self._fallback_from: ModeUnit | None = None  # the unit Descend replaced, flown again if the position returns
        self.failsafes = FailsafeState(FAILSAFE_TABLE)
        self._gcs_heartbeat_s = math.nan
        self._fence = Geofence()
        self._est: Estimate | None = None
        self._now_s = 0.0
        self._landed_since_s: float | None = 0.0
        self._armed_since_s = 0.0
        self._home_ned_m = np.zeros(3)
        self._home_yaw_rad = 0.0
        self.collision_prevention = CollisionPrevention(
            params, cascade.position, airframe.collision_radius_m, self.event
        )
        # The commander's tick (``step``): what the last tick decided, repeated on the physics steps until the next.
        self._held: _Held | None = None  # None: the next step is a tick
        self._since_tick_s = 0.0
        self._tick_version = -1  # the parameter store's version at the last tick (a change forces a tick)
        self._tick_period_s = outer_loop_period_s(params)

    # ---- helpers ---------------------------------------------------------------------------------------------------
    def event(self, severity: int, text: str) -> None:
        self.events.append(VehicleEvent(severity=severity, text=text))

    def p(self, name: str) -> float:
        return self.params[name]

    def _mode_params(self) -> ModeParams:
        """The parameters the mode units read, taken again only when one changed (this runs every tick)."""
        if self._mode_params_cache is None or self._mode_params_version != self.params.version:
            self._mode_params_version = self.params.version
            self._mode_params_cache = ModeParams.from_store(self.params)
        return self._mode_params_cache

    def _mode_inputs(self, est: Estimate, now_s: float) -> ModeInputs:
        """What the active unit reads, as it is now."""
        return new_mode_inputs(
            est=est,
            now_s=now_s,
            landed=self.landed,
            home_ned_m=self._home_ned_m,
            home_yaw_rad=self._home_yaw_rad,
            reference_ned_m=self.trajectory.position,
            target_ned_m=self.target_ned_m,
            target_yaw_rad=self.target_yaw_rad,
            speed_override_mps=self.speed_override_mps,
            params=self._mode_params(),
        )

    def _carry_out(self, decision: ModeDecision) -> None:
        """Do what a unit decided, in the order ``ModeDecision`` gives; a mode it asks for is entered as the
        operator's request would enter it (a return to launch is planned, and refused on the ground)."""
        if decision is NO_CHANGE:
            return
        if decision.text is not None:
            self.event(6, decision.text)
        if decision.speed_limit_mps is not None:
            self.set_speed(decision.speed_limit_mps)
        goto = decision.goto
        if goto is not None:
            if goto.from_rest:
                self.trajectory.reset(self.current_pos())
            self.start_goto(goto.target_ned_m, goto.yaw_rad)
        if decision.request is Px4Mode.AUTO_RTL:
            self.return_to_launch()
        elif decision.request is not None:
            self.enter(decision.request)

    @property
    def estimate(self) -> Estimate | None:
        return self._est

    @property
    def home_ned_m(self) -> Vec3:
        return self._home_ned_m

    @property
    def home_yaw_rad(self) -> float:
        return self._home_yaw_rad

    def set_home(self, home_ned_m: Vec3 | None) -> CommandOutcome:
        """DO_SET_HOME: the current position (None) or a given local point becomes home."""
        if home_ned_m is None:
            if self._est is None or not self._est.position_valid:
                return CommandOutcome(CommandResult.DENIED, "Set home denied: no position")
            home_ned_m = self._est.pos_ned_m
        self._home_ned_m = np.array(home_ned_m, dtype=np.float64)
        self._held = None
        self.event(6, "Home position set")
        return ACCEPTED

    @property
    def landed(self) -> bool:
        return self._land_detector.landed

    def altitude_above_home_m(self) -> float:
        return 0.0 if self._est is None else float(self._home_ned_m[2] - self._est.pos_ned_m[2])

    def current_pos(self) -> Vec3:
        return np.zeros(3) if self._est is None else self._est.pos_ned_m.copy()

    def enter(self, mode: Px4Mode) -> None:
        """Switch to the unit flying ``mode`` (the old unit drops what must not survive the switch)."""
        self._switch_to(self._unit_of[mode])

    def _switch_to(self, unit: ModeUnit) -> None:
        if unit is self._unit:
            return
        self._held = None
        self._unit.exit()
        self._unit = unit
        mode = unit.mode
        if mode is not self.status.mode:
            self.status.mode = mode
            self.event(6, f"Mode {mode.px4_name}")

    def start_goto(self, target_ned_m: Vec3, yaw_rad: float = math.nan) -> None:
        """Fly to a point on a smooth trajectory, starting from where the reference currently is."""
        self._held = None
        self.target_ned_m = np.array(target_ned_m, dtype=np.float64)
        self.target_yaw_rad = yaw_rad

    def hold_here(self) -> None:
        """Hold at the point where the vehicle can stop without a jerk (braking distance included)."""
        pos = self.current_pos()
        if self._est is not None and self.status.armed and not self.landed:
            vel = self._est.vel_ned_mps
            speed = math.hypot(*vel)
            if speed > 0.1:
                pos = pos + vel * (speed / (2.0 * self.p("MPC_ACC_HOR")))
                # The reference starts from the vehicle's own motion and brakes along it to that point; from rest
                # it would stop dead at the vehicle (which overshoots it) and then accelerate again to that point.
                self.trajectory.reset_moving(self.current_pos(), vel)
            else:
                self.trajectory.reset(self.current_pos())
        self.start_goto(pos, self._est.yaw_rad if self._est is not None else math.nan)

    def track_setpoint(self, limits: MotionLimits, max_speed_mps: float, dt_s: float) -> TrajectorySetpoint:
        """Advance the smooth reference towards the target and fly it."""
        return self.track_setpoint_to(self.target_ned_m, limits, max_speed_mps, dt_s)

    def track_setpoint_to(
        self, goal_ned_m: Vec3, limits: MotionLimits, max_speed_mps: float, dt_s: float
    ) -> TrajectorySetpoint:
        """Advance the smooth reference towards ``goal_ned_m`` and fly it."""
        ref = self.trajectory.update(goal_ned_m, limits, dt_s, max_speed_mps)
        return TrajectorySetpoint(
            pos_ned_m=_tuple3(ref.pos_ned_m),
            vel_ned_mps=_tuple3(ref.vel_ned_mps),
            acc_ned_mps2=_tuple3(ref.acc_ned_mps2),
            yaw_rad=self.target_yaw_rad,
        )

    def land_descent_setpoint(self, limits: MotionLimits, max_speed_mps: float, dt_s: float) -> TrajectorySetpoint:
        """Descend at the landing speed into the ground: the land detector ends the descent, not a target.
        Horizontally the reference glides to the landing point (it is already there when landing in place).

        A landing point farther than NAV_ACC_RAD is first flown to at the current altitude, as PX4's mission inserts
        a "move to land" leg for a multicopter: gliding there while descending, a point more than a few metres
        away was reached only at the ground, and the vehicle touched down at cruise speed and broke."""
        ref_z = float(self.trajectory.position[2])
        goal = vec3(self.target_ned_m[0], self.target_ned_m[1], ref_z)
        ahead = goal[:2] - self.trajectory.position[:2]
        if math.hypot(float(ahead[0]), float(ahead[1])) > self.p("NAV_ACC_RAD"):
            return self.track_setpoint_to(goal, limits, max_speed_mps, dt_s)
        land_speed = self.p("MPC_LAND_SPEED")
        if self.altitude_above_home_m() > self.p("MPC_LAND_ALT2"):
            land_speed = self.p("MPC_Z_V_AUTO_DN")
        ref = self.trajectory.update(goal, limits, dt_s, max_speed_mps)
        return TrajectorySetpoint(
            pos_ned_m=(float(ref.pos_ned_m[0]), float(ref.pos_ned_m[1]), math.nan),
            vel_ned_mps=(float(ref.vel_ned_mps[0]), float(ref.vel_ned_mps[1]), land_speed),
            yaw_rad=self.target_yaw_rad,
        )

    def _operator_takes_over(self) -> None:
        """A mode commanded by the operator ends the failsafe in force (PX4: cleared on mode change)."""
        self._intended = None
        self._fallback_from = None
        self.failsafes.cleared()
        self.status.failsafe = False
        self.status.active_failsafe = FailsafeKind.NONE

    # ---- requests (called by the MAVLink layer or by tests) --------------------------------------------------------
    def preflight_problem(self) -> str | None:
        """The first failing pre-arm check, or None when the vehicle may arm."""
        est = self._est
        if est is None or not est.attitude_valid:
            return "Preflight Fail: attitude estimate not converged"
        if not est.altitude_valid:
            return "Preflight Fail: no altitude estimate"
        if not est.position_valid and self.p("COM_ARM_WO_GPS") == 0:
            return "Preflight Fail: no valid global position yet (GPS)"
        if self._battery_remaining() < self.p("BAT_CRIT_THR"):
            return "Preflight Fail: battery too low"
        # As PX4: with a datalink-loss action set, a ground station must be heard before arming ...
        if self.p("NAV_DLL_ACT") != 0 and not self._gcs_heard_within(self._now_s, self.p("COM_DL_LOSS_T")):
            return "Preflight Fail: No connection to the ground control station"
        # ... and with a geofence that acts, the vehicle must start inside it (zones only: home is set on arming).
        if self.p("GF_ACTION") > 1 and est.position_valid and self._fence.zones:
            pos = _tuple3(est.pos_ned_m)
            if self._fence.breach(pos, pos) is not None:
                return "Preflight Fail: Vehicle outside geofence"
        return None

    def _gcs_heard_within(self, now_s: float, timeout_s: float) -> bool:
        return not math.isnan(self._gcs_heartbeat_s) and now_s - self._gcs_heartbeat_s <= timeout_s

    def arm(self, force: bool = False) -> CommandOutcome:
        if self.status.armed:
            return ACCEPTED
        if self.crashed:
            return CommandOutcome(CommandResult.DENIED, "Arming denied: vehicle crashed")
        if not self.landed:
            return CommandOutcome(CommandResult.DENIED, "Arming denied: vehicle in the air")
        problem = None if force else self.preflight_problem()
        if problem is not None:
            self.event(4, problem)
            return CommandOutcome(CommandResult.DENIED, problem)
        if self.status.mode not in (
            Px4Mode.AUTO_LOITER,
            Px4Mode.POSCTL,
            Px4Mode.AUTO_MISSION,
            Px4Mode.OFFBOARD,
            Px4Mode.AUTO_TAKEOFF,
        ):
            return CommandOutcome(CommandResult.DENIED, f"Arming denied: not possible in {self.status.mode.px4_name}")
        self.status.armed = True
        self._held = None
        self._armed_since_s = self._now_s
        self.failsafes.on_arming()
        self._landed_since_s = self._now_s
        self.cascade.reset()
        pos = self.current_pos()
        self._home_ned_m = pos.copy()  # PX4 sets home on arming
        self._home_yaw_rad = self._est.yaw_rad if self._est is not None else 0.0
        self.trajectory.reset(pos)
        self.start_goto(pos, self._home_yaw_rad)
        self.event(6, "Armed")
        return ACCEPTED

    def disarm(self, force: bool = False) -> CommandOutcome:
        if not self.status.armed:
            return ACCEPTED
        if not force and not self.landed:
            return CommandOutcome(CommandResult.DENIED, "Disarming denied: vehicle in the air")
        self._disarm("Disarmed" if not force else "Disarmed (forced)")
        return ACCEPTED

    def kill(self) -> CommandOutcome:
        if self.status.armed:
            self._disarm("Motors killed")
        return ACCEPTED

    def crash(self, text: str) -> None:
        """A collision or a hard impact: the motors stop wherever the vehicle is, and it stays grounded (arming is
        refused)."""
        self._stop_for_good(text, "Motors stopped: crashed")

    def _stop_for_good(self, text: str, disarm_text: str) -> None:
        """A crash or a flight termination (the first one counts): say why, stop the motors, refuse to arm again."""
        if self.crashed:
            return
        self.crashed = True
        self.event(2, text)
        if self.status.armed:
            self._disarm(disarm_text)

    def _disarm(self, text: str) -> None:
        self.status.armed = False
        self._held = None  # the motors stop at the next step, not at the next tick
        self.units.rtl.plan = None
        self._operator_takes_over()
        self.cascade.reset()
        if self.status.mode is not Px4Mode.OFFBOARD:
            self.enter(Px4Mode.AUTO_LOITER)
        self.event(6, text)

    def takeoff(self, altitude_above_home_m: float = math.nan) -> CommandOutcome:
        """Climb above home to the altitude (MIS_TAKEOFF_ALT when NaN), then hold."""
        alt = self.p("MIS_TAKEOFF_ALT") if not math.isfinite(altitude_above_home_m) else altitude_above_home_m
        if alt <= 0.0:
            return CommandOutcome(CommandResult.DENIED, "Takeoff denied: altitude must be above home")
        if not self.status.armed:
            return CommandOutcome(CommandResult.DENIED, "Takeoff denied: disarmed")
        if not self.landed and self.status.mode is Px4Mode.AUTO_TAKEOFF:
            return ACCEPTED
        pos = self.current_pos()
        if self.landed:
            self.trajectory.reset(pos)
        self.start_goto(vec3(pos[0], pos[1], self._home_ned_m[2] - alt), self.target_yaw_rad)
        self.enter(Px4Mode.AUTO_TAKEOFF)
        return ACCEPTED

    def land(self, at_ned_m: tuple[float, float, float] | None = None) -> CommandOutcome:
        """Land here, or fly to ``at_ned_m`` (north/east; down is ignored) while descending and land there."""
        if not self.status.armed:
            return CommandOutcome(CommandResult.DENIED, "Land denied: disarmed")
        if self.status.mode is not Px4Mode.AUTO_LAND or at_ned_m is not None:
            self.hold_here()
            if at_ned_m is not None:
                self.target_ned_m[0], self.target_ned_m[1] = at_ned_m[0], at_ned_m[1]
            self.enter(Px4Mode.AUTO_LAND)
        return ACCEPTED

    def hold(self) -> CommandOutcome:
        if self.status.mode is not Px4Mode.AUTO_LOITER:
            self.hold_here()
            self.enter(Px4Mode.AUTO_LOITER)
        self._operator_takes_over()
        return ACCEPTED

    def return_to_launch(self) -> CommandOutcome:
        if not self.status.armed or self.landed:
            return CommandOutcome(CommandResult.DENIED, "RTL denied: not flying")
        if self.status.mode is not Px4Mode.AUTO_RTL:
            self._start_return()
        return ACCEPTED

    def _start_return(self) -> None:
        """Enter RTL with its plan made from here (the caller has checked the vehicle is flying)."""
        climb = self.units.rtl.start(self.current_pos(), self._home_ned_m, self.p("RTL_RETURN_ALT"))
        self.hold_here()
        self.start_goto(climb.target_ned_m, climb.yaw_rad)
        self.enter(Px4Mode.AUTO_RTL)

    def goto(self, target_ned_m: Vec3, yaw_rad: float = math.nan) -> CommandOutcome:
        """Reposition: fly to a local point on a smooth trajectory and hold there (PX4 DO_REPOSITION)."""
        if not self.status.armed or self.landed:
            return CommandOutcome(CommandResult.DENIED, "Reposition denied: not flying")
        if not np.all(np.isfinite(target_ned_m)):
            return CommandOutcome(CommandResult.DENIED, "Reposition denied: target not finite")
        self.enter(Px4Mode.AUTO_LOITER)
        self._operator_takes_over()
        self.start_goto(np.asarray(target_ned_m, dtype=np.float64), yaw_rad)
        return ACCEPTED

    def set_speed(self, ground_speed_mps: float) -> CommandOutcome:
        """DO_CHANGE_SPEED: limit auto-mode speed; a negative value restores the default."""
        if not math.isfinite(ground_speed_mps):
            return CommandOutcome(CommandResult.DENIED, "Speed change denied: not a number")
        self.speed_override_mps = math.inf if ground_speed_mps <= 0 else ground_speed_mps
        self._held = None
        return ACCEPTED

    @property
    def mission(self) -> MissionExecutor:
        """The uploaded mission and its progress, as the Mission unit keeps it."""
        return self.units.mission.executor

    def set_mission(self, items: tuple[NavItem, ...]) -> CommandOutcome:
        """Replace the mission; flying it continues from the first item if the vehicle is in AUTO.MISSION."""
        self.units.mission.load(items, flying_it=self.status.mode is Px4Mode.AUTO_MISSION)
        self._held = None
        return ACCEPTED

    def retarget_mission(self, items: tuple[NavItem, ...]) -> None:
        """The same mission with targets recomputed (home moved): progress is kept."""
        self.mission.retarget(items)

    def set_mission_current(self, seq: int) -> CommandOutcome:
        if not self.mission.set_current(seq):
            return CommandOutcome(CommandResult.DENIED, f"Mission item {seq} does not exist")
        if self.status.mode is Px4Mode.AUTO_MISSION:
            self.mission.start()
        return ACCEPTED

    def start_mission(self) -> CommandOutcome:
        """Enter AUTO.MISSION (allowed on the ground: arming then takes off, as in PX4)."""
        if not self.mission.items:
            return CommandOutcome(CommandResult.DENIED, "Mission rejected: no mission uploaded")
        if self.status.mode is Px4Mode.AUTO_MISSION and self.mission.state is MissionRun.ACTIVE:
            return ACCEPTED
        self.enter(Px4Mode.AUTO_MISSION)
        self.mission.start()
        self._operator_takes_over()
        return ACCEPTED

    def set_offboard_setpoint(self, setpoint: TrajectorySetpoint | AttitudeSetpoint, now_s: float) -> None:
        self.units.offboard.receive(setpoint, now_s)
        self._held = None  # a new setpoint is acted on at once (the position loop runs for it at the next step)

    def _offboard_alive(self, now_s: float) -> bool:
        return self.units.offboard.alive(now_s, self.p("COM_OF_LOSS_T"))

    def start_offboard(self, now_s: float) -> CommandOutcome:
        if not self._offboard_alive(now_s):
            return CommandOutcome(CommandResult.DENIED, "Offboard denied: no setpoint stream")
        self._operator_takes_over()
        self.enter(Px4Mode.OFFBOARD)
        return ACCEPTED

    def note_gcs_heartbeat(self, now_s: float) -> None:
        """A ground station's HEARTBEAT (type MAV_TYPE_GCS) arrived: the datalink-loss failsafe watches these, and
        is armed only once the first one has been heard, as PX4's (with NAV_DLL_ACT set, arming needs one too)."""
        self._gcs_heartbeat_s = now_s

    def set_fence(self, fence: Geofence) -> None:
        """The geofence in force from now on (local frame); GF_ACTION says what a breach does."""
        self._fence = fence
        self._held = None

    @property
    def fence(self) -> Geofence:
        return self._fence

    def _fence_breach(self, est: Estimate) -> str | None:
        if not est.position_valid:
            return None
        hor = self.params["GF_MAX_HOR_DIST"]
        ver = self.params["GF_MAX_VER_DIST"]
        if not self._fence.zones and hor <= 0.0 and ver <= 0.0:
            return None
        return self._fence.breach(_tuple3(est.pos_ned_m), _tuple3(self._home_ned_m), hor, ver)

    def terminate(self, text: str) -> None:
        """Flight termination (PX4): the motors stop and stay stopped; like a crash, arming is refused after it."""
        self._stop_for_good(text, "Flight terminated")

    # ---- failsafes -------------------------------------------------------------------------------------------------
    def _failsafe_inputs(self, est: Estimate, now_s: float) -> FailsafeInputs:
        return FailsafeInputs(
            now_s=now_s,
            landed=self.landed,
            mode=self.status.mode,
            needs_position=(self._intended or self._unit).needs_position(),
            offboard_alive=self._offboard_alive(now_s),
            gcs_heartbeat_s=self._gcs_heartbeat_s,
            battery_remaining=self._battery_remaining(),
            position_valid=est.position_valid,
            altitude_valid=est.altitude_valid,
            fence_breach=self._fence_breach(est),
        )

    def _run_failsafes(self, est: Estimate, now_s: float) -> None:
        for order in self.failsafes.evaluate(self._failsafe_inputs(est, now_s), self.params):
            self._apply_failsafe(order)
        delayed = self.failsafes.delayed_action(now_s, self.status.mode, self.p("COM_FAIL_ACT_T"))
        if delayed is not None:
            self._apply_failsafe(delayed)

    def _apply_failsafe(self, order: FailsafeOrder) -> None:
        self.event(order.severity, order.text)
        if order.resume:
            self._resume_after_fallback()
        action = order.action
        if action <= FailsafeAction.WARN:
            return
        if not self.status.failsafe:
            self._intended = self._unit
        self.status.failsafe = True
        self.status.active_failsafe = order.kind
        mode = self.status.mode
        if action is FailsafeAction.HOLD:
            self.hold_here()
            self.enter(Px4Mode.AUTO_LOITER)
        elif action is FailsafeAction.RTL:
            if mode not in (Px4Mode.AUTO_RTL, Px4Mode.AUTO_LAND):  # never climb back out of a landing
                self.return_to_launch()
        elif action is FailsafeAction.LAND and mode is not Px4Mode.AUTO_LAND:
            self.hold_here()
            self.enter(Px4Mode.AUTO_LAND)
        elif action is FailsafeAction.DESCEND:
            if self._unit is not self.units.descend:
                self._fallback_from = self._unit
            self.units.descend.start(self._est)
            self._switch_to(self.units.descend)
        elif action is FailsafeAction.DISARM:
            self._disarm("Motors stopped: lockdown")
        elif action is FailsafeAction.TERMINATE:
            self.terminate("Flight termination")

    def _resume_after_fallback(self) -> None:
        """The cause of a mode fallback (Descend) cleared while it still flies: back to the mode it replaced, and to
        whatever failsafe was in force before it (FailsafeState has restored that)."""
        before = self._fallback_from
        self._fallback_from = None
        if before is None or self._unit is not self.units.descend or self.landed:
            return
        units = self.units
        if before is units.mission:
            self.enter(Px4Mode.AUTO_MISSION)
            self.mission.start()
        elif before is units.rtl:
            self._start_return()
        elif before is units.land:
            self.hold_here()
            self.enter(Px4Mode.AUTO_LAND)
        elif before is units.offboard and self._offboard_alive(self._now_s):
            self.enter(Px4Mode.OFFBOARD)
        else:
            self.hold_here()
            self.enter(Px4Mode.AUTO_LOITER)
        self.status.failsafe = self.failsafes.in_failsafe
        self.status.active_failsafe = self.failsafes.active
        if not self.status.failsafe:
            self._intended = None

    # ---- the step --------------------------------------------------------------------------------------------------
    def step(self, est: Estimate, now_s: float, dt_s: float) -> tuple[float, ...]:
        """One physics step: returns motor commands in [0, 1] (all zero when disarmed).

        The commander (mode units, failsafes, the land detector, collision prevention and the position loops) runs
        on ticks at MPC_LOOP_HZ, as PX4's flight tasks run with its position controller and its commander at about
        100 Hz; the attitude, rate and allocation loops run at every step. Between ticks a step repeats what the last
        tick decided: motors off, idle, or the inner loops towards the attitude the position loops last produced.
        A command (arming, a mode, a setpoint, a target) or a parameter change makes the next step a tick, so nothing
        waits for the commander's clock to be acted on."""
        self._est = est
        self._now_s = now_s
        self._since_tick_s += dt_s
        # Between ticks the thrust shown (status.thrust_n) stays the one the last tick set: the held collective.
        held = self._held
        if held is not None and self.params.version == self._tick_version:
            if held.trajectory is not None:
                if not self.cascade.outer_due(dt_s):  # as ``holds_inner_loops`` says
                    return self.cascade.update(est, held.trajectory, dt_s, landed=self.landed).motor_cmds
            elif self._since_tick_s < self._tick_period_s - 1e-9:
                if held.motors is not None:
                    return held.motors
                if held.attitude is not None:
                    self.trajectory.reset(est.pos_ned_m)
                    return self.cascade.update_attitude(est, held.attitude, dt_s, landed=self.landed).motor_cmds
        return self._tick(est, now_s, dt_s)

    def holds_inner_loops(self, dt_s: float) -> bool:
        """Will the next step, of ``dt_s``, only run the inner loops towards the position loops' held output (no
        tick, no attitude setpoint)? Then the caller may take it with ``inner_loops_stepped`` instead of ``step``."""
        held = self._held
        return (
            held is not None
            and held.trajectory is not None
            and self.params.version == self._tick_version
            and not self.cascade.outer_due(dt_s)
        )

    def inner_loops_stepped(self, est: Estimate, now_s: float, dt_s: float) -> tuple[float, ...]:
        """The step ``holds_inner_loops`` announced was taken outside (sitl/kernels/between_ticks.py: the inner
        loops on the cascade's rows, to the estimate ``est``): note it as ``step`` would have, and return its motor
        commands."""
        self._est = est
        self._now_s = now_s
        self._since_tick_s += dt_s
        return self.cascade.inner_step_taken(dt_s)

    def _tick(self, est: Estimate, now_s: float, dt_s: float) -> tuple[float, ...]:
        """The commander's tick: everything ``step`` describes, with the mode units advanced by the time since the
        last tick."""
        tick_dt_s = self._since_tick_s
        self._since_tick_s = 0.0
        version = self.params.version
        if version != self._tick_version:
            self._tick_version = version
            self._tick_period_s = outer_loop_period_s(self.params)
        n = len(self.airframe.rotors)
        if not self.status.armed:
            if not self.landed and self._land_detector.update(
                now_s, float(est.vel_ned_mps[2]), 0.0, self.altitude_above_home_m()
            ):
                # Killed in the air: the detector keeps watching with the motors off, so once the vehicle lies
                # still on the ground it counts as landed again and may re-arm (PX4 treats disarmed as landed).
                self.event(6, "Landing detected")
            self.status.landed_state = LandedState.ON_GROUND if self.landed else LandedState.IN_AIR
            self.status.thrust_n = 0.0
            self._held = _Held(motors=(0.0,) * n)
            return (0.0,) * n
        self._carry_out(self._unit.advance(self._mode_inputs(est, now_s)))
        self._run_failsafes(est, now_s)
        unit = self._unit
        if self.landed and not unit.wants_air(True):
            # Armed on the ground: motors idle, controllers held at rest so nothing winds up.
            self.cascade.reset()
            self.trajectory.reset(est.pos_ned_m)
            self.target_ned_m = est.pos_ned_m.copy()
            self.status.thrust_n = 0.0
            self._check_auto_disarm(now_s)
            self.status.landed_state = LandedState.ON_GROUND
            self._held = _Held(motors=self._idle) if self.status.armed else None
            return self._idle
        out = self._control(unit, est, now_s, dt_s, tick_dt_s)
        self.status.thrust_n = out.collective_sp_n
        was_landed = self.landed
        landed = self._land_detector.update(
            now_s,
            float(est.vel_ned_mps[2]),
            out.collective_sp_n / self._hover_thrust_n,
            self.altitude_above_home_m(),
        )
        if was_landed and not landed:
            self.event(6, "Takeoff detected")
        elif landed and not was_landed:
            self.event(6, "Landing detected")
            self._landed_since_s = now_s
            self._carry_out(unit.on_touchdown(self._mode_inputs(est, now_s)))
            self.cascade.reset()
            self._held = None
            return self._idle
        self.status.landed_state = unit.landed_state(landed)
        return out.motor_cmds

    def _control(self, unit: ModeUnit, est: Estimate, now_s: float, dt_s: float, tick_dt_s: float) -> CascadeOutput:
        decided = unit.setpoint(self._mode_inputs(est, now_s), tick_dt_s)
        # Held only while armed: a failsafe that disarmed in this tick (lockdown, termination) leaves the next step a
        # tick, which stops the motors.
        armed = self.status.armed
        if isinstance(decided, Track):
            setpoint = self._fly_reference(decided, tick_dt_s)
        else:
            # A setpoint of the unit's own: the auto-mode reference follows the vehicle, so a switch back to an auto
            # mode starts where the vehicle is.
            self.trajectory.reset(est.pos_ned_m)
            if isinstance(decided, AttitudeSetpoint):
                self._held = _Held(attitude=decided) if armed else None
                return self.cascade.update_attitude(est, decided, dt_s, landed=self.landed)
            setpoint = decided
        if not self.landed:
            setpoint = self.collision_prevention.apply(setpoint, est.pos_ned_m, est.vel_ned_mps, now_s)
        self._held = _Held(trajectory=setpoint) if armed else None
        return self.cascade.update(est, setpoint, dt_s, landed=self.landed)

    def _fly_reference(self, track: Track, dt_s: float) -> TrajectorySetpoint:
        if track.descend_to_land:
            return self.land_descent_setpoint(track.limits, track.max_speed_mps, dt_s)
        return self.track_setpoint(track.limits, track.max_speed_mps, dt_s)

    def _check_auto_disarm(self, now_s: float) -> None:
        since = self._landed_since_s if self._landed_since_s is not None else now_s
        took_off = since > self._armed_since_s
        delay = self.p("COM_DISARM_LAND") if took_off else self.p("COM_DISARM_PRFLT")
        if delay >= 0 and now_s - since >= delay:
            self._disarm("Auto-disarmed after landing" if took_off else "Auto-disarmed: no takeoff")
