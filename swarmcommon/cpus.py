"""How many CPUs a process may use, and whether one is idle now, read alike wherever it is asked: the harness (how many
processes host the drones), the command line (how many flights a sweep or a falsify campaign runs side by side), and
the two sides of a lockstep gate (whether to look again before sleeping)."""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from typing import Final

# Wall seconds a lockstep waiter looks again, without sleeping, while no task waits for a CPU. A swarm whose drones
# and supervisor wait for each other at every gate pays a wake-up there each time, and on a machine whose idle CPUs
# halt at once a wake-up costs 0.5 ms (docs/benchmarks.md, "What the machine charges for sleeping"): more than a frame
# of one drone's work. Looking again is free only while a CPU would otherwise be idle (``RunQueue``).
LOOK_AGAIN_S: Final = 0.001
LOADAVG: Final = "/proc/loadavg"


def usable_cpus() -> int:
    """CPUs this process may run on (its affinity mask, which containers and taskset narrow), at least 1."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return max(1, os.cpu_count() or 1)


class RunQueue:
    """Whether any task waits for a CPU now: more tasks runnable on the machine (/proc/loadavg's fourth field, which
    counts the caller) than this process may use CPUs. The file is kept open and read again at offset 0 (1.5 us).
    Without it (not Linux) every CPU counts as taken, so nobody looks again."""

    def __init__(self, path: str = LOADAVG) -> None:
        self._cpus = usable_cpus()
        try:
            self._fd: int | None = os.open(path, os.O_RDONLY)
        except OSError:
            self._fd = None

    def crowded(self) -> bool:
        fd = self._fd
        if fd is None:
            return True
        try:
            runnable = int(os.pread(fd, 128, 0).split()[3].split(b"/")[0])
        except (OSError, IndexError, ValueError):
            return True
        return runnable > self._cpus

    def close(self) -> None:
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None


def look_again(ready: Callable[[], bool], queue: RunQueue, budget_s: float = LOOK_AGAIN_S) -> bool:
    """Ask ``ready`` again and again, without sleeping, for up to ``budget_s`` of wall time while no task waits for a
    CPU; whether it became true. The waiter sleeps as before when it returns False: at once when the machine is busy,
    so a waiter never takes the CPU of the one it waits for when there are more tasks than CPUs."""
    if queue.crowded():
        return False
    give_up = time.perf_counter() + budget_s
    while not ready():
        if time.perf_counter() > give_up or queue.crowded():
            return False
    return True
