"""The autopilot: arming, flight modes, failsafes. Pure: estimate and time in, motor commands out.

This is the drone's "commander + navigator" in PX4 terms. It owns the mode machine and turns the active mode into a
trajectory setpoint for the controller cascade (sitl/control), and it decides when the motors may spin. It never
reads ground truth, a clock or a socket: the simulation loop passes the estimate and the simulation time, and the
MAVLink layer calls the request methods (arm, takeoff, set_mode, ...), each answering with an ``Outcome``.

Behaviour follows PX4 where a client could notice: takeoff climbs to MIS_TAKEOFF_ALT and switches to Hold; land
descends and auto-disarms COM_DISARM_LAND seconds after touchdown; RTL climbs to RTL_RETURN_ALT, returns and lands;
offboard needs a live setpoint stream and falls back to Hold, then lands, when it stops; below BAT_LOW_THR it warns,
and below BAT_CRIT_THR in the air it returns to launch.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from sitl.airframe import Airframe
from sitl.collision_prevention import CollisionPrevention
from sitl.control.cascade import AttitudeSetpoint, Cascade, CascadeOutput, TrajectorySetpoint
from sitl.estimation import Estimate
from sitl.geofence import Geofence
from sitl.guidance import MotionLimits, StraightLineTrajectory
from sitl.land_detector import LandDetector, LandDetectorConfig
from sitl.mathutil import Vec3, vec3
from sitl.mission_exec import MissionAction, MissionExecutor, MissionRun
from sitl.mission_plan import NavItem, NavKind
from sitl.params import ParamStore
from sitl.protocol.modes import Px4Mode
from sitl.protocol.vehicle_api import CommandOutcome, CommandResult, LandedState

NAN3 = (math.nan, math.nan, math.nan)
# Armed on the ground the rotors spin at idle so a person sees the vehicle is live (PX4 and ArduPilot do this).
ARMED_IDLE_CMD = 0.15


def _tuple3(v: Vec3) -> tuple[float, float, float]:
    return (float(v[0]), float(v[1]), float(v[2]))


ACCEPTED = CommandOutcome.accepted()


@dataclass(frozen=True, slots=True, kw_only=True)
class VehicleEvent:
    """Something a ground station should hear about (becomes a STATUSTEXT)."""

    severity: int  # MAV_SEVERITY: 2 critical, 4 warning, 6 info
    text: str


@dataclass(slots=True)
class _RtlPlan:
    phase: str  # "climb", "return", "descend"
    cruise_down_m: float


@dataclass(slots=True)
class _Failsafe:
    since_s: float


@dataclass(slots=True)
class VehicleStatus:
    """Mutable view of the autopilot's state, read by telemetry."""

    armed: bool = False
    mode: Px4Mode = Px4Mode.AUTO_LOITER
    landed_state: LandedState = LandedState.ON_GROUND
    failsafe: bool = False
    thrust_n: float = 0.0


class Vehicle:
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
        self._limits_version = -1
        self._limits_cache: MotionLimits | None = None
        self.events: list[VehicleEvent] = []
        self._battery_remaining = battery_remaining
        self._hover_thrust_n = airframe.mass_kg * 9.80665
        self._idle = (ARMED_IDLE_CMD,) * len(airframe.rotors)
        self._land_detector = LandDetector(LandDetectorConfig())
        self._trajectory = StraightLineTrajectory(np.zeros(3))
        self._target_ned_m: Vec3 = np.zeros(3)
        self._target_yaw_rad = math.nan
        self._speed_override_mps = math.inf
        self._offboard: TrajectorySetpoint | AttitudeSetpoint | None = None
        self._offboard_time_s = -math.inf
        self._rtl: _RtlPlan | None = None
        self._failsafe: _Failsafe | None = None
        self._est: Estimate | None = None
        self._now_s = 0.0
        self._landed_since_s: float | None = 0.0
        self._armed_since_s = 0.0
        self._home_ned_m = np.zeros(3)
        self._home_yaw_rad = 0.0
        self.mission = MissionExecutor()
        self._mission_climb_down_m: float | None = None  # auto takeoff before the first mission item
        self._mission_landing = False
        self._battery_low_warned = False
        self._battery_critical = False
        self.collision_prevention = CollisionPrevention(
            params, cascade.position, airframe.collision_radius_m, self._event
        )

    # ---- helpers ---------------------------------------------------------------------------------------------------
    def _event(self, severity: int, text: str) -> None:
        self.events.append(VehicleEvent(severity=severity, text=text))

    def _p(self, name: str) -> float:
        return self.params[name]

    def _limits(self) -> MotionLimits:
        """Auto-mode motion limits, rebuilt only when a parameter changed (this runs every control step)."""
        if self._limits_cache is None or self._limits_version != self.params.version:
            self._limits_version = self.params.version
            self._limits_cache = MotionLimits(
                speed_xy_mps=self._p("MPC_XY_CRUISE"),
                speed_up_mps=self._p("MPC_Z_V_AUTO_UP"),
                speed_down_mps=self._p("MPC_Z_V_AUTO_DN"),
                accel_xy_mps2=self._p("MPC_ACC_HOR"),
                accel_z_mps2=self._p("MPC_ACC_UP_MAX"),
            )
        return self._limits_cache

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
        self._event(6, "Home position set")
        return ACCEPTED

    @property
    def landed(self) -> bool:
        return self._land_detector.landed

    def altitude_above_home_m(self) -> float:
        return 0.0 if self._est is None else float(self._home_ned_m[2] - self._est.pos_ned_m[2])

    def _current_pos(self) -> Vec3:
        return np.zeros(3) if self._est is None else self._est.pos_ned_m.copy()

    def _enter(self, mode: Px4Mode) -> None:
        if mode is not self.status.mode:
            if self.status.mode is Px4Mode.AUTO_MISSION:
                self.mission.pause()
                self._mission_landing = False
                self._mission_climb_down_m = None
            self.status.mode = mode
            self._event(6, f"Mode {mode.px4_name}")

    def _start_goto(self, target_ned_m: Vec3, yaw_rad: float = math.nan) -> None:
        """Fly to a point on a smooth trajectory, starting from where the reference currently is."""
        self._target_ned_m = np.array(target_ned_m, dtype=np.float64)
        self._target_yaw_rad = yaw_rad

    def _hold_here(self) -> None:
        """Hold at the point where the vehicle can stop without a jerk (braking distance included)."""
        pos = self._current_pos()
        if self._est is not None and self.status.armed and not self.landed:
            vel = self._est.vel_ned_mps
            speed = float(np.linalg.norm(vel))
            if speed > 0.1:
                pos = pos + vel * (speed / (2.0 * self._p("MPC_ACC_HOR")))
            self._trajectory.reset(self._current_pos())
        self._start_goto(pos, self._est.yaw_rad if self._est is not None else math.nan)

    # ---- requests (called by the MAVLink layer or by tests) --------------------------------------------------------
    def preflight_problem(self) -> str | None:
        """The first failing pre-arm check, or None when the vehicle may arm."""
        est = self._est
        if est is None or not est.attitude_valid:
            return "Preflight Fail: attitude estimate not converged"
        if not est.altitude_valid:
            return "Preflight Fail: no altitude estimate"
        if not est.position_valid and self._p("COM_ARM_WO_GPS") == 0:
            return "Preflight Fail: no valid global position yet (GPS)"
        if self._battery_remaining() < self._p("BAT_CRIT_THR"):
            return "Preflight Fail: battery too low"
        return None

    def arm(self, force: bool = False) -> CommandOutcome:
        if self.status.armed:
            return ACCEPTED
        if self.crashed:
            return CommandOutcome(CommandResult.DENIED, "Arming denied: vehicle crashed")
        if not self.landed:
            return CommandOutcome(CommandResult.DENIED, "Arming denied: vehicle in the air")
        problem = None if force else self.preflight_problem()
        if problem is not None:
            self._event(4, problem)
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
        self._armed_since_s = self._now_s
        self._battery_low_warned = False
        self._battery_critical = False
        self._landed_since_s = self._now_s
        self.cascade.reset()
        pos = self._current_pos()
        self._home_ned_m = pos.copy()  # PX4 sets home on arming
        self._home_yaw_rad = self._est.yaw_rad if self._est is not None else 0.0
        self._trajectory.reset(pos)
        self._start_goto(pos, self._home_yaw_rad)
        self._event(6, "Armed")
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
        """A collision: the motors stop wherever the vehicle is, and it stays grounded (arming is refused)."""
        if self.crashed:
            return
        self.crashed = True
        self._event(2, text)
        if self.status.armed:
            self._disarm("Motors stopped: crashed")

    def _disarm(self, text: str) -> None:
        self.status.armed = False
        self._rtl = None
        self._failsafe = None
        self.status.failsafe = False
        self.cascade.reset()
        if self.status.mode is not Px4Mode.OFFBOARD:
            self._enter(Px4Mode.AUTO_LOITER)
        self._event(6, text)

    def takeoff(self, altitude_above_home_m: float = math.nan) -> CommandOutcome:
        """Climb above home to the altitude (MIS_TAKEOFF_ALT when NaN), then hold."""
        alt = self._p("MIS_TAKEOFF_ALT") if not math.isfinite(altitude_above_home_m) else altitude_above_home_m
        if alt <= 0.0:
            return CommandOutcome(CommandResult.DENIED, "Takeoff denied: altitude must be above home")
        if not self.status.armed:
            return CommandOutcome(CommandResult.DENIED, "Takeoff denied: disarmed")
        if not self.landed and self.status.mode is Px4Mode.AUTO_TAKEOFF:
            return ACCEPTED
        pos = self._current_pos()
        if self.landed:
            self._trajectory.reset(pos)
        self._start_goto(vec3(pos[0], pos[1], self._home_ned_m[2] - alt), self._target_yaw_rad)
        self._enter(Px4Mode.AUTO_TAKEOFF)
        return ACCEPTED

    def land(self, at_ned_m: tuple[float, float, float] | None = None) -> CommandOutcome:
        """Land here, or fly to ``at_ned_m`` (north/east; down is ignored) while descending and land there."""
        if not self.status.armed:
            return CommandOutcome(CommandResult.DENIED, "Land denied: disarmed")
        if self.status.mode is not Px4Mode.AUTO_LAND or at_ned_m is not None:
            self._hold_here()
            if at_ned_m is not None:
                self._target_ned_m[0], self._target_ned_m[1] = at_ned_m[0], at_ned_m[1]
            self._enter(Px4Mode.AUTO_LAND)
        return ACCEPTED

    def hold(self) -> CommandOutcome:
        if self.status.mode is not Px4Mode.AUTO_LOITER:
            self._hold_here()
            self._enter(Px4Mode.AUTO_LOITER)
        self._failsafe = None
        self.status.failsafe = False
        return ACCEPTED

    def return_to_launch(self) -> CommandOutcome:
        if not self.status.armed or self.landed:
            return CommandOutcome(CommandResult.DENIED, "RTL denied: not flying")
        if self.status.mode is not Px4Mode.AUTO_RTL:
            cruise = min(self._current_pos()[2], self._home_ned_m[2] - self._p("RTL_RETURN_ALT"))
            self._rtl = _RtlPlan(phase="climb", cruise_down_m=cruise)
            self._hold_here()
            pos = self._current_pos()
            self._start_goto(vec3(pos[0], pos[1], cruise))
            self._enter(Px4Mode.AUTO_RTL)
        return ACCEPTED

    def goto(self, target_ned_m: Vec3, yaw_rad: float = math.nan) -> CommandOutcome:
        """Reposition: fly to a local point on a smooth trajectory and hold there (PX4 DO_REPOSITION)."""
        if not self.status.armed or self.landed:
            return CommandOutcome(CommandResult.DENIED, "Reposition denied: not flying")
        if not np.all(np.isfinite(target_ned_m)):
            return CommandOutcome(CommandResult.DENIED, "Reposition denied: target not finite")
        self._enter(Px4Mode.AUTO_LOITER)
        self._failsafe = None
        self.status.failsafe = False
        self._start_goto(np.asarray(target_ned_m, dtype=np.float64), yaw_rad)
        return ACCEPTED

    def set_speed(self, ground_speed_mps: float) -> CommandOutcome:
        """DO_CHANGE_SPEED: limit auto-mode speed; a negative value restores the default."""
        if not math.isfinite(ground_speed_mps):
            return CommandOutcome(CommandResult.DENIED, "Speed change denied: not a number")
        self._speed_override_mps = math.inf if ground_speed_mps <= 0 else ground_speed_mps
        return ACCEPTED

    def set_mission(self, items: tuple[NavItem, ...]) -> CommandOutcome:
        """Replace the mission; flying it continues from the first item if the vehicle is in AUTO.MISSION."""
        self.mission.load(items)
        self._mission_landing = False
        if self.status.mode is Px4Mode.AUTO_MISSION and items:
            self.mission.start()
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
        self._enter(Px4Mode.AUTO_MISSION)
        self.mission.start()
        self._failsafe = None
        self.status.failsafe = False
        return ACCEPTED

    def _mission_step(self, est: Estimate, now_s: float) -> None:
        if self.landed and self.mission.state is MissionRun.ACTIVE and self._mission_climb_down_m is None:
            first = self.mission.items[self.mission.index]
            if first.kind is not NavKind.TAKEOFF:
                # PX4 takes off to MIS_TAKEOFF_ALT before flying a mission started on the ground.
                pos = self._current_pos()
                self._mission_climb_down_m = float(self._home_ned_m[2] - self._p("MIS_TAKEOFF_ALT"))
                self._trajectory.reset(pos)
                self._start_goto(vec3(pos[0], pos[1], self._mission_climb_down_m), self._target_yaw_rad)
                return
        if self._mission_climb_down_m is not None:
            if self.landed or abs(est.pos_ned_m[2] - self._mission_climb_down_m) > 0.3:
                return
            self._mission_climb_down_m = None
        action = self.mission.step(now_s, est.pos_ned_m, self.landed, self._p("NAV_ACC_RAD"))
        if action is not None:
            self._apply_mission_action(action)

    def _apply_mission_action(self, action: MissionAction) -> None:
        target = np.array(action.target_ned_m, dtype=np.float64)
        if action.kind is NavKind.SPEED:
            self.set_speed(action.speed_mps if math.isfinite(action.speed_mps) else -1.0)
        elif action.kind is NavKind.RTL:
            self.return_to_launch()
        elif action.kind is NavKind.LAND:
            self._mission_landing = True
            self._start_goto(target, action.yaw_rad)
        else:
            if self.landed:
                self._trajectory.reset(self._current_pos())
            self._start_goto(target, action.yaw_rad)

    def set_offboard_setpoint(self, setpoint: TrajectorySetpoint | AttitudeSetpoint, now_s: float) -> None:
        self._offboard = setpoint
        self._offboard_time_s = now_s

    def _offboard_alive(self, now_s: float) -> bool:
        return self._offboard is not None and now_s - self._offboard_time_s <= self._p("COM_OF_LOSS_T")

    def start_offboard(self, now_s: float) -> CommandOutcome:
        if not self._offboard_alive(now_s):
            return CommandOutcome(CommandResult.DENIED, "Offboard denied: no setpoint stream")
        self._failsafe = None
        self.status.failsafe = False
        self._enter(Px4Mode.OFFBOARD)
        return ACCEPTED

    # ---- the step --------------------------------------------------------------------------------------------------
    def _setpoint_for_mode(self, est: Estimate, now_s: float, dt_s: float) -> TrajectorySetpoint:
        mode = self.status.mode
        if mode is Px4Mode.OFFBOARD and isinstance(self._offboard, TrajectorySetpoint):
            self._trajectory.reset(est.pos_ned_m)
            return self._offboard
        limits = self._limits()
        max_speed = self._speed_override_mps
        if mode is Px4Mode.AUTO_TAKEOFF:
            max_speed = min(max_speed, self._p("MPC_TKO_SPEED"))
            limits = MotionLimits(
                speed_xy_mps=limits.speed_xy_mps,
                speed_up_mps=self._p("MPC_TKO_SPEED"),
                speed_down_mps=limits.speed_down_mps,
                accel_xy_mps2=limits.accel_xy_mps2,
                accel_z_mps2=limits.accel_z_mps2,
            )
        if self._descending_to_land():
            land_speed = self._p("MPC_LAND_SPEED")
            if self.altitude_above_home_m() > self._p("MPC_LAND_ALT2"):
                land_speed = self._p("MPC_Z_V_AUTO_DN")
            # Descend at the landing speed into the ground: the land detector ends the descent, not a target.
            # Horizontally the reference glides to the landing point (it is already there when landing in place).
            ref_z = float(self._trajectory.position[2])
            goal = vec3(self._target_ned_m[0], self._target_ned_m[1], ref_z)
            ref = self._trajectory.update(goal, limits, dt_s, max_speed)
            return TrajectorySetpoint(
                pos_ned_m=(float(ref.pos_ned_m[0]), float(ref.pos_ned_m[1]), math.nan),
                vel_ned_mps=(float(ref.vel_ned_mps[0]), float(ref.vel_ned_mps[1]), land_speed),
                yaw_rad=self._target_yaw_rad,
            )
        ref = self._trajectory.update(self._target_ned_m, limits, dt_s, max_speed)
        return TrajectorySetpoint(
            pos_ned_m=_tuple3(ref.pos_ned_m),
            vel_ned_mps=_tuple3(ref.vel_ned_mps),
            acc_ned_mps2=_tuple3(ref.acc_ned_mps2),
            yaw_rad=self._target_yaw_rad,
        )

    def _advance_modes(self, est: Estimate, now_s: float) -> None:
        mode = self.status.mode
        if mode is Px4Mode.AUTO_MISSION:
            self._mission_step(est, now_s)
        if (
            mode is Px4Mode.AUTO_TAKEOFF
            and abs(est.pos_ned_m[2] - self._target_ned_m[2]) < 0.15
            and float(np.linalg.norm(self._trajectory.position - self._target_ned_m)) < 1e-3
        ):
            self._event(6, "Takeoff complete")
            self._enter(Px4Mode.AUTO_LOITER)
        elif mode is Px4Mode.AUTO_RTL and self._rtl is not None:
            arrived = float(np.linalg.norm(self._trajectory.position - self._target_ned_m)) < 1e-3
            if self._rtl.phase == "climb" and arrived:
                self._rtl.phase = "return"
                self._start_goto(
                    vec3(self._home_ned_m[0], self._home_ned_m[1], self._rtl.cruise_down_m),
                    self._home_yaw_rad,
                )
            elif self._rtl.phase == "return" and arrived:
                self._rtl.phase = "descend"
                descend_down = max(self._rtl.cruise_down_m, self._home_ned_m[2] - self._p("RTL_DESCEND_ALT"))
                self._start_goto(vec3(self._home_ned_m[0], self._home_ned_m[1], descend_down), self._home_yaw_rad)
            elif self._rtl.phase == "descend" and arrived:
                self._rtl.phase = "land"
        elif mode is Px4Mode.OFFBOARD and not self._offboard_alive(now_s):
            self._event(2, "Failsafe: offboard setpoints lost, holding")
            self._failsafe = _Failsafe(since_s=now_s)
            self.status.failsafe = True
            self._hold_here()
            self._enter(Px4Mode.AUTO_LOITER)
        self._check_battery()
        if (
            self._failsafe is not None
            and self.status.mode is Px4Mode.AUTO_LOITER
            and now_s - self._failsafe.since_s >= self._p("COM_FAIL_ACT_T")
        ):
            self._failsafe = None
            self._event(2, "Failsafe: landing")
            self._hold_here()
            self._enter(Px4Mode.AUTO_LAND)

    def _check_battery(self) -> None:
        """BAT_LOW_THR warns once per flight; below BAT_CRIT_THR in the air the vehicle returns to launch."""
        if self._battery_critical:
            return
        remaining = self._battery_remaining()
        if not self._battery_low_warned and remaining < self._p("BAT_LOW_THR"):
            self._battery_low_warned = True
            self._event(4, f"Low battery: {remaining:.0%} remaining")
        if remaining < self._p("BAT_CRIT_THR") and not self.landed:
            self._battery_critical = True
            self._failsafe = None  # supersedes an offboard-loss failsafe in progress
            self.status.failsafe = True
            self._event(2, "Failsafe: battery critical, returning to launch")
            if self.status.mode not in (Px4Mode.AUTO_RTL, Px4Mode.AUTO_LAND):
                self.return_to_launch()

    def step(self, est: Estimate, now_s: float, dt_s: float) -> tuple[float, ...]:
        """One control step: returns motor commands in [0, 1] (all zero when disarmed)."""
        self._est = est
        self._now_s = now_s
        n = len(self.airframe.rotors)
        if not self.status.armed:
            if not self.landed and self._land_detector.update(
                now_s, float(est.vel_ned_mps[2]), 0.0, self.altitude_above_home_m()
            ):
                # Killed in the air: the detector keeps watching with the motors off, so once the vehicle lies
                # still on the ground it counts as landed again and may re-arm (PX4 treats disarmed as landed).
                self._event(6, "Landing detected")
            self.status.landed_state = LandedState.ON_GROUND if self.landed else LandedState.IN_AIR
            self.status.thrust_n = 0.0
            return (0.0,) * n
        self._advance_modes(est, now_s)
        mode = self.status.mode
        mission_flying = mode is Px4Mode.AUTO_MISSION and self.mission.state is MissionRun.ACTIVE
        wants_air = (
            mode in (Px4Mode.AUTO_TAKEOFF, Px4Mode.OFFBOARD)
            or (mode in (Px4Mode.AUTO_LOITER, Px4Mode.AUTO_RTL, Px4Mode.AUTO_MISSION) and not self.landed)
            or (mission_flying and not self._mission_landing)
        )
        if self.landed and not wants_air:
            # Armed on the ground: motors idle, controllers held at rest so nothing winds up.
            self.cascade.reset()
            self._trajectory.reset(est.pos_ned_m)
            self._target_ned_m = est.pos_ned_m.copy()
            self.status.thrust_n = 0.0
            self._check_auto_disarm(now_s)
            self.status.landed_state = LandedState.ON_GROUND
            return self._idle
        out = self._control(est, now_s, dt_s)
        self.status.thrust_n = out.collective_sp_n
        was_landed = self.landed
        landed = self._land_detector.update(
            now_s,
            float(est.vel_ned_mps[2]),
            out.collective_sp_n / self._hover_thrust_n,
            self.altitude_above_home_m(),
        )
        if was_landed and not landed:
            self._event(6, "Takeoff detected")
        elif landed and not was_landed:
            self._event(6, "Landing detected")
            self._landed_since_s = now_s
            self._rtl = None
            if mode is Px4Mode.AUTO_MISSION and self._mission_landing:
                self.mission.step(now_s, est.pos_ned_m, True, self._p("NAV_ACC_RAD"))
            elif mode is not Px4Mode.AUTO_LAND:
                self._enter(Px4Mode.AUTO_LAND)
            self.cascade.reset()
            return self._idle
        self.status.landed_state = self._landed_state(mode, landed)
        return out.motor_cmds

    def _control(self, est: Estimate, now_s: float, dt_s: float) -> CascadeOutput:
        if self.status.mode is Px4Mode.OFFBOARD and isinstance(self._offboard, AttitudeSetpoint):
            self._trajectory.reset(est.pos_ned_m)
            return self.cascade.update_attitude(est, self._offboard, dt_s, landed=self.landed)
        setpoint = self._setpoint_for_mode(est, now_s, dt_s)
        if not self.landed:
            setpoint = self.collision_prevention.apply(setpoint, est.pos_ned_m, est.vel_ned_mps, now_s)
        return self.cascade.update(est, setpoint, dt_s, landed=self.landed)

    def _descending_to_land(self) -> bool:
        mode = self.status.mode
        return (
            mode is Px4Mode.AUTO_LAND
            or (mode is Px4Mode.AUTO_RTL and self._rtl is not None and self._rtl.phase == "land")
            or (mode is Px4Mode.AUTO_MISSION and self._mission_landing)
        )

    def _landed_state(self, mode: Px4Mode, landed: bool) -> LandedState:
        if landed:
            return LandedState.TAKEOFF if mode is Px4Mode.AUTO_TAKEOFF else LandedState.ON_GROUND
        if mode is Px4Mode.AUTO_TAKEOFF:
            return LandedState.TAKEOFF
        if self._descending_to_land():
            return LandedState.LANDING
        return LandedState.IN_AIR

    def _check_auto_disarm(self, now_s: float) -> None:
        since = self._landed_since_s if self._landed_since_s is not None else now_s
        took_off = since > self._armed_since_s
        delay = self._p("COM_DISARM_LAND") if took_off else self._p("COM_DISARM_PRFLT")
        if delay >= 0 and now_s - since >= delay:
            self._disarm("Auto-disarmed after landing" if took_off else "Auto-disarmed: no takeoff")

    def set_fence(self, fence: Geofence) -> None:
        """The geofence uploaded by a ground station, in the local frame."""
        self.fence = fence

    def note_gcs_heartbeat(self, now_s: float) -> None:
        """A ground-station HEARTBEAT arrived at ``now_s``."""
        self.gcs_heartbeat_s = now_s
