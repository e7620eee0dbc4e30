"""The invariants checked at every tick (pure: ``TickState`` in, violations out).

``Monitor.check`` applies each invariant's form to its property (gcs/invariants/spec.py): ``always`` checks it at the
tick unless the tick is within ``grace_s`` of the last ``after`` event; ``eventually`` opens a window at each
``after`` event and is violated when a window reaches its end without one tick at which the property held (a tick
that holds closes every open window). Only the first violation of each invariant is kept, and an invariant that
has failed is not checked again: what a user reads is when and how it first broke.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from gcs.invariants.spec import Invariant
from gcs.invariants.state import TickState

# ``swarm fly``'s exit code for a flight that flew (its report written) and broke one of its invariants: apart from a
# failure (1), so that a sweep counts the run as flown and its violations as an outcome
EXIT_VIOLATED = 3


@dataclass(frozen=True, slots=True, kw_only=True)
class Violation:
    """The first violation of one invariant."""

    name: str
    kind: str
    time_s: float  # mission time
    sysids: tuple[int, ...]  # the drones involved (none for a user's predicate that names none)
    detail: str

    def line(self) -> str:
        who = f" (drones {', '.join(map(str, self.sysids))})" if self.sysids else ""
        return f"invariant {self.name} violated at t={self.time_s:.1f} s{who}: {self.detail}"


class Monitor:
    def __init__(self, invariants: Sequence[Invariant], sysids: Sequence[int]) -> None:
        """``sysids``: the swarm's drones in order (a mission's drone k is ``sysids[k - 1]``)."""
        self._sysids = list(sysids)
        self.invariants: tuple[Invariant, ...] = ()
        self._drones: dict[str, frozenset[int] | None] = {}
        self._last_event_s: dict[str, float] = {}  # always: the last ``after`` event's time
        self._windows: dict[str, list[float]] = {}  # eventually: the ends of the windows open
        self.first: dict[str, Violation] = {}
        self.add(invariants)

    def add(self, invariants: Sequence[Invariant]) -> None:
        """More invariants, checked from the next tick; ValueError (one line) for a name already checked."""
        for inv in invariants:
            if inv.name in self._drones:
                raise ValueError(f"an invariant named {inv.name!r} is checked already (give each its own name)")
            sysids = self._sysids
            self._drones[inv.name] = (
                None if inv.drones is None else frozenset(sysids[d - 1] for d in inv.drones if d <= len(sysids))
            )
            self._windows[inv.name] = []
            self.invariants = (*self.invariants, inv)

    def check(self, state: TickState) -> list[Violation]:
        """Check every invariant not yet violated at this tick; the violations new at it."""
        new = []
        for inv in self.invariants:
            if inv.name in self.first:
                continue
            violation = self._check(inv, state)
            if violation is not None:
                self.first[inv.name] = violation
                new.append(violation)
        return new

    def _check(self, inv: Invariant, state: TickState) -> Violation | None:
        triggered = inv.after in state.events
        drones = self._drones[inv.name]
        if inv.form == "always":
            if triggered:
                self._last_event_s[inv.name] = state.time_s
            last = self._last_event_s.get(inv.name)
            if inv.grace_s > 0.0 and last is not None and state.time_s - last < inv.grace_s:
                return None
            breach = inv.prop.breach(state, drones)
            if breach is None:
                return None
            return Violation(name=inv.name, kind=inv.kind, time_s=state.time_s, sysids=breach.sysids,
                             detail=breach.detail)  # fmt: skip
        windows = self._windows[inv.name]
        if triggered:
            windows.append(state.time_s + inv.within_s)
        if not windows:
            return None
        breach = inv.prop.breach(state, drones)
        if breach is None:
            windows.clear()
            return None
        if min(windows) > state.time_s:
            return None
        opened = min(windows) - inv.within_s
        return Violation(name=inv.name, kind=inv.kind, time_s=state.time_s, sysids=breach.sysids,
                         detail=f"not within {inv.within_s:g} s of the {inv.after} at t={opened:.1f} s: "
                         f"{breach.detail}")  # fmt: skip
