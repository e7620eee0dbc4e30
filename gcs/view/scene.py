"""One frame of the live view, built from what the ground station knows (pure: inputs in, a JSON-ready dict out).

Everything comes from MAVLink telemetry as the fleet view holds it (never simulation truth), in the swarm frame:
north-east-down metres from the swarm origin, so the page draws north up, as QGroundControl's map. A drone's state,
which the page shows as its colour, is the first that applies of:

- ``lost``: the swarm has lost it (process ended, crashed, silent: docs/drone-loss.md);
- ``external``: a vehicle the simulation does not run, attached to the swarm (docs/external.md), drawn where its
  GLOBAL_POSITION_INT says;
- ``failsafe``: its HEARTBEAT says MAV_STATE_CRITICAL (a failsafe in force);
- ``avoiding``: its latest avoidance text is a start ("Avoidance: ..."), not an end ("Avoidance ended ...");
- ``armed`` or ``disarmed``.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterable, Mapping
from typing import Any, Final

from gcs.fleet.telemetry import DroneView
from gcs.missions.mission_file import ObstacleSpec
from gcs.record.metrics import AVOIDANCE_PREFIX
from gcs.record.recording import ObstacleShape

MAV_STATE_CRITICAL: Final = 5
AVOIDANCE_END: Final = "Avoidance ended"
DECIMALS: Final = 3  # millimetres: the frame's size, not its precision, is what costs


def obstacle_shape(spec: ObstacleSpec) -> ObstacleShape:
    """A mission's obstacle as the page draws it."""
    if spec.cylinder:
        return ObstacleShape(kind="cylinder", north_m=spec.north_m, east_m=spec.east_m, radius_m=spec.radius_m,
                             height_m=spec.height_m)  # fmt: skip
    return ObstacleShape(kind="sphere", north_m=spec.north_m, east_m=spec.east_m, radius_m=spec.radius_m,
                         height_m=spec.alt_m)  # fmt: skip


def drone_state(view: DroneView, lost: bool) -> str:
    """The state the page colours the drone by (module docstring)."""
    if lost:
        return "lost"
    if view.system_status == MAV_STATE_CRITICAL:
        return "failsafe"
    for _time, _severity, text in reversed(view.texts):
        if text.startswith(AVOIDANCE_END):
            break
        if text.startswith(AVOIDANCE_PREFIX):
            return "avoiding"
    return "armed" if view.armed else "disarmed"


def _round(values: Iterable[float]) -> list[float | None]:
    return [round(v, DECIMALS) if math.isfinite(v) else None for v in values]


def frame(*, time_s: float, drones: Mapping[int, DroneView], positions_ned_m: Mapping[int, tuple[float, float, float]],
          homes_ned_m: Mapping[int, tuple[float, float, float]], slots_ned_m: Mapping[int, tuple[float, float, float]],
          lost: Iterable[int], now_s: float, separation_m: float | None, min_separation_m: float | None,
          realtime_factor: float | None, obstacles: Iterable[ObstacleShape] = (),
          external: Iterable[int] = ()) -> dict[str, Any]:  # fmt: skip
    """The frame for ``time_s`` (mission time); ``now_s`` is the swarm's clock, for link ages. Drones without a
    position in the swarm frame yet (no home) are listed with a null position."""
    gone = set(lost)
    outside = set(external)
    out = []
    for sysid in sorted(drones):
        view = drones[sysid]
        pos = positions_ned_m.get(sysid)
        slot = slots_ned_m.get(sysid)
        home = homes_ned_m.get(sysid)
        out.append(
            {
                "sysid": sysid,
                "pos_ned_m": _round(pos) if pos is not None else None,
                "vel_ned_mps": _round(view.vel_ned_mps),
                "heading_deg": round(view.heading_deg, 1) if math.isfinite(view.heading_deg) else None,
                "alt_m": round(-pos[2], DECIMALS) if pos is not None and math.isfinite(pos[2]) else None,
                "home_ned_m": _round(home) if home is not None else None,
                "slot_ned_m": _round(slot) if slot is not None else None,
                "mode": view.mode,
                "armed": view.armed,
                "state": "external" if sysid in outside and sysid not in gone else drone_state(view, sysid in gone),
                "battery": round(view.battery_remaining, 3) if math.isfinite(view.battery_remaining) else None,
                "link_age_s": round(max(view.link_age_s(now_s), 0.0), 2),
                "text": view.texts[-1][2] if view.texts else None,
            }
        )
    return {
        "time_s": round(time_s, 3),
        "drones": out,
        "separation_m": round(separation_m, DECIMALS) if separation_m is not None else None,
        "min_separation_m": round(min_separation_m, DECIMALS) if min_separation_m is not None else None,
        "realtime_factor": round(realtime_factor, 3) if realtime_factor is not None else None,
        "obstacles": [dataclasses.asdict(o) for o in obstacles],
    }
