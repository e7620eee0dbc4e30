"""Matrix products that give the same bits on every CPU.

numpy hands ``@`` and ``np.dot`` to OpenBLAS, which picks its kernels by CPU, and their rounding differs: a lockstep
flight, a function of its seeds, would then differ in its last bits between two machines (a sweep spread over a
cluster of mixed CPUs). Elementwise products and sums along an axis give the same bits everywhere, so the ground
station's flight code (frames, behaviours, paths) multiplies with ``mat_mul`` instead. The drone has the same
function of its own (sitl/mathutil.py), since the ground station never imports the simulation
(docs/architecture.md, "The same flight on every CPU").
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt


def mat_mul(a: npt.ArrayLike, b: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """``a @ b`` for a 2-D ``a`` and a 1-D or 2-D ``b``, without BLAS."""
    left = np.asarray(a)
    right = np.asarray(b)
    if right.ndim == 1:
        return np.asarray((left * right[None, :]).sum(axis=1), dtype=np.float64)
    return np.asarray((left[:, :, None] * right[None, :, :]).sum(axis=1), dtype=np.float64)
