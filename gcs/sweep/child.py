"""How one run of a sweep ends with its parent: ``python -m gcs.sweep_run ARGS`` (``RUN_MODULE``, the top of the
ground station's layers) is ``swarm ARGS`` tied to its parent by ``tie_to_parent`` first.

The process that starts a run (the sweep, or a Ray worker) may be killed with SIGKILL, which runs none of its clean-up.
So the run asks the kernel for SIGTERM when its parent goes (``PR_SET_PDEATHSIG``, Linux), and ``swarm fly`` answers
SIGTERM as it answers Ctrl-C: it lands and stops its drones. Set in the run, after exec, rather than between fork and
exec, where a multi-threaded parent must not run Python code.

A parent may die before the request is made: the interpreter takes some 70 ms to get there after exec, far longer on a
loaded machine, and a Ray worker killed as soon as its run's process showed up went unnoticed: the run took the dead
parent's successor (init, or a subreaper) for its parent and flew to its end, over 30 s on a loaded CI machine. So the
parent names itself in ``PARENT_ENV`` (gcs/sweep/runs.py ``fly`` does, for a sweep and a Ray task alike), and a run
whose parent is not that process once the request is in place ends at once, having started nothing. Without
``PARENT_ENV`` the parent is the one found there.

The kernel's signal comes when the parent *thread* that forked the run ends, not the process: the thread that starts
a run waits for it to end (gcs/sweep/runs.py ``fly``, in a Ray task's main thread or a sweep's pool thread), so the
two coincide. Once the parent process has gone, the run has ``ORPHAN_GRACE_S`` of wall time to land and stop its
drones as on Ctrl-C (in lockstep a landing takes simulated time, which a loaded machine stretches without bound),
and is then killed: its drone factory and drones end with it (their own ``PR_SET_PDEATHSIG``), and nobody is left
waiting for its result anyway.

The run's entry point lives above the swarm command (gcs/sweep_run.py), not here: the swarm command imports the
sweeps, so a sweep module that ran the swarm command would import its own importer.
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import signal
import threading
import time
from typing import Final

RUN_MODULE: Final = "gcs.sweep_run"  # what a run's process runs (``python -m``): the swarm command, tied to its parent
PR_SET_PDEATHSIG: Final = 1
PARENT_ENV: Final = "SWARM_SWEEP_PARENT"  # the PID of the process that starts the run, set by that process
ORPHAN_GRACE_S: Final = 10.0  # wall time a run whose parent died has to stop on its own before it is killed
WATCH_S: Final = 0.2  # how often the run looks whether its parent is still there


def parent_named() -> dict[str, str]:
    """What the process that is about to start runs puts in its environment: its own PID as their parent's."""
    return {PARENT_ENV: str(os.getpid())}


def _end_when_orphaned(parent: int, signalled: bool) -> None:
    """In a thread of the run: once ``parent`` is no longer the run's parent (it died), SIGTERM the run unless the
    kernel does (``signalled``), give it ORPHAN_GRACE_S, then SIGKILL it."""
    while os.getppid() == parent:
        time.sleep(WATCH_S)
    if not signalled:
        os.kill(os.getpid(), signal.SIGTERM)
    time.sleep(ORPHAN_GRACE_S)
    os.kill(os.getpid(), signal.SIGKILL)


def tie_to_parent() -> bool:
    """In the run's process, before it starts anything: ask for SIGTERM when the parent goes and watch for it going;
    False when the parent has died already (the run must end at once, having started nothing)."""
    named = os.environ.pop(PARENT_ENV, None)  # for this run alone: the processes it starts have a parent of their own
    parent = int(named) if named is not None and named.isdigit() else os.getppid()
    signalled = False
    with contextlib.suppress(OSError, AttributeError):  # not Linux: the thread below sends the SIGTERM itself
        signalled = ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGTERM, 0, 0, 0) == 0
    if os.getppid() != parent:
        return False
    threading.Thread(target=_end_when_orphaned, args=(parent, signalled), name="orphan-watch", daemon=True).start()
    return True
