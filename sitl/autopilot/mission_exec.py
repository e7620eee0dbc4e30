"""Mission execution logic (PX4's navigator mission block), pure: where the mission is and what to do next.

The executor walks the ``NavItem`` list and tells the autopilot what to fly when an item starts (an action);
the autopilot flies it and reports position and landed state back each step, from which the executor decides
when an item is reached. Items that are not navigation (camera, gimbal ...) are skipped; DO_CHANGE_SPEED is an
action that completes at once.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import Enum

from sitl.autopilot.mission_plan import NavItem, NavKind
from sitl.mathutil import Vec3

TAKEOFF_ALT_ACCEPT_M = 0.3  # PX4 accepts the takeoff item within a fraction of a metre of its altitude
LAND_GOTO_ACCEPT_M = 0.5


class MissionRun(Enum):
    NO_MISSION = "no mission"
    NOT_STARTED = "not started"
    ACTIVE = "active"
    PAUSED = "paused"
    COMPLETE = "complete"


@dataclass(frozen=True, slots=True, kw_only=True)
class MissionAction:
    kind: NavKind
    target_ned_m: tuple[float, float, float]  # resolved: unset components are the position at item start
    yaw_rad: float = math.nan
    speed_mps: float = math.nan


class MissionExecutor:
    def __init__(self) -> None:
        self.items: tuple[NavItem, ...] = ()
        self.index = 0
        self.state = MissionRun.NO_MISSION
        self.reached_seq = -1
        self._entered = False
        self._arrived_at_s: float | None = None
        self._target: tuple[float, float, float] = (0.0, 0.0, 0.0)
        self._land_phase = ""

    @property
    def current_seq(self) -> int:
        return self.items[min(self.index, len(self.items) - 1)].seq if self.items else 0

    def load(self, items: tuple[NavItem, ...]) -> None:
        self.items = items
        self.index = 0
        self.reached_seq = -1
        self._entered = False
        self.state = MissionRun.NOT_STARTED if items else MissionRun.NO_MISSION

    def retarget(self, items: tuple[NavItem, ...]) -> None:
        """Replace the items by the same mission with recomputed targets, keeping the progress.

        The item being flown keeps the target it started with; later items fly to their new targets.
        """
        if [item.seq for item in items] != [item.seq for item in self.items]:
            raise ValueError("retarget needs the same mission items")
        self.items = items

    def set_current(self, seq: int) -> bool:
        if not (0 <= seq < len(self.items)):
            return False
        self.index = seq
        self._entered = False
        if self.state is MissionRun.COMPLETE:
            self.state = MissionRun.PAUSED
        return True

    def start(self) -> bool:
        if not self.items:
            return False
        if self.state is MissionRun.COMPLETE:
            self.index = 0
            self.reached_seq = -1
        self._entered = False  # re-issue the current item's action (the vehicle may have been elsewhere)
        self.state = MissionRun.ACTIVE
        return True

    def pause(self) -> None:
        if self.state is MissionRun.ACTIVE:
            self.state = MissionRun.PAUSED

    def _advance(self) -> None:
        self.reached_seq = self.items[self.index].seq
        self.index += 1
        self._entered = False
        if self.index >= len(self.items):
            self.index = len(self.items) - 1
            self.state = MissionRun.COMPLETE

    def step(self, now_s: float, pos_ned_m: Vec3, landed: bool, default_radius_m: float) -> MissionAction | None:
        """Call every control step in AUTO.MISSION; returns an action when the vehicle must do something new."""
        while self.state is MissionRun.ACTIVE:
            item = self.items[self.index]
            if not self._entered:
                self._entered = True
                self._arrived_at_s = None
                self._land_phase = ""
                self._target = tuple(  # type: ignore[assignment]
                    float(t) if math.isfinite(t) else float(p)
                    for t, p in zip(item.target_ned_m, pos_ned_m, strict=True)
                )
                if item.kind is NavKind.SKIP:
                    self._advance()
                    continue
                if item.kind is NavKind.SPEED:
                    self._advance()
                    return MissionAction(kind=NavKind.SPEED, target_ned_m=self._target, speed_mps=item.speed_mps)
                if item.kind is NavKind.LAND:
                    far = math.hypot(self._target[0] - pos_ned_m[0], self._target[1] - pos_ned_m[1])
                    if far > LAND_GOTO_ACCEPT_M:
                        self._land_phase = "goto"
                        goto = (self._target[0], self._target[1], float(pos_ned_m[2]))
                        return MissionAction(kind=NavKind.WAYPOINT, target_ned_m=goto, yaw_rad=item.yaw_rad)
                    self._land_phase = "descend"
                if item.kind is NavKind.RTL:
                    self._advance()
                    self.state = MissionRun.COMPLETE
                    return MissionAction(kind=NavKind.RTL, target_ned_m=self._target)
                return MissionAction(kind=item.kind, target_ned_m=self._target, yaw_rad=item.yaw_rad)
            return self._progress(item, now_s, pos_ned_m, landed, default_radius_m)
        return None

    def _progress(
        self, item: NavItem, now_s: float, pos: Vec3, landed: bool, default_radius_m: float
    ) -> MissionAction | None:
        target = self._target
        if item.kind is NavKind.TAKEOFF:
            if not landed and abs(pos[2] - target[2]) < TAKEOFF_ALT_ACCEPT_M:
                self._advance()
            return None
        if item.kind is NavKind.LAND:
            if self._land_phase == "goto" and math.hypot(target[0] - pos[0], target[1] - pos[1]) < LAND_GOTO_ACCEPT_M:
                self._land_phase = "descend"
                return MissionAction(kind=NavKind.LAND, target_ned_m=target, yaw_rad=item.yaw_rad)
            if self._land_phase == "descend" and landed:
                self._advance()
                self.state = MissionRun.COMPLETE
            return None
        if item.kind is NavKind.LOITER_UNLIMITED:
            return None
        radius = item.acceptance_radius_m if math.isfinite(item.acceptance_radius_m) else default_radius_m
        distance = math.sqrt(sum((t - p) * (t - p) for t, p in zip(target, pos, strict=True)))
        if self._arrived_at_s is None and distance <= radius:
            self._arrived_at_s = now_s
        if self._arrived_at_s is not None and now_s - self._arrived_at_s >= item.hold_s:
            self._advance()
        return None
