"""One unit per flight mode, all behind one interface (``ModeUnit``).

A unit owns its mode's state (the RTL plan, the mission's phase, the offboard stream) and answers, each control
step: what changes now (``advance``: transitions such as "takeoff complete"), what to fly (``setpoint``), does the
vehicle want to be in the air (``wants_air``: on the ground and not wanting air the motors idle), is it landing
(``descending_to_land``, ``landed_state``), can it fly without a position (``needs_position``, for the GPS-loss
failsafe) and what happens at touchdown (``on_touchdown``). Adding a mode means one class here and its field in
``Units``.

The units reach the vehicle through ``ModeContext``, the narrow surface sitl/autopilot/commander.py offers them: the
shared smooth trajectory, the target it tracks, home, the land detector's verdict and the mode switch. They never read a
clock or a socket either: the estimate and the simulation time come in as arguments.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar, Protocol

import numpy as np

from sitl.autopilot.guidance import MotionLimits, StraightLineTrajectory
from sitl.autopilot.mission_exec import MissionAction, MissionExecutor, MissionRun
from sitl.autopilot.mission_plan import NavItem, NavKind
from sitl.autopilot.px4_modes import Px4Mode
from sitl.autopilot.vehicle_api import CommandOutcome, LandedState
from sitl.control.cascade import AttitudeSetpoint, TrajectorySetpoint
from sitl.estimation.estimator import Estimate
from sitl.mathutil import Vec3, vec3

from .phases import MissionPhase, RtlPhase

# The reference has arrived at its target when it is this close (the trajectory converges exactly; this only absorbs
# float rounding).
ARRIVED_M = 1e-3
# Takeoff is complete once the estimate is within this of the takeoff altitude (and the reference has arrived).
TAKEOFF_DONE_M = 0.15
# A mission's automatic takeoff hands over to the first item within this of MIS_TAKEOFF_ALT.
MISSION_CLIMB_DONE_M = 0.3


class ModeContext(Protocol):
    """What a mode unit may use of the vehicle (implemented by sitl.autopilot.commander.Commander)."""

    trajectory: StraightLineTrajectory
    target_ned_m: Vec3
    target_yaw_rad: float
    speed_override_mps: float

    @property
    def landed(self) -> bool: ...
    @property
    def home_ned_m(self) -> Vec3: ...
    @property
    def home_yaw_rad(self) -> float: ...
    def p(self, name: str) -> float: ...
    def limits(self) -> MotionLimits: ...
    def current_pos(self) -> Vec3: ...
    def start_goto(self, target_ned_m: Vec3, yaw_rad: float = math.nan) -> None: ...
    def hold_here(self) -> None: ...
    def enter(self, mode: Px4Mode) -> None: ...
    def event(self, severity: int, text: str) -> None: ...
    def return_to_launch(self) -> CommandOutcome: ...
    def set_speed(self, ground_speed_mps: float) -> CommandOutcome: ...
    def track_setpoint(self, limits: MotionLimits, max_speed_mps: float, dt_s: float) -> TrajectorySetpoint: ...
    def land_descent_setpoint(self, limits: MotionLimits, max_speed_mps: float, dt_s: float) -> TrajectorySetpoint: ...


class ModeUnit(Protocol):
    """The one interface every flight mode implements."""

    mode: ClassVar[Px4Mode]  # what HEARTBEAT shows while the unit flies

    def exit(self, v: ModeContext) -> None:
        """Leaving the mode: drop what must not survive it."""

    def advance(self, v: ModeContext, est: Estimate, now_s: float) -> None:
        """The mode's own transitions, before the setpoint of this step is computed."""

    def setpoint(self, v: ModeContext, est: Estimate, dt_s: float) -> TrajectorySetpoint | AttitudeSetpoint: ...

    def wants_air(self, v: ModeContext) -> bool: ...

    def descending_to_land(self) -> bool: ...

    def needs_position(self) -> bool:
        """Does flying this mode need a horizontal position (the GPS-loss failsafe watches this)?"""
        ...

    def on_touchdown(self, v: ModeContext, est: Estimate, now_s: float) -> None: ...

    def landed_state(self, landed: bool) -> LandedState: ...


class TrackTarget:
    """Fly the shared smooth trajectory to the current target; the behaviour every auto mode starts from."""

    mode: ClassVar[Px4Mode] = Px4Mode.AUTO_LOITER

    def exit(self, v: ModeContext) -> None:
        return None

    def advance(self, v: ModeContext, est: Estimate, now_s: float) -> None:
        return None

    def setpoint(self, v: ModeContext, est: Estimate, dt_s: float) -> TrajectorySetpoint | AttitudeSetpoint:
        limits = v.limits()
        if self.descending_to_land():
            return v.land_descent_setpoint(limits, v.speed_override_mps, dt_s)
        return v.track_setpoint(limits, v.speed_override_mps, dt_s)

    def wants_air(self, v: ModeContext) -> bool:
        return not v.landed

    def descending_to_land(self) -> bool:
        return False

    def needs_position(self) -> bool:
        return True

    def on_touchdown(self, v: ModeContext, est: Estimate, now_s: float) -> None:
        v.enter(Px4Mode.AUTO_LAND)  # PX4 treats any touchdown as a landing, whatever mode brought it down

    def landed_state(self, landed: bool) -> LandedState:
        if landed:
            return LandedState.ON_GROUND
        return LandedState.LANDING if self.descending_to_land() else LandedState.IN_AIR


class Hold(TrackTarget):
    """AUTO.LOITER: hold the target (a reposition is a Hold with a new target, as PX4's DO_REPOSITION)."""

    mode = Px4Mode.AUTO_LOITER


class Takeoff(TrackTarget):
    """AUTO.TAKEOFF: climb at MPC_TKO_SPEED to the takeoff altitude, then Hold."""

    mode = Px4Mode.AUTO_TAKEOFF

    def advance(self, v: ModeContext, est: Estimate, now_s: float) -> None:
        if (
            abs(est.pos_ned_m[2] - v.target_ned_m[2]) < TAKEOFF_DONE_M
            and math.hypot(*(v.trajectory.position - v.target_ned_m)) < ARRIVED_M
        ):
            v.event(6, "Takeoff complete")
            v.enter(Px4Mode.AUTO_LOITER)

    def setpoint(self, v: ModeContext, est: Estimate, dt_s: float) -> TrajectorySetpoint | AttitudeSetpoint:
        limits = v.limits()
        tko_speed = v.p("MPC_TKO_SPEED")
        climb = MotionLimits(
            speed_xy_mps=limits.speed_xy_mps,
            speed_up_mps=tko_speed,
            speed_down_mps=limits.speed_down_mps,
            accel_xy_mps2=limits.accel_xy_mps2,
            accel_z_mps2=limits.accel_z_mps2,
        )
        return v.track_setpoint(climb, min(v.speed_override_mps, tko_speed), dt_s)

    def wants_air(self, v: ModeContext) -> bool:
        return True

    def landed_state(self, landed: bool) -> LandedState:
        return LandedState.TAKEOFF


class Land(TrackTarget):
    """AUTO.LAND: glide to the landing point while descending; the land detector ends the descent."""

    mode = Px4Mode.AUTO_LAND

    def wants_air(self, v: ModeContext) -> bool:
        return False

    def descending_to_land(self) -> bool:
        return True


@dataclass(slots=True)
class RtlPlan:
    phase: RtlPhase
    cruise_down_m: float  # the return leg's down coordinate


class ReturnToLaunch(TrackTarget):
    """AUTO.RTL: climb to RTL_RETURN_ALT, fly home, descend to RTL_DESCEND_ALT, land."""

    mode = Px4Mode.AUTO_RTL

    def __init__(self) -> None:
        self.plan: RtlPlan | None = None

    def start(self, v: ModeContext) -> None:
        """Plan the return from here (the caller has checked the vehicle is flying and not already returning)."""
        cruise = min(v.current_pos()[2], v.home_ned_m[2] - v.p("RTL_RETURN_ALT"))
        self.plan = RtlPlan(phase=RtlPhase.CLIMB, cruise_down_m=cruise)
        v.hold_here()
        pos = v.current_pos()
        v.start_goto(vec3(pos[0], pos[1], cruise))
        v.enter(Px4Mode.AUTO_RTL)

    def advance(self, v: ModeContext, est: Estimate, now_s: float) -> None:
        plan = self.plan
        if plan is None:
            return
        arrived = math.hypot(*(v.trajectory.position - v.target_ned_m)) < ARRIVED_M
        if not arrived:
            return
        home = v.home_ned_m
        if plan.phase is RtlPhase.CLIMB:
            plan.phase = RtlPhase.RETURN
            v.start_goto(vec3(home[0], home[1], plan.cruise_down_m), v.home_yaw_rad)
        elif plan.phase is RtlPhase.RETURN:
            plan.phase = RtlPhase.DESCEND
            descend_down = max(plan.cruise_down_m, home[2] - v.p("RTL_DESCEND_ALT"))
            v.start_goto(vec3(home[0], home[1], descend_down), v.home_yaw_rad)
        elif plan.phase is RtlPhase.DESCEND:
            plan.phase = RtlPhase.LAND

    def descending_to_land(self) -> bool:
        return self.plan is not None and self.plan.phase is RtlPhase.LAND

    def on_touchdown(self, v: ModeContext, est: Estimate, now_s: float) -> None:
        self.plan = None
        super().on_touchdown(v, est, now_s)


class Mission(TrackTarget):
    """AUTO.MISSION: the executor (sitl/autopilot/mission_exec.py) sequences the items; this unit flies what it asks."""

    mode = Px4Mode.AUTO_MISSION

    def __init__(self) -> None:
        self.executor = MissionExecutor()  # the uploaded mission and how far it has been flown
        self.phase = MissionPhase.NAVIGATE
        self.climb_down_m = math.nan  # the automatic takeoff's target while in MissionPhase.CLIMB

    def reset(self) -> None:
        self.phase = MissionPhase.NAVIGATE
        self.climb_down_m = math.nan

    def exit(self, v: ModeContext) -> None:
        self.executor.pause()
        self.reset()

    def load(self, items: tuple[NavItem, ...], *, flying_it: bool) -> None:
        """Replace the mission; ``flying_it`` (the vehicle is in AUTO.MISSION): fly it from its first item. A new
        mission replaces the one whose LAND item was being flown."""
        self.executor.load(items)
        if self.phase is MissionPhase.LAND:
            self.phase = MissionPhase.NAVIGATE
        if flying_it and items:
            self.executor.start()

    def advance(self, v: ModeContext, est: Estimate, now_s: float) -> None:
        mission = self.executor
        if v.landed and mission.state is MissionRun.ACTIVE and self.phase is not MissionPhase.CLIMB:
            first = mission.items[mission.index]
            if first.kind is not NavKind.TAKEOFF:
                # PX4 takes off to MIS_TAKEOFF_ALT before flying a mission started on the ground.
                pos = v.current_pos()
                self.phase = MissionPhase.CLIMB
                self.climb_down_m = float(v.home_ned_m[2] - v.p("MIS_TAKEOFF_ALT"))
                v.trajectory.reset(pos)
                v.start_goto(vec3(pos[0], pos[1], self.climb_down_m), v.target_yaw_rad)
                return
        if self.phase is MissionPhase.CLIMB:
            if v.landed or abs(est.pos_ned_m[2] - self.climb_down_m) > MISSION_CLIMB_DONE_M:
                return
            self.phase = MissionPhase.NAVIGATE
        action = mission.step(now_s, est.pos_ned_m, v.landed, v.p("NAV_ACC_RAD"))
        if action is not None:
            self._apply(v, action)

    def _apply(self, v: ModeContext, action: MissionAction) -> None:
        target = np.array(action.target_ned_m, dtype=np.float64)
        if action.kind is NavKind.SPEED:
            v.set_speed(action.speed_mps if math.isfinite(action.speed_mps) else -1.0)
        elif action.kind is NavKind.RTL:
            v.return_to_launch()
        elif action.kind is NavKind.LAND:
            self.phase = MissionPhase.LAND
            v.start_goto(target, action.yaw_rad)
        else:
            if v.landed:
                v.trajectory.reset(v.current_pos())
            v.start_goto(target, action.yaw_rad)

    def wants_air(self, v: ModeContext) -> bool:
        return not v.landed or (self.executor.state is MissionRun.ACTIVE and self.phase is not MissionPhase.LAND)

    def descending_to_land(self) -> bool:
        return self.phase is MissionPhase.LAND

    def on_touchdown(self, v: ModeContext, est: Estimate, now_s: float) -> None:
        if self.phase is MissionPhase.LAND:
            self.executor.step(now_s, est.pos_ned_m, True, v.p("NAV_ACC_RAD"))  # the LAND item is done
        else:
            super().on_touchdown(v, est, now_s)


class Offboard(TrackTarget):
    """OFFBOARD: fly the client's latest setpoint (trajectory or attitude). The stream's liveness is watched by the
    offboard-loss row of the failsafe table, not here."""

    mode = Px4Mode.OFFBOARD

    def __init__(self) -> None:
        self.setpoint_in: TrajectorySetpoint | AttitudeSetpoint | None = None
        self.received_s = -math.inf

    def receive(self, setpoint: TrajectorySetpoint | AttitudeSetpoint, now_s: float) -> None:
        self.setpoint_in = setpoint
        self.received_s = now_s

    def alive(self, now_s: float, timeout_s: float) -> bool:
        return self.setpoint_in is not None and now_s - self.received_s <= timeout_s

    def setpoint(self, v: ModeContext, est: Estimate, dt_s: float) -> TrajectorySetpoint | AttitudeSetpoint:
        sp = self.setpoint_in
        if isinstance(sp, TrajectorySetpoint):
            # The auto-mode reference follows the vehicle, so a switch back to Hold starts where it is.
            v.trajectory.reset(est.pos_ned_m)
            return sp
        if isinstance(sp, AttitudeSetpoint):
            return sp
        return super().setpoint(v, est, dt_s)

    def wants_air(self, v: ModeContext) -> bool:
        return True

    def needs_position(self) -> bool:
        return not isinstance(self.setpoint_in, AttitudeSetpoint)


# Descend without a position: the sink-rate loop on the altitude estimate. Thrust is a fraction of hover thrust:
# proportional on the sink-rate error (fraction per m/s) plus an integrator that finds the thrust that sinks at the
# landing speed and, on the ground where sinking stops, winds the thrust down until the land detector sees it.
DESCEND_KP = 0.4
DESCEND_KI = 0.5
DESCEND_RATIO_MIN = 0.3
DESCEND_RATIO_MAX = 1.2
# Without an altitude estimate either there is nothing to close a loop on: PX4 descends at a fixed thrust below hover.
DESCEND_BLIND_RATIO = 0.9


class Descend(TrackTarget):
    """PX4's Descend: the fallback of the position-loss failsafe. Level attitude, heading kept, sinking at
    MPC_LAND_SPEED on the altitude estimate (or at a fixed thrust without one). Shown as AUTO.LAND, as PX4 shows it.
    """

    mode = Px4Mode.AUTO_LAND

    def __init__(self, hover_thrust_n: float) -> None:
        self.hover_thrust_n = hover_thrust_n
        self.ratio = 1.0
        self.yaw_rad = 0.0

    def start(self, est: Estimate | None) -> None:
        self.ratio = 1.0
        self.yaw_rad = est.yaw_rad if est is not None else 0.0

    def setpoint(self, v: ModeContext, est: Estimate, dt_s: float) -> TrajectorySetpoint | AttitudeSetpoint:
        if est.altitude_valid:
            error = v.p("MPC_LAND_SPEED") - float(est.vel_ned_mps[2])  # > 0: sinking too slowly
            self.ratio = min(DESCEND_RATIO_MAX, max(DESCEND_RATIO_MIN, self.ratio - DESCEND_KI * error * dt_s))
            ratio = min(DESCEND_RATIO_MAX, max(DESCEND_RATIO_MIN, self.ratio - DESCEND_KP * error))
        else:
            ratio = DESCEND_BLIND_RATIO
        half = 0.5 * self.yaw_rad
        return AttitudeSetpoint(att_q=(math.cos(half), 0.0, 0.0, math.sin(half)), thrust_n=ratio * self.hover_thrust_n)

    def wants_air(self, v: ModeContext) -> bool:
        return False

    def descending_to_land(self) -> bool:
        return True

    def needs_position(self) -> bool:
        return False


@dataclass(frozen=True, slots=True)
class Units:
    """The vehicle's mode units, one instance each for the vehicle's lifetime (their state is per flight)."""

    hold: Hold
    takeoff: Takeoff
    land: Land
    rtl: ReturnToLaunch
    mission: Mission
    offboard: Offboard
    descend: Descend  # entered only by the failsafe; AUTO.LAND on the wire, so not in ``by_mode``

    def by_mode(self) -> dict[Px4Mode, ModeUnit]:
        units: tuple[ModeUnit, ...] = (self.hold, self.takeoff, self.land, self.rtl, self.mission, self.offboard)
        return {u.mode: u for u in units}


def build_units(hover_thrust_n: float) -> Units:
    """Every mode unit; ``hover_thrust_n``: the collective that holds the vehicle's weight (Descend's)."""
    return Units(
        hold=Hold(),
        takeoff=Takeoff(),
        land=Land(),
        rtl=ReturnToLaunch(),
        mission=Mission(),
        offboard=Offboard(),
        descend=Descend(hover_thrust_n),
    )
