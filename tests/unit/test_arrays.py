"""The BLAS-free matrix products (gcs/flight/arrays.py, sitl/mathutil.py): ``@``'s answer, and the same bits on both
sides."""

from __future__ import annotations

import numpy as np
import pytest

from gcs.flight.arrays import mat_mul as ground_mat_mul
from sitl.mathutil import mat_mul as drone_mat_mul


@pytest.mark.parametrize("seed", range(5))
def test_both_products_give_the_answer_of_matmul_and_the_same_bits(seed: int) -> None:
    rng = np.random.default_rng(seed)
    rotation, points = rng.normal(size=(3, 3)), rng.normal(size=(40, 3))
    mask, velocities = rng.random((12, 12)) > 0.5, rng.normal(size=(12, 2))
    for a, b in ((rotation, rotation.T), (points, rotation), (mask, velocities)):
        ground, drone = ground_mat_mul(a, b), drone_mat_mul(a, b)
        assert ground.shape == drone.shape == (a @ b).shape
        np.testing.assert_allclose(ground, a @ b, rtol=0, atol=1e-12)
        assert ground.tobytes() == drone.tobytes()
    vector = rng.normal(size=3)
    np.testing.assert_allclose(ground_mat_mul(rotation, vector), rotation @ vector, rtol=0, atol=1e-12)
