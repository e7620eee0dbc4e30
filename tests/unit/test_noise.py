"""A noise stream hands out one seeded sequence whichever way its rows are taken (pure)."""

from __future__ import annotations

import random

import numpy as np
import pytest

from sitl.dynamics.noise import NoiseSource

pytestmark = pytest.mark.timeout(30)


def test_rows_come_in_the_seeds_order_whether_taken_as_floats_arrays_or_by_a_kernel_across_refills() -> None:
    # GIVEN the stream of a seed, and the blocks that seed gives
    source = NoiseSource(np.random.default_rng(5))
    rng = np.random.default_rng(5)
    expected = np.concatenate([rng.standard_normal((4096, 3)) for _ in range(4)])
    # WHEN its rows are taken in a random mix of the three ways, across three refills
    pick = random.Random(1)
    i = 0
    while i < 3 * 4096:
        way = pick.random()
        taken = source.take_rows(2) if way < 0.3 else None
        if taken is not None:  # a kernel reads two rows from the block itself
            block, first = taken
            assert block[first : first + 2].tolist() == expected[i : i + 2].tolist()
            i += 2
        elif way < 0.8:
            assert source.floats3() == tuple(expected[i].tolist()), i
            i += 1
        else:
            assert source.vec3().tolist() == expected[i].tolist(), i
            i += 1
    # THEN every row was the seed's, in order (the assertions above), and a float is a float
    assert all(type(v) is float for v in source.floats3())
