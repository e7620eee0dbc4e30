"""CPython's ``math.hypot`` and numpy's ``sum``, for kernels: the same bits as the Python code they replace.

CPython does not call the C library's ``hypot``: since 3.8 ``math.hypot`` is its own ``vector_norm`` (lossless
scaling by a power of two, squares split exactly with Veltkamp's constant, compensated sums and a differential
correction of the square root), correctly rounded in nearly every case. In a compiled kernel ``math.hypot`` is the C
library's, which differs in the last bit on about one input in ten, so kernels call these instead; written out here
as CPython 3.11 computes it (tests/unit/test_kernels.py holds both to ``math.hypot`` on random inputs of every
scale). Python 3.12 switched the exact squares to ``fma``, which gives the same result but for a rare last bit.

CPython's ``x ** 2`` is the C library's ``pow(x, 2.0)``, which is not always ``x * x`` (glibc's pow is within about
half an ulp, not correctly rounded); in a kernel ``x ** 2`` is ``x * x``, and LLVM turns ``pow(x, 2.0)`` into it too,
so ``py_square`` hides the exponent from the optimiser.

numpy sums a float64 array pairwise (blocks of at most 128 with eight accumulators, halves above that, from an
identity of 0.0), not from left to right; ``np_sum`` does the same, so a kernel's sum of a pixel set is numpy's.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from sitl.kernels import kernel

_T27 = 134217729.0  # 2**27 + 1: Veltkamp's constant, splits a double into two 26-bit halves


@kernel("float64(float64, float64, float64, float64)")
def _norm(a: float, b: float, c: float, largest: float) -> float:
    """CPython 3.11's vector_norm of the non-negative (a, b, c) whose largest is ``largest`` (finite, non-zero)."""
    csum = 1.0
    frac1 = 0.0
    frac2 = 0.0
    frac3 = 0.0
    _mant, max_e = math.frexp(largest)
    if max_e >= -1023:
        scale = math.ldexp(1.0, -max_e)
        for i in range(3):
            x = a if i == 0 else (b if i == 1 else c)
            x *= scale
            t = x * _T27
            hi = t - (t - x)
            lo = x - hi
            x = hi * hi
            oldcsum = csum
            csum += x
            frac1 += (oldcsum - csum) + x
            x = 2.0 * hi * lo
            oldcsum = csum
            csum += x
            frac2 += (oldcsum - csum) + x
            frac3 += lo * lo
        h = math.sqrt(csum - 1.0 + (frac1 + frac2 + frac3))
        x = h
        t = x * _T27
        hi = t - (t - x)
        lo = x - hi
        x = -hi * hi
        oldcsum = csum
        csum += x
        frac1 += (oldcsum - csum) + x
        x = -2.0 * hi * lo
        oldcsum = csum
        csum += x
        frac2 += (oldcsum - csum) + x
        x = -lo * lo
        oldcsum = csum
        csum += x
        frac3 += (oldcsum - csum) + x
        x = csum - 1.0 + (frac1 + frac2 + frac3)
        return (h + x / (2.0 * h)) / scale
    # Scaling would overflow (subnormal inputs): divide by the largest instead.
    for i in range(3):
        x = a if i == 0 else (b if i == 1 else c)
        x /= largest
        x = x * x
        oldcsum = csum
        csum += x
        frac1 += (oldcsum - csum) + x
    return largest * math.sqrt(csum - 1.0 + frac1)


@kernel("float64(float64, float64, float64)")
def hypot3(x: float, y: float, z: float) -> float:
    """``math.hypot(x, y, z)`` as CPython 3.11 computes it."""
    a, b, c = abs(x), abs(y), abs(z)
    largest = max(a, max(b, c))
    if math.isinf(a) or math.isinf(b) or math.isinf(c):
        return math.inf
    if math.isnan(a) or math.isnan(b) or math.isnan(c):
        return math.nan
    if largest == 0.0:
        return largest
    return _norm(a, b, c, largest)


@kernel("float64(float64, float64)")
def hypot2(x: float, y: float) -> float:
    """``math.hypot(x, y)`` as CPython 3.11 computes it (a zero third coordinate changes none of its sums)."""
    return hypot3(x, y, 0.0)


@kernel("float64(float64, float64)")
def pmax(a: float, b: float) -> float:
    """Python's ``max(a, b)``: the first argument unless the second is strictly greater (NaN and signed zeros as
    Python has them)."""
    return b if b > a else a


@kernel("float64(float64, float64)")
def pmin(a: float, b: float) -> float:
    """Python's ``min(a, b)``: the first argument unless the second is strictly smaller."""
    return b if b < a else a


@kernel("float64(float64)")
def py_square(x: float) -> float:
    """CPython's ``x ** 2``: the C library's ``pow(x, 2.0)``. The exponent is computed (``2.0 + 0.0 * x`` is 2.0 for
    every finite x), so the compiler cannot replace the call by ``x * x``."""
    return x ** (2.0 + 0.0 * x)


_PAIRWISE_BLOCK = 128  # numpy's PW_BLOCKSIZE


@kernel("float64(float64[::1], int64, int64)")
def _pairwise(a: npt.NDArray[np.float64], start: int, n: int) -> float:
    if n < 8:
        res = 0.0
        for i in range(start, start + n):
            res += a[i]
        return res
    if n <= _PAIRWISE_BLOCK:
        r0, r1, r2, r3 = a[start], a[start + 1], a[start + 2], a[start + 3]
        r4, r5, r6, r7 = a[start + 4], a[start + 5], a[start + 6], a[start + 7]
        i = 8
        while i < n - (n % 8):
            j = start + i
            r0 += a[j]
            r1 += a[j + 1]
            r2 += a[j + 2]
            r3 += a[j + 3]
            r4 += a[j + 4]
            r5 += a[j + 5]
            r6 += a[j + 6]
            r7 += a[j + 7]
            i += 8
        res = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
        while i < n:
            res += a[start + i]
            i += 1
        return res
    n2 = n // 2
    n2 -= n2 % 8
    return _pairwise(a, start, n2) + _pairwise(a, start + n2, n - n2)


@kernel("float64(float64[::1])")
def np_sum(a: npt.NDArray[np.float64]) -> float:
    """``float(a.sum())`` for a contiguous float64 array, as numpy adds it up (0.0 + its pairwise sum)."""
    return 0.0 + _pairwise(a, 0, a.shape[0])
