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
  (tests/unit/test_kernels.py starts them together). numba judges a cached kernel by its own source file only, yet
  the machine code of a kernel holds the kernels it calls from other modules: the whole cache is dropped when any
  kernel module's source differs from the one it was compiled from (``_drop_stale_cache``);
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

import contextlib
import hashlib
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar, cast

F = TypeVar("F", bound=Callable[..., Any])

# Set to "python" to run every kernel uncompiled (debugging, bisecting); anything else compiles.
KERNELS_ENV = "SWARM_KERNELS"


def compiled() -> bool:
    """Whether kernels run compiled in this process (not with SWARM_KERNELS=python or NUMBA_DISABLE_JIT=1)."""
    return os.environ.get(KERNELS_ENV, "") != "python" and os.environ.get("NUMBA_DISABLE_JIT", "0") in ("", "0")


# The file in the cache directory that names the kernel sources its compiled code came from.
FINGERPRINT_FILE = "swarm-kernels.sources"
_checked_cache = False


def sources_fingerprint() -> str:
    """A hash of every kernel module's source (this package's ``.py`` files)."""
    digest = hashlib.sha256()
    for path in sorted(Path(__file__).parent.glob("*.py")):
        digest.update(path.name.encode() + b"\0" + path.read_bytes() + b"\0")
    return digest.hexdigest()


def drop_stale_cache(cache_dir: Path, fingerprint: str) -> bool:
    """Delete the compiled kernels in ``cache_dir`` unless they were compiled from the sources ``fingerprint``
    names, then record it; whether anything was dropped. A kernel calling one of another module is compiled with
    the callee's machine code inside it, and numba would keep using it after only the callee's source changed
    (it checks the caller's file alone). Processes starting together may each drop and recompile: every one of
    them compiles the same current sources."""
    stamp = cache_dir / FINGERPRINT_FILE
    with contextlib.suppress(OSError):
        if stamp.read_text() == fingerprint:
            return False
    dropped = False
    for pattern in ("*.nbi", "*.nbc"):
        for path in cache_dir.glob(pattern):
            with contextlib.suppress(OSError):  # another process dropped it first
                path.unlink()
                dropped = True
    with contextlib.suppress(OSError):  # a read-only tree: numba caches elsewhere or not at all
        cache_dir.mkdir(parents=True, exist_ok=True)
        partial = cache_dir / f"{FINGERPRINT_FILE}.{os.getpid()}"
        partial.write_text(fingerprint)
        os.replace(partial, stamp)
    return dropped


def _drop_stale_cache(function: Callable[..., Any]) -> None:
    """``drop_stale_cache`` for the directory numba caches this package's kernels in, once per process, before the
    first kernel is compiled or loaded."""
    global _checked_cache
    if _checked_cache:
        return
    _checked_cache = True
    try:
        from numba.core.caching import FunctionCache

        cache_dir = Path(FunctionCache(function)._cache_path)
    except Exception:  # numba's locator moved: its own checks remain
        return
    drop_stale_cache(cache_dir, sources_fingerprint())


def kernel(signature: str) -> Callable[[F], F]:
    """Compile ``function`` for ``signature`` when its module is imported, cached on disk, without fastmath or
    threads; or leave it Python when kernels are switched off (``compiled``)."""

    def wrap(function: F) -> F:
        if not compiled():
            return function
        import numba

        _drop_stale_cache(function)
        compile_ = numba.njit(signature, cache=True, fastmath=False, parallel=False, nogil=False)
        return cast(F, compile_(function))

    return wrap
