"""One unit per flight mode, all behind one interface (``ModeUnit``).

A unit owns its mode's state (the RTL plan, the mission's phase, the offboard stream) and answers, each commander
tick: what changes now (``advance``: transitions such as "takeoff complete"), what to fly (``setpoint``), does the
vehicle want to be in the air (``wants_air``: on the ground and not wanting air the motors idle), is it landing
(``descending_to_land``, ``landed_state``), can it fly without a position (``needs_position``, for the GPS-loss
failsafe) and what happens at touchdown (``on_touchdown``). Adding a mode means one class here and its field in
``Units``.

A unit is given what it reads and gives back what it decides (sitl/autopilot/mode_io.py): ``ModeInputs`` in (the
estimate, the time, home, the shared smooth reference and its target, the parameters), a setpoint or a ``Track`` of
the reference, and a ``ModeDecision`` (a text, a new target, the mode it asks for) out. It holds nothing of the
commander and calls nothing of it: the commander carries the decisions out, and enters the modes asked for as it
would for the operator. It never reads a clock or a socket either.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar, Protocol

import numpy as np

from sitl.autopilot.guidance import MotionLimits
from sitl.autopilot.mission_exec import MissionAction, MissionExecutor, MissionRun
from sitl.autopilot.mission_plan import NavItem, NavKind
from sitl.autopilot.mode_io import NO_CHANGE, Goto, ModeDecision, ModeInputs, Track
from sitl.autopilot.orbit import (
    OrbitPlan,
    bearing_to_centre_rad,
    circle_point,
    entry_phase_rad,
    heading_on_circle,
    on_circle,
)
from sitl.autopilot.px4_modes import Px4Mode
from sitl.autopilot.vehicle_api import LandedState
from sitl.control.cascade import AttitudeSetpoint, TrajectorySetpoint
from sitl.estimation.estimator import Estimate
from sitl.mathutil import Vec3, vec3

from .phases import MissionPhase, OrbitPhase, RtlPhase

# The reference has arrived at its target when it is this close (the trajectory converges exactly; this only absorbs
# float rounding).
ARRIVED_M = 1e-3
# Takeoff is complete once the estimate is within this of the takeoff altitude (and the reference has arrived).
TAKEOFF_DONE_M = 0.15
# A mission's automatic takeoff hands over to the first item within this of MIS_TAKEOFF_ALT.
MISSION_CLIMB_DONE_M = 0.3

# What a unit flies: a setpoint of its own, or the shared reference (``Track``).
UnitSetpoint = Track | TrajectorySetpoint | AttitudeSetpoint
# Every touchdown is a landing, whatever mode brought the vehicle down (PX4).
_LAND = ModeDecision(request=Px4Mode.AUTO_LAND)


def _arrived(inp: ModeInputs) -> bool:
    """Has the shared reference reached its target?"""
    return math.hypot(*np.subtract(inp.reference_ned_m, inp.target_ned_m)) < ARRIVED_M


class ModeUnit(Protocol):
    """The one interface every flight mode implements."""

    mode: ClassVar[Px4Mode]  # what HEARTBEAT shows while the unit flies

    def exit(self) -> None:
        """Leaving the mode: drop what must not survive it."""

    def advance(self, inp: ModeInputs) -> ModeDecision:
        """The mode's own transitions, before the setpoint of this tick is computed."""

    def setpoint(self, inp: ModeInputs, dt_s: float) -> UnitSetpoint: ...

    def wants_air(self, landed: bool) -> bool: ...

    def descending_to_land(self) -> bool: ...

    def needs_position(self) -> bool:
        """Does flying this mode need a horizontal position (the GPS-loss failsafe watches this)?"""
        ...

    def on_touchdown(self, inp: ModeInputs) -> ModeDecision: ...

    def landed_state(self, landed: bool) -> LandedState: ...


class TrackTarget:
    """Fly the shared smooth trajectory to the current target; the behaviour every auto mode starts from."""

    mode: ClassVar[Px4Mode] = Px4Mode.AUTO_LOITER

    def exit(self) -> None:
        return None

    def advance(self, inp: ModeInputs) -> ModeDecision:
        return NO_CHANGE

    def setpoint(self, inp: ModeInputs, dt_s: float) -> UnitSetpoint:
        return Track(
            limits=inp.params.limits, max_speed_mps=inp.speed_override_mps, descend_to_land=self.descending_to_land()
        )

    def wants_air(self, landed: bool) -> bool:
        return not landed

    def descending_to_land(self) -> bool:
        return False

    def needs_position(self) -> bool:
        return True

    def on_touchdown(self, inp: ModeInputs) -> ModeDecision:
        return _LAND

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

    def advance(self, inp: ModeInputs) -> ModeDecision:
        if abs(inp.est.pos_ned_m[2] - inp.target_ned_m[2]) < TAKEOFF_DONE_M and _arrived(inp):
            return ModeDecision(text="Takeoff complete", request=Px4Mode.AUTO_LOITER)
        return NO_CHANGE

    def setpoint(self, inp: ModeInputs, dt_s: float) -> UnitSetpoint:
        limits = inp.params.limits
        tko_speed = inp.params.takeoff_speed_mps
        climb = MotionLimits(
            speed_xy_mps=limits.speed_xy_mps,
            speed_up_mps=tko_speed,
            speed_down_mps=limits.speed_down_mps,
            accel_xy_mps2=limits.accel_xy_mps2,
            accel_z_mps2=limits.accel_z_mps2,
        )
        return Track(limits=climb, max_speed_mps=min(inp.speed_override_mps, tko_speed))

    def wants_air(self, landed: bool) -> bool:
        return True

    def landed_state(self, landed: bool) -> LandedState:
        return LandedState.TAKEOFF


class Land(TrackTarget):
    """AUTO.LAND: glide to the landing point while descending; the land detector ends the descent."""

    mode = Px4Mode.AUTO_LAND

    def wants_air(self, landed: bool) -> bool:
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

    def start(self, pos_ned_m: Vec3, home_ned_m: Vec3, return_alt_m: float) -> Goto:
        """Plan the return from ``pos_ned_m`` (the caller has checked the vehicle is flying and not already
        returning, and enters the mode): the climb, straight up to the return altitude, is the first leg."""
        cruise = min(pos_ned_m[2], home_ned_m[2] - return_alt_m)
        self.plan = RtlPlan(phase=RtlPhase.CLIMB, cruise_down_m=cruise)
        return Goto(target_ned_m=vec3(pos_ned_m[0], pos_ned_m[1], cruise))

    def advance(self, inp: ModeInputs) -> ModeDecision:
        plan = self.plan
        if plan is None or not _arrived(inp):
            return NO_CHANGE
        home = inp.home_ned_m
        if plan.phase is RtlPhase.CLIMB:
            plan.phase = RtlPhase.RETURN
            return_leg = vec3(home[0], home[1], plan.cruise_down_m)
            return ModeDecision(goto=Goto(target_ned_m=return_leg, yaw_rad=inp.home_yaw_rad))
        if plan.phase is RtlPhase.RETURN:
            plan.phase = RtlPhase.DESCEND
            descend_down = max(plan.cruise_down_m, home[2] - inp.params.rtl_descend_alt_m)
            descent = vec3(home[0], home[1], descend_down)
            return ModeDecision(goto=Goto(target_ned_m=descent, yaw_rad=inp.home_yaw_rad))
        if plan.phase is RtlPhase.DESCEND:
            plan.phase = RtlPhase.LAND
        return NO_CHANGE

    def descending_to_land(self) -> bool:
        return self.plan is not None and self.plan.phase is RtlPhase.LAND

    def on_touchdown(self, inp: ModeInputs) -> ModeDecision:
        self.plan = None
        return super().on_touchdown(inp)


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

    def exit(self) -> None:
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

    def advance(self, inp: ModeInputs) -> ModeDecision:
        mission = self.executor
        est = inp.est
        if inp.landed and mission.state is MissionRun.ACTIVE and self.phase is not MissionPhase.CLIMB:
            first = mission.items[mission.index]
            if first.kind is not NavKind.TAKEOFF:
                # PX4 takes off to MIS_TAKEOFF_ALT before flying a mission started on the ground.
                pos = est.pos_ned_m
                self.phase = MissionPhase.CLIMB
                self.climb_down_m = float(inp.home_ned_m[2] - inp.params.mission_takeoff_alt_m)
                climb = vec3(pos[0], pos[1], self.climb_down_m)
                return ModeDecision(goto=Goto(target_ned_m=climb, yaw_rad=inp.target_yaw_rad, from_rest=True))
        if self.phase is MissionPhase.CLIMB:
            if inp.landed or abs(est.pos_ned_m[2] - self.climb_down_m) > MISSION_CLIMB_DONE_M:
                return NO_CHANGE
            self.phase = MissionPhase.NAVIGATE
        action = mission.step(inp.now_s, est.pos_ned_m, inp.landed, inp.params.acceptance_radius_m)
        return NO_CHANGE if action is None else self._decide(inp, action)

    def _decide(self, inp: ModeInputs, action: MissionAction) -> ModeDecision:
        if action.kind is NavKind.SPEED:
            return ModeDecision(speed_limit_mps=action.speed_mps if math.isfinite(action.speed_mps) else -1.0)
        if action.kind is NavKind.RTL:
            return ModeDecision(request=Px4Mode.AUTO_RTL)
        target = np.array(action.target_ned_m, dtype=np.float64)
        if action.kind is NavKind.LAND:
            self.phase = MissionPhase.LAND
            return ModeDecision(goto=Goto(target_ned_m=target, yaw_rad=action.yaw_rad))
        return ModeDecision(goto=Goto(target_ned_m=target, yaw_rad=action.yaw_rad, from_rest=inp.landed))

    def wants_air(self, landed: bool) -> bool:
        return not landed or (self.executor.state is MissionRun.ACTIVE and self.phase is not MissionPhase.LAND)

    def descending_to_land(self) -> bool:
        return self.phase is MissionPhase.LAND

    def on_touchdown(self, inp: ModeInputs) -> ModeDecision:
        if self.phase is MissionPhase.LAND:
            # The LAND item is done.
            self.executor.step(inp.now_s, inp.est.pos_ned_m, True, inp.params.acceptance_radius_m)
            return NO_CHANGE
        return super().on_touchdown(inp)


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

    def setpoint(self, inp: ModeInputs, dt_s: float) -> UnitSetpoint:
        sp = self.setpoint_in
        if sp is None:
            return super().setpoint(inp, dt_s)
        return sp

    def wants_air(self, landed: bool) -> bool:
        return True

    def needs_position(self) -> bool:
        return not isinstance(self.setpoint_in, AttitudeSetpoint)


class Orbit(TrackTarget):
    """PX4's Orbit (nav state ORBIT, POSCTL sub mode ORBIT on the wire): circle a centre at a radius, speed and
    altitude (sitl/autopilot/orbit.py), entered from where the vehicle is without a jump.

    As PX4's FlightTaskOrbit it first approaches the circle: the shared reference flies from the vehicle's own motion
    to the circle's nearest point, facing the centre. There it circles with a setpoint of its own: the position on
    the circle at a phase advanced by speed / radius each tick, the velocity and the centripetal acceleration as
    feed-forward, the heading of the yaw behaviour. The tangential speed starts from rest and changes at most at
    MPC_ACC_HOR, so entering the circle or a new speed is smooth too. Any other mode request ends it; the failsafes
    apply as in any auto mode.
    """

    mode = Px4Mode.ORBIT

    def __init__(self) -> None:
        self.plan: OrbitPlan | None = None
        self.phase = OrbitPhase.APPROACH
        self.phase_rad = 0.0  # on the circle: 0 north of the centre, growing clockwise seen from above
        self.speed_mps = 0.0  # the signed tangential speed flown now (> 0 clockwise)

    def start(self, plan: OrbitPlan, pos_ned_m: tuple[float, float, float], *, orbiting: bool) -> Goto | None:
        """Fly ``plan`` from ``pos_ned_m``: the approach to the circle (the caller sends the shared reference there
        and enters the mode), or None when an orbit already flown goes on from where it is, on the new circle."""
        self.plan = plan
        if orbiting and self.phase is OrbitPhase.CIRCLE and on_circle(plan, pos_ned_m):
            self.phase_rad = entry_phase_rad(plan, pos_ned_m)
            return None
        self.phase = OrbitPhase.APPROACH
        entry = circle_point(plan, entry_phase_rad(plan, pos_ned_m))
        return Goto(target_ned_m=vec3(*entry), yaw_rad=bearing_to_centre_rad(plan, entry))

    def exit(self) -> None:
        self.plan = None
        self.phase = OrbitPhase.APPROACH
        self.speed_mps = 0.0

    def advance(self, inp: ModeInputs) -> ModeDecision:
        plan = self.plan
        if plan is not None and self.phase is OrbitPhase.APPROACH and _arrived(inp):
            # The reference stands at the entry point: the circle starts there, from rest.
            target = inp.target_ned_m
            self.phase = OrbitPhase.CIRCLE
            self.phase_rad = entry_phase_rad(plan, (float(target[0]), float(target[1]), float(target[2])))
            self.speed_mps = 0.0
        return NO_CHANGE

    def setpoint(self, inp: ModeInputs, dt_s: float) -> UnitSetpoint:
        plan = self.plan
        if plan is None or self.phase is OrbitPhase.APPROACH:
            return super().setpoint(inp, dt_s)
        before = self.speed_mps
        wanted = plan.signed_speed_mps
        step = inp.params.limits.accel_xy_mps2 * dt_s
        speed = min(wanted, before + step) if wanted > before else max(wanted, before - step)
        self.speed_mps = speed
        tangential_acc = (speed - before) / dt_s if dt_s > 0.0 else 0.0
        radius = plan.radius_m
        self.phase_rad = (self.phase_rad + speed / radius * dt_s) % math.tau
        cos_p, sin_p = math.cos(self.phase_rad), math.sin(self.phase_rad)
        centripetal = speed * speed / radius
        pos = inp.est.pos_ned_m
        yaw, yaw_rate = heading_on_circle(plan, (float(pos[0]), float(pos[1]), float(pos[2])), speed)
        return TrajectorySetpoint(
            pos_ned_m=circle_point(plan, self.phase_rad),
            vel_ned_mps=(-speed * sin_p, speed * cos_p, 0.0),
            acc_ned_mps2=(
                -centripetal * cos_p - tangential_acc * sin_p,
                -centripetal * sin_p + tangential_acc * cos_p,
                0.0,
            ),
            yaw_rad=yaw,
            yawspeed_radps=yaw_rate,
        )


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

    def setpoint(self, inp: ModeInputs, dt_s: float) -> UnitSetpoint:
        est = inp.est
        if est.altitude_valid:
            error = inp.params.land_speed_mps - float(est.vel_ned_mps[2])  # > 0: sinking too slowly
            self.ratio = min(DESCEND_RATIO_MAX, max(DESCEND_RATIO_MIN, self.ratio - DESCEND_KI * error * dt_s))
            ratio = min(DESCEND_RATIO_MAX, max(DESCEND_RATIO_MIN, self.ratio - DESCEND_KP * error))
        else:
            ratio = DESCEND_BLIND_RATIO
        half = 0.5 * self.yaw_rad
        return AttitudeSetpoint(att_q=(math.cos(half), 0.0, 0.0, math.sin(half)), thrust_n=ratio * self.hover_thrust_n)

    def wants_air(self, landed: bool) -> bool:
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
    orbit: Orbit
    descend: Descend  # entered only by the failsafe; AUTO.LAND on the wire, so not in ``by_mode``

    def by_mode(self) -> dict[Px4Mode, ModeUnit]:
        units: tuple[ModeUnit, ...] = (
            self.hold,
            self.takeoff,
            self.land,
            self.rtl,
            self.mission,
            self.offboard,
            self.orbit,
        )
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
        orbit=Orbit(),
        descend=Descend(hover_thrust_n),
    )
