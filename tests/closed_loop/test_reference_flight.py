"""The reference flight (tests/closed_loop/reference_flight.py) flies bit for bit as it did when recorded.

It exercises takeoff, goto, hold, offboard (position and attitude), offboard loss, a mission flown from the air and
one started on the ground, RTL, land and a critical battery. A change meant to leave behaviour alone (a refactor)
must leave these figures alone; a deliberate behaviour change re-records them and says why in its commit.
"""

from __future__ import annotations

import pytest

from tests.closed_loop.reference_flight import fly

pytestmark = pytest.mark.timeout(60)

RECORDED_STEPS = 15324
RECORDED_MOTOR_SHA256 = "d9125d72a2c72bb6acf22d082b98eed112c6584d4b08669aef03ba52cb389253"
RECORDED_FINAL_TRUTH = (
    -0.14816820763708108,
    -0.03302528371499439,
    -0.11632240770808266,
    1.77481394309418e-09,
    2.6263455233169194e-09,
    1.3875299546967983e-08,
    0.9998197398364845,
    -5.260992613803789e-10,
    2.3636168201499425e-08,
    0.01898651714516733,
)


def test_the_reference_flight_is_bit_identical_to_the_recorded_one() -> None:
    figures = fly()
    assert figures.steps == RECORDED_STEPS
    assert figures.final_truth == RECORDED_FINAL_TRUTH
    assert figures.motor_sha256 == RECORDED_MOTOR_SHA256
