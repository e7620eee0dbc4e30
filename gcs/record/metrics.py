"""Flight metrics: the numbers a flight report states and acceptance tests check, computed from a FlightRecording.

Pure functions of the recording (numpy, no IO), so the report, the acceptance tests and any later analysis agree on
one definition of each number. The definitions below are the contract; thresholds are module constants.

Conventions
    Times are seconds on the recording's clock (mission start = 0). Positions are swarm-frame NED metres; altitude is
    ``-down``. Distances are 3D Euclidean.

Resampling
    Each drone's samples are sorted by time. Positions are interpolated linearly between consecutive samples; the
    armed flag and the commanded slot are held from the latest sample at or before the instant. A drone is *present*
    at an instant between its first and last sample unless the two samples around it are more than ``MAX_GAP_S``
    apart (lost telemetry: no position is invented across the gap). The common grid is every multiple of
    ``1 / GRID_HZ`` seconds from the first to the last sample of the recording.

Airborne
    A drone's ground level is the lowest point (largest ``down``) among its disarmed samples, or the swarm origin
    (``down = 0``) if it was never recorded disarmed. A drone is *airborne* when it is present, armed and more than
    ``AIRBORNE_HEIGHT_M`` above its ground level.

``min_separation_m``, ``min_separation_time_s``, ``min_separation_pair``
    The closest two drones came, from two sources, whichever is smaller:
    - the telemetry: for every pair of drones airborne at a grid instant, the 3D distance between their interpolated
      positions. The ``separation`` series is, per grid instant, the minimum over those pairs (null when fewer than
      two drones are airborne). Between two consecutive grid instants at which a pair is airborne the pair's relative
      position is taken as linear, so a pass between grid instants is found, not only its nearest grid instant. What
      this can miss: the drones' curvature within one grid interval (the relative path is a chord), their estimate's
      error (it is what the drones reported), and anything after a drone left the pairs (it touched down, was lost,
      or fell silent for more than ``MAX_GAP_S``). At a relative speed v a pass is found within about v / GRID_HZ of
      its true distance, plus the estimates' error (docs/metrics.md, "The minimum separation").
    - the contacts: every "Collision with drone N at D m" a simulated drone reported (its world's check, at physics
      rate, of the true positions) is a separation of D between the two (the contact distance,
      ``collision_radius_m``, when the text gives none) at the instant the report arrived. A drone that touched
      another crashes and leaves the pairs within a sample or two, so telemetry alone would miss the contact; with
      it, a flight with a contact never reports a minimum above the contact distance.
    Null when no two drones are ever airborne together and none touched. The series holds the telemetry alone.

``attached``
    Per vehicle the simulation did not run (docs/external.md), by sysid: its ``role`` and ``link``, and its closest
    approach to an airborne simulated drone (``min_separation_m``, ``min_separation_time_s``, ``closest_drone``),
    from its own position reports, resampled and searched between grid instants as ``min_separation_m``, and from a
    drone's contact with it, as the drones' contacts count; it counts as there whenever it reported, flying or not.
    Its contacts are among ``collisions``. A member's distance to its slots over the settled part of every formation
    step (from the instant the drones settled, ``time_to_formation_s``, to the step's end): ``slot_rms_m`` and
    ``max_slot_error_m``; null when it held no slot in a settled formation.

``invariants``, ``violations``
    The flight's invariants (docs/invariants.md), each as it describes itself, and the first violation of each one
    violated, in time order: its ``name``, ``kind``, ``time_s`` (mission time), the ``sysids`` involved and a
    ``detail`` saying what was seen.

``collisions``, ``collision_events``, ``avoidance_events``, ``avoidance_starts``, ``avoidance_closest_approach_m``
    The number of the recording's events whose text starts with "Collision" (listed in ``collision_events``); the
    number of onboard avoidance episodes (events starting "Avoidance:", one when a drone starts correcting, each
    saying why: the body, its predicted closest approach and when; listed in ``avoidance_starts``), and the
    smallest "closest approach" any drone reported at the end of an episode ("Avoidance ended: closest approach
    1.34 m"; the drone's own perception, centre to centre; null when no episode ended).

``takeoff_time_s``, ``takeoff_time_per_drone_s``
    For the first step of kind "takeoff" that has a target altitude: for each drone with a sample inside the step,
    the time from the step's start until the drone's altitude is within ``TAKEOFF_TOLERANCE_M`` of the target and
    stays within it until the step's end (altitude linear between samples, the crossing into the band interpolated).
    Null for a drone outside the band at the step's end. ``takeoff_time_s`` is the maximum over drones (null if any
    drone is null or none flew). Every takeoff step also carries its own values in ``steps``.

``mission_items_reached``
    Per drone that flew a mission (a plan step, ``swarm plan start``), each MISSION_ITEM_REACHED it sent, in order:
    ``seq`` and ``time_s`` (a repeated report of the same arrival counted once).

``steps``
    One entry per step: ``index, name, kind, start_s, end_s`` (and ``arrival_s`` for a formation flown through a
    planned transition), and, when drones had a commanded slot during the step:
    - swarm error e(t) at a grid instant in [start_s, end_s) (at end_s the next step's command is in force): the
      root mean square, over the present drones with a commanded slot, of the 3D distance between position and slot;
      a slot counts only if held from a sample inside the step (not the previous step's command, still held for
      a few milliseconds after the boundary);
    - ``time_to_formation_s``: from the step's start to the earliest instant from which e(t) stays at or below
      ``FORMATION_SETTLED_RMS_M`` until the step's end (crossing interpolated between grid instants; resolution
      ``1 / GRID_HZ``, counted from the step's first grid instant with a slot), and not before the step's planned
      arrival (``arrival_s``: a formation's synchronised transition puts every drone's setpoint on its slot then;
      before it a drone on its way counts as off its slot though e(t) may already be below the bound); null if e(t)
      is above it at the step's last grid instant;
    - ``formation_rms_m``: sqrt of the mean of e(t)^2 over the grid instants of the settled part (from the settled
      instant to the step's end), i.e. the RMS over time and drones once in formation; null if never settled;
    - ``max_error_m``: the largest single drone's distance to its slot over the settled part; null if never settled;
    - ``step_rms_m``: like ``formation_rms_m`` but over the whole step (includes the transition).
    ``FORMATION_SETTLED_RMS_M`` is deliberately looser than typical acceptance limits on ``formation_rms_m`` (the
    settled part only contains e(t) at or below it, so a limit equal to it would be met by construction).

``alignment`` (steps of kind "flock")
    The velocity alignment order parameter ``phi(t) = |sum_i v_i| / sum_i |v_i|`` over the airborne drones at a grid
    instant in [start_s, end_s), with ``v_i`` the drone's horizontal velocity (interpolated like positions; the
    vertical velocity is altitude-hold noise, not the flock's motion). 1 when every drone flies the same way, about
    ``1 / sqrt(n)`` for random directions. Undefined (null) with fewer than two airborne drones or a mean horizontal
    speed below ``ALIGNMENT_MIN_SPEED_MPS``: a hovering swarm has no direction to agree on.
    - ``converged_time_s``: from the step's start to the first grid instant with ``phi >= ALIGNMENT_CONVERGED``;
      null if never;
    - ``mean``, ``min``: of phi over the defined grid instants from that instant to the step's end (after
      convergence; later dips count); null if never converged;
    - ``time_s``, ``phi``: the series over the step.
    ``ALIGNMENT_CONVERGED`` is deliberately looser than typical acceptance limits on ``mean``.

``duration_s``, ``n_drones``, ``sysids``, ``distance_flown_m``
    ``duration_s`` runs from the earliest to the latest of all sample times and step boundaries. ``n_drones`` is the
    recording's configured count; ``sysids`` those that reported. ``distance_flown_m`` per drone is the length of the
    polyline through its raw samples while armed (segments with both ends armed; a segment across a telemetry gap
    counts as a straight line, a lower bound). Estimator noise adds to it, as to any path length.

``requested_speed``, ``realtime_factor_min``, ``realtime_factor_mean``
    Paced flights only (null in lockstep): the speed factor asked for, and the slowest and mean of the drones'
    achieved real-time factor as the supervisor measured it at each status line (the slowest drone's own clock
    against the wall clock over 5 s, gcs/fleet/pace_monitor.py). Below 90 % of the request the summary flags the flight:
    the mission's timing, which follows the wall clock, ran ahead of the drones.

``LiveMetrics`` gives the same quantities approximately while flying, for a status line: it keeps the latest sample
per drone and compares drones at the newest sample's time (older positions extrapolated with their velocity); it also
gives phi of the latest velocities when defined.
"""

from __future__ import annotations

import math
import re
from collections.abc import Collection, Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from gcs.fleet.losses import DroneLoss
from gcs.invariants.monitor import Violation
from gcs.mavlink.statustext import COLLISION_PREFIX, parse_contact
from gcs.record.recording import DroneSample, EventRecord, FaultRecord, FlightRecording, ItemReached, StepRecord

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]

GRID_HZ = 10.0  # common time grid for comparing drones
MAX_GAP_S = 1.0  # samples further apart than this: the drone is unknown in between
AIRBORNE_HEIGHT_M = 0.5  # above ground level; below it a drone counts as on the ground
TAKEOFF_TOLERANCE_M = 0.2  # altitude band around the takeoff target
FORMATION_SETTLED_RMS_M = 0.5  # swarm RMS error at or below which the formation counts as reached
ALIGNMENT_CONVERGED = 0.8  # phi from which a flock counts as aligned
ALIGNMENT_MIN_SPEED_MPS = 0.2  # mean horizontal speed below which phi is undefined
ALIGNMENT_STEP_KINDS = frozenset({"flock"})
AVOIDANCE_PREFIX = "Avoidance:"
AVOIDANCE_CLOSEST = re.compile(r"^Avoidance ended: closest approach ([0-9.]+) m")

_SCALAR_DECIMALS = 4  # 0.1 mm / 0.1 ms in metrics.json
_SERIES_DECIMALS = 3


@dataclass(frozen=True, slots=True, kw_only=True, eq=False)
class AlignmentMetrics:
    """Velocity alignment of a flock step (module docstring); phi NaN where undefined."""

    converged_time_s: float | None
    mean: float | None
    min: float | None
    time_s: FloatArray
    phi: FloatArray


@dataclass(frozen=True, slots=True, kw_only=True)
class StepMetrics:
    index: int
    name: str
    kind: str
    start_s: float
    end_s: float
    time_to_formation_s: float | None
    formation_rms_m: float | None
    max_error_m: float | None
    step_rms_m: float | None
    target_alt_m: float | None = None
    arrival_s: float | None = None  # formation steps: the planned transition's arrival
    takeoff_time_s: float | None = None  # takeoff steps only
    takeoff_time_per_drone_s: dict[int, float | None] = field(default_factory=dict)
    alignment: AlignmentMetrics | None = None  # flock steps only


@dataclass(frozen=True, slots=True, kw_only=True)
class SeparationSeries:
    """Minimum pairwise separation of airborne drones on the common grid; NaN where fewer than two are airborne."""

    time_s: FloatArray
    min_separation_m: FloatArray


@dataclass(frozen=True, slots=True, kw_only=True)
class FlightMetrics:
    mission_name: str
    n_drones: int
    sysids: tuple[int, ...]
    duration_s: float
    collision_radius_m: float
    min_separation_m: float | None
    min_separation_time_s: float | None
    min_separation_pair: tuple[int, int] | None
    collisions: int
    collision_events: tuple[EventRecord, ...]
    avoidance_events: int
    avoidance_closest_approach_m: float | None
    takeoff_time_s: float | None
    takeoff_time_per_drone_s: dict[int, float | None]
    steps: tuple[StepMetrics, ...]
    distance_flown_m: dict[int, float]
    separation: SeparationSeries
    loss_policy: str = "continue"
    losses: tuple[DroneLoss, ...] = ()
    regained: tuple[DroneLoss, ...] = ()  # silent drones heard again and taken back
    faults: tuple[FaultRecord, ...] = ()
    failsafes: tuple[EventRecord, ...] = ()
    policy_events: tuple[EventRecord, ...] = ()
    requested_speed: float | None = None  # paced flights only
    avoidance_starts: tuple[EventRecord, ...] = ()  # each episode's first text, in time order
    signing_key_id: str | None = None  # MAVLink signing: the key's id (not the key) when on, None when off
    neighbours: str = "relay"  # how neighbours' positions travelled: relay, mesh (with its range), both, none
    link_counters: dict[str, dict[str, float]] = field(default_factory=dict)  # the link model's counts by channel
    realtime_factor_min: float | None = None  # the drones' achieved pace, over 5 s windows
    realtime_factor_mean: float | None = None
    items_reached: tuple[ItemReached, ...] = ()
    attached: dict[int, AttachedMetrics] = field(default_factory=dict)  # vehicles the simulation did not run
    invariants: tuple[str, ...] = ()  # the flight's invariants, as each describes itself
    violations: tuple[Violation, ...] = ()  # the first violation of each violated invariant, in time order

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready: fixed key order, rounded floats, None for undefined values, drone keys as strings."""
        return {
            "mission": self.mission_name,
            "n_drones": self.n_drones,
            "sysids": list(self.sysids),
            "duration_s": _r(self.duration_s),
            "collision_radius_m": _r(self.collision_radius_m),
            "min_separation_m": _r(self.min_separation_m),
            "min_separation_time_s": _r(self.min_separation_time_s),
            "min_separation_pair": list(self.min_separation_pair) if self.min_separation_pair else None,
            "collisions": self.collisions,
            "collision_events": [
                {"time_s": _r(e.time_s), "sysid": e.sysid, "text": e.text} for e in self.collision_events
            ],
            "avoidance_events": self.avoidance_events,
            "avoidance_starts": [
                {"time_s": _r(e.time_s), "sysid": e.sysid, "text": e.text} for e in self.avoidance_starts
            ],
            "avoidance_closest_approach_m": _r(self.avoidance_closest_approach_m),
            "takeoff_time_s": _r(self.takeoff_time_s),
            "takeoff_time_per_drone_s": {str(k): _r(v) for k, v in self.takeoff_time_per_drone_s.items()},
            "steps": [_step_dict(s) for s in self.steps],
            "distance_flown_m": {str(k): _r(v) for k, v in self.distance_flown_m.items()},
            "loss_policy": self.loss_policy,
            "losses": [_loss_dict(x) for x in self.losses],
            "regained": [_loss_dict(x) for x in self.regained],
            "faults": [
                {"time_s": _r(f.time_s), "sysid": f.sysid, "fault": f.fault, "result": f.result} for f in self.faults
            ],
            "failsafes": [{"time_s": _r(e.time_s), "sysid": e.sysid, "text": e.text} for e in self.failsafes],
            "loss_policy_actions": [
                {"time_s": _r(e.time_s), "sysid": e.sysid, "text": e.text} for e in self.policy_events
            ],
            "requested_speed": _r(self.requested_speed),
            "signing": {"on": self.signing_key_id is not None, "key_id": self.signing_key_id},
            "neighbours": self.neighbours,
            "links": {name: link_summary(c) for name, c in self.link_counters.items()},
            "realtime_factor_min": _r(self.realtime_factor_min),
            "realtime_factor_mean": _r(self.realtime_factor_mean),
            "attached": {str(sysid): _attached_dict(a) for sysid, a in self.attached.items()},
            "invariants": list(self.invariants),
            "violations": [
                {"name": v.name, "kind": v.kind, "time_s": _r(v.time_s), "sysids": list(v.sysids), "detail": v.detail}
                for v in self.violations
            ],
            "mission_items_reached": {
                str(sysid): [{"seq": r.seq, "time_s": _r(r.time_s)} for r in self.items_reached if r.sysid == sysid]
                for sysid in sorted({r.sysid for r in self.items_reached})
            },
            "parameters": {
                "grid_hz": GRID_HZ,
                "max_gap_s": MAX_GAP_S,
                "airborne_height_m": AIRBORNE_HEIGHT_M,
                "takeoff_tolerance_m": TAKEOFF_TOLERANCE_M,
                "formation_settled_rms_m": FORMATION_SETTLED_RMS_M,
                "alignment_converged": ALIGNMENT_CONVERGED,
                "alignment_min_speed_mps": ALIGNMENT_MIN_SPEED_MPS,
            },
            "separation": {
                "time_s": [_r(t, _SERIES_DECIMALS) for t in self.separation.time_s.tolist()],
                "min_separation_m": [_r(d, _SERIES_DECIMALS) for d in self.separation.min_separation_m.tolist()],
            },
        }


def _attached_dict(a: AttachedMetrics) -> dict[str, Any]:
    return {
        "role": a.role,
        "link": a.link,
        "min_separation_m": _r(a.min_separation_m),
        "min_separation_time_s": _r(a.min_separation_time_s),
        "closest_drone": a.closest_drone,
        "slot_rms_m": _r(a.slot_rms_m),
        "max_slot_error_m": _r(a.max_slot_error_m),
    }


def _loss_dict(loss: DroneLoss) -> dict[str, Any]:
    down = [_r(v) for v in loss.down_ne_m] if loss.down_ne_m is not None else None
    out = {"sysid": loss.sysid, "time_s": _r(loss.time_s), "cause": loss.cause, "down_ne_m": down}
    if loss.regained_s is not None:
        out["regained_s"] = _r(loss.regained_s)
    return out


def link_summary(counts: dict[str, float]) -> dict[str, Any]:
    """One channel's counts with the rates a reader wants: the share of frames lost, the mean delay."""
    offered = counts.get("frames_offered", 0.0)
    lost = counts.get("frames_lost", 0.0)
    delayed = counts.get("delayed", 0.0)
    delivered = offered - lost
    out: dict[str, Any] = {
        "frames_offered": int(offered),
        "frames_lost": int(lost),
        "loss_rate": _r(lost / offered) if offered else None,
        "frames_delayed": int(delayed),
        "mean_delay_ms": _r(1000.0 * counts.get("total_delay_s", 0.0) / delivered) if delivered else None,
    }
    # The drone-to-drone mesh (docs/links.md "Mesh") says why each report was not heard, and what the neighbour
    # tables took from each source.
    for key in MESH_DETAIL_KEYS:
        if key in counts:
            out[key] = int(counts[key])
    return out


MESH_DETAIL_KEYS = ("frames_delivered", "lost_range", "lost_path", "lost_model", "lost_overrun", "relay_updates",
                    "link_updates", "mesh_updates")  # fmt: skip


def _step_dict(step: StepMetrics) -> dict[str, Any]:
    out: dict[str, Any] = {
        "index": step.index,
        "name": step.name,
        "kind": step.kind,
        "start_s": _r(step.start_s),
        "end_s": _r(step.end_s),
        "time_to_formation_s": _r(step.time_to_formation_s),
        "formation_rms_m": _r(step.formation_rms_m),
        "max_error_m": _r(step.max_error_m),
        "step_rms_m": _r(step.step_rms_m),
    }
    if step.arrival_s is not None:
        out["arrival_s"] = _r(step.arrival_s)
    if step.kind == "takeoff":
        out["target_alt_m"] = _r(step.target_alt_m)
        out["takeoff_time_s"] = _r(step.takeoff_time_s)
        out["takeoff_time_per_drone_s"] = {str(k): _r(v) for k, v in step.takeoff_time_per_drone_s.items()}
    if step.alignment is not None:
        a = step.alignment
        out["alignment"] = {
            "converged_time_s": _r(a.converged_time_s),
            "mean": _r(a.mean),
            "min": _r(a.min),
            "time_s": [_r(t, _SERIES_DECIMALS) for t in a.time_s.tolist()],
            "phi": [_r(v, _SERIES_DECIMALS) for v in a.phi.tolist()],
        }
    return out


def _r(value: float | None, decimals: int = _SCALAR_DECIMALS) -> float | None:
    if value is None or not math.isfinite(value):
        return None
    return round(float(value), decimals)


# --- one drone's samples as arrays -----------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class _Track:
    sysid: int
    time_s: FloatArray  # (n,) sorted
    pos_ned_m: FloatArray  # (n, 3)
    vel_ned_mps: FloatArray  # (n, 3)
    armed: BoolArray  # (n,)
    target_ned_m: FloatArray  # (n, 3), NaN where no slot was commanded
    ground_down_m: float


def _tracks(samples: Iterable[DroneSample]) -> dict[int, _Track]:
    by_sysid: dict[int, list[DroneSample]] = {}
    for sample in samples:
        by_sysid.setdefault(sample.sysid, []).append(sample)
    tracks = {}
    for sysid in sorted(by_sysid):
        ordered = sorted(by_sysid[sysid], key=lambda s: s.time_s)
        pos = np.array([s.pos_ned_m for s in ordered], dtype=float).reshape(-1, 3)
        armed = np.array([s.armed for s in ordered], dtype=bool)
        target = np.array(
            [s.target_ned_m if s.target_ned_m is not None else (math.nan,) * 3 for s in ordered], dtype=float
        ).reshape(-1, 3)
        disarmed_down = pos[~armed, 2]
        tracks[sysid] = _Track(
            sysid=sysid,
            time_s=np.array([s.time_s for s in ordered], dtype=float),
            pos_ned_m=pos,
            vel_ned_mps=np.array([s.vel_ned_mps for s in ordered], dtype=float).reshape(-1, 3),
            armed=armed,
            target_ned_m=target,
            ground_down_m=float(disarmed_down.max()) if disarmed_down.size else 0.0,
        )
    return tracks


@dataclass(frozen=True, slots=True)
class Resampled:
    pos_ned_m: FloatArray  # (T, 3), NaN where not present
    vel_ned_mps: FloatArray  # (T, 3), NaN where not present
    airborne: BoolArray  # (T,)
    target_ned_m: FloatArray  # (T, 3), NaN where not present or no slot
    target_since_s: FloatArray  # (T,) time of the sample the slot is held from


def _resample(track: _Track, grid_s: FloatArray) -> Resampled:
    t = track.time_s
    n = t.size
    last = np.searchsorted(t, grid_s, side="right") - 1  # latest sample at or before each instant
    i0 = np.clip(last, 0, n - 1)
    i1 = np.clip(last + 1, 0, n - 1)
    span = t[i1] - t[i0]
    present = (last >= 0) & (grid_s <= t[-1]) & (span <= MAX_GAP_S)
    frac = np.divide(grid_s - t[i0], span, out=np.zeros_like(grid_s), where=span > 0)
    pos = track.pos_ned_m[i0] + frac[:, None] * (track.pos_ned_m[i1] - track.pos_ned_m[i0])
    pos[~present] = np.nan
    vel = track.vel_ned_mps[i0] + frac[:, None] * (track.vel_ned_mps[i1] - track.vel_ned_mps[i0])
    vel[~present] = np.nan
    target = track.target_ned_m[i0].copy()
    target[~present] = np.nan
    airborne = present & track.armed[i0] & (track.ground_down_m - pos[:, 2] > AIRBORNE_HEIGHT_M)
    return Resampled(pos_ned_m=pos, vel_ned_mps=vel, airborne=airborne, target_ned_m=target, target_since_s=t[i0])


def resample_samples(samples: Iterable[DroneSample], grid_s: FloatArray) -> dict[int, Resampled]:
    """Each drone's samples on the grid ``grid_s``, by sysid, as the metrics see them (linear between samples, absent
    across gaps of more than MAX_GAP_S, airborne as defined above). The flight report's replay draws from this, so
    that what it shows between two grid instants is what the metrics assume there."""
    return {sysid: _resample(track, grid_s) for sysid, track in _tracks(samples).items()}


def time_grid(start_s: float, end_s: float, rate_hz: float = GRID_HZ) -> FloatArray:
    """Every multiple of 1/rate_hz in [start_s, end_s] (aligned to the clock's zero, so grids of one clock agree)."""
    first = math.ceil(start_s * rate_hz - 1e-9)
    last = math.floor(end_s * rate_hz + 1e-9)
    return np.arange(first, last + 1, dtype=float) / rate_hz


# --- separation -----------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class ClosestPair:
    """Two drones at their closest: from the telemetry, or a contact one of them reported (``pair`` in order)."""

    distance_m: float
    time_s: float
    pair: tuple[int, int]


def _separation(
    grid_s: FloatArray, sysids: Sequence[int], resampled: Sequence[Resampled]
) -> tuple[FloatArray, ClosestPair | None]:
    n_t = grid_s.size
    pos = _airborne_positions(grid_s, resampled)
    series = np.full(n_t, np.inf)
    best: ClosestPair | None = None
    for i in range(len(sysids) - 1):
        rel = pos[:, i : i + 1, :] - pos[:, i + 1 :, :]  # (T, others, 3), NaN unless both airborne
        dist = np.linalg.norm(rel, axis=2)
        series = np.fmin(series, np.where(np.isnan(dist), np.inf, dist).min(axis=1))
        found = _closest_approach(grid_s, rel)
        if found is not None and (best is None or found[0] < best.distance_m):
            best = ClosestPair(distance_m=found[0], time_s=found[1], pair=(sysids[i], sysids[i + 1 + found[2]]))
    series[np.isinf(series)] = np.nan
    return series, best


def drone_contacts(events: Iterable[EventRecord], contact_distance_m: float) -> list[ClosestPair]:
    """Every contact between two drones the recording's events report, as a separation (module docstring): the
    distance the text gives, else the contact distance, at the instant the report arrived, each pair once."""
    out: dict[tuple[int, int], ClosestPair] = {}
    for event in events:
        contact = parse_contact(event.text)
        if contact is None or contact.drone is None or event.sysid is None or contact.drone == event.sysid:
            continue
        pair = (min(event.sysid, contact.drone), max(event.sysid, contact.drone))
        distance = contact.distance_m if contact.distance_m is not None else contact_distance_m
        if pair not in out or distance < out[pair].distance_m:
            out[pair] = ClosestPair(distance_m=distance, time_s=event.time_s, pair=pair)
    return sorted(out.values(), key=lambda c: c.time_s)


def swarm_contacts(recording: FlightRecording) -> list[ClosestPair]:
    """``drone_contacts`` between two simulated drones (those in ``min_separation_m``; a contact with an attached
    vehicle counts in its own ``attached`` entry)."""
    contacts = drone_contacts(recording.events, recording.collision_radius_m)
    return [c for c in contacts if not set(c.pair) & set(recording.attached)]


def _closer(found: ClosestPair | None, contacts: Iterable[ClosestPair]) -> ClosestPair | None:
    """The smallest of a telemetry minimum and the contacts (the earlier on a tie)."""
    for contact in contacts:
        if found is None or contact.distance_m < found.distance_m:
            found = contact
    return found


def _airborne_positions(grid_s: FloatArray, resampled: Sequence[Resampled]) -> FloatArray:
    """(T, drones, 3): each drone's position at each grid instant where it is airborne, NaN elsewhere."""
    pos = np.full((grid_s.size, len(resampled), 3), np.nan)
    for k, r in enumerate(resampled):
        pos[r.airborne, k] = r.pos_ned_m[r.airborne]
    return pos


def _closest_approach(grid_s: FloatArray, rel: FloatArray) -> tuple[float, float, int] | None:
    """The smallest of the relative distances ``rel`` (T, others, 3; NaN where a pair is not both there) over every
    grid instant and the closest approach of the linear relative motion between two consecutive instants:
    (distance, time, index of the other), or None when no pair is ever there."""
    dist = np.linalg.norm(rel, axis=2)
    r0, dr = rel[:-1], rel[1:] - rel[:-1]
    dr2 = np.einsum("tpk,tpk->tp", dr, dr)
    s = np.clip(np.divide(-np.einsum("tpk,tpk->tp", r0, dr), dr2, out=np.zeros_like(dr2), where=dr2 > 0), 0, 1)
    candidates = np.concatenate([dist, np.linalg.norm(r0 + s[..., None] * dr, axis=2)])
    times = np.concatenate(
        [np.broadcast_to(grid_s[:, None], dist.shape), grid_s[:-1, None] + s * np.diff(grid_s)[:, None]]
    )
    if np.all(np.isnan(candidates)):
        return None
    t_idx, other = np.unravel_index(np.nanargmin(candidates), candidates.shape)
    return float(candidates[t_idx, other]), float(times[t_idx, other]), int(other)


@dataclass(frozen=True, slots=True, kw_only=True)
class AttachedMetrics:
    """An attached vehicle (docs/external.md) as the flight saw it: its closest approach to an airborne simulated
    drone (3D, centre to centre; between grid instants as ``min_separation_m``), when and to which drone; None when
    it was never there while a drone flew."""

    role: str
    link: str
    min_separation_m: float | None
    min_separation_time_s: float | None
    closest_drone: int | None
    # a member: its distance to its slot over the settled part of every formation step (as ``formation_rms_m``, the
    # settled instant the drones'), RMS and largest; None when it held no slot in a settled formation
    slot_rms_m: float | None = None
    max_slot_error_m: float | None = None


def _attached_metrics(
    recording: FlightRecording,
    grid_s: FloatArray,
    sysids: Sequence[int],
    resampled: Sequence[Resampled],
    steps: Sequence[StepMetrics],
    contacts: Sequence[ClosestPair],
) -> dict[int, AttachedMetrics]:
    """Each attached vehicle's closest approach to the simulated drones (it counts as there whenever it reported,
    flying or not: a real vehicle standing on the field is an obstacle too; a drone's contact with it counts as the
    drones' do), and a member's slot error."""
    out: dict[int, AttachedMetrics] = {}
    drones = _airborne_positions(grid_s, resampled)
    for sysid, (role, link) in sorted(recording.attached.items()):
        samples = [x for x in recording.attached_samples if x.sysid == sysid]
        found = None
        slot_errors = np.empty(0)
        if samples and grid_s.size:
            (track,) = _tracks(samples).values()
            resampled_track = _resample(track, grid_s)
            there = resampled_track.pos_ned_m  # (T, 3), NaN where it did not report
            approach = _closest_approach(grid_s, there[:, None, :] - drones)
            if approach is not None:
                found = ClosestPair(distance_m=approach[0], time_s=approach[1], pair=(sysid, sysids[approach[2]]))
            slot_errors = _settled_slot_errors(resampled_track, grid_s, steps)
        touched = [
            ClosestPair(distance_m=c.distance_m, time_s=c.time_s, pair=(sysid, c.pair[1 - c.pair.index(sysid)]))
            for c in contacts
            if sysid in c.pair and not set(c.pair) & (set(recording.attached) - {sysid})
        ]
        found = _closer(found, touched)
        out[sysid] = AttachedMetrics(
            role=role, link=link, min_separation_m=found.distance_m if found else None,
            min_separation_time_s=found.time_s if found else None, closest_drone=found.pair[1] if found else None,
            slot_rms_m=float(np.sqrt(np.mean(slot_errors**2))) if slot_errors.size else None,
            max_slot_error_m=float(slot_errors.max()) if slot_errors.size else None,
        )  # fmt: skip
    return out


def _settled_slot_errors(track: Resampled, grid_s: FloatArray, steps: Sequence[StepMetrics]) -> FloatArray:
    """A vehicle's distances to its slots at the grid instants of every formation step's settled part (from the
    instant the drones settled to the step's end, slots commanded in the step), NaN-free."""
    out = []
    for step in steps:
        if step.time_to_formation_s is None:
            continue
        settled = (grid_s >= step.start_s + step.time_to_formation_s - 1e-9) & (grid_s < step.end_s - 1e-9)
        settled &= track.target_since_s >= step.start_s - 1e-9
        error = np.linalg.norm(track.pos_ned_m[settled] - track.target_ned_m[settled], axis=1)
        out.append(error[np.isfinite(error)])
    return np.concatenate(out) if out else np.empty(0)


# --- alignment --------------------------------------------------------------------------------------------------


def alignment_order_parameter(vel_ne_mps: npt.ArrayLike) -> FloatArray:
    """phi = |sum v_i| / sum |v_i| over the drones (axis -2) of horizontal velocities shaped (..., n, 2).

    Rows with a NaN are absent drones. NaN where fewer than two are present or their mean speed is below
    ``ALIGNMENT_MIN_SPEED_MPS``. Returns shape (...) (a 0-d array for one instant).
    """
    v = np.asarray(vel_ne_mps, dtype=np.float64)
    present = np.all(np.isfinite(v), axis=-1)
    v = np.where(present[..., None], v, 0.0)
    count = present.sum(axis=-1)
    total = np.linalg.norm(v, axis=-1).sum(axis=-1)
    resultant = np.linalg.norm(v.sum(axis=-2), axis=-1)
    defined = (count >= 2) & (total >= np.maximum(count, 1) * ALIGNMENT_MIN_SPEED_MPS)
    return np.asarray(np.where(defined, resultant / np.where(defined, total, 1.0), np.nan), dtype=np.float64)


def _alignment(step: StepRecord, grid_s: FloatArray, resampled: Sequence[Resampled]) -> AlignmentMetrics:
    in_step = (grid_s >= step.start_s - 1e-9) & (grid_s < step.end_s - 1e-9)
    times = grid_s[in_step]
    vel = np.full((times.size, len(resampled), 2), np.nan)
    for k, r in enumerate(resampled):
        airborne = r.airborne[in_step]
        vel[airborne, k] = r.vel_ned_mps[in_step][airborne, :2]
    phi = alignment_order_parameter(vel).reshape(times.size)
    reached = np.flatnonzero(phi >= ALIGNMENT_CONVERGED)
    converged = mean = low = None
    if reached.size:
        first = int(reached[0])
        converged = float(times[first]) - step.start_s
        after = phi[first:]
        after = after[np.isfinite(after)]
        mean, low = float(after.mean()), float(after.min())
    return AlignmentMetrics(converged_time_s=converged, mean=mean, min=low, time_s=times, phi=phi)


# --- settling ---------------------------------------------------------------------------------------------------


def settle_time(times_s: FloatArray, error: FloatArray, tolerance: float) -> float | None:
    """The earliest instant from which |error| <= tolerance holds through the last point, or None.

    ``error`` is signed (or non-negative) and taken as linear between points; the crossing into the band is
    interpolated. If every point is inside, the first point's time.
    """
    if times_s.size == 0:
        return None
    inside = np.abs(error) <= tolerance
    if not inside[-1]:
        return None
    outside = np.flatnonzero(~inside)
    if outside.size == 0:
        return float(times_s[0])
    k = int(outside[-1])
    e_out, e_in = float(error[k]), float(error[k + 1])
    edge = tolerance if e_out > tolerance else -tolerance
    frac = (edge - e_out) / (e_in - e_out)
    return float(times_s[k] + frac * (times_s[k + 1] - times_s[k]))


def _window(times_s: FloatArray, values: FloatArray, start_s: float, end_s: float) -> tuple[FloatArray, FloatArray]:
    """Samples inside [start_s, end_s] plus the values interpolated at the two ends (where the samples reach)."""
    inner = (times_s > start_s) & (times_s < end_s)
    t = list(times_s[inner])
    v = list(values[inner])
    if times_s[0] <= start_s <= times_s[-1]:
        t.insert(0, start_s)
        v.insert(0, float(np.interp(start_s, times_s, values)))
    if times_s[0] <= end_s <= times_s[-1] and end_s > start_s:
        t.append(end_s)
        v.append(float(np.interp(end_s, times_s, values)))
    return np.array(t, dtype=float), np.array(v, dtype=float)


def _takeoff_times(step: StepRecord, tracks: dict[int, _Track]) -> dict[int, float | None]:
    assert step.target_alt_m is not None
    out: dict[int, float | None] = {}
    for sysid, track in tracks.items():
        if not np.any((track.time_s >= step.start_s) & (track.time_s <= step.end_s)):
            continue
        altitude_error = -track.pos_ned_m[:, 2] - step.target_alt_m
        t, e = _window(track.time_s, altitude_error, step.start_s, step.end_s)
        settled = settle_time(t, e, TAKEOFF_TOLERANCE_M)
        out[sysid] = None if settled is None else settled - step.start_s
    return out


def _slowest(per_drone: dict[int, float | None]) -> float | None:
    if not per_drone or any(v is None for v in per_drone.values()):
        return None
    return max(v for v in per_drone.values() if v is not None)


def _step_metrics(
    step: StepRecord, grid_s: FloatArray, resampled: Sequence[Resampled], tracks: dict[int, _Track]
) -> StepMetrics:
    # half-open: at end_s the next step's command is already in force
    in_step = (grid_s >= step.start_s - 1e-9) & (grid_s < step.end_s - 1e-9)
    times = grid_s[in_step]
    errors = np.empty((0, times.size))
    for r in resampled:
        error = np.linalg.norm(r.pos_ned_m[in_step] - r.target_ned_m[in_step], axis=1)
        # a slot held from a sample before the step belongs to the previous step's command
        error[r.target_since_s[in_step] < step.start_s - 1e-9] = np.nan
        errors = np.vstack([errors, error])
    has_slot = ~np.isnan(errors)  # (drones, T)
    counted = has_slot.any(axis=0)
    sq_sum = np.where(has_slot, errors**2, 0.0).sum(axis=0)
    mean_sq = np.divide(sq_sum, has_slot.sum(axis=0), out=np.full(times.size, np.nan), where=counted)
    times, mean_sq, errors = times[counted], mean_sq[counted], errors[:, counted]
    rms = np.sqrt(mean_sq)

    time_to_formation = formation_rms = max_error = step_rms = None
    if times.size:
        step_rms = float(np.sqrt(mean_sq.mean()))
        settled_at = settle_time(times, rms, FORMATION_SETTLED_RMS_M)
        if settled_at is not None and step.arrival_s is not None:
            # not before the plan's arrival: until then a drone's setpoint is still on its way to its slot, and one
            # drone 1.5 m short of it among nine meets the swarm RMS bound
            settled_at = max(settled_at, step.arrival_s)
        settled = times >= (settled_at if settled_at is not None else math.inf) - 1e-9
        if settled_at is not None and settled.any():  # (a step that ended before its plan arrived never settled)
            time_to_formation = max(0.0, settled_at - step.start_s)
            formation_rms = float(np.sqrt(mean_sq[settled].mean()))
            max_error = float(np.nanmax(errors[:, settled]))

    takeoff_per_drone: dict[int, float | None] = {}
    if step.kind == "takeoff" and step.target_alt_m is not None:
        takeoff_per_drone = _takeoff_times(step, tracks)
    return StepMetrics(
        index=step.index,
        name=step.name,
        kind=step.kind,
        start_s=step.start_s,
        end_s=step.end_s,
        time_to_formation_s=time_to_formation,
        formation_rms_m=formation_rms,
        max_error_m=max_error,
        step_rms_m=step_rms,
        target_alt_m=step.target_alt_m,
        arrival_s=step.arrival_s,
        takeoff_time_s=_slowest(takeoff_per_drone),
        takeoff_time_per_drone_s=takeoff_per_drone,
        alignment=_alignment(step, grid_s, resampled) if step.kind in ALIGNMENT_STEP_KINDS else None,
    )


def _distance_flown(track: _Track) -> float:
    counted = track.armed[:-1] & track.armed[1:]
    segments = np.linalg.norm(np.diff(track.pos_ned_m, axis=0), axis=1)
    return float(segments[counted].sum())


# --- entry point ------------------------------------------------------------------------------------------------


def flying_samples(recording: FlightRecording) -> list[DroneSample]:
    """The samples of drones still in the swarm: a lost drone's from before its loss only (a silent one heard again:
    none from its loss to its return), so that formation errors and separations are those of the drones still
    flying (a falling or silent drone is no formation member; its stale last report is no separation)."""
    lost_at = {loss.sysid: loss.time_s for loss in recording.losses}
    away: dict[int, list[tuple[float, float]]] = {}  # silent drones heard again: out of the swarm while lost
    for loss in recording.regained:
        away.setdefault(loss.sysid, []).append((loss.time_s, math.inf if loss.regained_s is None else loss.regained_s))
    return [
        s
        for s in recording.samples
        if s.time_s < lost_at.get(s.sysid, math.inf)
        and not any(start <= s.time_s < end for start, end in away.get(s.sysid, ()))
    ]


def compute_metrics(recording: FlightRecording) -> FlightMetrics:
    """Every metric of the module docstring for one recorded flight."""
    tracks = _tracks(flying_samples(recording))
    sysids = tuple(tracks)
    sample_times = [float(t) for track in tracks.values() for t in (track.time_s[0], track.time_s[-1])]
    bounds = sample_times + [t for s in recording.steps for t in (s.start_s, s.end_s)]
    duration = max(bounds) - min(bounds) if bounds else 0.0

    grid = time_grid(min(sample_times), max(sample_times)) if sample_times else np.empty(0)
    resampled = [_resample(track, grid) for track in tracks.values()]
    series, closest = _separation(grid, sysids, resampled)
    contacts = drone_contacts(recording.events, recording.collision_radius_m)
    closest = _closer(closest, swarm_contacts(recording))

    steps = tuple(_step_metrics(step, grid, resampled, tracks) for step in recording.steps)
    first_takeoff = next((s for s in steps if s.kind == "takeoff" and s.target_alt_m is not None), None)

    collision_events = tuple(e for e in recording.events if e.text.startswith(COLLISION_PREFIX))
    avoidance_starts = tuple(e for e in recording.events if e.text.startswith(AVOIDANCE_PREFIX))
    attached = _attached_metrics(recording, grid, sysids, resampled, steps, contacts)
    return FlightMetrics(
        mission_name=recording.mission_name,
        n_drones=recording.n_drones,
        sysids=sysids,
        duration_s=duration,
        collision_radius_m=recording.collision_radius_m,
        min_separation_m=closest.distance_m if closest else None,
        min_separation_time_s=closest.time_s if closest else None,
        min_separation_pair=closest.pair if closest else None,
        collisions=len(collision_events),
        collision_events=collision_events,
        avoidance_events=len(avoidance_starts),
        avoidance_starts=avoidance_starts,
        avoidance_closest_approach_m=min(
            (float(m.group(1)) for e in recording.events if (m := AVOIDANCE_CLOSEST.match(e.text))), default=None
        ),
        takeoff_time_s=first_takeoff.takeoff_time_s if first_takeoff else None,
        takeoff_time_per_drone_s=dict(first_takeoff.takeoff_time_per_drone_s) if first_takeoff else {},
        steps=steps,
        distance_flown_m={sysid: _distance_flown(track) for sysid, track in tracks.items()},
        separation=SeparationSeries(time_s=grid, min_separation_m=series),
        loss_policy=recording.loss_policy,
        losses=tuple(recording.losses),
        regained=tuple(recording.regained),
        faults=tuple(recording.faults),
        failsafes=tuple(recording.failsafes),
        policy_events=tuple(recording.policy_events),
        requested_speed=recording.requested_speed,
        signing_key_id=recording.signing_key_id,
        neighbours=recording.neighbours,
        link_counters=dict(recording.link_counters),
        realtime_factor_min=min(recording.realtime_factors, default=None),
        realtime_factor_mean=(
            sum(recording.realtime_factors) / len(recording.realtime_factors) if recording.realtime_factors else None
        ),
        items_reached=tuple(recording.items_reached),
        attached=attached,
        invariants=tuple(recording.invariants),
        violations=tuple(sorted(recording.violations, key=lambda v: v.time_s)),
    )


# --- live status ------------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True, kw_only=True)
class LiveStatus:
    time_s: float | None  # newest sample seen
    rms_error_m: float | None  # swarm RMS distance to the commanded slots, now
    separation_m: float | None  # minimum pairwise separation of airborne drones, now
    min_separation_m: float | None  # smallest separation seen so far
    alignment: float | None = None  # phi of the latest velocities of airborne drones, when defined

    def line(self) -> str:
        def fmt(value: float | None, unit: str) -> str:
            return "-" if value is None else f"{value:.2f} {unit}"

        phi = "" if self.alignment is None else f"  phi {self.alignment:.2f}"
        return (
            f"t {fmt(self.time_s, 's')}  rms {fmt(self.rms_error_m, 'm')}  "
            f"sep {fmt(self.separation_m, 'm')} (min {fmt(self.min_separation_m, 'm')}){phi}"
        )


class LiveMetrics:
    """Incremental, approximate metrics for the status line while flying; the report's values are authoritative.

    Feed every sample to ``observe``. Drones whose latest sample is older than ``max_age_s`` are left out; the others
    are compared at the newest sample's time, each position extrapolated with its velocity.
    """

    def __init__(self, *, max_age_s: float = MAX_GAP_S) -> None:
        self._max_age_s = max_age_s
        self._latest: dict[int, DroneSample] = {}
        self._ground_down_m: dict[int, float] = {}
        self._now_s: float | None = None
        self._min_separation_m: float | None = None

    def observe(self, sample: DroneSample) -> None:
        if not sample.armed:
            ground = self._ground_down_m.get(sample.sysid, -math.inf)
            self._ground_down_m[sample.sysid] = max(ground, sample.pos_ned_m[2])
        self._latest[sample.sysid] = sample
        self._now_s = sample.time_s if self._now_s is None else max(self._now_s, sample.time_s)
        if not self._airborne(sample):
            return
        here = np.array(sample.pos_ned_m)
        for sysid, other in self._fresh_airborne(sample.time_s).items():
            if sysid != sample.sysid:
                self._closest(math.hypot(*(here - other)))

    def observe_event(self, event: EventRecord, contact_distance_m: float, attached: Collection[int] = ()) -> None:
        """A drone's event: a contact between two simulated drones is a separation, as in the report
        (``swarm_contacts``; one with an ``attached`` vehicle is that vehicle's, as its samples are not fed here)."""
        for contact in drone_contacts((event,), contact_distance_m):
            if not set(contact.pair) & set(attached):
                self._closest(contact.distance_m)

    def _closest(self, distance_m: float) -> None:
        if self._min_separation_m is None or distance_m < self._min_separation_m:
            self._min_separation_m = distance_m

    def status(self) -> LiveStatus:
        if self._now_s is None:
            return LiveStatus(time_s=None, rms_error_m=None, separation_m=None, min_separation_m=None)
        now = self._now_s
        positions = self._fresh_airborne(now)
        points = list(positions.values())
        separation = min((math.hypot(*(a - b)) for i, a in enumerate(points) for b in points[i + 1 :]), default=None)
        squared = [
            float(np.sum((_extrapolate(s, now) - np.array(s.target_ned_m)) ** 2))
            for s in self._latest.values()
            if s.target_ned_m is not None and now - s.time_s <= self._max_age_s
        ]
        rms = math.sqrt(sum(squared) / len(squared)) if squared else None
        velocities = [
            s.vel_ned_mps[:2]
            for s in self._latest.values()
            if abs(now - s.time_s) <= self._max_age_s and self._airborne(s)
        ]
        phi = float(alignment_order_parameter(velocities)) if len(velocities) >= 2 else math.nan
        return LiveStatus(
            time_s=now,
            rms_error_m=rms,
            separation_m=separation,
            min_separation_m=self._min_separation_m,
            alignment=phi if math.isfinite(phi) else None,
        )

    def _airborne(self, sample: DroneSample) -> bool:
        ground = self._ground_down_m.get(sample.sysid, 0.0)
        return sample.armed and ground - sample.pos_ned_m[2] > AIRBORNE_HEIGHT_M

    def _fresh_airborne(self, now_s: float) -> dict[int, FloatArray]:
        return {
            sysid: _extrapolate(s, now_s)
            for sysid, s in self._latest.items()
            if abs(now_s - s.time_s) <= self._max_age_s and self._airborne(s)
        }


def _extrapolate(sample: DroneSample, time_s: float) -> FloatArray:
    return np.array(sample.pos_ned_m, dtype=float) + np.array(sample.vel_ned_mps, dtype=float) * (
        time_s - sample.time_s
    )
