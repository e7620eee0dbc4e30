"""Seeded Gaussian noise drawn in blocks.

Drawing three normals per sensor per 400 Hz step from ``numpy.random.Generator`` costs a call each time; drawing a
block of a few thousand at once and handing them out keeps the physics loop cheap while staying exactly
reproducible for a given seed (the block size is fixed, so the sequence does not depend on timing).
"""

from __future__ import annotations

import numpy as np

from sitl.mathutil import Vec3

_BLOCK = 4096


class NoiseSource:
    """Standard-normal 3-vectors from one seeded stream; each sensor owns its own stream."""

    def __init__(self, rng: np.random.Generator) -> None:
        self._rng = rng
        self._block = rng.standard_normal((_BLOCK, 3))
        self._next = 0

    def vec3(self) -> Vec3:
        if self._next == _BLOCK:
            self._block = self._rng.standard_normal((_BLOCK, 3))
            self._next = 0
        row = self._block[self._next]
        self._next += 1
        return row

    def scalar(self) -> float:
        return float(self.vec3()[0])
