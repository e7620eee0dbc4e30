"""The smooth reference every auto mode flies and the point it heads for: one for the vehicle, shared by the mode
units, so a switch between modes, or a new target, continues from where the reference is instead of jumping.

The requests and the mode authority aim it (``goto``, ``hold``); the flight tick flies it (``fly``: a unit's
``Track`` made a trajectory setpoint). It is the numeric half of the auto modes, kept apart from the decisions about
modes so that a compiled tick can take it over whole.
"""

from __future__ import annotations

import math

import numpy as np

from sitl.autopilot.commander_state import CommanderState
from sitl.autopilot.guidance import MotionLimits, StraightLineTrajectory
from sitl.autopilot.mode_io import Track
from sitl.control.cascade import TrajectorySetpoint
from sitl.mathutil import Vec3, vec3
from sitl.params import ParamStore


class TargetTracker:
    """The shared reference and its target: aimed by requests and transitions, flown by the tick."""

    def __init__(self, state: CommanderState, params: ParamStore) -> None:
        self._state = state
        self._params = params
        self.trajectory = StraightLineTrajectory(np.zeros(3))
        self.target_ned_m: Vec3 = np.zeros(3)
        self.target_yaw_rad = math.nan  # NaN: keep the heading
        self.speed_override_mps = math.inf  # DO_CHANGE_SPEED's limit on auto-mode speed

    def goto(self, target_ned_m: Vec3, yaw_rad: float = math.nan) -> None:
        """Fly to a point on a smooth trajectory, starting from where the reference currently is."""
        self._state.tick_due = True
        self.target_ned_m = np.array(target_ned_m, dtype=np.float64)
        self.target_yaw_rad = yaw_rad

    def hold(self) -> None:
        """Hold at the point where the vehicle can stop without a jerk (braking distance included)."""
        state = self._state
        est = state.est
        pos = state.current_pos()
        if est is not None and state.status.armed and not state.landed:
            vel = est.vel_ned_mps
            speed = math.hypot(*vel)
            if speed > 0.1:
                pos = pos + vel * (speed / (2.0 * self._params["MPC_ACC_HOR"]))
                # The reference starts from the vehicle's own motion and brakes along it to that point; from rest
                # it would stop dead at the vehicle (which overshoots it) and then accelerate again to that point.
                self.trajectory.reset_moving(state.current_pos(), vel)
            else:
                self.trajectory.reset(state.current_pos())
        self.goto(pos, est.yaw_rad if est is not None else math.nan)

    def limit_speed(self, ground_speed_mps: float) -> None:
        """Limit auto-mode speed; zero or less restores the default."""
        self.speed_override_mps = math.inf if ground_speed_mps <= 0 else ground_speed_mps
        self._state.tick_due = True

    def fly(self, track: Track, dt_s: float) -> TrajectorySetpoint:
        """Advance the reference by ``dt_s`` as a unit's ``Track`` asks, and the setpoint that flies it."""
        if track.descend_to_land:
            return self._land_descent_setpoint(track.limits, track.max_speed_mps, dt_s)
        return self._track_setpoint_to(self.target_ned_m, track.limits, track.max_speed_mps, dt_s)

    def _track_setpoint_to(
        self, goal_ned_m: Vec3, limits: MotionLimits, max_speed_mps: float, dt_s: float
    ) -> TrajectorySetpoint:
        """Advance the reference towards ``goal_ned_m`` and fly it."""
        pos, vel, acc = self.trajectory.advance(goal_ned_m, limits, dt_s, max_speed_mps)
        return TrajectorySetpoint(pos_ned_m=pos, vel_ned_mps=vel, acc_ned_mps2=acc, yaw_rad=self.target_yaw_rad)

    def _land_descent_setpoint(self, limits: MotionLimits, max_speed_mps: float, dt_s: float) -> TrajectorySetpoint:
        """Descend at the landing speed into the ground: the land detector ends the descent, not a target.
        Horizontally the reference glides to the landing point (it is already there when landing in place).

        A landing point farther than NAV_ACC_RAD is first flown to at the current altitude, as PX4's mission inserts
        a "move to land" leg for a multicopter: gliding there while descending, a point more than a few metres
        away was reached only at the ground, and the vehicle touched down at cruise speed and broke."""
        params = self._params
        reference = self.trajectory.position
        goal = vec3(self.target_ned_m[0], self.target_ned_m[1], float(reference[2]))
        ahead = goal[:2] - reference[:2]
        if math.hypot(float(ahead[0]), float(ahead[1])) > params["NAV_ACC_RAD"]:
            return self._track_setpoint_to(goal, limits, max_speed_mps, dt_s)
        land_speed = params["MPC_LAND_SPEED"]
        if self._state.altitude_above_home_m() > params["MPC_LAND_ALT2"]:
            land_speed = params["MPC_Z_V_AUTO_DN"]
        (north, east, _), (v_north, v_east, _), _ = self.trajectory.advance(goal, limits, dt_s, max_speed_mps)
        return TrajectorySetpoint(
            pos_ned_m=(north, east, math.nan), vel_ned_mps=(v_north, v_east, land_speed), yaw_rad=self.target_yaw_rad
        )
