"""The facts the commander's parts share (sitl/autopilot/commander.py): what telemetry reads (``VehicleStatus``, the
events), what the last physics step brought (the estimate, the time, the land detector's verdict), home, the fence
and the ground station's heartbeat, and whether the next step must be a tick.

It holds facts and no decisions: the requests (sitl/autopilot/requests.py), the mode authority
(sitl/autopilot/mode_authority.py) and the flight tick (sitl/autopilot/flight_tick.py) each read and write it, and
none of them holds another part for a fact, so each can be read, tested and replaced without the others.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sitl.autopilot.geofence import Geofence
from sitl.autopilot.land_detector import LandDetector, LandDetectorConfig
from sitl.autopilot.px4_modes import FailsafeKind, Px4Mode
from sitl.autopilot.vehicle_api import LandedState
from sitl.estimation.estimator import Estimate
from sitl.mathutil import Vec3


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


class CommanderState:
    """What the commander's parts share; plain attributes, written where the part that knows writes them."""

    def __init__(self) -> None:
        self.status = VehicleStatus()
        self.events: list[VehicleEvent] = []
        self.crashed = False  # a crash or a flight termination: the motors stay stopped, arming is refused
        self.est: Estimate | None = None  # the estimate of the latest physics step
        self.now_s = 0.0  # the simulation time of the latest physics step
        self.land_detector = LandDetector(LandDetectorConfig())
        self.home_ned_m: Vec3 = np.zeros(3)
        self.home_yaw_rad = 0.0
        self.armed_since_s = 0.0
        self.landed_since_s: float | None = 0.0
        self.gcs_heartbeat_s = math.nan  # the last ground station HEARTBEAT; NaN before the first
        self.fence = Geofence()
        # Something the last tick's decision rests on has changed (a command, a mode, a target): the next physics
        # step is a tick, whatever the tick's clock says, so nothing waits for it to be acted on.
        self.tick_due = False

    def event(self, severity: int, text: str) -> None:
        self.events.append(VehicleEvent(severity=severity, text=text))

    @property
    def landed(self) -> bool:
        return self.land_detector.landed

    def current_pos(self) -> Vec3:
        return np.zeros(3) if self.est is None else self.est.pos_ned_m.copy()

    def altitude_above_home_m(self) -> float:
        return 0.0 if self.est is None else float(self.home_ned_m[2] - self.est.pos_ned_m[2])
