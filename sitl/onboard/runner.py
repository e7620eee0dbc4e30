"""Runs an onboard behaviour inside a simulated drone, as a companion computer runs one beside PX4.

While the behaviour's enable parameter (``BHV_EN``) is 1, the runner calls its ``step`` at ``RATE_HZ`` of simulated
time with what the drone knows (``OnboardState``), feeds the result to the autopilot as an offboard setpoint, and,
once setpoints are flowing, switches the drone to OFFBOARD, as a companion's ``offboard.start()`` does. Onboard
avoidance (collision prevention) stays under it as the safety layer.

It stops, and sets ``BHV_EN`` back to 0, when:
- the operator takes the drone out of OFFBOARD (land, Hold, Return: the operator's command wins, as in PX4);
- ``BHV_EN`` is set to 0 (from a ground station, MAVSDK, QGroundControl);
- the behaviour raises: the drone holds where it is (PX4 Hold), the traceback goes to the drone's log and a
  STATUSTEXT says which behaviour stopped, why and where (``Behaviour Flock stopped: ZeroDivisionError at
  flock.py:42``). The drone process flies on.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Sequence

from sitl.autopilot.commander import Commander
from sitl.autopilot.px4_modes import Px4Mode
from sitl.avoidance.algorithm import Obstacle
from sitl.avoidance.collision_prevention import RelayedNeighbour
from sitl.control.cascade import TrajectorySetpoint
from sitl.estimation.estimator import Estimate
from sitl.onboard.interface import Detection, GroundMessage, NeighbourReport, OnboardSetpoint, OnboardState
from sitl.onboard.loader import ENABLE_PARAM, LoadedBehaviour, error_line
from sitl.params import ParamStore

log = logging.getLogger(__name__)

SEVERITY_CRITICAL = 2  # MAV_SEVERITY of the text that says a behaviour stopped on an error
SEVERITY_INFO = 6


class OnboardRunner:
    """One behaviour instance on one drone; ``tick`` after every physics step."""

    def __init__(self, loaded: LoadedBehaviour, *, sysid: int, vehicle: Commander, params: ParamStore,
                 estimate: Callable[[], Estimate | None], relayed: Callable[[], Sequence[RelayedNeighbour]],
                 camera: Callable[[], Sequence[Obstacle]]) -> None:  # fmt: skip
        self.loaded = loaded
        self._sysid = sysid
        self._vehicle = vehicle
        self._params = params
        self._estimate = estimate
        self._relayed = relayed
        self._camera = camera
        self._own = tuple(d.name for d in loaded.params if d.name != ENABLE_PARAM)
        self._period_s = 1.0 / loaded.rate_hz
        self._behaviour: object | None = None  # made when it starts: each start is a fresh instance
        self._next_s = -math.inf
        self._flying = False  # it has had the drone in OFFBOARD since it started
        self._messages: list[GroundMessage] = []
        self.steps = 0

    def receive(self, message: GroundMessage) -> None:
        """A ground station's NAMED_VALUE_FLOAT for the behaviour: handed to it at its next step."""
        self._messages.append(message)
        del self._messages[:-64]  # a behaviour that is not running keeps only the latest

    def tick(self, now_s: float) -> None:
        if self._params[ENABLE_PARAM] != 1:
            if self._behaviour is not None:
                self._stop("stopped (BHV_EN 0)", SEVERITY_INFO)
            return
        if self._behaviour is None and not self._start():
            return
        mode = self._vehicle.status.mode
        if self._flying and mode is not Px4Mode.OFFBOARD:  # the operator (or a failsafe) took the drone
            self._stop(f"stopped: the drone left OFFBOARD for {mode.px4_name}", SEVERITY_INFO)
            return
        if now_s < self._next_s:
            return
        self._next_s = now_s + self._period_s
        state = self._state(now_s)
        if state is None:
            return
        try:
            setpoint = self._behaviour.step(state)  # type: ignore[union-attr]
        except Exception as exc:
            self._fail(exc)
            return
        self.steps += 1
        self._feed(setpoint, state, now_s)
        if not self._flying:
            self._flying = self._vehicle.start_offboard(now_s).ok

    def _start(self) -> bool:
        try:
            self._behaviour = self.loaded.cls()
        except Exception as exc:
            self._fail(exc)
            return False
        self._next_s, self._flying = -math.inf, False
        self._vehicle.event(SEVERITY_INFO, f"Behaviour {self.loaded.name} started")
        return True

    def _state(self, now_s: float) -> OnboardState | None:
        est = self._estimate()
        if est is None or not est.position_valid:
            return None
        messages, self._messages = tuple(self._messages), []
        return OnboardState(
            time_s=now_s, sysid=self._sysid,
            pos_ned_m=(float(est.pos_ned_m[0]), float(est.pos_ned_m[1]), float(est.pos_ned_m[2])),
            vel_ned_mps=(float(est.vel_ned_mps[0]), float(est.vel_ned_mps[1]), float(est.vel_ned_mps[2])),
            yaw_rad=float(est.yaw_rad), armed=self._vehicle.status.armed, in_air=not self._vehicle.landed,
            neighbours=tuple(NeighbourReport(sysid=n.sysid, pos_ned_m=n.pos_ned_m, vel_ned_mps=n.vel_ned_mps,
                                             age_s=max(0.0, now_s - n.received_s)) for n in self._relayed()),
            detections=tuple(Detection(rel_pos_ned_m=o.rel_pos_ned_m, radius_m=o.radius_m, age_s=o.age_s)
                             for o in self._camera()),
            params={name: self._params[name] for name in self._own},
            messages=messages,
        )  # fmt: skip

    def _feed(self, setpoint: OnboardSetpoint | None, state: OnboardState, now_s: float) -> None:
        """The behaviour's setpoint to the autopilot; None holds where the drone is."""
        if setpoint is None:
            target = TrajectorySetpoint(pos_ned_m=state.pos_ned_m, vel_ned_mps=(0.0, 0.0, 0.0))
        else:
            target = TrajectorySetpoint(pos_ned_m=setpoint.pos_ned_m, vel_ned_mps=setpoint.vel_ned_mps,
                                        acc_ned_mps2=setpoint.acc_ned_mps2, yaw_rad=setpoint.yaw_rad)  # fmt: skip
        self._vehicle.set_offboard_setpoint(target, now_s)

    def _stop(self, why: str, severity: int) -> None:
        self._behaviour, self._flying = None, False
        if self._params[ENABLE_PARAM] != 0:
            self._params.set(ENABLE_PARAM, 0)
        self._vehicle.event(severity, f"Behaviour {self.loaded.name} {why}")

    def _fail(self, exc: Exception) -> None:
        """The behaviour raised: it stops, the drone holds where it is, and the drone says why, in one line."""
        path = self.loaded.file
        log.error("behaviour %s raised", self.loaded.spec, exc_info=exc)
        self._stop(f"stopped: {type(exc).__name__} at {path.name}:{error_line(exc, path)}", SEVERITY_CRITICAL)
        if self._vehicle.status.armed and not self._vehicle.landed:
            self._vehicle.hold()
