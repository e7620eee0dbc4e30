"""How many CPUs a process may use: read alike by the ground station (how many simulation processes to start, whether
the lockstep gate may be watched without sleeping) and the drones (whether a lockstep host may)."""

from __future__ import annotations

import os


def usable_cpus() -> int:
    """CPUs this process may run on (its affinity mask, which containers and taskset narrow), at least 1."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return max(1, os.cpu_count() or 1)
