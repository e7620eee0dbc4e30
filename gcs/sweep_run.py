"""``python -m gcs.sweep_run ARGS``: ``swarm ARGS`` as one run of a sweep, ended with its parent.

The run ties itself to the process that started it (gcs/sweep/child.py ``tie_to_parent``: PR_SET_PDEATHSIG, the
parent named in PARENT_ENV, ORPHAN_GRACE_S), then is the swarm command. It sits above the swarm command in the
ground station's layers (pyproject.toml), the one module that imports both the command and the sweeps' parts: the
command imports the sweeps, so the sweeps cannot import the command back. gcs/sweep/runs.py starts it
(gcs/sweep/child.py ``RUN_MODULE``).
"""

from __future__ import annotations

import sys
from typing import Final

from gcs.sweep.child import tie_to_parent

ORPHANED_EXIT: Final = 130  # the exit code of a run whose parent died before it could ask to end with it


def main() -> int:
    if not tie_to_parent():
        return ORPHANED_EXIT
    # Imported once the run is tied to its parent: the swarm command's imports take a while, and a parent that dies
    # meanwhile must end the run
    from gcs.cli import main as swarm

    return swarm(sys.argv[1:])


if __name__ == "__main__":
    sys.exit(main())
