"""How many CPUs a process may use, read alike wherever it is asked: the harness (how many processes host the drones)
and the command line (how many flights a sweep or a falsify campaign runs side by side)."""

from __future__ import annotations

import os


def usable_cpus() -> int:
    """CPUs this process may run on (its affinity mask, which containers and taskset narrow), at least 1."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return max(1, os.cpu_count() or 1)
