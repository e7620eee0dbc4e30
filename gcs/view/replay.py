"""The flight report page's replay: a recorded flight as one JSON-ready document (pure: a recording in, a dict out).

Every drone is put on the metrics' common time grid (``GRID_HZ``, gcs/record/metrics.py) exactly as the metrics
resample it, so the page, interpolating linearly between grid instants, draws what the metrics assume between them:
the distance it computes between two drawn drones at any instant is the metrics' distance there, and the minimum over
the whole replay is ``min_separation_m`` of metrics.json. That minimum also holds the contacts the drones reported
("Collision with drone N at D m": a separation of D, the moment telemetry misses, docs/metrics.md), so the document
lists them, ``contacts``, as the metrics take them (between two simulated drones, the contact distance when the text
gives none), and the page folds each into its smallest separation so far from the instant it arrived. Per drone and
grid instant the document holds the position (null where the drone was not heard: the page keeps it where it was last
seen), its course over ground (the page's heading arrow: the recording holds no attitude), whether it counts as
airborne for separation (the metrics' definition, lost drones excluded), armed, its mode and its formation slot.
Colours follow the live view's states (gcs/view/scene.py), given as changes in time:

- ``lost`` from its loss until it was heard again (docs/drone-loss.md);
- ``failsafe`` from the failsafe the recorder saw it enter until it disarmed (PX4 ends a failsafe on the ground);
- ``avoiding`` from an "Avoidance: ..." text until "Avoidance ended ...";
- ``armed`` or ``disarmed``.

Vehicles the simulation did not run, attached to the swarm (docs/external.md), come apart under ``external``, in the
same form: where they said they were on the same grid (null where they were silent: the page keeps them where they
were last known), their slots (a member's), their role and link, and the state ``external``, or ``lost`` while
silent. They are drawn, not counted in the page's separation (the metrics count them apart: ``attached``).

Where the page opens, ``open_s``: the first grid instant at which every drone of the flight has a position (each
is drawn from its first, then kept where it was last seen). The timeline starts at the flight's first sample, but the
recorder hears the drones one by one as their telemetry starts, so at that instant it may know one drone of nine:
opening there shows "1 drone", frames the 3D camera on it and lists one row, while the whole swarm flew. Drawing each
drone, before it was first heard, where it was first heard would open on the whole swarm too, but at positions
nobody reported at that time, and a reader who finds a drone drawn must be able to trust it was there; so the page
opens on the first instant the whole swarm is known, and the timeline still reaches back to the first sample (scrub
or press play from it) with the drones not yet heard not drawn there. Attached vehicles do not count towards it:
they may join the swarm at any time (docs/external.md). Where it opens moves nothing: every drawn position is a
reported one, and the minimum separation above is over the whole timeline, from its first instant, which is the
metrics' (a drone not yet heard is no separation for them either).

Timeline marks are the flight's events: avoidance starts, collisions, failsafes, losses, drones heard again, injected
faults, what the swarm did about each loss, and the first violation of each invariant; the mission's steps are
bands.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from typing import Any, Final

import numpy as np
import numpy.typing as npt

from gcs.record.metrics import (
    AVOIDANCE_PREFIX,
    COLLISION_PREFIX,
    GRID_HZ,
    Resampled,
    flying_samples,
    resample_samples,
    swarm_contacts,
    time_grid,
)
from gcs.record.recording import DroneSample, FlightRecording
from gcs.view.scene import AVOIDANCE_END

DECIMALS: Final = 4  # 0.1 mm: rounding must not move the page's minimum separation off the metrics' (to 1e-3 m)
COURSE_MIN_SPEED_MPS: Final = 0.3  # slower than this, a drone's course over ground is noise: no heading is drawn
REPLAY_VERSION: Final = 2  # 2: ``open_s`` and ``contacts``

FloatArray = npt.NDArray[np.float64]


def _column(values: npt.ArrayLike, decimals: int = DECIMALS) -> list[float | None]:
    return [round(float(v), decimals) if math.isfinite(v) else None for v in np.asarray(values, dtype=float)]


def _latest_index(times_s: FloatArray, grid_s: FloatArray) -> npt.NDArray[np.intp]:
    """For each grid instant, the index of the latest sample at or before it (-1: none yet)."""
    return np.searchsorted(times_s, grid_s, side="right") - 1


def _changes(grid_s: FloatArray, states: Sequence[str]) -> list[list[Any]]:
    """Run-length form of a state per grid instant: [[time_s, state], ...] at each change."""
    out: list[list[Any]] = []
    for t, state in zip(grid_s, states, strict=True):
        if not out or out[-1][1] != state:
            out.append([round(float(t), 3), state])
    return out


def _intervals_lost(recording: FlightRecording, sysid: int) -> list[tuple[float, float]]:
    spans = {(loss.time_s, loss.regained_s if loss.regained_s is not None else math.inf)
             for loss in (*recording.losses, *recording.regained) if loss.sysid == sysid}  # fmt: skip
    return sorted(spans)


def _states(recording: FlightRecording, sysid: int, grid_s: FloatArray, armed: npt.NDArray[np.bool_]) -> list[str]:
    """The live view's state of drone ``sysid`` at every grid instant (module docstring)."""
    lost = np.zeros(grid_s.size, dtype=bool)
    for start, end in _intervals_lost(recording, sysid):
        lost |= (grid_s >= start) & (grid_s < end)
    failsafe = np.zeros(grid_s.size, dtype=bool)
    for event in recording.failsafes:
        if event.sysid == sysid:
            after = grid_s >= event.time_s
            disarmed_after = np.flatnonzero(after & ~armed)
            end = grid_s[disarmed_after[0]] if disarmed_after.size else math.inf
            failsafe |= after & (grid_s < end)
    avoiding = np.zeros(grid_s.size, dtype=bool)
    since: float | None = None  # the start of the avoidance episode in progress
    for event in sorted((e for e in recording.events if e.sysid == sysid), key=lambda e: e.time_s):
        if event.text.startswith(AVOIDANCE_END):
            if since is not None:
                avoiding |= (grid_s >= since) & (grid_s < event.time_s)
            since = None
        elif event.text.startswith(AVOIDANCE_PREFIX) and since is None:
            since = event.time_s
    if since is not None:
        avoiding |= grid_s >= since
    return [
        "lost" if lo else "failsafe" if fs else "avoiding" if av else "armed" if ar else "disarmed"
        for lo, fs, av, ar in zip(lost, failsafe, avoiding, armed, strict=True)
    ]


def _drone(recording: FlightRecording, sysid: int, samples: list[DroneSample], grid_s: FloatArray, drawn: Resampled,
           flying: Resampled | None, modes: list[str]) -> dict[str, Any]:  # fmt: skip
    times = np.array([s.time_s for s in samples])
    latest = _latest_index(times, grid_s)
    heard = latest >= 0
    at = np.clip(latest, 0, len(samples) - 1)
    armed = np.array([samples[i].armed for i in at]) & heard
    mode_index = {m: k for k, m in enumerate(modes)}
    vel = drawn.vel_ned_mps
    speed = np.hypot(vel[:, 0], vel[:, 1])
    course = np.where(speed >= COURSE_MIN_SPEED_MPS, np.degrees(np.arctan2(vel[:, 1], vel[:, 0])) % 360.0, np.nan)
    slot = drawn.target_ned_m
    return {
        "sysid": sysid,
        "north_m": _column(drawn.pos_ned_m[:, 0]),
        "east_m": _column(drawn.pos_ned_m[:, 1]),
        "down_m": _column(drawn.pos_ned_m[:, 2]),
        "course_deg": _column(course, 1),
        "airborne": [int(a) for a in (flying.airborne if flying is not None else np.zeros(grid_s.size, dtype=bool))],
        "armed": [int(a) for a in armed],
        "mode": [mode_index[samples[i].mode] if h else None for i, h in zip(at, heard, strict=True)],
        "slot_north_m": _column(slot[:, 0]),
        "slot_east_m": _column(slot[:, 1]),
        "slot_down_m": _column(slot[:, 2]),
        "home_ned_m": _column(samples[0].pos_ned_m),  # where it stood when first heard: its home at boot
        "states": _changes(grid_s, _states(recording, sysid, grid_s, armed)),
        "texts": [[round(e.time_s, 3), e.text] for e in recording.events if e.sysid == sysid],
    }


def _external(recording: FlightRecording, sysid: int, samples: list[DroneSample], grid_s: FloatArray,
              drawn: Resampled, modes: list[str]) -> dict[str, Any]:  # fmt: skip
    """An attached vehicle as the page draws it (module docstring)."""
    out = _drone(recording, sysid, samples, grid_s, drawn, None, modes)
    heard = np.all(np.isfinite(drawn.pos_ned_m), axis=1)
    role, link = recording.attached[sysid]
    out.update(role=role, link=link, states=_changes(grid_s, ["external" if h else "lost" for h in heard]), texts=[])
    return out


def _mark(time_s: float, sysid: int | None, kind: str, text: str) -> dict[str, Any]:
    return {"time_s": round(time_s, 3), "sysid": sysid, "kind": kind, "text": text}


def _marks(recording: FlightRecording) -> list[dict[str, Any]]:
    """The timeline's marks, in time order: {time_s, sysid, kind, text}."""
    marks = [
        _mark(e.time_s, e.sysid, "collision" if e.text.startswith(COLLISION_PREFIX) else "avoidance", e.text)
        for e in recording.events
        if e.text.startswith((COLLISION_PREFIX, AVOIDANCE_PREFIX))
    ]
    marks += [_mark(e.time_s, e.sysid, "failsafe", e.text) for e in recording.failsafes]
    marks += [_mark(loss.time_s, loss.sysid, "loss", loss.cause) for loss in recording.losses]
    marks += [_mark(loss.regained_s, loss.sysid, "regained", "heard again")
              for loss in recording.regained if loss.regained_s is not None]  # fmt: skip
    marks += [_mark(f.time_s, f.sysid, "fault", f"{f.fault}: {f.result}") for f in recording.faults]
    marks += [_mark(e.time_s, e.sysid, "policy", e.text) for e in recording.policy_events]
    marks += [_mark(v.time_s, v.sysids[0] if v.sysids else None, "violation", f"{v.name}: {v.detail}")
              for v in recording.violations]  # fmt: skip
    return sorted(marks, key=lambda m: (m["time_s"], m["sysid"] or 0))


def _contacts(recording: FlightRecording) -> list[dict[str, Any]]:
    """The drones' contacts as separations, those the metrics count in ``min_separation_m`` (module docstring)."""
    return [
        {"time_s": round(c.time_s, DECIMALS), "pair": list(c.pair), "distance_m": round(c.distance_m, DECIMALS)}
        for c in swarm_contacts(recording)
    ]


def opening_time(grid_s: FloatArray, drawn: Sequence[Resampled]) -> float | None:
    """The first grid instant at which every drone in ``drawn`` has had a position (module docstring: where the
    page opens); a drone never placed on the grid does not hold it back. None on an empty grid."""
    if not grid_s.size:
        return None
    firsts = [int(np.argmax(known)) for d in drawn if (known := np.all(np.isfinite(d.pos_ned_m), axis=1)).any()]
    return float(grid_s[max(firsts, default=0)])


def replay_document(recording: FlightRecording) -> dict[str, Any]:
    """The page's whole replay (module docstring). The page computes the separations itself, from the positions."""
    by_drone: dict[int, list[DroneSample]] = {}
    for sample in sorted(recording.samples, key=lambda s: s.time_s):
        by_drone.setdefault(sample.sysid, []).append(sample)
    times = [s.time_s for s in recording.samples]
    grid = time_grid(min(times), max(times)) if times else np.empty(0)
    drawn = resample_samples(recording.samples, grid)
    flying = resample_samples(flying_samples(recording), grid)
    modes = sorted({s.mode for s in (*recording.samples, *recording.attached_samples)})
    drones = [_drone(recording, sysid, by_drone[sysid], grid, drawn[sysid], flying.get(sysid), modes)
              for sysid in sorted(drawn)]  # fmt: skip
    by_vehicle: dict[int, list[DroneSample]] = {}
    for sample in sorted(recording.attached_samples, key=lambda s: s.time_s):
        by_vehicle.setdefault(sample.sysid, []).append(sample)
    there = resample_samples(recording.attached_samples, grid) if grid.size else {}
    external = [_external(recording, sysid, by_vehicle[sysid], grid, there[sysid], modes) for sysid in sorted(there)
                if sysid in recording.attached]  # fmt: skip
    opens = opening_time(grid, [drawn[sysid] for sysid in sorted(drawn)])
    return {
        "version": REPLAY_VERSION,
        "mission": recording.mission_name,
        "grid_hz": GRID_HZ,
        "time_s": _column(grid, 3),
        "open_s": None if opens is None else round(opens, 3),
        "modes": modes,
        "drones": drones,
        "external": external,
        "obstacles": [dataclasses.asdict(o) for o in recording.obstacles],
        "steps": [
            {"name": s.name, "kind": s.kind, "start_s": round(s.start_s, 3), "end_s": round(s.end_s, 3)}
            for s in recording.steps
        ],
        "marks": _marks(recording),
        "contacts": _contacts(recording),
    }
