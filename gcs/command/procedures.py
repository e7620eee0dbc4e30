"""Swarm procedures that ``swarm fly``, ``swarm up`` and ``swarm bench`` share, each written once.

- ``SteadyAltitude`` (pure): the takeoff is done when every drone holds the target altitude within
  ``ALT_TOLERANCE_M`` for ``ALT_HOLD_S`` without a break.
- ``check_takeoff_alt``: the altitudes a takeoff may ask for (0.5-100 m), checked once for every front-end.
- ``start_takeoff``: arm (after the pre-arm checks) unless armed, NAV_TAKEOFF for every drone, and the test that
  they hold the altitude (``SteadyAltitude``; at the drones' MIS_TAKEOFF_ALT when asked for less: they climb that
  high, as PX4); the takeoff verb (gcs/supervisor/verbs.py) starts it and every front-end, the bench too, waits.
- ``PaceWatch``: the pace monitor (gcs/fleet/pace_monitor.py) fed from a running swarm, its warning said once.
- ``start_onboard_behaviours`` / ``stop_onboard_behaviours``: every drone's onboard behaviour on (BHV_EN = 1, the
  ground station's own setpoint stream stopped) or off (BHV_EN = 0, then Hold); docs/onboard.md.

Arming, pre-arm waiting and the forced disarm are the swarm's own commands (gcs/fleet/commanding.py
``Commands.arm_all``, ``wait_prearm``, ``force_disarm``); collisions are counted by ``CollisionPairs``
(gcs/record/recorder.py).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping
from typing import Final

from gcs.command.streamer import FormationStreamer
from gcs.fleet.errors import SwarmError
from gcs.fleet.pace_monitor import PaceMonitor
from gcs.fleet.swarm import Swarm

ALT_TOLERANCE_M: Final = 0.2  # takeoff is done when every drone holds the target altitude within this...
ALT_HOLD_S: Final = 1.0  # ...for this long (simulated seconds)
TAKEOFF_MIN_PARAM: Final = "MIS_TAKEOFF_ALT"  # PX4's minimum takeoff altitude above home
TAKEOFF_MIN_ALT_M: Final = 0.5  # the takeoff altitudes a user may ask for, above home: below half a metre a
TAKEOFF_MAX_ALT_M: Final = 100.0  # quadrotor sits in ground effect; above 100 m it leaves any test field

Say = Callable[[str], None]


class SteadyAltitude:
    """Whether every drone has held ``alt_m`` (above the swarm origin) for ``hold_s`` without a break."""

    def __init__(self, alt_m: float, *, tolerance_m: float = ALT_TOLERANCE_M, hold_s: float = ALT_HOLD_S) -> None:
        self.alt_m = alt_m
        self.tolerance_m = tolerance_m
        self.hold_s = hold_s
        self._since_s: float | None = None

    def update(self, positions_ned_m: Mapping[int, tuple[float, float, float]], n_drones: int, now_s: float) -> bool:
        """One look at the drones' positions (swarm frame, NED: down is -altitude); True once they have held."""
        at_alt = len(positions_ned_m) == n_drones and all(
            abs(p[2] + self.alt_m) < self.tolerance_m for p in positions_ned_m.values()
        )
        if not at_alt:
            self._since_s = None
            return False
        if self._since_s is None:
            self._since_s = now_s
        return now_s - self._since_s >= self.hold_s


def takeoff_floor_m(swarm: Swarm) -> float:
    """The highest MIS_TAKEOFF_ALT among the drones (read from each): PX4 climbs at least that high on NAV_TAKEOFF
    ("Using minimum takeoff altitude"), whatever altitude the command asks for."""
    answers = [r.kept for r in swarm.params.read(TAKEOFF_MIN_PARAM, swarm.liveness.active_sysids) if r.kept is not None]
    return max(answers, default=0.0)


def check_takeoff_alt(alt_m: float) -> None:
    """The one check of a takeoff altitude, for every front-end (ValueError: one line)."""
    if not (math.isfinite(alt_m) and TAKEOFF_MIN_ALT_M <= alt_m <= TAKEOFF_MAX_ALT_M):
        raise ValueError(f"takeoff altitude must be between {TAKEOFF_MIN_ALT_M:g} and {TAKEOFF_MAX_ALT_M:g} m, "
                         f"got {alt_m:g}")  # fmt: skip


def start_takeoff(
    swarm: Swarm, streamer: FormationStreamer, alt_m: float, *, tick: Callable[[float], None] | None = None,
    say: Say | None = None,
) -> tuple[float, Callable[[], bool]]:  # fmt: skip
    """Arm every surviving drone unless all are armed (after their pre-arm checks) and take them off to ``alt_m``
    above their own homes; the altitude they will hold, and the test that they hold it (``SteadyAltitude``). The
    attached members the swarm may arm (``--arm-external``) are armed and taken off with them, to ``alt_m`` above
    the swarm's origin.

    Below the drones' minimum takeoff altitude (MIS_TAKEOFF_ALT) they climb to that instead, as PX4 does, and that is
    the altitude to wait for (``say`` is told)."""
    if not all(swarm.fleet.drones[s].armed for s in swarm.liveness.active_sysids) or swarm.attachments.to_arm():
        swarm.commands.arm_all(tick=tick)
    floor = takeoff_floor_m(swarm)
    swarm.commands.takeoff_all(alt_m)  # what was asked: the drones apply their own minimum, as PX4
    if alt_m < floor:
        if say is not None:
            say(f"takeoff to {alt_m:g} m: below the drones' {TAKEOFF_MIN_PARAM} ({floor:g} m), they climb to "
                f"{floor:g} m (as PX4); a later step sets the altitude")  # fmt: skip
        alt_m = floor
    steady = SteadyAltitude(alt_m)
    members = swarm.attachments.taken_off()  # the attached members taken off with the drones climb with them

    def holding() -> bool:
        climbing = [*swarm.liveness.active_sysids, *members]
        positions = swarm.picture.positions(climbing)
        return steady.update({s: positions[s] for s in climbing if s in positions}, len(climbing), swarm.clock.now())

    return alt_m, holding


class PaceWatch:
    """A paced swarm's achieved rate against the wall clock; the warning is said once when it falls behind.

    None of it in lockstep, whose clock is the drones' own."""

    def __init__(self, swarm: Swarm, say: Say) -> None:
        self.swarm = swarm
        self.say = say
        self.monitor = PaceMonitor.for_plan(swarm.plan)

    @property
    def requested_speed(self) -> float | None:
        return self.monitor.speed_factor if self.monitor is not None else None

    def tick(self) -> float | None:
        """Sample the slowest drone's clock; returns the real-time factor over the last window (None: unknown)."""
        if self.monitor is None:
            return None
        warning = self.monitor.update(time.monotonic(), self.swarm.harness.drone_time_s())
        if warning is not None:
            self.say(warning)
        return self.monitor.rate()


BEHAVIOUR_ENABLE_PARAM: Final = "BHV_EN"  # a drone's onboard behaviour runs while it is 1 (docs/onboard.md)


def start_onboard_behaviours(swarm: Swarm, streamer: FormationStreamer) -> list[int]:
    """Every drone still in the swarm runs its onboard behaviour: the ground station stops its own setpoint stream
    (the behaviour feeds the offboard input now) and sets BHV_EN = 1; returns those sysids."""
    streamer.stop()
    sysids = swarm.liveness.active_sysids
    _set_enable(swarm, sysids, 1)
    return sysids


def stop_onboard_behaviours(swarm: Swarm) -> list[int]:
    """BHV_EN = 0 on every drone, then Hold where they are (from where the next command takes them); returns the
    sysids put in Hold."""
    _set_enable(swarm, swarm.liveness.active_sysids, 0)
    return swarm.commands.hold_all()


def _set_enable(swarm: Swarm, sysids: list[int], value: int) -> None:
    bad = [r.sysid for r in swarm.params.set_all(BEHAVIOUR_ENABLE_PARAM, value, sysids) if not r.ok]
    if bad:
        raise SwarmError(f"{BEHAVIOUR_ENABLE_PARAM} = {value} not set on sysid {bad} (no onboard behaviour loaded?)")
