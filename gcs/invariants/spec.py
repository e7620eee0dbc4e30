"""What an invariant says: a property of one instant, and a form (docs/invariants.md).

Properties (``KINDS``), each a frozen dataclass whose ``breach`` says, for one ``TickState``, which drones break it
and by how much (None: it holds):

- ``separation``: no two airborne drones nearer than ``min_m`` (centre to centre), nor a drone and an attached
  vehicle; a contact a drone reports is a separation of the distance it gives (as the flight report counts it);
- ``contact``: no drone reports a contact (the simulation's truth);
- ``altitude``: every airborne drone between ``min_m`` and ``max_m`` above the origin;
- ``fence``: every drone within ``radius_m`` of the origin, horizontally;
- ``connected``: the graph of airborne drones, an edge between two within ``range_m``, is connected (a
  breadth-first search: the same answer on every CPU);
- ``formation``: every drone with a slot within ``max_m`` of it;
- ``answered``: every command answered within ``within_s``;
- ``no_failsafe``: no drone enters a failsafe, unless a fault was injected into it;
- ``predicate``: a user's function ``file.py:function`` of the ``TickState``, returning True (or None) when it
  holds, False or a sentence saying what is wrong when it does not.

Forms: ``always`` (at every tick; not within ``grace_s`` after each event of kind ``after``, e.g. a formation's
error only once it had ``grace_s`` to form after each step began) and ``eventually`` (within ``within_s`` after
each event of kind ``after``, e.g. re-formed within 10 s of a loss). ``drones`` (1-based, as a mission's fault
steps number them) limits a property to some drones.
"""

from __future__ import annotations

import importlib.util
import math
import sys
from collections import deque
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final, Protocol

from gcs.invariants.state import FAULT, LOSS, START, STEP, TickState, Vec3
from gcs.mavlink.statustext import parse_contact

KINDS: Final = ("separation", "contact", "altitude", "fence", "connected", "formation", "answered", "no_failsafe",
                "predicate")  # fmt: skip
FORMS: Final = ("always", "eventually")
TRIGGERS: Final = (START, LOSS, FAULT, STEP)


class InvariantError(ValueError):
    """An invariant that cannot be checked as written; the message is one line naming the field."""


@dataclass(frozen=True, slots=True)
class Breach:
    """Which drones break a property at one instant, and what was seen (one phrase)."""

    sysids: tuple[int, ...]
    detail: str


class Property(Protocol):
    def breach(self, state: TickState, drones: frozenset[int] | None) -> Breach | None: ...


def _chosen(ids: Iterable[int], drones: frozenset[int] | None) -> list[int]:
    return sorted(s for s in ids if drones is None or s in drones)


def _out_of_bounds(values: Iterable[tuple[int, float]], bad: Callable[[float], bool], each: str,
                   bound: str) -> Breach | None:  # fmt: skip
    """The drones whose value is ``bad``, each said as ``each`` (a format of ``s`` and ``v``), then the ``bound``."""
    out = [(s, v) for s, v in values if bad(v)]
    if not out:
        return None
    return Breach(tuple(s for s, _ in out), ", ".join(each.format(s=s, v=v) for s, v in out) + f" {bound}")


@dataclass(frozen=True, slots=True, kw_only=True)
class Separation:
    min_m: float

    def breach(self, state: TickState, drones: frozenset[int] | None) -> Breach | None:
        flying = _chosen(state.airborne & set(state.positions_ned_m), drones)
        closest: tuple[float, int, int] | None = None
        for i, a in enumerate(flying):
            pa = state.positions_ned_m[a]
            for b in flying[i + 1 :]:
                d = math.dist(pa, state.positions_ned_m[b])
                if closest is None or d < closest[0]:
                    closest = (d, a, b)
            for b, pb in state.attached_ned_m.items():
                d = math.dist(pa, pb)
                if closest is None or d < closest[0]:
                    closest = (d, a, b)
        for a, b, d in _touched(state, drones):  # the moment two touched: positions at ticks come before or after it
            if closest is None or d < closest[0]:
                closest = (d, a, b)
        if closest is None or closest[0] >= self.min_m:
            return None
        d, a, b = closest
        return Breach((a, b), f"{a} and {b} {d:.2f} m apart (at least {self.min_m:g} m)")


def _touched(state: TickState, drones: frozenset[int] | None) -> list[tuple[int, int, float]]:
    """The contacts between two drones reported at this tick by the drones chosen: (reporter, other, distance), the
    distance 0 when the text gives none (the bodies touched; how far apart is not known)."""
    out = []
    for sysid, text in state.contacts:
        contact = parse_contact(text)
        if contact is not None and contact.drone is not None and (drones is None or sysid in drones):
            out.append((sysid, contact.drone, contact.distance_m if contact.distance_m is not None else 0.0))
    return out


@dataclass(frozen=True, slots=True, kw_only=True)
class Contact:
    def breach(self, state: TickState, drones: frozenset[int] | None) -> Breach | None:
        hits = [(s, text) for s, text in state.contacts if drones is None or s in drones]
        if not hits:
            return None
        involved = {s for s, _ in hits} | {b for _, b, _ in _touched(state, drones)}
        return Breach(tuple(sorted(involved)), "; ".join(f"{s}: {text}" for s, text in hits))


@dataclass(frozen=True, slots=True, kw_only=True)
class Altitude:
    min_m: float
    max_m: float

    def breach(self, state: TickState, drones: frozenset[int] | None) -> Breach | None:
        flying = _chosen(state.airborne & set(state.positions_ned_m), drones)
        return _out_of_bounds(((s, -state.positions_ned_m[s][2]) for s in flying),
                              lambda h: not self.min_m <= h <= self.max_m, "{s} at {v:.2f} m",
                              f"(band {self.min_m:g}..{self.max_m:g} m above the origin)")  # fmt: skip


@dataclass(frozen=True, slots=True, kw_only=True)
class Fence:
    radius_m: float

    def breach(self, state: TickState, drones: frozenset[int] | None) -> Breach | None:
        ranges = ((s, math.hypot(*state.positions_ned_m[s][:2])) for s in _chosen(state.positions_ned_m, drones))
        return _out_of_bounds(ranges, lambda r: r > self.radius_m, "{s} {v:.2f} m",
                              f"from the origin (at most {self.radius_m:g} m)")  # fmt: skip


def components(points: Mapping[int, Vec3], range_m: float) -> list[list[int]]:
    """The connected components of the graph with an edge between points within ``range_m``, each sorted, in order
    of their smallest id (breadth-first search)."""
    left = sorted(points)
    out = []
    while left:
        seen = {left[0]}
        queue = deque([left[0]])
        while queue:
            a = queue.popleft()
            for b in left:
                if b not in seen and math.dist(points[a], points[b]) <= range_m:
                    seen.add(b)
                    queue.append(b)
        out.append(sorted(seen))
        left = [s for s in left if s not in seen]
    return out


@dataclass(frozen=True, slots=True, kw_only=True)
class Connected:
    range_m: float

    def breach(self, state: TickState, drones: frozenset[int] | None) -> Breach | None:
        flying = _chosen(state.airborne & set(state.positions_ned_m), drones)
        parts = components({s: state.positions_ned_m[s] for s in flying}, self.range_m)
        if len(parts) <= 1:
            return None
        groups = " | ".join(", ".join(map(str, p)) for p in parts)
        return Breach(tuple(parts[1]) if len(parts) == 2 else tuple(flying),
                      f"{len(parts)} groups out of each other's {self.range_m:g} m: {groups}")  # fmt: skip


@dataclass(frozen=True, slots=True, kw_only=True)
class FormationError:
    max_m: float

    def breach(self, state: TickState, drones: frozenset[int] | None) -> Breach | None:
        errors = ((s, math.dist(state.positions_ned_m[s], state.slots_ned_m[s]))
                  for s in _chosen(set(state.slots_ned_m) & set(state.positions_ned_m), drones))  # fmt: skip
        return _out_of_bounds(errors, lambda e: e > self.max_m, "{s} {v:.2f} m",
                              f"from its slot (at most {self.max_m:g} m)")  # fmt: skip


@dataclass(frozen=True, slots=True, kw_only=True)
class Answered:
    within_s: float

    def breach(self, state: TickState, drones: frozenset[int] | None) -> Breach | None:
        ages = ((s, state.unanswered_s[s]) for s in _chosen(state.unanswered_s, drones))
        return _out_of_bounds(ages, lambda a: a > self.within_s, "{s} unanswered for {v:.1f} s",
                              f"(at most {self.within_s:g} s)")  # fmt: skip


@dataclass(frozen=True, slots=True, kw_only=True)
class NoFailsafe:
    def breach(self, state: TickState, drones: frozenset[int] | None) -> Breach | None:
        hits = [(s, text) for s, text in state.failsafes
                if s not in state.faulted and (drones is None or s in drones)]  # fmt: skip
        if not hits:
            return None
        return Breach(tuple(sorted({s for s, _ in hits})), "; ".join(f"{s}: {text}" for s, text in hits)
                      + " (no fault injected)")  # fmt: skip


@dataclass(frozen=True, slots=True, kw_only=True)
class Predicate:
    """A user's function of the ``TickState`` (``file.py:function``, the path absolute once read)."""

    function: str
    call: Callable[[TickState], Any]

    def breach(self, state: TickState, drones: frozenset[int] | None) -> Breach | None:
        try:
            verdict = self.call(state)
        except Exception as exc:  # the user's code: its failure is a violation, said in one line, not a crash
            return Breach((), f"{self.function} raised {type(exc).__name__}: {' '.join(str(exc).split())}")
        if verdict is None or verdict is True:
            return None
        return Breach((), f"{self.function}: {verdict if isinstance(verdict, str) else 'false'}")


@dataclass(frozen=True, slots=True, kw_only=True)
class Invariant:
    """A property, its form, and the drones it is about (1-based, as a mission numbers them; None: all)."""

    name: str
    kind: str
    prop: Property
    form: str = "always"
    after: str = START
    grace_s: float = 0.0  # always: not checked this long after each ``after`` event
    within_s: float = 0.0  # eventually: must hold this soon after each ``after`` event
    drones: tuple[int, ...] | None = None

    def describe(self) -> str:
        if self.form == "eventually":
            return f"{self.name} within {self.within_s:g} s of each {self.after}"
        grace = f" ({self.grace_s:g} s after each {self.after})" if self.grace_s > 0 else ""
        return f"{self.name} always{grace}"


# ---- reading ------------------------------------------------------------------------------------------------------
_PARAMS: Final[dict[str, tuple[str, ...]]] = {
    "separation": ("min_m",),
    "contact": (),
    "altitude": ("min_m", "max_m"),
    "fence": ("radius_m",),
    "connected": ("range_m",),
    "formation": ("max_m",),
    "answered": ("within_s",),
    "no_failsafe": (),
    "predicate": ("function",),
}
_COMMON: Final = ("kind", "name", "form", "after", "grace_s", "within_s", "drones")


def _number(fields: Mapping[str, Any], key: str, *, positive: bool = True) -> float:
    value = fields[key]
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise InvariantError(f"{key}: must be a number, got {value!r}")
    if value < 0 or (positive and value == 0):
        raise InvariantError(f"{key}: must be {'positive' if positive else 'zero or more'}, got {value!r}")
    return float(value)


def load_predicate(text: str, base: Path) -> Callable[[TickState], Any]:
    """``file.py:function`` (the file relative to ``base``); InvariantError (one line) when it cannot be loaded."""
    file, sep, function = text.rpartition(":")
    if not sep or not file.endswith(".py") or not function.isidentifier():
        raise InvariantError(f"function: must be file.py:function, got {text!r}")
    path = (base / file).resolve()
    if not path.is_file():
        raise InvariantError(f"function: no file {path}")
    name = f"swarm_invariant_{abs(hash(str(path)))}"
    try:
        spec = importlib.util.spec_from_file_location(name, path)
        assert spec is not None and spec.loader is not None
        module = importlib.util.module_from_spec(spec)
        sys.modules[name] = module
        spec.loader.exec_module(module)
    except Exception as exc:  # the user's file: any error importing it is one line
        raise InvariantError(f"function: {path} cannot be imported: {type(exc).__name__}: {exc}") from None
    call = getattr(module, function, None)
    if not callable(call):
        raise InvariantError(f"function: {path} has no function {function!r}")
    return call


def build_invariant(fields: Mapping[str, Any], *, base: Path, drone_count: int) -> Invariant:
    """An invariant from plain fields (a mission's ``[[invariants]]`` table, the API's keywords); InvariantError
    (one line, naming the field) for a kind, form or event that does not exist, a missing or bad number, a drone
    the swarm does not have, or a predicate that cannot be imported."""
    kind = fields.get("kind")
    if kind not in KINDS:
        raise InvariantError(f"kind: must be one of {', '.join(KINDS)}, got {kind!r}")
    params = _PARAMS[kind]
    for key in fields:
        if key not in _COMMON and key not in params:
            raise InvariantError(f"{key}: not a field of a {kind} invariant (fields: {', '.join(params) or 'none'})")
    for key in params:
        if key not in fields:
            raise InvariantError(f"missing field '{key}' for a {kind} invariant")
    form = fields.get("form", "always")
    if form not in FORMS:
        raise InvariantError(f"form: must be one of {', '.join(FORMS)}, got {form!r}")
    after = fields.get("after", START)
    if after not in TRIGGERS:
        raise InvariantError(f"after: must be one of {', '.join(TRIGGERS)}, got {after!r}")
    if form == "eventually" and "within_s" not in fields:
        raise InvariantError("missing field 'within_s' for an eventually invariant")
    if form == "always" and "within_s" in fields and kind != "answered":
        raise InvariantError("within_s: only for form = 'eventually' (or an answered invariant)")
    name = fields.get("name", kind)
    if not isinstance(name, str) or not name:
        raise InvariantError(f"name: must be a string, got {name!r}")
    drones = fields.get("drones")
    if drones is not None:
        if (
            not isinstance(drones, list | tuple)
            or not drones
            or not all(isinstance(d, int) and not isinstance(d, bool) for d in drones)
        ):
            raise InvariantError(f"drones: must be a list of drone numbers, got {drones!r}")
        bad = [d for d in drones if not 1 <= d <= drone_count]
        if bad:
            raise InvariantError(f"drones: no drone {bad[0]} (the swarm's drones are 1..{drone_count})")
        drones = tuple(sorted(set(drones)))
    prop = _property(kind, fields, base)
    return Invariant(
        name=name, kind=kind, prop=prop, form=form, after=after, drones=drones,
        grace_s=_number(fields, "grace_s", positive=False) if "grace_s" in fields else 0.0,
        within_s=_number(fields, "within_s") if form == "eventually" else 0.0,
    )  # fmt: skip


def _property(kind: str, fields: Mapping[str, Any], base: Path) -> Property:
    if kind == "separation":
        return Separation(min_m=_number(fields, "min_m"))
    if kind == "contact":
        return Contact()
    if kind == "altitude":
        low, high = _number(fields, "min_m", positive=False), _number(fields, "max_m")
        if low >= high:
            raise InvariantError(f"min_m: must be below max_m, got {low:g} and {high:g}")
        return Altitude(min_m=low, max_m=high)
    if kind == "fence":
        return Fence(radius_m=_number(fields, "radius_m"))
    if kind == "connected":
        return Connected(range_m=_number(fields, "range_m"))
    if kind == "formation":
        return FormationError(max_m=_number(fields, "max_m"))
    if kind == "answered":
        return Answered(within_s=_number(fields, "within_s"))
    if kind == "no_failsafe":
        return NoFailsafe()
    function = fields["function"]
    if not isinstance(function, str):
        raise InvariantError(f"function: must be file.py:function, got {function!r}")
    call = load_predicate(function, base)
    file, _, name = function.rpartition(":")
    return Predicate(function=f"{(base / file).resolve()}:{name}", call=call)


def unique_names(invariants: Sequence[Invariant]) -> None:
    """InvariantError when two invariants share a name (their violations would be told apart by it)."""
    seen: set[str] = set()
    for inv in invariants:
        if inv.name in seen:
            raise InvariantError(f"name: two invariants named {inv.name!r} (give each its own name)")
        seen.add(inv.name)
