"""The space a falsification searches, and its points as plain mission files (pure).

A mission's ``[falsify]`` table (docs/falsify.md) gives ranges and choices over what a mission file can say
(docs/missions.md): the seed, the wind and gusts, the spawn jitter, and perturbations, each either one drone's
parameter set to one of the values given or a fault injected into one drone at a mission time. A point of the space
(``Scenario``) is written back into the mission as its own keys (``[swarm] seed``, ``[swarm.drone.N] params``,
``[[faults]]``...), so that a flight found by a search is a plain mission file that replays with
``swarm fly FILE --lockstep`` and nothing else.

Every value is given in the direction a search simplifies towards, so that what a shrinker calls smaller is what a
reader calls simpler: fewer perturbations, a fault later and shorter, less wind, the mission's own seed first.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final

from gcs.fleet.faults import FAULT_NAMES
from gcs.flight.onboard import absolute_spec

FALSIFY_KEYS: Final = (
    "seed",
    "wind_ned_mps",
    "gust_mps",
    "spawn_jitter_m",
    "params",
    "param_drones",
    "faults",
    "max_perturbations",
)
FAULT_KEYS: Final = ("kinds", "drones", "at_s", "for_s")
MAX_PERTURBATIONS: Final = 8
DECIMALS: Final = 2  # a drawn time or speed is written to the centimetre (second): a file a person reads


class FalsifyError(ValueError):
    """A ``[falsify]`` table that cannot be searched; the message is one line naming the field."""


@dataclass(frozen=True, slots=True)
class Range:
    low: float
    high: float


@dataclass(frozen=True, slots=True, kw_only=True)
class FaultSpace:
    kinds: tuple[str, ...]
    drones: tuple[int, ...]
    at_s: Range  # when, mission time
    for_s: Range | None  # a link fault's duration (None: link faults last for good)


@dataclass(frozen=True, slots=True, kw_only=True)
class FalsifySpace:
    seeds: tuple[int, int] | None = None  # a range of seeds (None: the mission's own)
    wind_ned_mps: tuple[Range, Range, Range] | None = None
    gust_mps: Range | None = None
    spawn_jitter_m: Range | None = None
    params: tuple[tuple[str, tuple[float, ...]], ...] = ()  # a parameter and the values one drone may be given
    param_drones: tuple[int, ...] = ()  # the drones ``params`` may be given to (empty: every drone)
    faults: FaultSpace | None = None
    max_perturbations: int = 2
    drones: int = 1


@dataclass(frozen=True, slots=True)
class ParamChange:
    """Drone ``drone`` (1-based) flies with parameter ``name`` set to ``value``."""

    drone: int
    name: str
    value: float


@dataclass(frozen=True, slots=True)
class FaultAt:
    """Fault ``kind`` injected into drone ``drone`` at mission time ``at_s`` (a link fault for ``for_s``)."""

    drone: int
    kind: str
    at_s: float
    for_s: float | None = None


Perturbation = ParamChange | FaultAt


@dataclass(frozen=True, slots=True, kw_only=True)
class Scenario:
    """One point of the space."""

    seed: int | None = None  # None: the mission's own
    wind_ned_mps: tuple[float, float, float] | None = None
    gust_mps: float | None = None
    spawn_jitter_m: float | None = None
    perturbations: tuple[Perturbation, ...] = ()
    # cuts a shrinking makes after hypothesis's (gcs/falsify/campaign.py): the mission's first drones and steps only
    drones: int | None = None  # None: every drone of the mission
    steps: int | None = None  # None: every step of the mission

    def describe(self) -> str:
        parts = [] if self.drones is None else [f"{self.drones} drones"]
        if self.steps is not None:
            parts.append(f"its first {self.steps} step(s)")
        if self.seed is not None:
            parts.append(f"seed {self.seed}")
        if self.wind_ned_mps is not None:
            parts.append("wind " + ", ".join(f"{v:g}" for v in self.wind_ned_mps) + " m/s")
        if self.gust_mps is not None:
            parts.append(f"gusts {self.gust_mps:g} m/s")
        if self.spawn_jitter_m is not None:
            parts.append(f"jitter {self.spawn_jitter_m:g} m")
        for p in self.perturbations:
            if isinstance(p, ParamChange):
                parts.append(f"drone {p.drone} {p.name} = {p.value:g}")
            else:
                extra = f" for {p.for_s:g} s" if p.for_s is not None else ""
                parts.append(f"{p.kind} fault on drone {p.drone} at {p.at_s:g} s{extra}")
        return "; ".join(parts) or "the mission as it is"

    def to_json(self) -> dict[str, Any]:
        """JSON-ready, and the scenario's identity: two scenarios are the same flight when their JSON is equal."""
        return {"drones": self.drones, "steps": self.steps, "seed": self.seed,
                "wind_ned_mps": None if self.wind_ned_mps is None else list(self.wind_ned_mps),
                "gust_mps": self.gust_mps, "spawn_jitter_m": self.spawn_jitter_m,
                "perturbations": [{"drone": p.drone, "param": p.name, "value": p.value} if isinstance(p, ParamChange)
                                  else {"drone": p.drone, "fault": p.kind, "at_s": p.at_s, "for_s": p.for_s}
                                  for p in self.perturbations]}  # fmt: skip

    @classmethod
    def from_json(cls, data: Mapping[str, Any]) -> Scenario:
        wind = data["wind_ned_mps"]
        return cls(drones=data.get("drones"), steps=data.get("steps"), seed=data["seed"],
                   wind_ned_mps=None if wind is None else (wind[0], wind[1], wind[2]),
                   gust_mps=data["gust_mps"], spawn_jitter_m=data["spawn_jitter_m"],
                   perturbations=tuple(ParamChange(p["drone"], p["param"], p["value"]) if "param" in p
                                       else FaultAt(p["drone"], p["fault"], p["at_s"], p["for_s"])
                                       for p in data["perturbations"]))  # fmt: skip


# ---- reading ------------------------------------------------------------------------------------------------------
def _finite(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)


def _range(value: Any, key: str, *, low: float = 0.0, high: float = math.inf) -> Range:
    if not isinstance(value, list) or len(value) != 2 or not all(_finite(v) for v in value):
        raise FalsifyError(f"{key}: must be [low, high], got {value!r}")
    lo, hi = float(value[0]), float(value[1])
    if not low <= lo <= hi <= high:
        raise FalsifyError(f"{key}: must be [low, high] with {low:g} <= low <= high <= {high:g}, got {value!r}")
    return Range(lo, hi)


def parse_space(table: Mapping[str, Any], *, drones: int) -> FalsifySpace:
    """A mission's ``[falsify]`` table (``drones``: the mission's count); FalsifyError (one line, naming the field)
    for an unknown key, an empty or reversed range, a fault that does not exist, a drone the swarm does not have."""
    if not isinstance(table, Mapping):
        raise FalsifyError("falsify: must be a table")
    for key in table:
        if key not in FALSIFY_KEYS:
            raise FalsifyError(f"{key}: not a field of [falsify] (fields: {', '.join(FALSIFY_KEYS)})")
    fields: dict[str, Any] = {"drones": drones}
    if "seed" in table:
        seeds = _range(table["seed"], "seed", high=2**31 - 1)
        if not (seeds.low.is_integer() and seeds.high.is_integer()):
            raise FalsifyError(f"seed: must be whole numbers, got {table['seed']!r}")
        fields["seeds"] = (int(seeds.low), int(seeds.high))
    if "wind_ned_mps" in table:
        wind = table["wind_ned_mps"]
        if not isinstance(wind, list) or len(wind) != 3:
            raise FalsifyError(f"wind_ned_mps: must be three [low, high] ranges (north, east, down), got {wind!r}")
        fields["wind_ned_mps"] = tuple(_range(w, "wind_ned_mps", low=-20.0, high=20.0) for w in wind)
    for key in ("gust_mps", "spawn_jitter_m"):
        if key in table:
            fields[key] = _range(table[key], key, high=20.0 if key == "gust_mps" else 10.0)
    params = table.get("params", {})
    if not isinstance(params, Mapping):
        raise FalsifyError(f"params: must be a table of NAME = [values], got {params!r}")
    choices = []
    for name, values in params.items():
        if not isinstance(values, list) or not values or not all(_finite(v) for v in values):
            raise FalsifyError(f"params.{name}: must be a list of the values a drone may be given, got {values!r}")
        choices.append((str(name), tuple(values)))
    fields["params"] = tuple(choices)
    if "param_drones" in table:
        fields["param_drones"] = _drones(table["param_drones"], "param_drones", drones)
    if "faults" in table:
        fields["faults"] = _faults(table["faults"], drones)
    if "max_perturbations" in table:
        most = table["max_perturbations"]
        if isinstance(most, bool) or not isinstance(most, int) or not 0 <= most <= MAX_PERTURBATIONS:
            raise FalsifyError(f"max_perturbations: must be in 0..{MAX_PERTURBATIONS}, got {most!r}")
        fields["max_perturbations"] = most
    space = FalsifySpace(**fields)
    if space.max_perturbations > 0 and not space.params and space.faults is None and not _conditions(space):
        raise FalsifyError("falsify: nothing to vary (give ranges, params or faults)")
    return space


def _conditions(space: FalsifySpace) -> bool:
    return any(v is not None for v in (space.seeds, space.wind_ned_mps, space.gust_mps, space.spawn_jitter_m))


def _drones(chosen: Any, key: str, drones: int) -> tuple[int, ...]:
    if (
        not isinstance(chosen, list)
        or not chosen
        or any(isinstance(d, bool) or not isinstance(d, int) or not 1 <= d <= drones for d in chosen)
    ):
        raise FalsifyError(f"{key}: must be drones of the swarm, 1..{drones}, got {chosen!r}")
    return tuple(sorted(set(chosen)))


def _faults(table: Any, drones: int) -> FaultSpace:
    if not isinstance(table, Mapping):
        raise FalsifyError("faults: must be a table with kinds and at_s")
    for key in table:
        if key not in FAULT_KEYS:
            raise FalsifyError(f"faults.{key}: not a field (fields: {', '.join(FAULT_KEYS)})")
    kinds = table.get("kinds")
    if not isinstance(kinds, list) or not kinds or any(k not in FAULT_NAMES for k in kinds):
        raise FalsifyError(f"faults.kinds: must be a list of faults ({', '.join(FAULT_NAMES)}), got {kinds!r}")
    chosen = _drones(table.get("drones", list(range(1, drones + 1))), "faults.drones", drones)
    if "at_s" not in table:
        raise FalsifyError("faults: missing field 'at_s' ([earliest, latest] mission time)")
    for_s = _range(table["for_s"], "faults.for_s") if "for_s" in table else None
    if for_s is not None and for_s.low <= 0.0:
        raise FalsifyError(f"faults.for_s: a link fault lasts more than 0 s, got {table['for_s']!r}")
    return FaultSpace(kinds=tuple(kinds), drones=chosen, at_s=_range(table["at_s"], "faults.at_s"),
                      for_s=for_s)  # fmt: skip


# ---- writing ------------------------------------------------------------------------------------------------------
def scenario_mission(mission: Mapping[str, Any], scenario: Scenario, base: Path | None = None) -> dict[str, Any]:
    """The mission (as its TOML file reads) with the scenario written into its own keys, without ``[falsify]``: a
    plain mission file. ``base``: the folder of the mission file (absolute), against which the files it names (a
    plan, a behaviour, a predicate, a key) are made absolute: the mission written is read from another folder."""
    out = {k: v for k, v in mission.items() if k != "falsify"}
    if base is not None:
        out = _anchored(out, base)
    swarm = dict(out["swarm"])
    if scenario.seed is not None:
        swarm["seed"] = scenario.seed
    if scenario.wind_ned_mps is not None:
        swarm["wind_ned_mps"] = list(scenario.wind_ned_mps)
    if scenario.gust_mps is not None:
        swarm["gust_mps"] = scenario.gust_mps
    if scenario.spawn_jitter_m is not None:
        swarm["spawn_jitter_m"] = scenario.spawn_jitter_m
    per_drone = {str(k): dict(v) for k, v in swarm.get("drone", {}).items()}
    faults = list(out.get("faults", []))
    for p in scenario.perturbations:
        if isinstance(p, ParamChange):
            settings = per_drone.setdefault(str(p.drone), {})
            settings["params"] = {**settings.get("params", {}), p.name: p.value}
        else:
            fault: dict[str, Any] = {"drone": p.drone, "fault": p.kind, "at_s": p.at_s}
            if p.for_s is not None and p.kind == "link":
                fault["for_s"] = p.for_s
            faults.append(fault)
    if scenario.drones is not None:  # the first drones only: what names the others goes with them
        swarm["drones"] = scenario.drones
        per_drone = {k: v for k, v in per_drone.items() if int(k) <= scenario.drones}
        faults = [f for f in faults if int(f.get("drone", 1)) <= scenario.drones]
    if scenario.steps is not None:
        out["steps"] = list(out["steps"])[: scenario.steps]
    if per_drone:
        swarm["drone"] = per_drone
    else:
        swarm.pop("drone", None)
    out["swarm"] = swarm
    if faults:
        out["faults"] = faults
    else:
        out.pop("faults", None)
    return out


def _anchored(mission: dict[str, Any], base: Path) -> dict[str, Any]:
    """The mission with the files it names relative to its folder made absolute (docs/missions.md says which)."""

    def spec(text: Any) -> Any:  # path/file.py:Name (a module's package.module:Name stays as it is)
        return absolute_spec(text, base) if isinstance(text, str) and ":" in text else text

    def path(text: Any) -> Any:
        return str(base / text) if isinstance(text, str) and not Path(text).is_absolute() else text

    out = dict(mission)
    swarm = dict(out["swarm"])
    if "behaviour" in swarm:
        swarm["behaviour"] = spec(swarm["behaviour"])
    if isinstance(swarm.get("attach"), list):
        swarm["attach"] = [{**a, "signing_key": path(a["signing_key"])} if isinstance(a, dict) and "signing_key" in a
                           else a for a in swarm["attach"]]  # fmt: skip
    out["swarm"] = swarm
    if isinstance(out.get("steps"), list):
        out["steps"] = [{**st, "file": path(st["file"])} if isinstance(st, dict) and "file" in st else st
                        for st in out["steps"]]  # fmt: skip
    if isinstance(out.get("invariants"), list):
        out["invariants"] = [{**inv, "function": spec(inv["function"])} if isinstance(inv, dict) and "function" in inv
                             else inv for inv in out["invariants"]]  # fmt: skip
    return out


def mission_text(mission: Mapping[str, Any], header: Sequence[str] = ()) -> str:
    """A mission as TOML text, each line of ``header`` a comment above it."""
    import tomli_w  # the [falsify] extra's; swarm falsify says so when it is missing

    comments = "".join(f"# {line}\n" for line in header)
    return comments + tomli_w.dumps(dict(mission))


# ---- searching ----------------------------------------------------------------------------------------------------
def strategy(space: FalsifySpace) -> Any:
    """The space as a hypothesis strategy of ``Scenario``, each dimension drawn so that hypothesis's shrinking goes
    where a reader would simplify: the mission's own seed and wind (None) before any other, less gust and jitter,
    fewer perturbations, a fault later (``at_s`` is drawn back from the latest) and shorter."""
    from hypothesis import strategies as st  # the [falsify] extra's

    def drawn(r: Range) -> Any:
        return st.floats(r.low, r.high, allow_nan=False, allow_infinity=False).map(lambda v: round(v, DECIMALS))

    seed = st.none() | st.integers(*space.seeds) if space.seeds is not None else st.none()
    wind = (st.none() | st.tuples(*(drawn(r) for r in space.wind_ned_mps))
            if space.wind_ned_mps is not None else st.none())  # fmt: skip
    gust = drawn(space.gust_mps) if space.gust_mps is not None else st.none()
    jitter = drawn(space.spawn_jitter_m) if space.spawn_jitter_m is not None else st.none()
    kinds: list[Any] = []
    if space.params:
        kinds.append(st.builds(
            lambda drone, choice: ParamChange(drone, choice[0], choice[1]),
            st.sampled_from(space.param_drones or range(1, space.drones + 1)),
            st.sampled_from([(name, value) for name, values in space.params for value in values]),
        ))  # fmt: skip
    faults = space.faults
    if faults is not None:
        latest, span = faults.at_s.high, faults.at_s.high - faults.at_s.low

        def fault(drone: int, kind: str, back: float, for_s: float | None) -> FaultAt:
            return FaultAt(drone, kind, round(latest - back, DECIMALS), for_s if kind == "link" else None)

        duration = drawn(faults.for_s) if faults.for_s is not None else st.none()
        kinds.append(st.builds(fault, st.sampled_from(faults.drones), st.sampled_from(faults.kinds),
                               drawn(Range(0.0, span)), duration))  # fmt: skip
    perturbations = (st.lists(st.one_of(*kinds), max_size=space.max_perturbations).map(tuple)
                     if kinds and space.max_perturbations > 0 else st.just(()))  # fmt: skip

    def scenario(s: int | None, w: Any, g: float | None, j: float | None, p: tuple[Perturbation, ...]) -> Scenario:
        return Scenario(seed=s, wind_ned_mps=w, gust_mps=g, spawn_jitter_m=j, perturbations=p)

    return st.builds(scenario, seed, wind, gust, jitter, perturbations)
