"""``python -m gcs.sweep.child ARGS``: ``swarm ARGS`` for one run of a sweep, ended with its parent.

The process that starts a run (the sweep, or a Ray worker) may be killed with SIGKILL, which runs none of its clean-up.
So the run asks the kernel for SIGTERM when its parent goes (``PR_SET_PDEATHSIG``, Linux), and ``swarm fly`` answers
SIGTERM as it answers Ctrl-C: it lands and stops its drones. Set here, after exec, rather than between fork and exec,
where a multi-threaded parent must not run Python code; a parent already gone by then is noticed at once.
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import signal
import sys

PR_SET_PDEATHSIG = 1


def main() -> int:
    parent = os.getppid()
    with contextlib.suppress(OSError, AttributeError):  # not Linux: the run outlives a killed sweep, ends on its own
        ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGTERM, 0, 0, 0)
    if os.getppid() != parent:
        return 130  # the parent died before the request took effect
    from gcs.cli import main as swarm

    return swarm(sys.argv[1:])


if __name__ == "__main__":
    sys.exit(main())
