"""Which drones the swarm has: those launched, each loss recorded once, with why and where the drone came down, and
the silent drones that are heard again taken back.

A drone is lost when the harness reports its flight software ended (any cause), when it reports
MAV_STATE_FLIGHT_TERMINATION (crashed, terminated), or when it stays silent for the link-loss time
(gcs/fleet/telemetry.py ``LINK_LOST_S``); gcs/fleet/losses.py defines what a loss records.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable, Iterable
from typing import Final

from pymavlink.dialects.v20 import common as mavlink

from gcs.fleet.clock import SwarmClock
from gcs.fleet.errors import SwarmError
from gcs.fleet.harness import SimulationHarness
from gcs.fleet.losses import MAV_STATE_FLIGHT_TERMINATION, DroneLoss
from gcs.fleet.telemetry import LINK_LOST_S, Fleet
from gcs.flight.frames import Vec3
from gcs.flight.geodesy import GeoPoint

CRASH_TEXT_AGE_S: Final = 5.0  # a warning this recent says why a drone crashed; an older one is about something else


class Liveness:
    """The swarm's drones, their losses and returns, from the harness's word and the fleet view."""

    def __init__(self, harness: SimulationHarness, fleet: Fleet, clock: SwarmClock,
                 ned_from_geo: Callable[[GeoPoint], Vec3], *, lockstep: bool) -> None:  # fmt: skip
        """``ned_from_geo``: a geodetic point in the swarm frame, the picture's (gcs/fleet/picture.py): where a lost
        drone came down."""
        self.harness = harness
        self.fleet = fleet
        self.clock = clock
        self.ned_from_geo = ned_from_geo
        self.lockstep = lockstep
        self.losses: dict[int, DroneLoss] = {}  # sysid -> the loss, recorded once
        self.regained: list[DroneLoss] = []  # losses that ended: silent drones heard again (``detect_regains``)
        self._sysids: tuple[int, ...] = ()  # the simulated drones, in spawn order, once launched
        self._heard_wall_s: dict[int, float] = {}  # sysid -> wall time of its last sign of life

    def launched(self, sysids: list[int]) -> None:
        """The harness has launched these drones (spawn order): the swarm's drones from now on."""
        self._sysids = tuple(sysids)

    @property
    def sysids(self) -> list[int]:
        """Every simulated drone launched, lost or not (spawn order)."""
        return list(self._sysids)

    @property
    def active_sysids(self) -> list[int]:
        """The drones the swarm still has: every one not in ``losses``."""
        return [s for s in self._sysids if s not in self.losses]

    def armed_sysids(self, sysids: Iterable[int] | None = None) -> list[int]:
        """Of ``sysids`` (default: every drone), those not lost whose last HEARTBEAT said armed (a lost drone's last
        report may say armed for ever)."""
        drones = self.fleet.drones
        return [
            s
            for s in (self._sysids if sysids is None else sysids)
            if s not in self.losses and s in drones and drones[s].armed
        ]

    def heard(self, sysid: int) -> None:
        """A sign of life from ``sysid`` now (any message but RADIO_STATUS)."""
        self._heard_wall_s[sysid] = time.monotonic()

    def kill(self, sysid: int) -> str:
        """Crash drone ``sysid``'s flight software (the harness kills what runs it); returns what was done, in one
        line. The loss is recorded by ``detect_losses`` when the harness reports the end, as for any other end."""
        done = self.harness.kill(sysid)
        if done is None:
            raise SwarmError(f"drone {sysid}: its flight software has already ended")
        return done

    def detect_losses(self, time_s: float) -> list[DroneLoss]:
        """Record every new loss once and return them (``time_s``: the time to record, the caller's mission clock).
        The harness says which drones ended and how (their bodies then fall in the simulated world from their last
        state)."""
        sysids, now_s = self._sysids, self.clock.now()
        new: list[DroneLoss] = []
        for sysid, cause in self.harness.ended().items():
            if sysid not in self.losses:
                new.append(self._record(sysid, time_s, cause))
        for sysid in sysids:
            view = self.fleet.drones.get(sysid)
            if view is None or sysid in self.losses:
                continue
            if view.system_status == MAV_STATE_FLIGHT_TERMINATION:
                new.append(self._record(sysid, time_s, crash_cause(view.texts, now_s)))
            elif view.lost(now_s) and (self.lockstep or self._silent_on_the_wall_clock(sysid)):
                cause = f"link lost (nothing heard for {view.link_age_s(now_s):.1f} s)"
                new.append(self._record(sysid, time_s, cause, silent=True))
        self._settle_down_positions(sysids, now_s)
        return new

    def detect_regains(self, time_s: float) -> list[DroneLoss]:
        """Take back every drone lost for silence that has been heard again (QGroundControl's "communication
        regained"), once: it leaves ``losses`` and its ended loss, with ``regained_s``, goes to ``regained``. A drone
        lost any other way stays lost. What the swarm flies takes it in again (gcs/command/degrade.py
        ``apply_regain``)."""
        now_s = self.clock.now()
        back: list[DroneLoss] = []
        for sysid, loss in list(self.losses.items()):
            view = self.fleet.drones.get(sysid)
            if loss.silent and view is not None and not view.lost(now_s):
                del self.losses[sysid]
                ended = dataclasses.replace(loss, regained_s=time_s)
                self.regained.append(ended)
                back.append(ended)
        return back

    def _silent_on_the_wall_clock(self, sysid: int) -> bool:
        """Paced, a drone is lost when it is silent for the link-loss time on both clocks: a loaded machine that
        delays a paced drone's heartbeat by a fraction of a wall second (3 s at --speed 4 is 0.75 s) must not lose it
        for good. In lockstep the simulated clock alone decides: the drones cannot run more than the gate's lead
        ahead of the supervisor, so a heartbeat sent is read within that lead, however fast or slow the machine;
        counting wall seconds there kept a silent drone in the swarm when the simulation ran faster than real time."""
        return time.monotonic() - self._heard_wall_s.get(sysid, -math.inf) > LINK_LOST_S

    def _record(self, sysid: int, time_s: float, cause: str, *, silent: bool = False) -> DroneLoss:
        loss = DroneLoss(sysid=sysid, time_s=time_s, cause=cause, silent=silent)
        self.losses[sysid] = loss
        return loss

    def _settle_down_positions(self, sysids: tuple[int, ...], now_s: float) -> None:
        """Fill in where each lost drone came down, once its body is on the ground (north/east of the origin)."""
        if not sysids:
            return
        for sysid, loss in list(self.losses.items()):
            if loss.down_ne_m is None:
                geo = self.harness.grounded_body_geo(sysid, now_s)
                if geo is not None:
                    point = GeoPoint(lat_deg=geo[0], lon_deg=geo[1], alt_amsl_m=geo[2])
                    north, east, _ = self.ned_from_geo(point)
                    self.losses[sysid] = dataclasses.replace(loss, down_ne_m=(north, east))


def crash_cause(texts: list[tuple[float, int, str]], now_s: float) -> str:
    """``crashed``, with the first of the drone's recent warnings: the cause (``crashed: Collision with drone 2 at
    0.61 m``, an injected motor failure), not its consequences (``Motors stopped: crashed``) that follow it."""
    warnings = [
        text
        for t, severity, text in texts
        if severity <= mavlink.MAV_SEVERITY_WARNING and now_s - t <= CRASH_TEXT_AGE_S
    ]
    return f"crashed: {warnings[0]}" if warnings else "crashed"
