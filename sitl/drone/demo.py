"""The ``sitl --demo`` flight: arm, take off to 3 m, hover, land, with progress a person can read.

A tiny pure script over the autopilot's request API, stepped once per physics step; it prints through a callback
so the runtime decides where output goes.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from enum import Enum, auto

from sitl.autopilot.px4_modes import Px4Mode
from sitl.drone.closed_loop import ClosedLoop

DEMO_ALT_M = 3.0
DEMO_HOVER_S = 5.0
_PRINT_EVERY_S = 0.5


class _Phase(Enum):
    PREFLIGHT = auto()
    CLIMB = auto()
    HOVER = auto()
    LAND = auto()
    DONE = auto()


class DemoFlight:
    def __init__(self, sim: ClosedLoop, say: Callable[[str], None]) -> None:
        self._sim = sim
        self._say = say
        self._phase = _Phase.PREFLIGHT
        self._phase_since_s = 0.0
        self._next_print_s = 0.0
        self._max_alt_m = 0.0
        self._hover_sq_err = 0.0
        self._hover_samples = 0
        self._touchdown_speed_mps = math.nan
        self._last_problem: str | None = None
        self._last_airborne_vz_mps = math.nan

    @property
    def done(self) -> bool:
        return self._phase is _Phase.DONE

    def _to(self, phase: _Phase) -> None:
        self._phase = phase
        self._phase_since_s = self._sim.time_s

    def _line(self, text: str) -> None:
        self._say(f"[{self._sim.time_s:7.2f} s] {text}")

    def event(self, text: str) -> None:
        """An autopilot event (also sent as STATUSTEXT), shown in the demo's log."""
        self._line(f"autopilot: {text}")

    def tick(self) -> None:
        sim, vehicle = self._sim, self._sim.vehicle
        alt = sim.altitude_above_start_m()
        if not sim.truth.on_ground:
            self._last_airborne_vz_mps = float(sim.truth.vel_ned_mps[2])
        self._max_alt_m = max(self._max_alt_m, alt)
        if self._phase is _Phase.PREFLIGHT:
            problem = vehicle.preflight_problem()
            if problem is None:
                vehicle.arm()
                vehicle.takeoff(DEMO_ALT_M)
                self._line(f"pre-flight checks passed; arming and taking off to {DEMO_ALT_M:.1f} m")
                self._to(_Phase.CLIMB)
            elif problem != self._last_problem:
                self._line(f"waiting: {problem}")
                self._last_problem = problem
        elif self._phase is _Phase.CLIMB and vehicle.status.mode is Px4Mode.AUTO_LOITER:
            self._line(f"reached {alt:.2f} m; hovering for {DEMO_HOVER_S:.0f} s")
            self._to(_Phase.HOVER)
        elif self._phase is _Phase.HOVER:
            if sim.time_s - self._phase_since_s > 1.0:
                self._hover_sq_err += (alt - DEMO_ALT_M) ** 2
                self._hover_samples += 1
            if sim.time_s - self._phase_since_s >= DEMO_HOVER_S:
                vehicle.land()
                self._line("landing")
                self._to(_Phase.LAND)
        elif self._phase is _Phase.LAND:
            if sim.truth.on_ground and math.isnan(self._touchdown_speed_mps):
                self._touchdown_speed_mps = self._last_airborne_vz_mps
            if not vehicle.status.armed:
                self._summary()
                self._to(_Phase.DONE)
                return
        if self._phase in (_Phase.CLIMB, _Phase.HOVER, _Phase.LAND) and sim.time_s >= self._next_print_s:
            self._next_print_s = sim.time_s + _PRINT_EVERY_S
            est = sim.estimate
            climb = -float(sim.truth.vel_ned_mps[2])
            battery = sim.battery.state()
            est_alt = vehicle.altitude_above_home_m() if est is not None else math.nan
            self._line(
                f"{vehicle.status.mode.px4_name:<12} alt {alt:5.2f} m (est {est_alt:5.2f})  climb {climb:+5.2f} m/s  "
                f"battery {battery.voltage_v:5.2f} V {battery.remaining:4.0%}"
            )

    def _summary(self) -> None:
        rms = math.sqrt(self._hover_sq_err / self._hover_samples) if self._hover_samples else math.nan
        self._line(
            f"done: max altitude {self._max_alt_m:.2f} m, hover altitude RMS error {rms:.3f} m, "
            f"touchdown at {self._touchdown_speed_mps:.2f} m/s, disarmed"
        )
