"""Tests that fly in wall time get the machine to themselves (``pytest.mark.wall_clock``).

Most flights in the suite are lockstep: what they fly does not depend on the machine's load, so the suite runs a test
file on each CPU (pytest-xdist). A flight with an attached vehicle cannot be: the vehicle (a pymavlink script, a
``sitl`` started on its own) keeps wall time, so the simulated drones must keep it too, and beside another worker's
lockstep flight, which takes every CPU it can get, they fell to 0.6x real time on two cores and flew a different
flight (a leader outran its followers, a member never settled in its slot). A longer bound would hide a real
regression; so these tests run alone instead.

A reader-writer lock over the machine, two ``flock`` files in the temporary directory: every test holds the ``machine``
lock shared while it runs, and a wall-clock test holds it exclusively, through every wall-clock test its process runs
next (a module's flight is often a module-scoped fixture that the first test sets up; ``release_after``). The
``gate`` keeps the writer from starving: a writer takes it before it waits for the readers to drain, and a reader
passes through it before it takes its share, so no new reader starts while a writer waits. ``flock`` does not queue
its waiters, so a worker that has just let the gate go and asks again at once (a wall-clock test ends, the next test
of that worker wants a share) would take it before the writer blocked on it: so a writer also holds ``want`` shared
from the moment it asks, and a reader waits while anyone holds it (in a run, a campaign's share slipped in so and
held the next attach flight for 249 s). A killed worker's locks go
with its process. Every pytest session on the machine takes part, so two suites run side by side leave each other's
wall-clock tests alone.
"""

from __future__ import annotations

import fcntl
import os
import tempfile
import time
from pathlib import Path

import pytest

MARK = "wall_clock"
_READER_YIELD_S = 0.05  # how often a reader looks again while a writer waits
SUITE_DIR = Path(tempfile.gettempdir()) / "swarmsitl-tests"  # what the suite keeps on the machine: locks, bytecode


class MachineShare:
    """This process's place in the machine-wide reader-writer lock: nothing held, a share, or the whole machine."""

    def __init__(self, folder: Path = SUITE_DIR) -> None:
        folder.mkdir(parents=True, exist_ok=True)
        self._gate = os.open(folder / "gate.lock", os.O_RDWR | os.O_CREAT, 0o666)
        self._machine = os.open(folder / "machine.lock", os.O_RDWR | os.O_CREAT, 0o666)
        self._want = os.open(folder / "want.lock", os.O_RDWR | os.O_CREAT, 0o666)
        self.held: str | None = None  # "shared", "exclusive" or None

    def share(self) -> None:
        if self.held == "shared":
            return
        self.release()
        while self._a_writer_waits():
            time.sleep(_READER_YIELD_S)
        fcntl.flock(self._gate, fcntl.LOCK_EX)  # waits while a writer holds the gate
        try:
            fcntl.flock(self._machine, fcntl.LOCK_SH)
        finally:
            fcntl.flock(self._gate, fcntl.LOCK_UN)
        self.held = "shared"

    def whole(self) -> None:
        if self.held == "exclusive":
            return
        self.release()
        fcntl.flock(self._want, fcntl.LOCK_SH)  # readers yield from now on...
        try:
            fcntl.flock(self._gate, fcntl.LOCK_EX)  # ...and none passes the gate
            fcntl.flock(self._machine, fcntl.LOCK_EX)  # the readers under way finish
        finally:
            fcntl.flock(self._want, fcntl.LOCK_UN)
        self.held = "exclusive"

    def _a_writer_waits(self) -> bool:
        try:
            fcntl.flock(self._want, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            return True
        fcntl.flock(self._want, fcntl.LOCK_UN)
        return False

    def release(self) -> None:
        if self.held is None:
            return
        fcntl.flock(self._machine, fcntl.LOCK_UN)
        if self.held == "exclusive":
            fcntl.flock(self._gate, fcntl.LOCK_UN)
        self.held = None

    def close(self) -> None:
        self.release()
        os.close(self._gate)
        os.close(self._machine)
        os.close(self._want)


def needs_the_machine(item: pytest.Item) -> bool:
    return item.get_closest_marker(MARK) is not None


def hold_for(share: MachineShare, item: pytest.Item) -> None:
    """Before ``item`` runs: the whole machine for a wall-clock test, a share for any other."""
    if needs_the_machine(item):
        share.whole()
    else:
        share.share()


def release_after(share: MachineShare, item: pytest.Item, nextitem: pytest.Item | None) -> None:
    """After ``item`` ran: a wall-clock test keeps the machine while the next test this process runs needs it too (a
    module's later tests, whose module-scoped flight is torn down with its last; or the next wall-clock file, which
    the scheduler deals right after: let go in between, a test waiting for a share would take it first, and the next
    wall-clock test would then wait its whole length, 218 s of a 522 s acceptance run for a falsification campaign);
    anything else lets go, so that a writer waiting at the gate gets its turn."""
    if needs_the_machine(item) and nextitem is not None and needs_the_machine(nextitem):
        return
    share.release()
