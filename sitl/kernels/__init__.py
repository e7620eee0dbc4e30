"""Compiled kernels: the per-step numeric work of a drone, compiled once per machine by numba.

Why numba (docs/architecture.md, "Compiled kernels"): the flight core is a few hundred float operations per stage
at 250 Hz, and in Python each stage costs microseconds of interpreter work for nanoseconds of arithmetic; numpy does
not help on 3-vectors (a call costs about 0.35 us whatever its size) and its SIMD transcendentals are not the same
bits on every CPU. A kernel keeps the algorithm in Python syntax, so there is one source for it, and runs it as
machine code with the C library's ``sin``/``atan2`` (the same functions CPython's ``math`` calls).

Rules every kernel follows (``kernel`` enforces the first three):

- **explicit signatures**, so a kernel is compiled (or loaded from the cache) when its module is imported: the
  zygote (sitl/harness/zygote.py) imports every kernel module before it forks, and a forked drone never compiles;
- ``cache=True``: compiled code is kept on disk beside the module (or in ``NUMBA_CACHE_DIR``), once per machine;
  numba writes its cache files atomically, so processes compiling at once on a cold cache are safe
  (tests/unit/test_kernels.py starts them together);
- **no** ``fastmath`` **and no** ``parallel``: no reassociation, no fused multiply-adds, no threads, so a kernel
  gives the bits its Python form gives (tests/unit/test_kernels.py compares both on random states) and the same
  bits on every x86-64 CPU;
- no numpy transcendentals (``np.arctan2``, ``np.exp`` ...) in flight code: they are SIMD code chosen by CPU
  (tests/unit/test_kernels.py lints sitl/ and the ground station's flight laws); and in a kernel
  ``pymath.hypot2``/``hypot3`` instead of ``math.hypot``, which is the C library's in a kernel but CPython's own
  algorithm in Python;
- state lives in float64 arrays with named indices (``FIELD = 3``), one row per drone, so a host can hold the rows
  of all its drones in one array; records built for the event-driven Python parts are built from them.

``SWARM_KERNELS=python`` (or numba's own ``NUMBA_DISABLE_JIT=1``) runs every kernel as plain Python, for a debugger
or a bisection, many times slower. Kernels are written to give their Python form's bits (CPython's ``math.hypot``
and numpy's pairwise sums are spelled out in ``pymath``), and tests/unit/test_kernels.py flies a takeoff both ways
to the same bits, but that is not promised for every flight: treat the Python form as a debugging aid, not as the
reference.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from typing import Any, TypeVar, cast

F = TypeVar("F", bound=Callable[..., Any])

# Set to "python" to run every kernel uncompiled (debugging, bisecting); anything else compiles.
KERNELS_ENV = "SWARM_KERNELS"


def compiled() -> bool:
    """Whether kernels run compiled in this process (not with SWARM_KERNELS=python or NUMBA_DISABLE_JIT=1)."""
    return os.environ.get(KERNELS_ENV, "") != "python" and os.environ.get("NUMBA_DISABLE_JIT", "0") in ("", "0")


def kernel(signature: str) -> Callable[[F], F]:
    """Compile ``function`` for ``signature`` when its module is imported, cached on disk, without fastmath or
    threads; or leave it Python when kernels are switched off (``compiled``)."""

    def wrap(function: F) -> F:
        if not compiled():
            return function
        import numba

        compile_ = numba.njit(signature, cache=True, fastmath=False, parallel=False, nogil=False)
        return cast(F, compile_(function))

    return wrap
