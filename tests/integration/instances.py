"""Instances for the integration tests, leased across every process on this machine.

A test that starts drones needs instance numbers whose UDP ports nobody else uses (a drone's ports follow its
instance: sitl/process/ports.py). Tests that run at once (pytest-xdist workers, two suites on one machine, a
``swarm sweep`` a test or a user started) must not share them, so every test leases its instances through the
machine's instance locks, the ones ``swarm sweep`` runs hold (gcs/sweep/instance_locks.py: ``fcntl.flock`` on a
file per instance; the kernel drops a lock with its holder, so a killed run frees its instances). No file of the
suite names an instance number of its own; which instances a test gets does not change what it flies (a drone's
randomness comes from its seed).

A lease is a block of consecutive instances at or above ``--sitl-instance-base`` (default 20) and at most
HIGHEST_INSTANCE, clear of a user's instances 0-9 and of a ground station's port 14550, whose ports were all found
free. Sysids from 200 up are left to the tests' own stand-ins (a stranger sending garbage, probes, observers), so no
drone of the suite ever has one. Blocks are taken round robin
from where the process's last lease ended, so a test never receives stray datagrams still in flight to the ports of
the test before it. A block held for a whole session (``from_top``) is taken from the top of the range instead: one
held low for an hour would sit where a test needing a large block containing a low instance must take it
(tests/integration/test_many_drones_ports.py: 42 instances containing instance 38 must fit in 20-79), and no
reservation can wait out a holder that never lets go.
"""

from __future__ import annotations

import contextlib
import os
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import IO, Final

from gcs.sweep.instance_locks import InstanceLocks
from tests.integration.sitl_process import DronePorts, instance_is_clear_of_user_ports, udp_port_is_free
from tests.timing import LEASE, waiting

DEFAULT_LOWEST_INSTANCE: Final = 20
HIGHEST_INSTANCE: Final = 198  # sysid 199: sysids 200-254 are the tests' stand-ins, 255 the ground station's
LEASE_TIMEOUT_S: Final = 120.0  # wall seconds to wait for a block while other tests hold the rest
_RETRY_S: Final = 0.2
_RESERVE_AFTER_S: Final = 2.0  # wall seconds of finding no whole block free before reserving one (``_reserve``)
_RESERVE_STALL_S: Final = 150.0  # a reservation that gains no instance for this long lets go (longer than a test)


class LeaseError(RuntimeError):
    """No block of the size asked for came free in time."""


@dataclass
class _Cursor:
    """Where this process looks first for its next block (round robin over the instances)."""

    next_first: int = -1


_cursor = _Cursor()
_HELD_HERE: set[int] = set()  # the instances this process's leases hold: a reservation must not wait for them


def _worker_offset() -> int:
    """Workers start their round robin apart, so that they seldom try the same block at once."""
    digits = os.environ.get("PYTEST_XDIST_WORKER", "gw0").removeprefix("gw")
    return 64 * int(digits) if digits.isdigit() else 0


@dataclass
class Lease:
    """Instances ``first`` to ``first + count - 1``, held until ``release``."""

    first: int
    count: int
    _held: list[IO[bytes]] = field(repr=False)

    @property
    def instances(self) -> range:
        return range(self.first, self.first + self.count)

    def __post_init__(self) -> None:
        _HELD_HERE.update(self.instances)

    def release(self) -> None:
        for handle in self._held:
            handle.close()
        if self._held:
            _HELD_HERE.difference_update(self.instances)
        self._held.clear()


def _usable(first: int, count: int, containing: int | None) -> bool:
    block = range(first, first + count)
    return (containing is None or containing in block) and all(instance_is_clear_of_user_ports(i) for i in block)


def lease(count: int, *, lowest: int = DEFAULT_LOWEST_INSTANCE, containing: int | None = None,
          timeout_s: float = LEASE_TIMEOUT_S, from_top: bool = False) -> Lease:  # fmt: skip
    """A block of ``count`` consecutive instances nobody else on the machine holds, with their ports free;
    ``containing``: the block must include this instance (a test of what changes at an instance); ``from_top``: the
    highest free block, for a lease held for the whole session (the module's docstring says why). Waits while
    other tests hold every block that fits; after ``_RESERVE_AFTER_S`` of that it reserves one (``_reserve``), so
    that a large block is not starved by the small ones other workers and sweeps keep taking inside it."""
    starts = [f for f in range(lowest, HIGHEST_INSTANCE - count + 2) if _usable(f, count, containing)]
    if not starts:
        raise LeaseError(f"no block of {count} instances from {lowest} up (containing {containing}) exists")
    if _cursor.next_first < 0:
        _cursor.next_first = lowest + _worker_offset()
    locks = InstanceLocks(count)
    deadline = time.monotonic() + timeout_s
    reserve_at = time.monotonic() + _RESERVE_AFTER_S
    while True:
        pivot = next((i for i, f in enumerate(starts) if f >= _cursor.next_first), 0)
        others = locks.reserved()
        for first in starts[::-1] if from_top else starts[pivot:] + starts[:pivot]:
            held = locks.try_hold(first, reserved=others)
            if held is None:
                continue
            if _ports_free(first, count):
                if not from_top:
                    _cursor.next_first = first + count
                return Lease(first, count, held)
            for handle in held:
                handle.close()
        if time.monotonic() > deadline:
            raise LeaseError(f"no {count} consecutive instances from {lowest} up came free in {timeout_s:g} s")
        if time.monotonic() > reserve_at:
            mine = [f for f in starts if _HELD_HERE.isdisjoint(range(f, f + count))]  # never wait for itself
            if mine and (reserved := _reserve(mine, count, deadline)) is not None:
                if not from_top:
                    _cursor.next_first = reserved.first + count
                return reserved
            reserve_at = time.monotonic() + _RESERVE_AFTER_S
        time.sleep(_RETRY_S)


def _ports_free(first: int, count: int) -> bool:
    return all(udp_port_is_free(p) for i in range(first, first + count) for p in DronePorts(instance=i).all())


def _reserve(starts: list[int], count: int, deadline: float) -> Lease | None:
    """Reserve the block with the most instances free (gcs/sweep/instance_locks.py: nobody else then starts to hold an
    instance inside it, a sweep's runs or another worker's tests) and hold each of its instances as its holder lets
    it go. A reservation that gains nothing for ``_RESERVE_STALL_S`` lets everything go and returns None: a test in
    another process that holds one lease inside it while it waits for a second must not be waited for forever (this
    process's own leases are never in it: ``_HELD_HERE``)."""
    one = InstanceLocks(1)
    free: set[int] = set()
    for instance in range(starts[0], starts[-1] + count):
        if (probe := one.try_hold(instance)) is not None:
            free.add(instance)
            probe[0].close()
    reservation = InstanceLocks(count).reserve(starts, free)
    if reservation is None:
        return None  # every block that fits meets another's reservation: wait for it like any holder
    held: dict[int, IO[bytes]] = {}
    gained_at = time.monotonic()
    try:
        while len(held) < count:
            for instance in reservation.instances:
                if instance not in held and (handle := one.try_hold(instance, own=reservation)) is not None:
                    held[instance] = handle[0]
                    gained_at = time.monotonic()
            if len(held) < count:
                if time.monotonic() > min(deadline, gained_at + _RESERVE_STALL_S):
                    return None
                time.sleep(_RETRY_S)
        while not _ports_free(reservation.first, count):
            if time.monotonic() > deadline:
                return None
            time.sleep(_RETRY_S)
        taken = Lease(reservation.first, count, [held[i] for i in reservation.instances])
        held = {}
        return taken
    finally:
        reservation.release()
        for h in held.values():
            h.close()


class Leases:
    """The leases one test (or one module) takes; all given back at its end."""

    def __init__(self, lowest: int = DEFAULT_LOWEST_INSTANCE) -> None:
        self._lowest = lowest
        self._leases: list[Lease] = []

    def __call__(self, count: int = 1, *, containing: int | None = None, timeout_s: float = LEASE_TIMEOUT_S,
                 from_top: bool = False) -> int:  # fmt: skip
        """The first instance of a fresh block of ``count`` (``lease`` says what the keywords do)."""
        with waiting(LEASE):
            taken = lease(count, lowest=self._lowest, containing=containing, timeout_s=timeout_s, from_top=from_top)
        self._leases.append(taken)
        return taken.first

    def release(self) -> None:
        for taken in self._leases:
            taken.release()
        self._leases.clear()


@contextlib.contextmanager
def leases(lowest: int = DEFAULT_LOWEST_INSTANCE) -> Iterator[Leases]:
    held = Leases(lowest)
    try:
        yield held
    finally:
        held.release()
