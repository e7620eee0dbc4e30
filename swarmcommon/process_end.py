"""How the project's processes end: without the interpreter's last garbage collection.

A process that has loaded the drone's code holds millions of objects (numba's and llvmlite's compiled kernels and
their type system above all), and the garbage collection CPython runs while it shuts down visits every one of them:
0.7 s of CPU in a drone, a drone factory or a standalone ``sitl``, paid once per process, so once per flight by a
sweep's or a campaign's every run, and after every flight by the supervisor (0.2 s). Freezing the collector first
(``gc.freeze``: every object goes to a generation no collection visits) skips that pass and nothing else: atexit
handlers, thread joins, logging's flush and the deallocation of whatever its references free still happen as in any
exit; only objects kept alive by reference cycles are left for the kernel to reclaim, which CPython never promises
to finalize at exit anyway.
"""

from __future__ import annotations

import gc
from collections.abc import Callable


def ending(main: Callable[[], int]) -> int:
    """``main()``'s exit code, with the collector frozen once it returned (or raised): the last thing a console
    entry point does before the interpreter shuts down. Never call it from code that goes on running (a test calling
    a command's ``main``): frozen objects are never collected."""
    try:
        return main()
    finally:
        gc.freeze()
