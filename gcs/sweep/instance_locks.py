"""Instances held across every process on the machine: which run (or test) may use which drone ports.

Runs that share a machine must not share UDP ports, and a drone's ports follow its instance (PX4's convention:
18570+instance, 14580+instance, and a block of their own from instance 40 on: docs/mavlink.md), so every run holds a
lock on each instance it flies: ``fcntl.flock`` on one small file per instance in a directory every sweep on the
machine uses. The kernel drops a lock with its holder, so a sweep killed with SIGKILL frees its instances.

A block nobody lets go of whole (small runs that come and go keep taking instances inside it, always the lowest
free) would starve a large run that needs it, however long it waited. So a process may **reserve** a range: a file
``reserved-FIRST-COUNT.lock`` it holds locked for as long as it waits. Nobody else starts to hold an instance inside a
live reservation, so the range empties as its holders finish, and the reserver takes each instance as it comes free.
A reservation whose holder died has its lock dropped by the kernel, and is ignored (and removed) by the next look.
Reservations never overlap: one is made under the directory's ``reserve.lock``, clear of every live one.
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import tempfile
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Final

from gcs.fleet.harness import LAST_INSTANCE

FIRST_SWEEP_INSTANCE: Final = 20  # below it: the instances `swarm up` and `swarm fly` take by default
MAX_INSTANCE: Final = LAST_INSTANCE  # sysid = instance + 1 <= 254
LOCK_DIR: Final = Path(tempfile.gettempdir()) / "swarm-sweep-instances"
POLL_S: Final = 0.5
_RESERVED_PREFIX: Final = "reserved-"


@dataclass(frozen=True, slots=True)
class Block:
    first: int  # the block's first instance
    fds: tuple[int, ...]  # the open lock files: a process given them holds the locks too


@dataclass
class Reservation:
    """Instances ``first`` to ``first + count - 1`` kept for one waiting holder until ``release``."""

    first: int
    count: int
    path: Path  # the reservation's file, held locked by ``_file`` (opened under another name: ``reserve``)
    _file: IO[bytes]

    @property
    def instances(self) -> range:
        return range(self.first, self.first + self.count)

    def release(self) -> None:
        with contextlib.suppress(OSError):
            self.path.unlink()
        self._file.close()


class InstanceLocks:
    """Blocks of consecutive instances, each held by one run at a time across every process on the machine."""

    def __init__(self, n_drones: int, lock_dir: Path = LOCK_DIR) -> None:
        self.n = n_drones
        self.lock_dir = lock_dir
        self._guard = threading.Lock()  # one thread at a time looks for a block (flock is per open file)

    def try_hold(self, first: int, *, own: Reservation | None = None,
                 reserved: list[range] | None = None) -> list[IO[bytes]] | None:  # fmt: skip
        """The locks of instances ``first`` to ``first + n - 1``, or None (and nothing held) when any is taken or
        inside another's live reservation (``own``: the caller's, which does not count; ``reserved``: the live ones,
        as ``reserved`` gave them, for a caller trying many blocks in one pass). Closing a returned file drops its
        lock."""
        self.lock_dir.mkdir(parents=True, exist_ok=True)
        block = range(first, first + self.n)
        if any(_overlap(block, taken) for taken in (self.reserved(but=own) if reserved is None else reserved)):
            return None
        held: list[IO[bytes]] = []
        for instance in block:
            handle = (self.lock_dir / f"instance-{instance:03d}.lock").open("ab")
            try:
                fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError:
                handle.close()
                for h in held:
                    h.close()
                return None
            held.append(handle)
        return held

    def reserved(self, *, but: Reservation | None = None) -> list[range]:
        """The instances of every live reservation but ``but``; a dead holder's is removed on the way."""
        live: list[range] = []
        for path in self.lock_dir.glob(f"{_RESERVED_PREFIX}*.lock"):
            if but is not None and path == but.path:
                continue
            try:
                first, count = (int(part) for part in path.stem.removeprefix(_RESERVED_PREFIX).split("-"))
                with path.open("rb") as probe:
                    fcntl.flock(probe, fcntl.LOCK_EX | fcntl.LOCK_NB)
                    if os.stat(path).st_ino == os.fstat(probe.fileno()).st_ino:  # not a new one renamed onto it
                        path.unlink()  # nobody holds it: its holder died without letting it go
            except BlockingIOError:
                live.append(range(first, first + count))
            except (OSError, ValueError):
                continue  # gone meanwhile, or not a reservation's name
        return live

    def reserve(self, starts: list[int], free: set[int]) -> Reservation | None:
        """Reserve the block of ``n`` from one of ``starts`` clear of every live reservation with the most instances
        in ``free``; None when every such block meets a live one."""
        self.lock_dir.mkdir(parents=True, exist_ok=True)
        with (self.lock_dir / "reserve.lock").open("ab") as guard:
            fcntl.flock(guard, fcntl.LOCK_EX)  # one reservation made at a time: they never overlap
            others = self.reserved()
            clear = [f for f in starts if not any(_overlap(range(f, f + self.n), r) for r in others)]
            if not clear:
                return None
            first = max(clear, key=lambda f: sum(i in free for i in range(f, f + self.n)))
            # locked under a name nobody looks at, then renamed: a look never finds it unlocked and takes it for dead
            fd, scratch = tempfile.mkstemp(dir=self.lock_dir, prefix=".reserving-")
            handle = os.fdopen(fd, "ab")
            fcntl.flock(handle, fcntl.LOCK_EX)  # the lock goes with the open file, whatever its name
            final = self.lock_dir / f"{_RESERVED_PREFIX}{first:03d}-{self.n:03d}.lock"
            os.rename(scratch, final)
            return Reservation(first, self.n, final, handle)

    @contextlib.contextmanager
    def block(self, stop: threading.Event | None = None) -> Iterator[Block]:
        """A free block of instances, held until the ``with`` ends (and by any process its ``fds`` are passed to);
        waits while every block is taken."""
        starts = range(FIRST_SWEEP_INSTANCE, MAX_INSTANCE - self.n + 2, self.n)
        if not starts:
            raise RuntimeError(f"{self.n} drones do not fit in instances {FIRST_SWEEP_INSTANCE}..{MAX_INSTANCE}")
        while True:
            with self._guard:
                others = self.reserved()
                for first in starts:
                    if (held := self.try_hold(first, reserved=others)) is not None:
                        break
                else:
                    held = None
            if held is not None:
                break
            if stop is not None and stop.wait(POLL_S):
                raise InterruptedError("stopped while waiting for instances")
            if stop is None:
                time.sleep(POLL_S)
        try:
            yield Block(first, tuple(h.fileno() for h in held))
        finally:
            for handle in held:
                handle.close()


def _overlap(a: range, b: range) -> bool:
    return a.start < b.stop and b.start < a.stop
