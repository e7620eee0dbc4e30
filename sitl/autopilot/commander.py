"""The autopilot: arming, flight modes, failsafes. Pure: estimate and time in, motor commands out.

This is the drone's "commander + navigator" in PX4 terms. It arms and disarms, keeps home, and runs the active
flight mode's unit (sitl/autopilot/modes.py: one small unit per mode behind one interface) and the failsafe table
(sitl/autopilot/failsafe.py: pure decisions). It turns the mode's setpoint into motor commands through the controller
cascade (sitl/control). It never reads ground truth, a clock or a socket: the simulation loop passes the estimate and
the simulation time, and the MAVLink layer calls the request methods (arm, takeoff, set_mode, ...), each answering
with an ``Outcome``.

``Commander`` is the face the rest of the drone uses; the work is done by parts that never hold it:

- ``RequestHandler`` (requests.py): the requests, checked and answered;
- ``FlightTick`` (flight_tick.py): the physics steps and the commander's ticks, the land detector, auto-disarm;
- ``ModeAuthority`` (mode_authority.py): every mode transition, from a request, a unit's decision or a failsafe;
- ``TargetTracker`` (tracking.py): the smooth reference the auto modes share and the target it heads for;
- ``CommanderState`` (commander_state.py): the facts they share (status, events, estimate, home, fence).

Requests and the tick are apart because they run at different moments for different callers (a request between
steps, from the MAVLink side; the tick at MPC_LOOP_HZ from the closed loop), and the mode units are given their
inputs and return their decisions (mode_io.py) so the steady-state tick can later be compiled whole.

Behaviour follows PX4 where a client could notice: takeoff climbs to MIS_TAKEOFF_ALT and switches to Hold; land
descends and auto-disarms COM_DISARM_LAND seconds after touchdown; RTL climbs to RTL_RETURN_ALT, returns and lands;
offboard needs a live setpoint stream; the failsafes (link losses, battery levels, position loss, geofence) act as
PX4's parameters say (docs/failsafes.md).
"""

from __future__ import annotations

import math
from collections.abc import Callable

from sitl.autopilot.commander_state import CommanderState, VehicleEvent
from sitl.autopilot.flight_tick import FlightTick
from sitl.autopilot.geofence import Geofence
from sitl.autopilot.mission_exec import MissionExecutor
from sitl.autopilot.mission_plan import NavItem
from sitl.autopilot.mode_authority import ModeAuthority
from sitl.autopilot.modes import build_units
from sitl.autopilot.orbit import OrbitCommand, OrbitPlan
from sitl.autopilot.px4_modes import Px4Mode
from sitl.autopilot.requests import RequestHandler
from sitl.autopilot.tracking import TargetTracker
from sitl.autopilot.vehicle_api import CommandOutcome
from sitl.avoidance.collision_prevention import CollisionPrevention
from sitl.control.cascade import AttitudeSetpoint, Cascade, TrajectorySetpoint
from sitl.dynamics.airframe import Airframe
from sitl.estimation.estimator import Estimate
from sitl.mathutil import GRAVITY_MPS2, Vec3
from sitl.params import ParamStore


class Commander:
    """The autopilot of one drone: its parts wired together (module docstring), and their one face."""

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
        self._state = state = CommanderState()
        self.status = state.status  # what telemetry reads
        self.events: list[VehicleEvent] = state.events  # taken (and cleared) by the MAVLink side as STATUSTEXT
        hover_thrust_n = airframe.mass_kg * GRAVITY_MPS2
        tracker = TargetTracker(state, params)
        authority = ModeAuthority(state, tracker, build_units(hover_thrust_n), params, cascade)
        self.collision_prevention = CollisionPrevention(
            params, cascade.position, airframe.collision_radius_m, state.event
        )
        self._orbit = authority.units.orbit
        self._requests = RequestHandler(state, tracker, authority, params, cascade, battery_remaining)
        tick = FlightTick(
            state,
            tracker,
            authority,
            params,
            cascade,
            self.collision_prevention,
            rotor_count=len(airframe.rotors),
            hover_thrust_n=hover_thrust_n,
            battery_remaining=battery_remaining,
        )
        # The physics steps (sitl/drone/closed_loop.py) call these at every step: the tick's own methods, bound here,
        # as a method of this class passing each call on would cost a call more per step.
        self.step = tick.step
        self.holds_inner_loops = tick.holds_inner_loops
        self.inner_loops_stepped = tick.inner_loops_stepped
        self.steady_tick_ready = tick.steady_tick_ready
        self.steady_tick_plan = tick.steady_tick_plan
        self.steady_tick_taken = tick.steady_tick_taken
        self.steady_tick_run = tick.steady_tick_run
        self.steady_tick_avoiding_plan = tick.steady_tick_avoiding_plan
        self.steady_tick_avoided = tick.steady_tick_avoided

    # ---- what the rest of the drone reads --------------------------------------------------------------------------
    def event(self, severity: int, text: str) -> None:
        self._state.event(severity, text)

    @property
    def crashed(self) -> bool:
        return self._state.crashed

    @property
    def estimate(self) -> Estimate | None:
        return self._state.est

    @property
    def landed(self) -> bool:
        return self._state.landed

    @property
    def home_ned_m(self) -> Vec3:
        return self._state.home_ned_m

    @property
    def home_yaw_rad(self) -> float:
        return self._state.home_yaw_rad

    def altitude_above_home_m(self) -> float:
        return self._state.altitude_above_home_m()

    @property
    def fence(self) -> Geofence:
        return self._state.fence

    @property
    def mission(self) -> MissionExecutor:
        """The uploaded mission and its progress, as the Mission unit keeps it."""
        return self._requests.mission

    @property
    def orbit_plan(self) -> OrbitPlan | None:
        """The circle flown while in Orbit (ORBIT_EXECUTION_STATUS reports it); None in any other mode."""
        return self._orbit.plan if self._state.status.mode is Px4Mode.ORBIT else None

    # ---- requests (the MAVLink side, onboard behaviours, tests) ----------------------------------------------------
    def preflight_problem(self) -> str | None:
        return self._requests.preflight_problem()

    def arm(self, force: bool = False) -> CommandOutcome:
        return self._requests.arm(force)

    def disarm(self, force: bool = False) -> CommandOutcome:
        return self._requests.disarm(force)

    def kill(self) -> CommandOutcome:
        return self._requests.kill()

    def crash(self, text: str) -> None:
        self._requests.crash(text)

    def terminate(self, text: str) -> None:
        self._requests.terminate(text)

    def takeoff(self, altitude_above_home_m: float = math.nan) -> CommandOutcome:
        return self._requests.takeoff(altitude_above_home_m)

    def land(self, at_ned_m: tuple[float, float, float] | None = None) -> CommandOutcome:
        return self._requests.land(at_ned_m)

    def hold(self) -> CommandOutcome:
        return self._requests.hold()

    def return_to_launch(self) -> CommandOutcome:
        return self._requests.return_to_launch()

    def goto(self, target_ned_m: Vec3, yaw_rad: float = math.nan) -> CommandOutcome:
        return self._requests.goto(target_ned_m, yaw_rad)

    def orbit(self, command: OrbitCommand) -> CommandOutcome:
        return self._requests.orbit(command)

    def set_speed(self, ground_speed_mps: float) -> CommandOutcome:
        return self._requests.set_speed(ground_speed_mps)

    def set_home(self, home_ned_m: Vec3 | None) -> CommandOutcome:
        return self._requests.set_home(home_ned_m)

    def set_mission(self, items: tuple[NavItem, ...]) -> CommandOutcome:
        return self._requests.set_mission(items)

    def retarget_mission(self, items: tuple[NavItem, ...]) -> None:
        self._requests.retarget_mission(items)

    def set_mission_current(self, seq: int) -> CommandOutcome:
        return self._requests.set_mission_current(seq)

    def start_mission(self) -> CommandOutcome:
        return self._requests.start_mission()

    def set_offboard_setpoint(self, setpoint: TrajectorySetpoint | AttitudeSetpoint, now_s: float) -> None:
        self._requests.set_offboard_setpoint(setpoint, now_s)

    def start_offboard(self, now_s: float) -> CommandOutcome:
        return self._requests.start_offboard(now_s)

    def note_gcs_heartbeat(self, now_s: float) -> None:
        self._requests.note_gcs_heartbeat(now_s)

    def set_fence(self, fence: Geofence) -> None:
        self._requests.set_fence(fence)
