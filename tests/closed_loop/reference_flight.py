"""A scripted closed-loop flight through every mode and the failsafes that existed before the autopilot was split
into mode units, reduced to figures that change if a single bit of any motor command changes.

Run as a script it prints the figures; tests/closed_loop/test_reference_flight.py compares them with the recorded
ones, so a restructure that claims "no behaviour change" is checked bit for bit.
"""

from __future__ import annotations

import hashlib
import math
import struct
from dataclasses import dataclass

import numpy as np

from sitl.autopilot.mission_plan import NavItem, NavKind
from sitl.autopilot.px4_modes import Px4Mode
from sitl.control.cascade import AttitudeSetpoint, TrajectorySetpoint
from sitl.drone.closed_loop import ClosedLoop
from sitl.dynamics.battery import Battery
from tests.closed_loop.flight import make_sim


@dataclass(frozen=True, slots=True, kw_only=True)
class Figures:
    steps: int
    motor_sha256: str  # every motor command of every step, as float64 bytes
    final_truth: tuple[float, ...]  # position, velocity, attitude quaternion at the end
    mode_trace: tuple[str, ...]  # every mode the vehicle passed through, in order
    events: tuple[str, ...]


class _Recorder:
    """Wraps the plant's step to hash the motor commands it is given at every physics step, whichever path computed
    them (instrumentation only: the commands pass through)."""

    def __init__(self, sim: ClosedLoop) -> None:
        self.sim = sim
        self.hash = hashlib.sha256()
        self.steps = 0
        self.modes: list[str] = []
        inner = sim.plant.step

        def step(motors):  # type: ignore[no-untyped-def]
            self.hash.update(struct.pack(f"<{len(motors)}d", *motors))
            self.steps += 1
            mode = sim.vehicle.status.mode.px4_name
            if not self.modes or self.modes[-1] != mode:
                self.modes.append(mode)
            return inner(motors)

        sim.plant.step = step  # type: ignore[method-assign]


def _stream(sim: ClosedLoop, setpoint: TrajectorySetpoint | AttitudeSetpoint, duration_s: float) -> None:
    sim.run_for(duration_s, lambda s: s.vehicle.set_offboard_setpoint(setpoint, s.time_s))


def fly() -> Figures:
    sim = make_sim(seed=7)
    sim.params.set("COM_FAIL_ACT_T", 1.0)
    sim.params.set("RTL_RETURN_ALT", 5.0)
    sim.params.set("RTL_DESCEND_ALT", 3.0)
    sim.params.set("COM_LOW_BAT_ACT", 1)  # return at critical (PX4's default, 0, only warns)
    rec = _Recorder(sim)
    v = sim.vehicle
    assert sim.run_until(lambda s: s.vehicle.preflight_problem() is None, 10.0)
    assert v.arm().ok
    # takeoff, goto, hold
    assert v.takeoff(3.0).ok
    assert sim.run_until(lambda s: s.vehicle.status.mode is Px4Mode.AUTO_LOITER, 15.0)
    home = v.home_ned_m.copy()
    assert v.goto(home + np.array((4.0, 2.0, -4.0))).ok
    sim.run_for(4.0)
    assert v.hold().ok
    sim.run_for(2.0)
    # offboard: position, then attitude (level, a little over hover thrust), then the stream stops
    assert v.estimate is not None
    p = v.estimate.pos_ned_m
    position = TrajectorySetpoint(pos_ned_m=(float(p[0]) - 2.0, float(p[1]), float(p[2])), yaw_rad=0.3)
    v.set_offboard_setpoint(position, sim.time_s)
    assert v.start_offboard(sim.time_s).ok
    _stream(sim, position, 3.0)
    attitude = AttitudeSetpoint(
        att_q=(1.0, 0.0, 0.0, 0.0), thrust_n=sim.config.airframe.mass_kg * 9.81 * 1.02, rates_sp_frd_radps=(0.0,) * 3
    )
    _stream(sim, attitude, 1.0)
    _stream(sim, position, 2.0)
    # offboard loss: hold, then land after COM_FAIL_ACT_T; a mission interrupts the landing
    assert sim.run_until(lambda s: s.vehicle.status.mode is Px4Mode.AUTO_LAND, 5.0)
    sim.run_for(0.5)
    items = (
        NavItem(seq=0, kind=NavKind.WAYPOINT, target_ned_m=(home[0] + 3.0, home[1] - 3.0, home[2] - 4.0)),
        NavItem(seq=1, kind=NavKind.DELAY, hold_s=1.0),
        NavItem(seq=2, kind=NavKind.SPEED, speed_mps=2.0),
        NavItem(seq=3, kind=NavKind.WAYPOINT, target_ned_m=(home[0] + 6.0, home[1], home[2] - 3.0)),
        NavItem(seq=4, kind=NavKind.LAND, target_ned_m=(home[0] + 6.0, home[1] + 1.0, math.nan)),
    )
    assert v.set_mission(items).ok
    assert v.start_mission().ok
    assert sim.run_until(lambda s: s.vehicle.mission.current_seq >= 4, 30.0)
    sim.run_for(1.0)
    # RTL from the mission's landing approach, then land on the way home
    assert v.return_to_launch().ok
    sim.run_for(6.0)
    assert v.land().ok
    assert sim.run_until(lambda s: not s.vehicle.status.armed, 30.0)
    # mission started on the ground: PX4 takes off first; then a critical battery returns it home
    assert v.set_mission(items[:1]).ok
    assert v.start_mission().ok
    assert v.arm().ok
    sim.run_for(5.0)
    sim.battery = Battery(sim.config.battery, initial_remaining=0.065)
    assert sim.run_until(lambda s: not s.vehicle.status.armed, 60.0)
    sim.run_for(1.0)
    t = sim.truth
    final = (*t.pos_ned_m, *t.vel_ned_mps, *t.att_q_frd_to_ned)
    return Figures(
        steps=rec.steps,
        motor_sha256=rec.hash.hexdigest(),
        final_truth=tuple(float(x) for x in final),
        mode_trace=tuple(rec.modes),
        events=tuple(e.text for e in v.events),
    )


if __name__ == "__main__":
    import time

    t0 = time.process_time()
    figures = fly()
    print(figures)
    print(f"cpu {time.process_time() - t0:.1f} s")
