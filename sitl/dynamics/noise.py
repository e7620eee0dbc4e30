"""Seeded Gaussian noise drawn in blocks.

Drawing three normals per sensor per physics step from ``numpy.random.Generator`` costs a call each time; drawing a
block of a few thousand at once and handing them out keeps the physics loop cheap while staying exactly
reproducible for a given seed (the block size is fixed, so the sequence does not depend on timing).
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from sitl.mathutil import Vec3

_BLOCK = 4096
# Rows become Python floats this many at a time, when ``floats3`` first reaches them: most of an IMU's rows go to the
# kernel of a step between ticks straight from the block (``take_rows``), and turning a whole block into lists took
# 1.0 of a refill's 1.1 ms.
_CHUNK = 64


class NoiseSource:
    """Standard-normal 3-vectors from one seeded stream; each sensor owns its own stream.

    ``vec3`` hands out a row of the block as a numpy array, ``floats3`` the same row as Python floats (cheaper for
    scalar arithmetic); both consume the stream identically, one row per call.
    """

    def __init__(self, rng: np.random.Generator) -> None:
        self._rng = rng
        self._block = rng.standard_normal((_BLOCK, 3))
        self._next = 0
        self._rows: list[list[float]] = []  # rows ``_rows_from`` .. ``_listed_to`` of the block as floats
        self._rows_from = self._listed_to = 0

    def _refill(self) -> None:
        self._block = self._rng.standard_normal((_BLOCK, 3))
        self._next = 0
        self._rows_from = self._listed_to = 0

    def vec3(self) -> Vec3:
        if self._next == _BLOCK:
            self._refill()
        row = self._block[self._next]
        self._next += 1
        return row

    def floats3(self) -> tuple[float, float, float]:
        if self._next == _BLOCK:
            self._refill()
        i = self._next
        if i >= self._listed_to:  # rows taken in between by a kernel are never listed
            self._rows_from, self._listed_to = i, min(i + _CHUNK, _BLOCK)
            self._rows = self._block[i : self._listed_to].tolist()
        x, y, z = self._rows[i - self._rows_from]
        self._next = i + 1
        return x, y, z

    def holds(self, count: int) -> bool:
        """Does the block still hold ``count`` rows (so that ``take_rows(count)`` will not return None)?"""
        return self._next + count <= _BLOCK

    def take_rows(self, count: int) -> tuple[npt.NDArray[np.float64], int] | None:
        """The block and the index of the next ``count`` rows, handed out at once to a kernel that reads them itself
        (sitl/kernels/between_ticks.py): the stream is consumed as ``count`` calls of ``floats3`` would consume it.
        None when the block holds fewer (the caller draws them one by one, refilling as ``floats3`` does)."""
        first = self._next
        if first + count > _BLOCK:
            return None
        self._next = first + count
        return self._block, first

    def scalar(self) -> float:
        return self.floats3()[0]
