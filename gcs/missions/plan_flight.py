"""A QGroundControl plan flown by a swarm: one copy per drone, uploaded, started in AUTO.MISSION, watched to its end.

What ``swarm plan upload/start/download`` (gcs/supervisor/station.py) and a mission file's ``plan`` step
(gcs/supervisor/mission_runner.py) share, written once. The swarm carries out the protocol (gcs/fleet/transfers.py
``Missions.upload``, ``download``, its ``progress``); this module decides what each drone gets and when a plan is over.

Copies and their offsets: a plan drawn for one vehicle, uploaded unchanged to several, would send them all to the
same points. So each drone gets the plan moved by an offset (gcs/missions/qgc_plan.py ``shifted``):

- ``spawn`` (the default): the drone's own spawn offset from the swarm origin. A plan drawn in QGroundControl
  around the swarm origin (where its planned home is) flies as a formation of copies, each drone flying it from
  where it stands, the copies as far apart as the drones were at spawn;
- ``none``: the plan as drawn, for one drone, or for drones whose plans keep them apart already;
- explicit offsets ``N,E`` per drone, in the order of the chosen drones.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Final

from pymavlink.dialects.v20 import common as mavlink

from gcs.fleet.swarm import ARM_TIMEOUT_S, HOLD_MODE, Swarm, SwarmError, check
from gcs.mavlink.mission_transfer import MISSION_TYPE_FENCE, MISSION_TYPE_MISSION, TransferResult
from gcs.mavlink.modes import set_mode_params
from gcs.missions.qgc_plan import (
    FenceItemsError,
    QgcPlan,
    fence_items,
    last_item_lands,
    mission_items,
    plan_from_items,
    shifted,
)

OFFSET_MODES: Final = ("spawn", "none")
MISSION_MODE: Final = set_mode_params("MISSION")  # DO_SET_MODE params for PX4 AUTO.MISSION
# Items PX4 reports with MISSION_ITEM_REACHED when flown (not the instant ones: speed changes, camera ...)
_REPORTED: Final = frozenset({mavlink.MAV_CMD_NAV_WAYPOINT, mavlink.MAV_CMD_NAV_TAKEOFF, mavlink.MAV_CMD_NAV_LAND})
_RANGE = re.compile(r"^\s*(\d+)\s*(?:-\s*(\d+)\s*)?$")

Offset = tuple[float, float]


class PlanUsageError(ValueError):
    """A wrong choice of drones or offsets (one line, before anything is sent)."""


def parse_drones(text: str, known: Sequence[int]) -> list[int]:
    """``all`` or a list like ``1,3-5`` of numbers from ``known``, in ``known``'s order without repeats."""
    if text.strip() == "all":
        return list(known)
    chosen: set[int] = set()
    for part in text.split(","):
        match = _RANGE.match(part)
        if match is None:
            raise PlanUsageError(f"drones: {text!r} is not 'all' or a list like 1,3-5")
        first = int(match.group(1))
        last = int(match.group(2) or first)
        if last < first:
            raise PlanUsageError(f"drones: the range {part.strip()} runs backwards")
        unknown = [n for n in range(first, last + 1) if n not in known]
        if unknown:
            raise PlanUsageError(f"drones: {unknown[0]} is not one of {_listed(known)}")
        chosen.update(range(first, last + 1))
    return [n for n in known if n in chosen]


def _listed(known: Sequence[int]) -> str:
    return f"{known[0]}..{known[-1]}" if list(known) == list(range(known[0], known[-1] + 1)) else str(list(known))


def parse_offsets(text: str) -> str | list[Offset]:
    """``spawn``, ``none``, or offsets ``N,E N,E ...`` (metres north and east, pairs separated by spaces or ``;``)."""
    if text.strip() in OFFSET_MODES:
        return text.strip()
    out: list[Offset] = []
    for pair in text.replace(";", " ").split():
        try:
            north, east = (float(v) for v in pair.split(","))
        except ValueError:
            raise PlanUsageError(f"offsets: {pair!r} is not N,E (metres north, east)") from None
        out.append((north, east))
    if not out:
        raise PlanUsageError("offsets: give spawn, none, or N,E per drone")
    return out


def nothing_to_start(plan: QgcPlan, path: Path) -> str | None:
    """Why a plan cannot be started, or None: AUTO.MISSION needs a mission item, and a plan of a fence alone is
    uploaded only. A mission's plan step and ``swarm plan upload --start`` refuse it before anything is sent, each
    saying how to upload the fence alone."""
    return None if plan.items else f"{path}: the plan has no mission items to start"


def spawn_offsets(swarm: Swarm) -> dict[int, Offset]:
    """Every drone's spawn offset from the swarm origin, north/east metres, by sysid."""
    return dict(zip(swarm.liveness.sysids, swarm.plan.offsets_ne_m(), strict=True))


def copy_offsets(spawn: dict[int, Offset], sysids: Sequence[int], offsets: str | Sequence[Offset]) -> dict[int, Offset]:
    """Each chosen drone's offset: its spawn offset (``spawn``, from ``spawn_offsets``), none, or one given each."""
    if offsets == "spawn":
        return {s: spawn[s] for s in sysids}
    if isinstance(offsets, str):
        if offsets != "none":
            raise PlanUsageError(f"offsets: must be {', '.join(OFFSET_MODES)} or N,E per drone, got {offsets!r}")
        return {s: (0.0, 0.0) for s in sysids}
    given: list[Offset] = [(float(n), float(e)) for n, e in offsets]
    if len(given) != len(sysids):
        raise PlanUsageError(f"offsets: {len(given)} given for {len(sysids)} drones: give one N,E each")
    return dict(zip(sysids, given, strict=True))


@dataclass(frozen=True, slots=True, kw_only=True)
class Uploaded:
    """What went to each drone: its copy of the plan."""

    copies: dict[int, QgcPlan]

    @property
    def last_seq(self) -> int:
        return len(next(iter(self.copies.values())).items) - 1

    @property
    def lands(self) -> bool:
        return last_item_lands(next(iter(self.copies.values())))


def upload_plan(swarm: Swarm, plan: QgcPlan, offsets: dict[int, Offset]) -> Uploaded:
    """Every chosen drone's copy: the mission, then the fence (an empty one clears a fence left from before, as
    QGroundControl's upload does), all drones at once; SwarmError names each drone that refused or did not answer."""
    copies = {sysid: shifted(plan, north, east) for sysid, (north, east) in offsets.items()}
    missions = {sysid: mission_items(copy) for sysid, copy in copies.items()}
    _check(swarm.missions.upload(missions, MISSION_TYPE_MISSION))
    fences = {sysid: fence_items(copy) for sysid, copy in copies.items()}
    _check(swarm.missions.upload(fences, MISSION_TYPE_FENCE))
    return Uploaded(copies=copies)


def _check(results: list[TransferResult]) -> None:
    bad = [r.error for r in results if r.error is not None]
    if bad:
        raise SwarmError("; ".join(bad))


def start_missions(swarm: Swarm, sysids: Sequence[int]) -> None:
    """AUTO.MISSION on every chosen drone (DO_SET_MODE, as QGroundControl starts a PX4 mission), arming first the
    ones on the ground (QGroundControl's "start mission" arms too): a plan that begins with a takeoff takes off.

    The caller has stopped the setpoint stream (the chosen drones leave OFFBOARD); every other drone in the air is
    put in Hold where it is, so that it hovers instead of meeting the offboard-loss failsafe."""
    commands = swarm.commands
    others = [s for s in swarm.liveness.armed_sysids() if s not in sysids]
    if others:
        check(commands.command_all(mavlink.MAV_CMD_DO_SET_MODE, *HOLD_MODE, sysids=others), "hold")
    for sysid in sysids:
        swarm.missions.progress.reset(sysid)
    disarmed = [s for s in sysids if s not in swarm.liveness.armed_sysids(sysids)]
    if disarmed:
        drones = swarm.fleet.drones
        ready = swarm.pump.wait_until(lambda: all(drones[s].prearm_ok for s in disarmed), ARM_TIMEOUT_S)
        if not ready:
            raise SwarmError(f"sysid {[s for s in disarmed if not drones[s].prearm_ok]} did not pass pre-arm checks")
        check(commands.command_all(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1, sysids=disarmed), "arm")
    check(commands.command_all(mavlink.MAV_CMD_DO_SET_MODE, *MISSION_MODE, sysids=list(sysids)), "start mission")


def unfinished(swarm: Swarm, uploaded: Uploaded) -> list[int]:
    """The drones still in the swarm that have not finished their mission (MISSION_CURRENT complete, or the last
    item reported reached) or, when the plan ends with a land or a return, are not yet down and disarmed."""
    armed = set(swarm.liveness.armed_sysids())
    return [
        sysid
        for sysid in uploaded.copies
        if sysid not in swarm.liveness.losses
        and (not swarm.missions.progress.finished(sysid, uploaded.last_seq) or (uploaded.lands and sysid in armed))
    ]


def unreached(swarm: Swarm, uploaded: Uploaded) -> dict[int, list[int]]:
    """Per drone still in the swarm, the navigation items it never reported reached (empty lists omitted)."""
    out: dict[int, list[int]] = {}
    for sysid, copy in uploaded.copies.items():
        progress = swarm.missions.progress.drones.get(sysid)
        reached = set(progress.reached) if progress is not None else set()
        missing = [seq for seq, item in enumerate(copy.items) if item.command in _REPORTED and seq not in reached]
        if missing and sysid not in swarm.liveness.losses:
            out[sysid] = missing
    return out


def download_plan(swarm: Swarm, sysid: int) -> QgcPlan:
    """Drone ``sysid``'s mission and fence as a plan, its home as the planned home (``swarm plan download``)."""
    mission = swarm.missions.download([sysid], MISSION_TYPE_MISSION)[0]
    _check([mission])
    fence = swarm.missions.download([sysid], MISSION_TYPE_FENCE)[0]
    _check([fence])
    view = swarm.fleet.drones.get(sysid)
    home = view.home if view is not None and view.home is not None else (0.0, 0.0, 0.0)
    try:
        return plan_from_items(mission.items, fence.items, home=home)
    except FenceItemsError as exc:
        raise SwarmError(f"sysid {sysid}: {exc}") from None
