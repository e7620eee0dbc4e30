"""Mission files: a swarm flight written down as TOML, validated into frozen steps before anything flies.

```toml
name = "grid_to_circle"
[swarm]
drones = 9            # spawned on a grid (or line) with this spacing
spacing_m = 2.0
[[steps]]
action = "takeoff"    # takeoff | plan | formation | flock | follow | swap | hold | behaviour | fault | land | rtl
alt_m = 3.0
[[steps]]
action = "formation"
shape = "circle"      # grid | circle | line | v, with the fields of that shape (docs/missions.md)
radius_m = 3.0
alt_m = 3.0
hold_s = 30.0
```

``flock`` and ``follow`` steps carry the fields of ``FlockSpec`` and ``FollowSpec`` (gcs/flight/behaviours.py; angles in
degrees), and ``[swarm] params = { NAME = value }`` lists drone parameters set before arming (docs/missions.md).
A ``fault`` step (``drone``, ``fault``, optional ``motor``, ``for_s`` and ``after_s``) injects a fault
(gcs/fleet/faults.py) and ``[swarm] loss_policy`` says what the others do when a drone is lost (gcs/fleet/losses.py).

TOML is in the standard library (no new dependency) and reads well. A mistake is reported as one line
``FILE:LINE: steps[2].radius_m: must be a positive number``; tomllib gives no positions for values, so the line is
found by locating the step's ``[[steps]]`` header and the key inside it.
"""

from __future__ import annotations

import dataclasses
import math
import re
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Final

from gcs.command.procedures import check_takeoff_alt
from gcs.fleet.attach import (
    DEFAULT_KEEP_IN_M,
    DEFAULT_MAX_DISTANCE_M,
    DEFAULT_ROLE,
    AttachError,
    AttachSpec,
    parse_attach,
)
from gcs.fleet.faults import FaultError, FaultRequest, fault_request
from gcs.fleet.harness import LAYOUTS, MAX_DRONES, MAX_QUANTUM, MAX_SPAWN_JITTER_M, MAX_WIND_MPS
from gcs.fleet.links import NEIGHBOUR_MODES, LinkPlan, MeshPlan, NeighbourPlan, plan_from_tables
from gcs.fleet.losses import LOSS_POLICIES, LossPolicy
from gcs.fleet.relay import DEFAULT_RELAY_SCOPE, SCOPE_SPELLINGS, RelayScope
from gcs.flight.behaviours import FlockSpec, FollowAttachedSpec, FollowSpec
from gcs.flight.formation import CircleSpec, FieldError, Formation, FormationError, GridSpec, LineSpec, VSpec
from gcs.flight.onboard import FLOCKING, LEADER_FOLLOWER, absolute_spec
from gcs.flight.onboard import MAX_POINTS as ONBOARD_MAX_POINTS
from gcs.invariants.spec import Invariant, InvariantError, build_invariant, unique_names
from gcs.missions.plan_flight import OFFSET_MODES, PlanUsageError, nothing_to_start, parse_drones
from gcs.missions.qgc_plan import PlanFileError, QgcPlan, load_plan
from swarmcommon.links import LINK_CLASSES, LINK_KEYS, MESH_KEYS, mesh_value_problem, value_problem


class MissionFileError(ValueError):
    """One line: file, line, field and the problem."""


# What a step waits for by default, in simulated seconds; the swarm's verbs wait as long (gcs/supervisor/verbs.py),
# whichever front-end asks (the control channel, the Python API): one set of defaults, the documented ones.
TAKEOFF_TIMEOUT_S: Final = 30.0  # every drone holds its takeoff altitude
LAND_TIMEOUT_S: Final = 60.0  # every drone landed and disarmed
RTL_TIMEOUT_S: Final = 120.0  # every drone back, landed and disarmed
PLAN_TIMEOUT_S: Final = 120.0  # every drone of a plan step has finished its copy of the plan (and landed, if it lands)
TAKEOFF_ALT_M: Final = 3.0  # what a takeoff climbs to when it is not told (a mission's takeoff step must say)
# What a formation, a flock or a follow flies at when the command line does not say (a mission's steps must): where
# a takeoff that was not told either left the drones, so they neither climb nor descend to start it
FLIGHT_ALT_M: Final = TAKEOFF_ALT_M
SWAP_ACCEL_MPS2: Final = 1.0  # a swap's acceleration and braking
SWAP_TIMEOUT_S: Final = 30.0  # every drone within tolerance of its goal within this time of the swap's start
SWAP_TOLERANCE_M: Final = 0.5


@dataclass(frozen=True, slots=True, kw_only=True)
class SwarmSpec:
    drones: int
    layout: str = "grid"
    spacing_m: float = 2.0
    # Drone parameters set over MAVLink (PARAM_SET) before arming; an int travels as INT32, a float as REAL32.
    params: tuple[tuple[str, int | float], ...] = ()
    relay: bool = True  # false: no neighbour relay (the mesh, if any, or the cameras alone)
    relay_scope: RelayScope = DEFAULT_RELAY_SCOPE  # [swarm] relay_scope: which drones a position is relayed to
    # [swarm] neighbours = "mesh" | "both" and [swarm.mesh]: the drone-to-drone mesh radio; None: no mesh
    mesh: MeshPlan | None = None
    # [swarm.links]: the link model's settings per link class (docs/links.md)
    links: LinkPlan = field(default_factory=LinkPlan)
    # [swarm] behaviour = "file.py:Class": the onboard behaviour every drone carries (path absolute, read relative to
    # the mission file; docs/onboard.md); a ``behaviour`` step runs it
    behaviour: str | None = None
    # [[swarm.attach]]: vehicles the simulation does not run, attached over MAVLink (docs/external.md)
    attach: tuple[AttachSpec, ...] = ()
    # What else makes the flight what it is, so that a mission file replays with nothing on the command line:
    seed: int | None = None  # the drones' base seed (swarm fly --seed wins; default 0)
    wind_ned_mps: tuple[float, float, float] = (0.0, 0.0, 0.0)  # steady wind, NED m/s (the way it blows)
    gust_mps: float = 0.0  # gust RMS intensity, m/s
    spawn_jitter_m: float = 0.0  # each spawn point moved by up to this far north and east, seeded
    quantum: int | None = None  # lockstep: physics steps between waits (swarm fly --quantum wins; default 1)
    # [swarm.drone.N] params = {...}: drone N's own parameters, over the swarm's (drone number, its settings)
    drone_params: tuple[tuple[int, tuple[tuple[str, int | float], ...]], ...] = ()

    @property
    def relayed(self) -> RelayScope | None:
        """The relay's scope, or None without a relay (what ``Swarm`` takes)."""
        return self.relay_scope if self.relay else None


@dataclass(frozen=True, slots=True, kw_only=True)
class ObstacleSpec:
    """A static obstacle in the swarm frame: a vertical pole standing on the ground, or a sphere in the air."""

    cylinder: bool
    north_m: float
    east_m: float
    radius_m: float
    height_m: float = 0.0  # pole height above the ground (cylinder)
    alt_m: float = 0.0  # centre altitude (sphere)

    @property
    def centre_alt_m(self) -> float:
        return self.height_m / 2.0 if self.cylinder else self.alt_m


@dataclass(frozen=True, slots=True, kw_only=True)
class TakeoffStep:
    alt_m: float
    timeout_s: float = TAKEOFF_TIMEOUT_S


@dataclass(frozen=True, slots=True, kw_only=True)
class FormationStep:
    name: str
    formation: Formation
    hold_s: float  # time in the formation after the transition started


@dataclass(frozen=True, slots=True, kw_only=True)
class FlockStep:
    name: str
    spec: FlockSpec
    duration_s: float
    onboard: bool = False  # every drone flies the law itself (gcs/flight/onboard.py), not the ground station


@dataclass(frozen=True, slots=True, kw_only=True)
class FollowStep:
    name: str
    spec: FollowSpec  # leader_sysid None: resolved from leader_drone when the swarm is up
    leader_drone: int | None  # 1..drones: the swarm's n-th drone leads (its sysid depends on --first-instance)
    duration_s: float | None  # None: until the leader reaches its last waypoint
    onboard: bool = False  # every drone flies the law itself (gcs/flight/onboard.py), not the ground station


@dataclass(frozen=True, slots=True, kw_only=True)
class FollowAttachedStep:
    """The drones follow a leader attached to the swarm (``[[swarm.attach]] role = "leader"``), for a while."""

    name: str
    spec: FollowAttachedSpec


@dataclass(frozen=True, slots=True, kw_only=True)
class SwapStep:
    """Every drone straight to the point opposite it through the swarm's centre, paths crossing (avoidance test)."""

    speed_mps: float
    accel_mps2: float = SWAP_ACCEL_MPS2
    timeout_s: float = SWAP_TIMEOUT_S
    tolerance_m: float = SWAP_TOLERANCE_M


@dataclass(frozen=True, slots=True, kw_only=True)
class HoldStep:
    duration_s: float


@dataclass(frozen=True, slots=True, kw_only=True)
class BehaviourStep:
    """Every drone runs the mission's onboard behaviour for ``duration_s`` (BHV_EN = 1, then 0 and Hold)."""

    duration_s: float


@dataclass(frozen=True, slots=True, kw_only=True)
class PauseStep:
    """Every drone holds where it is in PX4 Hold for ``duration_s``, the ground station's setpoints stopped."""

    duration_s: float


@dataclass(frozen=True, slots=True, kw_only=True)
class LandStep:
    timeout_s: float = LAND_TIMEOUT_S


@dataclass(frozen=True, slots=True, kw_only=True)
class RtlStep:
    timeout_s: float = RTL_TIMEOUT_S


@dataclass(frozen=True, slots=True, kw_only=True)
class FaultStep:
    """A fault injected into one drone ``after_s`` after the step is reached; the mission goes straight on to the
    next step (so a fault placed before a formation step happens during that formation)."""

    drone: int  # 1..drones: the swarm's n-th drone (its sysid depends on --first-instance)
    fault: FaultRequest
    after_s: float = 0.0


@dataclass(frozen=True, slots=True, kw_only=True)
class PlanStep:
    """A QGroundControl plan flown in AUTO.MISSION by some of the drones, each its own copy moved by an offset
    (gcs/missions/plan_flight.py): uploaded, started (``start``), and over when every one has finished it (and landed,
    when the plan ends with a land or a return) or fails after ``timeout_s``."""

    file: Path
    plan: QgcPlan  # read and checked with the mission file, before anything flies
    drones: str = "all"  # "all" or drone numbers 1..drones like "1,3-5"
    offsets: str | tuple[tuple[float, float], ...] = "spawn"  # spawn | none | one (north, east) per drone
    start: bool = True
    timeout_s: float = PLAN_TIMEOUT_S


Step = (
    PlanStep
    | TakeoffStep
    | FormationStep
    | FlockStep
    | FollowStep
    | FollowAttachedStep
    | SwapStep
    | HoldStep
    | PauseStep
    | LandStep
    | RtlStep
    | FaultStep
    | BehaviourStep
)


@dataclass(frozen=True, slots=True, kw_only=True)
class MissionSpec:
    name: str
    description: str
    swarm: SwarmSpec
    steps: tuple[Step, ...]
    loss_policy: LossPolicy = LossPolicy.CONTINUE
    path: Path | None = None
    obstacles: tuple[ObstacleSpec, ...] = ()
    # [[invariants]]: properties checked at every tick of the flight (docs/invariants.md)
    invariants: tuple[Invariant, ...] = ()
    # [[faults]]: faults injected at a mission time (``after_s``: seconds from mission time zero), whatever step flies
    faults: tuple[FaultStep, ...] = ()


# Per shape: the spec class and its fields (name -> kind); angles are given in degrees in files.
_SHAPES: dict[str, tuple[type, dict[str, str]]] = {
    "grid": (GridSpec, {"rows": "count", "cols": "count", "spacing_m": "pos", "alt_m": "pos", "heading_deg": "angle"}),
    "circle": (
        CircleSpec,
        {
            "radius_m": "pos",
            "alt_m": "pos",
            "angular_rate_radps": "num",
            "alt_osc_amp_m": "nonneg",
            "alt_osc_rate_radps": "num",
            "alt_osc_phase_step_rad": "num",
            "phase_deg": "angle",
        },
    ),
    "line": (LineSpec, {"spacing_m": "pos", "alt_m": "pos", "heading_deg": "angle"}),
    "v": (VSpec, {"spacing_m": "pos", "alt_m": "pos", "angle_deg": "angle", "heading_deg": "angle"}),
}
SHAPE_NAMES: Final[dict[type, str]] = {spec: name for name, (spec, _fields) in _SHAPES.items()}  # GridSpec -> "grid"
_REQUIRED = {"grid": {"rows", "cols", "spacing_m", "alt_m"}, "circle": {"radius_m", "alt_m"},
             "line": {"spacing_m", "alt_m"}, "v": {"spacing_m", "alt_m"}}  # fmt: skip


# Behaviours: their fields (name -> kind) and the spec field each fills, where the file's differs (degrees).
_FLOCK_FIELDS: dict[str, str] = {
    "alt_m": "pos",
    "migration_ne_m": "points",
    "max_speed_mps": "pos",
    "max_accel_mps2": "pos",
    "neighbour_radius_m": "pos",
    "separation_radius_m": "pos",
    "separation_weight_mps2": "pos",
    "separation_lookahead_s": "nonneg",
    "alignment_weight_per_s": "nonneg",
    "cohesion_weight_per_s2": "nonneg",
    "migration_weight_per_s": "nonneg",
    "arrival_radius_m": "pos",
}
_FOLLOW_FIELDS: dict[str, str] = {
    "waypoints_ne_m": "points",
    "alt_m": "pos",
    "speed_mps": "pos",
    "leader_sysid": "count",
    "offsets_fr_m": "offsets",
    "spacing_m": "pos",
    "angle_deg": "angle",
    "turn_radius_m": "pos",
    "max_accel_mps2": "pos",
    "max_turn_rate_degps": "pos",
}
_FOLLOW_ATTACHED_FIELDS: dict[str, str] = {
    "alt_m": "pos",
    "duration_s": "pos",
    "leader_sysid": "count",
    "offsets_fr_m": "offsets",
    "spacing_m": "pos",
    "angle_deg": "angle",
    "max_turn_rate_degps": "pos",
}
_FOLLOW_ATTACHED_REQUIRED = {"alt_m", "duration_s"}
_RENAMED = {"angle_deg": "angle_rad", "max_turn_rate_degps": "max_turn_rate_radps"}
_FILE_NAMES = {
    **{spec: file for file, spec in _RENAMED.items()},
    "heading_rad": "heading_deg",
    "phase_rad": "phase_deg",
}
_FLOCK_REQUIRED = {"alt_m"}
_FOLLOW_REQUIRED = {"waypoints_ne_m", "alt_m"}
_PAIR_LABELS = {"points": "[north, east]", "offsets": "[forward, right]"}


def number_problem(value: Any, kind: str) -> str | None:
    """Why ``value`` is not a valid number of this kind (count, pos, nonneg, num, angle), or None."""
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        return f"must be a number, got {value!r}"
    if kind == "count" and (not isinstance(value, int) or value < 1):
        return f"must be a whole number >= 1, got {value!r}"
    if kind == "pos" and value <= 0:
        return f"must be a positive number, got {value!r}"
    if kind == "nonneg" and value < 0:
        return f"must be >= 0, got {value!r}"
    return None


def field_problem(value: Any, kind: str) -> str | None:
    """Like ``number_problem``, also for lists of pairs (kinds points, offsets)."""
    if kind not in _PAIR_LABELS:
        return number_problem(value, kind)
    label = _PAIR_LABELS[kind]
    if not isinstance(value, list | tuple) or not value:
        return f"must be a non-empty list of {label} pairs, got {value!r}"
    for pair in value:
        if not isinstance(pair, list | tuple) or len(pair) != 2 or any(number_problem(v, "num") for v in pair):
            return f"must be a list of {label} pairs of numbers, got {pair!r} in it"
    return None


def _convert(key: str, value: Any, kind: str) -> tuple[str, Any]:
    if kind in _PAIR_LABELS:
        return key, tuple((float(a), float(b)) for a, b in value)
    if key in _RENAMED:
        return _RENAMED[key], math.radians(value)
    return key, int(value) if kind == "count" else float(value)


def _spec(cls: type, kwargs: dict[str, Any]) -> Any:
    """A spec from converted fields; a field it refuses is a FieldError named as the file names it (degrees)."""
    try:
        return cls(**kwargs)
    except FieldError as exc:
        raise FieldError(_FILE_NAMES.get(exc.field, exc.field), exc.problem, str(exc)) from None
    except (FormationError, TypeError) as exc:
        raise ValueError(str(exc)) from None


def _build_behaviour(cls: type, what: str, kinds: dict[str, str], required: set[str], fields: dict[str, Any]) -> Any:
    for key in fields:
        if key not in kinds:
            raise FieldError(key, f"not a field of {what} (fields: {', '.join(kinds)})")
    missing = sorted(required - set(fields))
    if missing:
        raise ValueError(f"missing field '{missing[0]}' for {what}")
    kwargs: dict[str, Any] = {}
    for key, value in fields.items():
        problem = field_problem(value, kinds[key])
        if problem is not None:
            raise FieldError(key, problem)
        name, converted = _convert(key, value, kinds[key])
        kwargs[name] = converted
    return _spec(cls, kwargs)


def build_flock(fields: dict[str, Any]) -> FlockSpec:
    """A flocking spec from plain fields (a mission step's, or the CLI's); ValueError says which field is wrong."""
    spec: FlockSpec = _build_behaviour(FlockSpec, "flocking", _FLOCK_FIELDS, _FLOCK_REQUIRED, fields)
    return spec


def build_follow(fields: dict[str, Any]) -> FollowSpec:
    """A leader-follower spec from plain fields (the CLI's, with ``leader_sysid``); ValueError names the field."""
    spec: FollowSpec = _build_behaviour(FollowSpec, "leader-follower", _FOLLOW_FIELDS, _FOLLOW_REQUIRED, fields)
    return spec


def build_follow_attached(fields: dict[str, Any]) -> FollowAttachedSpec:
    """Following an attached leader (docs/external.md) from plain fields; ValueError names the field."""
    spec: FollowAttachedSpec = _build_behaviour(FollowAttachedSpec, "following an attached leader",
                                                _FOLLOW_ATTACHED_FIELDS, _FOLLOW_ATTACHED_REQUIRED, fields)  # fmt: skip
    return spec


def build_formation(shape: str, fields: dict[str, Any]) -> Formation:
    """A formation spec from plain fields (as in a mission file step); ValueError says which field is wrong."""
    if shape not in _SHAPES:
        raise ValueError(f"shape must be one of {', '.join(_SHAPES)}, got {shape!r}")
    spec_cls, kinds = _SHAPES[shape]
    for key in fields:
        if key not in kinds:
            raise FieldError(key, f"not a field of a {shape} formation (fields: {', '.join(kinds)})")
    missing = sorted(_REQUIRED[shape] - set(fields))
    if missing:
        raise ValueError(f"missing field '{missing[0]}' for a {shape} formation")
    kwargs: dict[str, Any] = {}
    for key, value in fields.items():
        problem = number_problem(value, kinds[key])
        if problem is not None:
            raise FieldError(key, problem)
        if kinds[key] == "angle":
            kwargs[key.replace("_deg", "_rad")] = math.radians(value)
        else:
            kwargs[key] = int(value) if kinds[key] == "count" else float(value)
    formation: Formation = _spec(spec_cls, kwargs)
    return formation


# A table header line: [name] or [[name]] alone (a comment may follow). Not the continuation of a multi-line array
# such as "  [12.0, 0.0],", which also starts with a bracket.
_HEADER = re.compile(r"""^\s*\[\[?\s*[A-Za-z_"'][^\]]*\]\]?\s*(#.*)?$""")


class _Locator:
    """Finds the line of a field in the TOML text (1-based), for error messages."""

    def __init__(self, text: str) -> None:
        self.lines = text.splitlines()

    def _table_start(self, table: str, index: int | None) -> int | None:
        pattern = re.compile(rf"^\s*\[\[\s*{table}\s*\]\]" if index is not None else rf"^\s*\[\s*{table}\s*\]")
        seen = -1
        for n, line in enumerate(self.lines):
            if pattern.match(line):
                seen += 1
                if index is None or seen == index:
                    return n
        return None

    def line_of(self, table: str | None, index: int | None, key: str | None) -> int:
        start = -1 if table is None else self._table_start(table, index)
        if start is None:
            return 1
        key_re = re.compile(rf"^\s*{re.escape(key)}\s*=") if key else None
        for n in range(start + 1, len(self.lines)):
            if _HEADER.match(self.lines[n]) and n > start:
                break
            if key_re is not None and key_re.match(self.lines[n]):
                return n + 1
        return start + 1 if start >= 0 else 1


class _Reader:
    def __init__(self, path: Path, locator: _Locator) -> None:
        self.path = path
        self.locator = locator

    def fail(self, where: tuple[str | None, int | None], key: str | None, problem: str) -> MissionFileError:
        table, index = where
        line = self.locator.line_of(table, index, key)
        label = ".".join(p for p in ((f"{table}[{index}]" if index is not None else table), key) if p)
        return MissionFileError(
            f"{self.path}:{line}: {label}: {problem}" if label else f"{self.path}:{line}: {problem}"
        )

    def number(self, table: dict[str, Any], key: str, where: tuple[str | None, int | None], kind: str) -> float:
        problem = number_problem(table[key], kind)
        if problem is not None:
            raise self.fail(where, key, problem)
        return float(table[key])

    def field(self, table: dict[str, Any], key: str, where: tuple[str | None, int | None], kind: str) -> None:
        problem = field_problem(table[key], kind)
        if problem is not None:
            raise self.fail(where, key, problem)

    def check_keys(self, table: dict[str, Any], allowed: set[str], where: tuple[str | None, int | None]) -> None:
        for key in table:
            if key not in allowed:
                raise self.fail(where, key, f"unknown field (allowed: {', '.join(sorted(allowed))})")


def _formation(reader: _Reader, step: dict[str, Any], where: tuple[str | None, int | None]) -> FormationStep:
    shape = step.get("shape")
    if shape not in _SHAPES:
        raise reader.fail(where, "shape", f"must be one of {', '.join(_SHAPES)}, got {shape!r}")
    fields = _SHAPES[shape][1]
    reader.check_keys(step, {"action", "shape", "hold_s", "name", *fields}, where)
    for key in sorted(_REQUIRED[shape] | {"hold_s"}):
        if key not in step:
            raise reader.fail(where, None, f"missing field '{key}' for a {shape} formation")
    for key in fields:
        if key in step:
            reader.number(step, key, where, fields[key])
    try:
        formation = build_formation(shape, {k: step[k] for k in fields if k in step})
    except FieldError as exc:
        raise reader.fail(where, exc.field, exc.problem) from None
    except ValueError as exc:
        raise reader.fail(where, None, str(exc)) from None
    name = step.get("name", shape)
    if not isinstance(name, str):
        raise reader.fail(where, "name", "must be a string")
    return FormationStep(name=name, formation=formation, hold_s=reader.number(step, "hold_s", where, "pos"))


def _step_name(reader: _Reader, step: dict[str, Any], where: tuple[str | None, int | None], default: str) -> str:
    name = step.get("name", default)
    if not isinstance(name, str):
        raise reader.fail(where, "name", "must be a string")
    return name


def _flock(reader: _Reader, step: dict[str, Any], where: tuple[str | None, int | None]) -> FlockStep:
    reader.check_keys(step, {"action", "name", "duration_s", "onboard", *_FLOCK_FIELDS}, where)
    for key in sorted(_FLOCK_REQUIRED | {"duration_s"}):
        if key not in step:
            raise reader.fail(where, None, f"missing field '{key}' for a flock step")
    for key, kind in _FLOCK_FIELDS.items():
        if key in step:
            reader.field(step, key, where, kind)
    duration = reader.number(step, "duration_s", where, "pos")
    try:
        spec = build_flock({k: step[k] for k in _FLOCK_FIELDS if k in step})
    except FieldError as exc:
        raise reader.fail(where, exc.field, exc.problem) from None
    except ValueError as exc:
        raise reader.fail(where, None, str(exc)) from None
    onboard = _onboard(reader, step, where, "migration_ne_m", spec.migration_ne_m)
    return FlockStep(name=_step_name(reader, step, where, "flock"), spec=spec, duration_s=duration, onboard=onboard)


def _onboard(reader: _Reader, step: dict[str, Any], where: tuple[str | None, int | None], points_key: str,
             points: tuple[tuple[float, float], ...]) -> bool:  # fmt: skip
    """``onboard = true``: the drones fly the step's law themselves; their parameters hold at most MAX_POINTS."""
    onboard = step.get("onboard", False)
    if not isinstance(onboard, bool):
        raise reader.fail(where, "onboard", f"must be true or false, got {onboard!r}")
    if onboard and len(points) > ONBOARD_MAX_POINTS:
        raise reader.fail(where, points_key, f"an onboard step takes at most {ONBOARD_MAX_POINTS} points, "
                                             f"got {len(points)}")  # fmt: skip
    return onboard


def _follow(reader: _Reader, step: dict[str, Any], where: tuple[str | None, int | None], drones: int) -> FollowStep:
    fields = {k: v for k, v in _FOLLOW_FIELDS.items() if k != "leader_sysid"}
    reader.check_keys(step, {"action", "name", "duration_s", "leader_drone", "onboard", *fields}, where)
    for key in sorted(_FOLLOW_REQUIRED):
        if key not in step:
            raise reader.fail(where, None, f"missing field '{key}' for a follow step")
    for key, kind in fields.items():
        if key in step:
            reader.field(step, key, where, kind)
    leader = None
    if "leader_drone" in step:
        leader = int(reader.number(step, "leader_drone", where, "count"))
        if leader > drones:
            raise reader.fail(where, "leader_drone", f"must be one of the swarm's drones 1..{drones}, got {leader}")
    offsets = step.get("offsets_fr_m")
    if offsets is not None and len(offsets) < drones - 1:
        raise reader.fail(where, "offsets_fr_m", f"{len(offsets)} offsets for {drones - 1} followers: give one each")
    duration = reader.number(step, "duration_s", where, "pos") if "duration_s" in step else None
    try:
        spec = build_follow({k: step[k] for k in fields if k in step})
    except FieldError as exc:
        raise reader.fail(where, exc.field, exc.problem) from None
    except ValueError as exc:
        raise reader.fail(where, None, str(exc)) from None
    name = _step_name(reader, step, where, "follow")
    onboard = _onboard(reader, step, where, "waypoints_ne_m", spec.waypoints_ne_m)
    return FollowStep(name=name, spec=spec, leader_drone=leader, duration_s=duration, onboard=onboard)


def _step(reader: _Reader, step: Any, index: int, drones: int) -> Step:
    where: tuple[str | None, int | None] = ("steps", index)
    if not isinstance(step, dict):
        raise reader.fail(where, None, "must be a table")
    action = step.get("action")
    if action == "takeoff":
        reader.check_keys(step, {"action", "alt_m", "timeout_s"}, where)
        if "alt_m" not in step:
            raise reader.fail(where, None, "missing field 'alt_m'")
        alt = reader.number(step, "alt_m", where, "pos")
        try:
            check_takeoff_alt(alt)
        except ValueError as exc:
            raise reader.fail(where, "alt_m", str(exc)) from None
        timeout = reader.number(step, "timeout_s", where, "pos") if "timeout_s" in step else TAKEOFF_TIMEOUT_S
        return TakeoffStep(alt_m=alt, timeout_s=timeout)
    if action == "formation":
        return _formation(reader, step, where)
    if action == "flock":
        return _flock(reader, step, where)
    if action == "follow":
        return _follow(reader, step, where, drones)
    if action == "follow_attached":
        fields = {k: v for k, v in step.items() if k not in ("action", "name")}
        try:
            spec = build_follow_attached(fields)
        except FieldError as exc:
            raise reader.fail(where, exc.field, exc.problem) from None
        except ValueError as exc:
            raise reader.fail(where, None, str(exc)) from None
        return FollowAttachedStep(name=_step_name(reader, step, where, "follow attached"), spec=spec)
    if action == "swap":
        reader.check_keys(step, {"action", "speed_mps", "accel_mps2", "timeout_s", "tolerance_m"}, where)
        if "speed_mps" not in step:
            raise reader.fail(where, None, "missing field 'speed_mps'")
        optional = {k: reader.number(step, k, where, "pos") for k in ("accel_mps2", "timeout_s", "tolerance_m")
                    if k in step}  # fmt: skip
        return SwapStep(speed_mps=reader.number(step, "speed_mps", where, "pos"), **optional)
    if action == "hold":
        reader.check_keys(step, {"action", "duration_s"}, where)
        if "duration_s" not in step:
            raise reader.fail(where, None, "missing field 'duration_s'")
        return HoldStep(duration_s=reader.number(step, "duration_s", where, "pos"))
    if action in ("behaviour", "pause"):
        reader.check_keys(step, {"action", "duration_s"}, where)
        if "duration_s" not in step:
            raise reader.fail(where, None, "missing field 'duration_s'")
        timed = BehaviourStep if action == "behaviour" else PauseStep
        return timed(duration_s=reader.number(step, "duration_s", where, "pos"))
    if action == "fault":
        return _fault(reader, step, where, drones)
    if action == "plan":
        return _plan(reader, step, where, drones)
    if action in ("land", "rtl"):
        reader.check_keys(step, {"action", "timeout_s"}, where)
        cls = LandStep if action == "land" else RtlStep
        return cls(timeout_s=reader.number(step, "timeout_s", where, "pos")) if "timeout_s" in step else cls()
    raise reader.fail(
        where,
        "action",
        f"must be takeoff, plan, formation, flock, follow, swap, hold, pause, behaviour, fault, land or rtl, "
        f"got {action!r}",
    )


def _plan(reader: _Reader, step: dict[str, Any], where: tuple[str | None, int | None], drones: int) -> PlanStep:
    reader.check_keys(step, {"action", "file", "drones", "offsets", "start", "timeout_s"}, where)
    if not isinstance(step.get("file"), str):
        raise reader.fail(where, "file" if "file" in step else None, "missing field 'file' (a QGroundControl .plan)")
    path = Path(step["file"])
    if not path.is_absolute() and reader.path.parent != Path():
        path = reader.path.parent / path  # relative to the mission file, wherever swarm fly runs
    try:
        plan = load_plan(path)
    except PlanFileError as exc:
        raise reader.fail(where, "file", str(exc)) from None
    chosen = step.get("drones", "all")
    known = list(range(1, drones + 1))
    if not isinstance(chosen, str):
        raise reader.fail(where, "drones", f'must be a string: all, or drone numbers like "1,3-5", got {chosen!r}')
    try:
        count = len(parse_drones(chosen, known))
    except PlanUsageError as exc:
        raise reader.fail(where, "drones", str(exc).removeprefix("drones: ")) from None
    offsets: str | tuple[tuple[float, float], ...] = "spawn"
    if "offsets" in step:
        value = step["offsets"]
        if isinstance(value, str):
            if value not in OFFSET_MODES:
                raise reader.fail(where, "offsets", f"must be spawn, none or [[north, east], ...], got {value!r}")
            offsets = value
        else:
            reader.field(step, "offsets", where, "points")
            offsets = tuple((float(n), float(e)) for n, e in value)
            if len(offsets) != count:
                raise reader.fail(where, "offsets", f"{len(offsets)} offsets for {count} drones: give one each")
    start = step.get("start", True)
    if not isinstance(start, bool):
        raise reader.fail(where, "start", f"must be true or false, got {start!r}")
    problem = nothing_to_start(plan, path) if start else None
    if problem is not None:
        raise reader.fail(where, "file", f"{problem} (start = false uploads its fence alone)")
    timeout = reader.number(step, "timeout_s", where, "pos") if "timeout_s" in step else PLAN_TIMEOUT_S
    return PlanStep(file=path, plan=plan, drones=chosen, offsets=offsets, start=start, timeout_s=timeout)


def _fault(reader: _Reader, step: dict[str, Any], where: tuple[str | None, int | None], drones: int, *,
           time_key: str = "after_s") -> FaultStep:  # fmt: skip
    """A fault step (or a [[faults]] table, whose time field is ``time_key``, read into the step's ``after_s``)."""
    reader.check_keys({(time_key if k == "after_s" else k): v for k, v in step.items()},
                      {"action", "drone", "fault", "motor", time_key, "for_s"}, where)  # fmt: skip
    for key in ("drone", "fault"):
        if key not in step:
            raise reader.fail(where, None, f"missing field '{key}' for a fault step")
    drone = int(reader.number(step, "drone", where, "count"))
    if drone > drones:
        raise reader.fail(where, "drone", f"must be one of the swarm's drones 1..{drones}, got {drone}")
    try:
        fault_request(step["fault"])
    except FaultError as exc:
        raise reader.fail(where, "fault", str(exc)) from None
    try:
        fault = fault_request(step["fault"], step.get("motor"), step.get("for_s"))
    except FaultError as exc:
        raise reader.fail(where, "for_s" if "for_s" in step else "motor", str(exc)) from None
    after = 0.0
    if "after_s" in step:
        problem = number_problem(step["after_s"], "nonneg")
        if problem is not None:
            raise reader.fail(where, time_key, problem)
        after = float(step["after_s"])
    return FaultStep(drone=drone, fault=fault, after_s=after)


_PARAM_NAME = re.compile(r"^[A-Za-z0-9_]{1,16}$")  # MAVLink param_id: at most 16 characters


def _params(reader: _Reader, table: Any, where: tuple[str | None, int | None]) -> tuple[tuple[str, int | float], ...]:
    if not isinstance(table, dict):
        raise reader.fail(where, "params", "must be a table of NAME = number, e.g. { AVOID_ENABLE = 0 }")
    out: list[tuple[str, int | float]] = []
    for name, value in table.items():
        if not _PARAM_NAME.match(name):
            raise reader.fail(where, "params", f"{name!r} is not a parameter name (letters, digits, _; 16 at most)")
        problem = number_problem(value, "num")
        if problem is not None:
            raise reader.fail(where, "params", f"{name} {problem}")
        out.append((name, value))
    return tuple(out)


def _attach(reader: _Reader, tables: Any) -> tuple[AttachSpec, ...]:
    """``[[swarm.attach]]``: ``url``, and optionally ``role`` (default member), ``radius_m`` (the body's size),
    ``max_distance_m`` (refused farther from the origin), ``signing_key`` (a key file, relative to the mission), and
    for a member ``arm`` (the swarm arms and takes it off) and ``keep_in_m`` (no setpoint outside)."""
    if not isinstance(tables, list) or not all(isinstance(t, dict) for t in tables):
        raise reader.fail(("swarm", None), "attach", "must be [[swarm.attach]] tables with url and role")
    specs = []
    for k, table in enumerate(tables):
        where: tuple[str | None, int | None] = ("swarm.attach", k)
        reader.check_keys(table, {"url", "role", "radius_m", "max_distance_m", "signing_key", "arm", "keep_in_m"},
                          where)  # fmt: skip
        url, role = table.get("url"), table.get("role", DEFAULT_ROLE)
        if not isinstance(url, str) or not isinstance(role, str):
            raise reader.fail(where, "url", 'url (and role) must be strings, e.g. url = "udpin:0.0.0.0:14560"')
        radius = reader.number(table, "radius_m", where, "pos") if "radius_m" in table else None
        farthest = DEFAULT_MAX_DISTANCE_M
        if "max_distance_m" in table:
            farthest = reader.number(table, "max_distance_m", where, "pos")
        key = table.get("signing_key")
        if key is not None and not isinstance(key, str):
            raise reader.fail(where, "signing_key", "must be a key file's path (relative to the mission file)")
        key_file = None if key is None else (reader.path.parent / key).resolve()
        arm = table.get("arm", False)
        if not isinstance(arm, bool):
            raise reader.fail(where, "arm", f"must be true or false, got {arm!r}")
        keep_in = reader.number(table, "keep_in_m", where, "pos") if "keep_in_m" in table else DEFAULT_KEEP_IN_M
        try:
            specs.append(parse_attach(f"{role}={url}", radius_m=radius, max_distance_m=farthest,
                                      signing_key_file=key_file, arm=arm, keep_in_m=keep_in))  # fmt: skip
        except AttachError as exc:
            raise reader.fail(where, "url", str(exc).removeprefix("--attach ")) from None
    return tuple(specs)


def _links(reader: _Reader, table: Any) -> LinkPlan:
    """``[swarm.links]``: keys for every link class, and ``[swarm.links.CLASS]`` tables over them for one class."""
    where: tuple[str | None, int | None] = ("swarm.links", None)
    if not isinstance(table, dict):
        raise reader.fail(("swarm", None), "links", "must be a table ([swarm.links])")
    reader.check_keys(table, {*LINK_KEYS, *LINK_CLASSES}, where)
    common = _link_values(reader, {k: v for k, v in table.items() if k in LINK_KEYS}, where)
    per_class: dict[str, dict[str, float]] = {}
    for link_class in LINK_CLASSES:
        if link_class not in table:
            continue
        sub: tuple[str | None, int | None] = (f"swarm.links.{link_class}", None)
        if not isinstance(table[link_class], dict):
            raise reader.fail(where, link_class, f"must be a table ([swarm.links.{link_class}])")
        reader.check_keys(table[link_class], set(LINK_KEYS), sub)
        per_class[link_class] = _link_values(reader, table[link_class], sub)
    try:
        return plan_from_tables(common, per_class)
    except ValueError as exc:  # a burst pair half given: named by its class's table, or the common one
        named, _, problem = str(exc).partition(": ")
        place = (f"swarm.links.{named}", None) if named in per_class else where
        raise reader.fail(place, None, problem) from None


def _neighbours(reader: _Reader, swarm: dict[str, Any]) -> NeighbourPlan:
    """``relay = true|false`` (the older key), ``neighbours = "relay"|"mesh"|"both"`` and ``[swarm.mesh]``; a
    combination that says two things (relay = true with neighbours = "mesh") is refused, not resolved."""
    where: tuple[str | None, int | None] = ("swarm", None)
    relay = swarm.get("relay", True)
    if not isinstance(relay, bool):
        raise reader.fail(where, "relay", f"must be true or false, got {relay!r}")
    plan = _relay_scoped(reader, swarm, where, _neighbour_modes(reader, swarm, where, relay))
    if "relay_scope" in swarm and not plan.relay:
        raise reader.fail(where, "relay_scope", f"is set but there is no relay (neighbours = {plan.mode!r})")
    return plan


def _relay_scoped(reader: _Reader, swarm: dict[str, Any], where: tuple[str | None, int | None],
                  plan: NeighbourPlan) -> NeighbourPlan:  # fmt: skip
    """``plan`` with ``relay_scope = "reach"|"all"|"within:M"|"nearest:K"`` from [swarm], if given."""
    if "relay_scope" not in swarm:
        return plan
    text = swarm["relay_scope"]
    try:
        if not isinstance(text, str):
            raise ValueError(f"must be a string ({SCOPE_SPELLINGS}), got {text!r}")
        return dataclasses.replace(plan, relay_scope=RelayScope.parse(text))
    except ValueError as exc:
        raise reader.fail(where, "relay_scope", str(exc)) from None


def _neighbour_modes(reader: _Reader, swarm: dict[str, Any], where: tuple[str | None, int | None],
                     relay: bool) -> NeighbourPlan:  # fmt: skip
    """The relay and the mesh as ``relay`` and ``neighbours`` say."""
    mesh = _mesh(reader, swarm["mesh"]) if "mesh" in swarm else None
    if "neighbours" not in swarm:
        if mesh is not None:
            raise reader.fail(("swarm.mesh", None), None, 'needs neighbours = "mesh" or "both" in [swarm]')
        return NeighbourPlan(relay=relay)
    mode = swarm["neighbours"]
    if mode not in NEIGHBOUR_MODES:
        raise reader.fail(where, "neighbours", f"must be one of {', '.join(NEIGHBOUR_MODES)}, got {mode!r}")
    plan = NeighbourPlan(relay=True, mesh=mesh).with_mode(mode)
    if "relay" in swarm and relay != plan.relay:
        raise reader.fail(where, "relay", f"relay = {str(relay).lower()} contradicts neighbours = {mode!r}")
    if mesh is not None and plan.mesh is None:
        raise reader.fail(("swarm.mesh", None), None, f"is set but neighbours = {mode!r} has no mesh")
    return plan


def _mesh(reader: _Reader, table: Any) -> MeshPlan:
    where: tuple[str | None, int | None] = ("swarm.mesh", None)
    if not isinstance(table, dict):
        raise reader.fail(("swarm", None), "mesh", "must be a table ([swarm.mesh])")
    reader.check_keys(table, set(MESH_KEYS), where)
    for key, value in table.items():
        problem = mesh_value_problem(key, value)
        if problem is not None:  # the label names the key already: the problem without it
            raise reader.fail(where, key, problem.removeprefix(f"{key} "))
    return MeshPlan(**{key: float(value) for key, value in table.items()})


def _link_values(reader: _Reader, table: dict[str, Any], where: tuple[str | None, int | None]) -> dict[str, float]:
    for key, value in table.items():
        problem = value_problem(key, value)
        if problem is not None:  # the label names the key already: the problem without it
            raise reader.fail(where, key, problem.removeprefix(f"{key} "))
    return {key: float(value) for key, value in table.items()}


def _obstacles(reader: _Reader, data: Any, max_obstacles: int | None) -> tuple[ObstacleSpec, ...]:
    if not isinstance(data, list):
        raise reader.fail((None, None), "obstacles", "must be [[obstacles]] tables")
    out = []
    for i, item in enumerate(data):
        where: tuple[str | None, int | None] = ("obstacles", i)
        if not isinstance(item, dict):
            raise reader.fail(where, None, "must be a table")
        shape = item.get("shape")
        if shape not in ("cylinder", "sphere"):
            raise reader.fail(where, "shape", f"must be cylinder or sphere, got {shape!r}")
        size = "height_m" if shape == "cylinder" else "alt_m"
        reader.check_keys(item, {"shape", "north_m", "east_m", "radius_m", size}, where)
        for key in ("north_m", "east_m", "radius_m", size):
            if key not in item:
                raise reader.fail(where, None, f"missing field '{key}' for a {shape}")
        out.append(
            ObstacleSpec(
                cylinder=shape == "cylinder",
                north_m=reader.number(item, "north_m", where, "num"),
                east_m=reader.number(item, "east_m", where, "num"),
                radius_m=reader.number(item, "radius_m", where, "pos"),
                **{size: reader.number(item, size, where, "pos")},
            )
        )
    if max_obstacles is not None and len(out) > max_obstacles:
        raise reader.fail((None, None), "obstacles", f"at most {max_obstacles}, got {len(out)}")
    return tuple(out)


def _conditions(reader: _Reader, swarm: dict[str, Any], where: tuple[str | None, int | None],
                drones: int) -> dict[str, Any]:  # fmt: skip
    """``[swarm]``'s seed, weather, spawn jitter, lockstep quantum and ``[swarm.drone.N]`` parameters."""
    out: dict[str, Any] = {}
    if "seed" in swarm:
        seed = swarm["seed"]
        if isinstance(seed, bool) or not isinstance(seed, int) or not 0 <= seed < 2**31:
            raise reader.fail(where, "seed", f"must be a whole number in 0..2^31-1, got {seed!r}")
        out["seed"] = seed
    if "wind_ned_mps" in swarm:
        wind = swarm["wind_ned_mps"]
        if not isinstance(wind, list) or len(wind) != 3 or any(number_problem(v, "num") for v in wind):
            raise reader.fail(where, "wind_ned_mps", f"must be [north, east, down] in m/s, got {wind!r}")
        if math.hypot(*wind) > MAX_WIND_MPS:
            raise reader.fail(where, "wind_ned_mps", f"at most {MAX_WIND_MPS:g} m/s, got {math.hypot(*wind):.1f}")
        out["wind_ned_mps"] = tuple(float(v) for v in wind)
    for key, largest in (("gust_mps", MAX_WIND_MPS), ("spawn_jitter_m", MAX_SPAWN_JITTER_M)):
        if key in swarm:
            value = reader.number(swarm, key, where, "nonneg")
            if value > largest:
                raise reader.fail(where, key, f"at most {largest:g}, got {value:g}")
            out[key] = value
    if "quantum" in swarm:
        quantum = int(reader.number(swarm, "quantum", where, "count"))
        if quantum > MAX_QUANTUM:
            raise reader.fail(where, "quantum", f"must be in 1..{MAX_QUANTUM} physics steps, got {quantum}")
        out["quantum"] = quantum
    table = swarm.get("drone", {})
    if not isinstance(table, dict):
        raise reader.fail(where, "drone", "must be [swarm.drone.N] tables with params, e.g. [swarm.drone.2]")
    per_drone = []
    for key, settings in sorted(table.items(), key=lambda kv: str(kv[0])):
        where_drone: tuple[str | None, int | None] = (f"swarm.drone.{key}", None)
        if not str(key).isdigit() or not 1 <= int(key) <= drones:
            raise reader.fail(where, "drone", f"[swarm.drone.{key}]: must name a drone 1..{drones}")
        if not isinstance(settings, dict):
            raise reader.fail(where_drone, None, "must be a table with params")
        reader.check_keys(settings, {"params"}, where_drone)
        per_drone.append((int(key), _params(reader, settings.get("params", {}), where_drone)))
    out["drone_params"] = tuple(sorted(per_drone))
    return out


def _timed_faults(reader: _Reader, tables: Any, drones: int) -> tuple[FaultStep, ...]:
    """``[[faults]]``: a fault step's fields, ``at_s`` (mission time) for its ``after_s``."""
    if not isinstance(tables, list) or not all(isinstance(t, dict) for t in tables):
        raise reader.fail((None, None), "faults", "must be [[faults]] tables with drone, fault and at_s")
    out = []
    for k, table in enumerate(tables):
        where: tuple[str | None, int | None] = ("faults", k)
        if "at_s" not in table:
            raise reader.fail(where, None, "missing field 'at_s' (the mission time it happens at)")
        fields = {("after_s" if key == "at_s" else key): value for key, value in table.items()}
        if "after_s" in table:
            raise reader.fail(where, "after_s", "a [[faults]] table takes at_s (mission time), not after_s")
        out.append(_fault(reader, fields, where, drones, time_key="at_s"))
    return tuple(sorted(out, key=lambda f: f.after_s))


def _invariants(reader: _Reader, tables: Any, drones: int) -> tuple[Invariant, ...]:
    """``[[invariants]]``: each table one invariant (gcs/invariants/spec.py), named by its line when it is wrong."""
    if not isinstance(tables, list) or not all(isinstance(t, dict) for t in tables):
        raise reader.fail((None, None), "invariants", "must be [[invariants]] tables, each with a kind")
    out = []
    for k, table in enumerate(tables):
        try:
            out.append(build_invariant(table, base=reader.path.parent, drone_count=drones))
        except InvariantError as exc:
            field, sep, problem = str(exc).partition(": ")
            named = sep and field in table
            raise reader.fail(("invariants", k), field if named else None, problem if named else str(exc)) from None
    try:
        unique_names(out)
    except InvariantError as exc:
        raise reader.fail((None, None), "invariants", str(exc)) from None
    return tuple(out)


def parse_mission(text: str, path: Path, *, max_obstacles: int | None = None) -> MissionSpec:
    """The mission in ``text`` (read from ``path``); ``max_obstacles``: what the simulation's world holds."""
    reader = _Reader(path, _Locator(text))
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise MissionFileError(f"{path}: not valid TOML: {exc}") from None
    # ([falsify] is swarm falsify's: the space it searches, docs/falsify.md; a flight leaves it alone)
    reader.check_keys(data, {"name", "description", "swarm", "steps", "obstacles", "invariants", "faults", "falsify"},
                      (None, None))  # fmt: skip
    swarm = data.get("swarm")
    if not isinstance(swarm, dict):
        raise reader.fail((None, None), None, "missing [swarm] table with 'drones'")
    where_swarm: tuple[str | None, int | None] = ("swarm", None)
    reader.check_keys(swarm, {"drones", "layout", "spacing_m", "params", "relay", "relay_scope", "loss_policy", "links",
                              "neighbours", "mesh", "behaviour", "attach", "seed", "wind_ned_mps", "gust_mps",
                              "spawn_jitter_m", "quantum", "drone"}, where_swarm)  # fmt: skip
    if "drones" not in swarm:
        raise reader.fail(where_swarm, None, "missing field 'drones'")
    drones = int(reader.number(swarm, "drones", where_swarm, "count"))
    if drones > MAX_DRONES:
        raise reader.fail(where_swarm, "drones", f"at most {MAX_DRONES}, got {drones}")
    layout = swarm.get("layout", "grid")
    if layout not in LAYOUTS:
        raise reader.fail(where_swarm, "layout", f"must be one of {', '.join(sorted(LAYOUTS))}, got {layout!r}")
    spacing = reader.number(swarm, "spacing_m", where_swarm, "pos") if "spacing_m" in swarm else 2.0
    params = _params(reader, swarm.get("params", {}), where_swarm)
    neighbours = _neighbours(reader, swarm)
    policy = swarm.get("loss_policy", LossPolicy.CONTINUE.value)
    if policy not in LOSS_POLICIES:
        raise reader.fail(where_swarm, "loss_policy", f"must be one of {', '.join(LOSS_POLICIES)}, got {policy!r}")
    steps_data = data.get("steps")
    if not isinstance(steps_data, list) or not steps_data:
        raise reader.fail((None, None), None, "missing [[steps]]: a mission needs at least one step")
    steps = tuple(_step(reader, s, i, drones) for i, s in enumerate(steps_data))
    try:
        behaviour = onboard_behaviour(steps, _behaviour(reader, swarm, path))
    except OnboardConflict as exc:
        raise reader.fail(("steps", exc.step), "onboard", str(exc)) from None
    if behaviour is None and any(isinstance(s, BehaviourStep) for s in steps):
        k = next(i for i, s in enumerate(steps) if isinstance(s, BehaviourStep))
        raise reader.fail(("steps", k), "action", 'a behaviour step needs [swarm] behaviour = "file.py:Class"')
    if not isinstance(steps[0], TakeoffStep | PlanStep):
        raise reader.fail(
            ("steps", 0), "action", "the first step must be a takeoff (or a plan whose mission takes off)"
        )
    name = data.get("name", path.stem)
    description = data.get("description", "")
    if not isinstance(name, str) or not isinstance(description, str):
        raise reader.fail((None, None), "name", "name and description must be strings")
    return MissionSpec(
        name=name,
        description=description,
        swarm=SwarmSpec(
            drones=drones,
            layout=layout,
            spacing_m=spacing,
            params=params,
            relay=neighbours.relay,
            relay_scope=neighbours.relay_scope,
            mesh=neighbours.mesh,
            links=_links(reader, swarm.get("links", {})),
            behaviour=behaviour,
            attach=_attach(reader, swarm.get("attach", [])),
            **_conditions(reader, swarm, where_swarm, drones),
        ),
        steps=steps,
        loss_policy=LossPolicy(policy),
        path=path,
        obstacles=_obstacles(reader, data.get("obstacles", []), max_obstacles),
        invariants=_invariants(reader, data.get("invariants", []), drones),
        faults=_timed_faults(reader, data.get("faults", []), drones),
    )


def flown_onboard(mission: MissionSpec) -> MissionSpec:
    """The same mission with every flock and follow step flown by the drones themselves (``swarm fly --onboard``);
    MissionFileError if it has no such step or the drones would need two behaviours (or carry another)."""
    steps = tuple(dataclasses.replace(s, onboard=True) if isinstance(s, FlockStep | FollowStep) else s
                  for s in mission.steps)  # fmt: skip
    if not any(isinstance(s, FlockStep | FollowStep) for s in steps):
        raise MissionFileError(f"{mission.path}: --onboard: the mission has no flock or follow step")
    try:
        behaviour = onboard_behaviour(steps, mission.swarm.behaviour)
    except OnboardConflict as exc:
        raise MissionFileError(f"{mission.path}: --onboard: steps[{exc.step}]: {exc}") from None
    return dataclasses.replace(mission, steps=steps, swarm=dataclasses.replace(mission.swarm, behaviour=behaviour))


class OnboardConflict(ValueError):
    """A step flown onboard needs another behaviour than the drones carry."""

    def __init__(self, step: int, problem: str) -> None:
        super().__init__(problem)
        self.step = step


def onboard_behaviour(steps: tuple[Step, ...], behaviour: str | None) -> str | None:
    """The behaviour the drones carry: a step flown onboard needs the shipped one (set here when [swarm] names none);
    a drone carries one behaviour, so one kind of onboard step per mission."""
    needed = {(k, FLOCKING if isinstance(s, FlockStep) else LEADER_FOLLOWER) for k, s in enumerate(steps)
              if isinstance(s, FlockStep | FollowStep) and s.onboard}  # fmt: skip
    for k, spec in sorted(needed):
        if behaviour is not None and behaviour != spec:
            raise OnboardConflict(k, f"flown onboard with {spec}, but the drones carry {behaviour} (one onboard "
                                     "behaviour per mission)")  # fmt: skip
        behaviour = spec
    return behaviour


def _behaviour(reader: _Reader, swarm: dict[str, Any], path: Path) -> str | None:
    """``[swarm] behaviour = "file.py:Class"``, the file relative to the mission's folder, made absolute (the drones
    start elsewhere). Whether the class loads is the simulation's to say (the CLI asks it before anything starts)."""
    if "behaviour" not in swarm:
        return None
    spec = swarm["behaviour"]
    file, sep, cls = spec.rpartition(":") if isinstance(spec, str) else ("", "", "")
    if not sep or not file or not cls.isidentifier():
        raise reader.fail(("swarm", None), "behaviour", f'must be "path/to/file.py:ClassName", got {spec!r}')
    return absolute_spec(spec, path.parent)


def load_mission(path: Path, *, max_obstacles: int | None = None) -> MissionSpec:
    try:
        text = path.read_text()
    except OSError as exc:
        raise MissionFileError(f"{path}: cannot read: {exc.strerror}") from None
    return parse_mission(text, path, max_obstacles=max_obstacles)
