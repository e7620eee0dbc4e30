"""What the ground station's MAVLink clients share: work in flight with MAVSDK's retry timing, and outcomes kept
until taken. No IO and no clock of its own, like the clients.

The command client (commands.py), the parameter client (params.py) and the mission-transfer client
(mission_transfer.py) each keep their own protocol: what they send, which answers count, what an answer does. What
they keep alike is here: a piece of work is keyed (a command to a drone, a parameter on a drone, a transfer with a
drone); one try waits ``timeout_s``; a try that times out is sent again, at most ``retries`` times, and then the work
ends without an answer; an answer that shows progress starts the count afresh; an ended piece of work leaves its
outcome until the caller ``take``s it; a caller that gives up ``cancel``s it, and late answers are ignored.
"""

from __future__ import annotations

import math
from collections.abc import Hashable
from typing import Generic, Protocol, TypeVar


class Try(Protocol):
    """A piece of work as the core times it."""

    due_s: float  # when the current try times out
    retries_left: int


K = TypeVar("K", bound=Hashable)  # what identifies work in flight
KO = TypeVar("KO", bound=Hashable)  # what identifies an outcome (the work's key, unless a client keeps them finer)
W = TypeVar("W", bound=Try)
R = TypeVar("R")


class Transactions(Generic[K, W, KO, R]):
    """Work in flight by key and outcomes by key; see the module docstring."""

    def __init__(self, timeout_s: float, retries: int) -> None:
        self.timeout_s = timeout_s
        self.retries = retries
        self._work: dict[K, W] = {}
        self._done: dict[KO, R] = {}

    # ---- work ------------------------------------------------------------------------------------------------------
    def begin(self, key: K, outcome_key: KO, work: W, now_s: float) -> W:
        """Put ``work`` in flight with its first try timed from ``now_s`` and every retry left; a previous outcome
        under ``outcome_key`` that was never taken is dropped. The caller checks ``running`` first: the same work
        twice is its own misuse, which each client names in its own words."""
        self._done.pop(outcome_key, None)
        self.fresh(work, now_s)
        self._work[key] = work
        return work

    def fresh(self, work: W, now_s: float) -> None:
        """An answer that shows progress: the next try is timed from now, with every retry left again."""
        work.retries_left = self.retries
        work.due_s = now_s + self.timeout_s

    def works(self) -> list[W]:
        """Everything in flight."""
        return list(self._work.values())

    def running(self, key: K) -> W | None:
        return self._work.get(key)

    def timed_out(self, now_s: float) -> list[tuple[W, bool]]:
        """The work whose try has timed out, in the order it was begun, each with whether it is out of retries (to
        end without an answer) or was given one try more (one retry fewer, its next try timed from now)."""
        out: list[tuple[W, bool]] = []
        for work in list(self._work.values()):
            if now_s < work.due_s:
                continue
            exhausted = work.retries_left <= 0
            if not exhausted:
                self.retry(work, now_s)
            out.append((work, exhausted))
        return out

    def retry(self, work: W, now_s: float) -> None:
        """One try more: one retry fewer, the next try timed from now."""
        work.retries_left -= 1
        work.due_s = now_s + self.timeout_s

    def finish(self, key: K, outcome_key: KO, outcome: R) -> None:
        """The work under ``key`` ends with ``outcome``, kept under ``outcome_key`` until taken."""
        del self._work[key]
        self._done[outcome_key] = outcome

    # ---- the caller's side -----------------------------------------------------------------------------------------
    def next_due_s(self) -> float:
        """When a try next times out (inf: nothing in flight)."""
        return min((w.due_s for w in self._work.values()), default=math.inf)

    def cancel(self, key: K, outcome_key: KO) -> None:
        """Forget work its caller gave up waiting for: no more tries, a late answer is ignored."""
        self._work.pop(key, None)
        self._done.pop(outcome_key, None)

    def take(self, outcome_key: KO) -> R | None:
        """How the work ended, once (None while it is in flight or was never begun)."""
        return self._done.pop(outcome_key, None)
