"""Helpers for closed-loop flights: a ClosedLoop driven through the autopilot's request API, truth recorded."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from sitl.autopilot.flight_tick import commander_tick_s
from sitl.autopilot.px4_modes import Px4Mode
from sitl.drone.closed_loop import ClosedLoop, SimConfig
from sitl.dynamics.airframe import load_airframe
from sitl.dynamics.wind import WindConfig
from sitl.mathutil import quat_to_dcm


@dataclass
class Trace:
    """Ground truth sampled every physics step."""

    time_s: list[float] = field(default_factory=list)
    pos_ned_m: list[np.ndarray] = field(default_factory=list)
    tilt_rad: list[float] = field(default_factory=list)

    def record(self, sim: ClosedLoop) -> None:
        self.time_s.append(sim.time_s)
        self.pos_ned_m.append(sim.truth.pos_ned_m.copy())
        body_z_down = quat_to_dcm(sim.truth.att_q_frd_to_ned)[2, 2]
        self.tilt_rad.append(math.acos(max(-1.0, min(1.0, body_z_down))))

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return np.array(self.time_s), np.array(self.pos_ned_m), np.array(self.tilt_rad)


def reaction_tolerance_s(sim: ClosedLoop) -> float:
    """How late a test sees the autopilot act on a time it watches (a timeout, a failsafe's delay, auto-disarm): the
    commander checks it on its ticks (``commander_tick_s``: up to a tick after the first step past the time), and the
    test reads ``sim.time_s`` after the step that acted, a step later."""
    return commander_tick_s(sim.params, sim.dt_s) + sim.dt_s


def make_sim(seed: int = 1, wind: WindConfig | None = None) -> ClosedLoop:
    return ClosedLoop(SimConfig(airframe=load_airframe(), seed=seed, wind=wind or WindConfig()))


def arm_when_ready(sim: ClosedLoop, timeout_s: float = 5.0) -> None:
    assert sim.run_until(lambda s: s.vehicle.preflight_problem() is None, timeout_s), sim.vehicle.preflight_problem()
    assert sim.vehicle.arm().ok


def take_off(sim: ClosedLoop, alt_m: float, timeout_s: float = 15.0) -> None:
    arm_when_ready(sim)
    assert sim.vehicle.takeoff(alt_m).ok
    assert sim.run_until(lambda s: s.vehicle.status.mode is Px4Mode.AUTO_LOITER, timeout_s), "takeoff did not complete"


def boot_position(sim: ClosedLoop) -> np.ndarray:
    """True CG position at rest before the flight (the reference for altitude and hold errors)."""
    return sim.truth_at_boot_ned_m.copy()
