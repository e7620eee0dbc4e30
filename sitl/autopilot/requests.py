"""The requests the MAVLink services (through sitl/drone/sim_vehicle_api.py), onboard behaviours and tests make of the
autopilot: arming and the pre-arm checks, the mode requests (takeoff, land, hold, RTL, reposition, orbit, mission,
offboard), home, speed, the mission and the fence. Each is checked here and answered with a ``CommandOutcome``; what
it changes in flight goes through the mode authority (mode switches) and the target tracker (targets), and the next
physics step becomes a tick (``CommanderState.tick_due``) wherever the last tick's decision no longer holds.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from sitl.autopilot.commander_state import CommanderState
from sitl.autopilot.geofence import Geofence
from sitl.autopilot.guidance import floats3
from sitl.autopilot.mission_exec import MissionExecutor, MissionRun
from sitl.autopilot.mission_plan import NavItem
from sitl.autopilot.mode_authority import ACCEPTED, ModeAuthority
from sitl.autopilot.orbit import OrbitCommand, plan_orbit
from sitl.autopilot.px4_modes import Px4Mode
from sitl.autopilot.tracking import TargetTracker
from sitl.autopilot.vehicle_api import CommandOutcome, CommandResult
from sitl.control.cascade import AttitudeSetpoint, Cascade, TrajectorySetpoint
from sitl.mathutil import Vec3, vec3
from sitl.params import ParamStore

# The modes arming is allowed in (PX4's: the auto modes that can start on the ground, offboard, position).
ARMABLE_MODES = frozenset(
    {Px4Mode.AUTO_LOITER, Px4Mode.POSCTL, Px4Mode.AUTO_MISSION, Px4Mode.OFFBOARD, Px4Mode.AUTO_TAKEOFF}
)


class RequestHandler:
    def __init__(
        self,
        state: CommanderState,
        tracker: TargetTracker,
        authority: ModeAuthority,
        params: ParamStore,
        cascade: Cascade,
        battery_remaining: Callable[[], float],
    ) -> None:
        self._state = state
        self._tracker = tracker
        self._authority = authority
        self._params = params
        self._cascade = cascade
        self._battery_remaining = battery_remaining

    # ---- arming ----------------------------------------------------------------------------------------------------
    def preflight_problem(self) -> str | None:
        """The first failing pre-arm check, or None when the vehicle may arm."""
        state, p = self._state, self._params
        est = state.est
        if est is None or not est.attitude_valid:
            return "Preflight Fail: attitude estimate not converged"
        if not est.altitude_valid:
            return "Preflight Fail: no altitude estimate"
        if not est.position_valid and p["COM_ARM_WO_GPS"] == 0:
            return "Preflight Fail: no valid global position yet (GPS)"
        if self._battery_remaining() < p["BAT_CRIT_THR"]:
            return "Preflight Fail: battery too low"
        # As PX4: with a datalink-loss action set, a ground station must be heard before arming ...
        heard_s = state.gcs_heartbeat_s
        if p["NAV_DLL_ACT"] != 0 and (math.isnan(heard_s) or state.now_s - heard_s > p["COM_DL_LOSS_T"]):
            return "Preflight Fail: No connection to the ground control station"
        # ... and with a geofence that acts, the vehicle must start inside it (zones only: home is set on arming).
        if p["GF_ACTION"] > 1 and est.position_valid and state.fence.zones:
            pos = floats3(est.pos_ned_m)
            if state.fence.breach(pos, pos) is not None:
                return "Preflight Fail: Vehicle outside geofence"
        return None

    def arm(self, force: bool = False) -> CommandOutcome:
        state = self._state
        status = state.status
        if status.armed:
            return ACCEPTED
        if state.crashed:
            return CommandOutcome(CommandResult.DENIED, "Arming denied: vehicle crashed")
        if not state.landed:
            return CommandOutcome(CommandResult.DENIED, "Arming denied: vehicle in the air")
        problem = None if force else self.preflight_problem()
        if problem is not None:
            state.event(4, problem)
            return CommandOutcome(CommandResult.DENIED, problem)
        if status.mode not in ARMABLE_MODES:
            return CommandOutcome(CommandResult.DENIED, f"Arming denied: not possible in {status.mode.px4_name}")
        status.armed = True
        state.tick_due = True
        state.armed_since_s = state.now_s
        self._authority.failsafes.on_arming()
        state.landed_since_s = state.now_s
        self._cascade.reset()
        pos = state.current_pos()
        state.home_ned_m = pos.copy()  # PX4 sets home on arming
        state.home_yaw_rad = state.est.yaw_rad if state.est is not None else 0.0
        self._tracker.trajectory.reset(pos)
        self._tracker.goto(pos, state.home_yaw_rad)
        state.event(6, "Armed")
        return ACCEPTED

    def disarm(self, force: bool = False) -> CommandOutcome:
        if not self._state.status.armed:
            return ACCEPTED
        if not force and not self._state.landed:
            return CommandOutcome(CommandResult.DENIED, "Disarming denied: vehicle in the air")
        self._authority.disarm("Disarmed" if not force else "Disarmed (forced)")
        return ACCEPTED

    def kill(self) -> CommandOutcome:
        if self._state.status.armed:
            self._authority.disarm("Motors killed")
        return ACCEPTED

    def crash(self, text: str) -> None:
        """A collision or a hard impact: the motors stop wherever the vehicle is, and it stays grounded (arming is
        refused)."""
        self._authority.stop_for_good(text, "Motors stopped: crashed")

    def terminate(self, text: str) -> None:
        """Flight termination (PX4): the motors stop and stay stopped; like a crash, arming is refused after it."""
        self._authority.terminate(text)

    # ---- mode requests ---------------------------------------------------------------------------------------------
    def takeoff(self, altitude_above_home_m: float = math.nan) -> CommandOutcome:
        """Climb above home to the altitude (MIS_TAKEOFF_ALT when NaN), then hold."""
        state, tracker = self._state, self._tracker
        alt = self._params["MIS_TAKEOFF_ALT"] if not math.isfinite(altitude_above_home_m) else altitude_above_home_m
        if alt <= 0.0:
            return CommandOutcome(CommandResult.DENIED, "Takeoff denied: altitude must be above home")
        if not state.status.armed:
            return CommandOutcome(CommandResult.DENIED, "Takeoff denied: disarmed")
        if not state.landed and state.status.mode is Px4Mode.AUTO_TAKEOFF:
            return ACCEPTED
        pos = state.current_pos()
        if state.landed:
            tracker.trajectory.reset(pos)
        tracker.goto(vec3(pos[0], pos[1], state.home_ned_m[2] - alt), tracker.target_yaw_rad)
        self._authority.enter(Px4Mode.AUTO_TAKEOFF)
        return ACCEPTED

    def land(self, at_ned_m: tuple[float, float, float] | None = None) -> CommandOutcome:
        """Land here, or fly to ``at_ned_m`` (north/east; down is ignored) while descending and land there."""
        if not self._state.status.armed:
            return CommandOutcome(CommandResult.DENIED, "Land denied: disarmed")
        if self._state.status.mode is not Px4Mode.AUTO_LAND or at_ned_m is not None:
            tracker = self._tracker
            tracker.hold()
            if at_ned_m is not None:
                tracker.target_ned_m[0], tracker.target_ned_m[1] = at_ned_m[0], at_ned_m[1]
            self._authority.enter(Px4Mode.AUTO_LAND)
        return ACCEPTED

    def hold(self) -> CommandOutcome:
        authority = self._authority
        if self._state.status.mode is not Px4Mode.AUTO_LOITER:
            self._tracker.hold()
            authority.enter(Px4Mode.AUTO_LOITER)
        authority.operator_takes_over()
        return ACCEPTED

    def return_to_launch(self) -> CommandOutcome:
        return self._authority.return_to_launch()

    def goto(self, target_ned_m: Vec3, yaw_rad: float = math.nan) -> CommandOutcome:
        """Reposition: fly to a local point on a smooth trajectory and hold there (PX4 DO_REPOSITION)."""
        if not self._state.status.armed or self._state.landed:
            return CommandOutcome(CommandResult.DENIED, "Reposition denied: not flying")
        if not np.all(np.isfinite(target_ned_m)):
            return CommandOutcome(CommandResult.DENIED, "Reposition denied: target not finite")
        self._authority.enter(Px4Mode.AUTO_LOITER)
        self._authority.operator_takes_over()
        self._tracker.goto(np.asarray(target_ned_m, dtype=np.float64), yaw_rad)
        return ACCEPTED

    def orbit(self, command: OrbitCommand) -> CommandOutcome:
        """MAV_CMD_DO_ORBIT: enter PX4's Orbit, or change the orbit flown (sitl/autopilot/orbit.py reads the command).

        Refused with TEMPORARILY_REJECTED, PX4's commander's answer to a mode it will not enter ("Orbit command
        rejected"), when the vehicle is not flying or has no position; a radius outside 1 m .. MC_ORBIT_RAD_MAX is
        DENIED with PX4's text, "Orbit radius limit exceeded" (PX4 accepts the mode first, then fails its task)."""
        state = self._state
        est = state.est
        if not state.status.armed or state.landed:
            return CommandOutcome(CommandResult.TEMPORARILY_REJECTED, "Orbit command rejected: not flying")
        if est is None or not est.position_valid:
            return CommandOutcome(CommandResult.TEMPORARILY_REJECTED, "Orbit command rejected: no position")
        unit = self._authority.units.orbit
        orbiting = state.status.mode is Px4Mode.ORBIT
        pos = floats3(est.pos_ned_m)
        plan = plan_orbit(
            command,
            unit.plan if orbiting else None,
            pos,
            est.yaw_rad,
            radius_max_m=self._params["MC_ORBIT_RAD_MAX"],
            speed_max_mps=self._params["MPC_XY_VEL_MAX"],
        )
        if plan is None:
            return CommandOutcome(CommandResult.DENIED, "Orbit radius limit exceeded")
        approach = unit.start(plan, pos, orbiting=orbiting)
        if approach is not None:
            # From the vehicle's own motion, as a hold starts, so the approach continues what the vehicle was doing.
            self._tracker.hold()
            self._tracker.goto(approach.target_ned_m, approach.yaw_rad)
        self._authority.enter(Px4Mode.ORBIT)
        self._authority.operator_takes_over()
        state.tick_due = True
        return ACCEPTED

    def set_speed(self, ground_speed_mps: float) -> CommandOutcome:
        """DO_CHANGE_SPEED: limit auto-mode speed; a negative value restores the default."""
        if not math.isfinite(ground_speed_mps):
            return CommandOutcome(CommandResult.DENIED, "Speed change denied: not a number")
        self._tracker.limit_speed(ground_speed_mps)
        return ACCEPTED

    def set_home(self, home_ned_m: Vec3 | None) -> CommandOutcome:
        """DO_SET_HOME: the current position (None) or a given local point becomes home."""
        state = self._state
        if home_ned_m is None:
            if state.est is None or not state.est.position_valid:
                return CommandOutcome(CommandResult.DENIED, "Set home denied: no position")
            home_ned_m = state.est.pos_ned_m
        state.home_ned_m = np.array(home_ned_m, dtype=np.float64)
        state.tick_due = True
        state.event(6, "Home position set")
        return ACCEPTED

    # ---- mission ---------------------------------------------------------------------------------------------------
    @property
    def mission(self) -> MissionExecutor:
        """The uploaded mission and its progress, as the Mission unit keeps it."""
        return self._authority.units.mission.executor

    def set_mission(self, items: tuple[NavItem, ...]) -> CommandOutcome:
        """Replace the mission; flying it continues from the first item if the vehicle is in AUTO.MISSION."""
        self._authority.units.mission.load(items, flying_it=self._state.status.mode is Px4Mode.AUTO_MISSION)
        self._state.tick_due = True
        return ACCEPTED

    def retarget_mission(self, items: tuple[NavItem, ...]) -> None:
        """The same mission with targets recomputed (home moved): progress is kept."""
        self.mission.retarget(items)

    def set_mission_current(self, seq: int) -> CommandOutcome:
        if not self.mission.set_current(seq):
            return CommandOutcome(CommandResult.DENIED, f"Mission item {seq} does not exist")
        if self._state.status.mode is Px4Mode.AUTO_MISSION:
            self.mission.start()
        return ACCEPTED

    def start_mission(self) -> CommandOutcome:
        """Enter AUTO.MISSION (allowed on the ground: arming then takes off, as in PX4)."""
        mission = self.mission
        if not mission.items:
            return CommandOutcome(CommandResult.DENIED, "Mission rejected: no mission uploaded")
        if self._state.status.mode is Px4Mode.AUTO_MISSION and mission.state is MissionRun.ACTIVE:
            return ACCEPTED
        self._authority.enter(Px4Mode.AUTO_MISSION)
        mission.start()
        self._authority.operator_takes_over()
        return ACCEPTED

    # ---- offboard, the link, the fence -----------------------------------------------------------------------------
    def set_offboard_setpoint(self, setpoint: TrajectorySetpoint | AttitudeSetpoint, now_s: float) -> None:
        self._authority.units.offboard.receive(setpoint, now_s)
        self._state.tick_due = True  # a new setpoint is acted on at once (the position loop runs for it next step)

    def start_offboard(self, now_s: float) -> CommandOutcome:
        if not self._authority.offboard_alive(now_s):
            return CommandOutcome(CommandResult.DENIED, "Offboard denied: no setpoint stream")
        self._authority.operator_takes_over()
        self._authority.enter(Px4Mode.OFFBOARD)
        return ACCEPTED

    def note_gcs_heartbeat(self, now_s: float) -> None:
        """A ground station's HEARTBEAT (type MAV_TYPE_GCS) arrived: the datalink-loss failsafe watches these, and
        is armed only once the first one has been heard, as PX4's (with NAV_DLL_ACT set, arming needs one too)."""
        self._state.gcs_heartbeat_s = now_s

    def set_fence(self, fence: Geofence) -> None:
        """The geofence in force from now on (local frame); GF_ACTION says what a breach does."""
        self._state.fence = fence
        self._state.tick_due = True
